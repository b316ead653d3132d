#!/usr/bin/env bash
# The kernel_io test tier (tests/kernel_io, docs/testing.md): the drivers against a real
# Linux kernel's GPIO character device (gpio-sim), i2c-dev (i2c-stub) and SocketCAN (vcan),
# and retained data across a power cut (dm-log-writes), in one QEMU guest running Debian's
# kernel on this machine's root.
#
# Installs what it needs from Debian's packages (as root), builds and caches the guest's
# kernel (Debian's linux-image, unpacked: the host's own kernel and /boot are never
# touched), gpio-sim.ko (Debian's kernels do not ship it: built from linux-source against
# the matching headers), the uncompressed vmlinux and the initramfs; boots the guest with a
# hard time limit, runs tests/kernel_io/guest/run.sh in it and exits with its status.
#
# Usage: scripts/kernel-io.sh [PYTEST ARGS...]   (the tests named there, else the whole tier)
# Environment:
#   KIO_CACHE    the cache directory (default build/kernel-io; remove it to take a newer
#                kernel)
#   KIO_TIMEOUT  seconds the guest may run before it is killed and the tier fails (1200)
#   KIO_SMP, KIO_MEM  the guest's processors (2) and memory in MiB (1536)
# Exit status: the tier's (pytest's); 124 the guest did not finish in time (killed); 125
# the guest left no status (it crashed or failed to boot); 3 the tier could not be
# prepared. Where this machine cannot run it (something missing and neither root nor
# password-less sudo to install it, or no apt) it says why and exits 0, unless CI is set:
# then 3, so CI fails loudly rather than skipping the tier (.ci/run sets KIO_REQUIRED to
# the same effect where CI is not set).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
CACHE=${KIO_CACHE:-$ROOT/build/kernel-io}
TIMEOUT=${KIO_TIMEOUT:-1200}
export DEBIAN_FRONTEND=noninteractive
say() { echo "kernel-io: $*" >&2; }
cannot() {  # this machine cannot run the tier
  say "cannot run: $*"
  if [ -n "${CI:-}${KIO_REQUIRED:-}" ]; then exit 3; fi
  say "skipped (outside CI)"; exit 0
}
start=$(date +%s.%N)
since() { printf '%.1f' "$(echo "$(date +%s.%N) - $1" | bc)"; }
cpu() {  # processor time of this script's finished children (user + system), s
  local stat
  read -r stat < "/proc/$$/stat"
  set -- ${stat##*) }  # from the state on: cutime and cstime are the 14th and 15th
  echo "scale=1; (${14} + ${15}) / $(getconf CLK_TCK)" | bc
}

# -- what the host needs --------------------------------------------------------------------
# the guest's root is this machine's: what its tests run (ip, dmsetup, mkfs.ext4, losetup)
# comes from here too
PKGS="qemu-system-x86 busybox-static cpio dmsetup e2fsprogs kmod make gcc binutils xz-utils
      iproute2 bc"
apt_ready=0 SUDO=""
can_apt() {  # root, or password-less sudo (SUDO is then "sudo"), and apt
  command -v apt-get >/dev/null || return 1
  if [ "$(id -u)" = 0 ]; then SUDO=""; return 0; fi
  command -v sudo >/dev/null && sudo -n true 2>/dev/null && SUDO="sudo -n"
}
apt_install() {
  can_apt || cannot "needs apt and root (or password-less sudo) to install $*"
  if [ $apt_ready = 0 ]; then $SUDO apt-get update -qq; apt_ready=1; fi
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}
missing=()
for p in $PKGS; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  say "installing ${missing[*]}"
  apt_install "${missing[@]}"
fi

# -- the kernel: Debian's, the release linux-image-amd64 points at --------------------------
mkdir -p "$CACHE"
KVER=$(cat "$CACHE/kver" 2>/dev/null || true)
if [ -z "$KVER" ] || [ ! -f "$CACHE/$KVER/ready" ]; then
  can_apt || cannot "needs apt and root (or password-less sudo) to fetch the kernel"
  pick() { apt-cache depends linux-image-amd64 2>/dev/null | sed -n 's/.*Depends: linux-image-\(.*\)/\1/p' | head -1; }
  KVER=$(pick)
  if [ -z "$KVER" ]; then $SUDO apt-get update -qq; apt_ready=1; KVER=$(pick); fi
  [ -n "$KVER" ] || cannot "apt knows no linux-image-amd64"
fi
K=$CACHE/$KVER
MODS=$K/tree/lib/modules/$KVER
if [ ! -f "$K/ready" ]; then
  say "preparing kernel $KVER in $K"
  rm -rf "$K"; mkdir -p "$K/dl"
  dpkg -s "linux-headers-$KVER" >/dev/null 2>&1 || apt_install "linux-headers-$KVER"
  # the image, unpacked
  (cd "$K/dl" && apt-get download -q "linux-image-$KVER" 2>&1 | grep -v '^W: Download is performed unsandboxed' || true)
  deb=$(ls "$K"/dl/linux-image-"$KVER"_*.deb)
  dpkg-deb -x "$deb" "$K/tree"
  version=$(dpkg-deb -f "$deb" Version)          # 6.1.192-2
  series=$(echo "$KVER" | cut -d. -f1,2)          # 6.1
  # the sources of gpio-sim and irq_sim, and the kernel's extract-vmlinux: from
  # linux-source of the same version when the archive still has it, else the newest
  (cd "$K/dl" && { apt-get download -q "linux-source-$series=$version" 2>/dev/null ||
                   apt-get download -q "linux-source-$series" 2>&1; } |
     grep -v '^W: Download is performed unsandboxed' || true)
  src=$(ls "$K"/dl/linux-source-"$series"_*.deb) || cannot "no linux-source-$series"
  dpkg-deb --fsys-tarfile "$src" | tar -x -C "$K/dl" --wildcards '*/linux-source-*.tar.xz'
  mkdir -p "$K/src"
  tar -xJf "$K/dl/usr/src/linux-source-$series.tar.xz" -C "$K/src" --strip-components=1 \
    "linux-source-$series/drivers/gpio/gpio-sim.c" "linux-source-$series/drivers/gpio/gpiolib.h" \
    "linux-source-$series/kernel/irq/irq_sim.c" "linux-source-$series/scripts/extract-vmlinux"
  rm -rf "$K/dl"
  # gpio-sim.ko: the driver with the interrupt simulator linked into the same module
  # (Debian builds neither). irq_sim.c calls irq_to_desc(), which modules cannot: it hands
  # the interrupt to the handler set when it was mapped, which generic_handle_irq() does too.
  b=$K/gpio-sim-build; mkdir -p "$b"
  cp "$K/src/drivers/gpio/gpio-sim.c" "$b/gpio-sim-main.c"
  cp "$K/src/drivers/gpio/gpiolib.h" "$b/"
  sed 's/handle_simple_irq(irq_to_desc(\([a-z_]*\)));/generic_handle_irq(\1);/' \
    "$K/src/kernel/irq/irq_sim.c" > "$b/irq_sim.c"
  grep -q 'generic_handle_irq(' "$b/irq_sim.c" || cannot "irq_sim.c of $KVER is not as expected"
  printf 'obj-m := gpio-sim.o\ngpio-sim-y := gpio-sim-main.o irq_sim.o\n' > "$b/Kbuild"
  make -s -C "/lib/modules/$KVER/build" M="$b" modules >/dev/null
  mkdir -p "$MODS/extra"
  cp "$b/gpio-sim.ko" "$MODS/extra/"
  rm -rf "$b"
  depmod -b "$K/tree" "$KVER"
  # the uncompressed ELF kernel: QEMU starts it at its PVH entry (no BIOS, no
  # decompression under emulation: about half the boot time)
  sh "$K/src/scripts/extract-vmlinux" "$K/tree/boot/vmlinuz-$KVER" > "$K/vmlinux"
  echo "$KVER" > "$CACHE/kver"
  touch "$K/ready"
  say "kernel $KVER prepared in $(since "$start") s"
fi

# -- the initramfs: busybox, the modules that mount the root, the init (rebuilt each run) ---
w=$(mktemp -d "${TMPDIR:-/tmp}/kernel-io.XXXXXX")
job=$w/job
trap 'rm -rf "$w"' EXIT
ir=$w/initramfs
mkdir -p "$ir"/{bin,dev,proc,sys,lower,rw,root,job,mods} "$job"
cp "$(command -v busybox)" "$ir/bin/busybox"
for a in sh mount insmod mkdir cat echo chroot cut sync poweroff; do ln -s busybox "$ir/bin/$a"; done
order=" "
add_module() {  # add MODULE to the initramfs after the modules it depends on
  local f dep
  case $order in *" $1 "*) return;; esac
  f=$(modinfo -b "$K/tree" -k "$KVER" -n "$1") || { say "no module $1 in $KVER"; exit 3; }
  for dep in $(modinfo -F depends "$f" | tr , ' '); do add_module "$dep"; done
  cp "$f" "$ir/mods/$1.ko"
  order="$order$1 "
}
for m in virtio_pci 9pnet_virtio 9p overlay; do add_module "$m"; done
echo "$order" > "$ir/mods/order"
cp tests/kernel_io/guest/init "$ir/init"
chmod 755 "$ir/init"
(cd "$ir" && find . | cpio -o -H newc --quiet) | gzip -1 > "$w/initramfs.gz"

