#!/usr/bin/env bash
# Set up a virtual environment with every test dependency and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
# Optional system tools some tests use (systemd-analyze for the unit, graphviz for draw,
# socat for pty pairs); tests skip with a reason where a tool is missing.
if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  missing=""
  command -v systemd-analyze >/dev/null || missing="$missing systemd"
  command -v dot >/dev/null || missing="$missing graphviz"
  command -v socat >/dev/null || missing="$missing socat"
  command -v ip >/dev/null || missing="$missing iproute2"
  if [ -n "$missing" ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null || \
      echo "test.sh: could not install:$missing (the tests that need them will skip)" >&2
  fi
fi
scripts/setup.sh test
exec .venv/bin/python -m pytest "$@"
