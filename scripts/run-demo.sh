#!/usr/bin/env bash
# Set up a virtual environment and run the two drawer testers of
# configs/drawer_tester/plant_sim.yaml on simulated I/O, in real time, with the story of
# configs/drawer_tester/story.yaml playing their buttons and limit switches, and the
# console on the Unix socket /tmp/softplc/drawer.sock. In a second terminal:
#     .venv/bin/softplc monitor /tmp/softplc/drawer.sock
# Stop with Ctrl-C (every output is written off). Extra arguments go to `softplc run`
# (e.g. --for 30s).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec .venv/bin/softplc run configs/drawer_tester/plant_sim.yaml --sim \
    --script configs/drawer_tester/story.yaml "$@"
