#!/usr/bin/env bash
# Regenerate the JSON Schemas editors read (configs/schema/grafcet.schema.json,
# plant.schema.json, script.schema.json, scenario.schema.json) from the declaration of
# each section of the files (runtime/language/shape.py; docs/language.md, "Files and their limits"). A test fails
# while the committed files differ from what this writes.
# Usage: scripts/make-schemas.sh [OUT_DIR]   (default configs/schema)
# PYTHON names the interpreter (default .venv/bin/python; set up by scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
"${PYTHON:-.venv/bin/python}" -m runtime.language.schemas "${1:-configs/schema}"