# -- the job: the tier, from this directory, with the kernel's modules at hand ----------------
{
  echo "export PATH='$PATH' HOME=/root LANG=C.UTF-8 KIO_MODULES='$K/tree' CI='${CI:-}'"
  # the tests' own settings (SOFTPLC_POWER_CUT_SAVES...) go along
  env | grep -E '^SOFTPLC_[A-Z0-9_]*=' | sed "s/'/'\\\\''/g; s/^\([^=]*\)=\(.*\)\$/export \1='\2'/" || true
  printf 'cd %q && exec sh tests/kernel_io/guest/run.sh' "$ROOT"
  for a in "$@"; do printf ' %q' "$a"; done
  echo
} > "$job/run"
say "prepared in $(since "$start") s; booting $KVER (at most $TIMEOUT s)"

# -- the guest --------------------------------------------------------------------------------
boot=$(date +%s.%N)
cpu0=$(cpu)
rc=0
timeout -k 10 "$TIMEOUT" qemu-system-x86_64 -M pc -accel tcg,thread=multi \
  -smp "${KIO_SMP:-2}" -m "${KIO_MEM:-1536}" \
  -nographic -nodefaults -no-reboot -serial stdio \
  -kernel "$K/vmlinux" -initrd "$w/initramfs.gz" \
  -append "console=ttyS0 quiet loglevel=3 panic=-1 mitigations=off no_timer_check" \
  -fsdev local,id=root,path=/,security_model=none,readonly=on,multidevs=remap \
  -device virtio-9p-pci,fsdev=root,mount_tag=root \
  -fsdev local,id=job,path="$job",security_model=none \
  -device virtio-9p-pci,fsdev=job,mount_tag=job </dev/null || rc=$?
if [ $rc = 124 ] || [ $rc = 137 ]; then
  say "FAILED: the guest did not finish within $TIMEOUT s (KIO_TIMEOUT): killed"
  exit 124
fi
if [ ! -f "$job/status" ]; then
  say "FAILED: the guest left no status (qemu exit $rc after $(since "$boot") s): it crashed or did not boot"
  exit 125
fi
status=$(cat "$job/status")
if [ -s "$job/report" ]; then sed 's/^/kernel-io: /' "$job/report" >&2; fi
say "guest ran $(since "$boot") s (QEMU used $(echo "$(cpu) - $cpu0" | bc) s of processor time), status $status; $(since "$start") s in all"
exit "$status"
