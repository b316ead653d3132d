#!/usr/bin/env bash
# Set up a virtual environment and run the two drawer testers of
# configs/drawer_tester/plant_sim.yaml on simulated I/O, in real time, with the story of
# configs/drawer_tester/story.yaml playing their buttons and limit switches, and the
# console on a Unix socket in your own runtime directory, ${RUNTIME_DIR} of the plant file:
# $XDG_RUNTIME_DIR/softplc, else /tmp/softplc-$UID (created 0700; docs/daemon.md). The
# script prints the socket's path and the command for a second terminal, e.g.
#     .venv/bin/softplc monitor /run/user/1000/softplc/drawer.sock
# Stop with Ctrl-C (every output is written off). Extra arguments go to `softplc run`
# (e.g. --for 30s).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
plant=configs/drawer_tester/plant_sim.yaml
sock=$(.venv/bin/python -c 'import sys
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import locate
print(locate(load_plant(sys.argv[1])).console)' "$plant")
echo "run-demo: console on $sock; in a second terminal: .venv/bin/softplc monitor $sock" >&2
exec .venv/bin/softplc run "$plant" --sim --script configs/drawer_tester/story.yaml "$@"
