#!/usr/bin/env bash
# Set up a virtual environment and run the two-drawer-tester plant on simulated I/O,
# with its console on a local socket (connect with: .venv/bin/softplc monitor out/console.sock).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
mkdir -p out
exec .venv/bin/softplc run configs/drawer_tester/plant_sim.yaml --sim "$@"
