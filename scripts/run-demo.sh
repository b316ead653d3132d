#!/usr/bin/env bash
# Set up a virtual environment and run the drawer-tester plant on simulated I/O with the console.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e .
exec .venv/bin/softplc run configs/drawer_tester/plant_sim.yaml --sim "$@"
