#!/bin/sh
# Inside the kernel_io guest (scripts/kernel-io.sh boots it and runs this from the project's
# directory): load the kernel's modules the tier uses, make the wired gpio-sim pair and
# name the i2c-stub chip for the two opt-in real-device tests of tests/drivers, and run
# the tier. A test that skips here fails the run (tests/kernel_io/noskip.py).
# Usage: run.sh [PYTEST ARGS...]   (the tests named there, else tests/kernel_io and the two
#   real-device tests)
# Environment: KIO_MODULES, the unpacked kernel package (its lib/modules/RELEASE).
set -eu
up() { cut -d' ' -f1 /proc/uptime; }
echo "kernel-io guest: $(uname -r), $(nproc) processors, up $(up) s"
M=${KIO_MODULES:?the kernel package unpacked}
# temporary files and the controllers' runtime directories in the guest's own /run, not in
# the host's /tmp seen through the overlay
mkdir -p /run/kio-tmp /run/user/0
chmod 700 /run/user/0
export TMPDIR=/run/kio-tmp XDG_RUNTIME_DIR=/run/user/0
# what the kernel loads by itself (a crypto algorithm for ext4, a block driver) comes from
# there too
printf '#!/bin/sh\nexec /sbin/modprobe -d %s "$@"\n' "$M" > /run/kio-modprobe
chmod 755 /run/kio-modprobe
echo /run/kio-modprobe > /proc/sys/kernel/modprobe
# gpio-sim (built by scripts/kernel-io.sh), i2c-stub with two chips behind i2c-dev, vcan
# and raw CAN sockets, and for the power cut: loop devices, dm-log-writes, ext4
for m in configfs gpio-sim i2c-dev "i2c-stub chip_addr=0x20,0x21" can-raw vcan loop \
         dm-log-writes ext4; do
  # shellcheck disable=SC2086 # a module and its parameters
  modprobe -d "$M" $m
done
grep -q ' /sys/kernel/config ' /proc/mounts || mount -t configfs configfs /sys/kernel/config
# the real-chip loop-back test: line 0 (its output) wired to line 1 (its input)
W=/sys/kernel/config/gpio-sim/kio-wired
mkdir "$W" "$W/bank0"
echo 8 > "$W/bank0/num_lines"
echo kio-wired > "$W/bank0/label"
echo 1 > "$W/live"
chip=$(cat "$W/bank0/chip_name")
.venv/bin/python -I -S tests/kernel_io/simwire.py "/sys/devices/platform/$(cat "$W/dev_name")/$chip" 0 1 &
wire=$!
bus=""
for a in /sys/bus/i2c/devices/i2c-*; do
  [ "$(cat "$a/name")" = "SMBus stub driver" ] && bus=${a##*/i2c-}
done
[ -n "$bus" ] || { echo "kernel-io guest: no i2c-stub adapter" >&2; exit 3; }
# KIO_REPORT: lines of results the tests leave for the host to show (the job's share)
export SOFTPLC_KERNEL_IO=guest SOFTPLC_TEST_GPIO="/dev/$chip:0:1" \
  SOFTPLC_TEST_I2C="mcp23017:$bus:0x21" KIO_REPORT=/run/kio-job/report
echo "kernel-io guest: devices ready at $(up) s (wired pair /dev/$chip 0->1, i2c-stub on /dev/i2c-$bus)"
# the tests: those named among the arguments (a path, with ::NAME or not), else the tier
named=0
for a in "$@"; do [ -e "${a%%::*}" ] && named=1; done
[ $named = 1 ] || set -- "$@" tests/kernel_io tests/drivers/test_gpio.py::test_real_chip_loopback \
  tests/drivers/test_i2c.py::test_real_expander_inputs
status=0
# faulthandler: a test stuck for 300 s prints every thread's stack (the host's time limit
# then ends the guest)
# (hypothesis's and anyio's pytest plugins are not loaded: no test here uses them, and
# they took half of pytest's start-up under emulation)
.venv/bin/python -m pytest -p no:cacheprovider -p no:hypothesispytest -p no:anyio \
  -p tests.kernel_io.noskip -rs --color=no \
  -o faulthandler_timeout=300 --durations=10 "$@" || status=$?
kill "$wire" 2>/dev/null || true
echo "kernel-io guest: tier done at $(up) s, status $status"
exit $status
