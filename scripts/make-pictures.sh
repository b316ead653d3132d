#!/usr/bin/env bash
# Regenerate the pictures of README.md from the drawer tester of seed 000:
#   docs/img/drawer_tester.svg  the chart (softplc draw, IEC 60848 style)
#   docs/img/drawer_story.svg   tester1 in configs/drawer_tester/story.yaml, 0-4 s
#                               (softplc simulate --trace, then softplc chronogram)
#   docs/img/web-page.png, web-forced.png  the web view (docs/web.md), with --web: taken
#                               by tests/web/test_browser.py in a real chromium
# Usage: scripts/make-pictures.sh [--web] [OUT_DIR]   (default docs/img)
# SOFTPLC names the command to run (default .venv/bin/softplc; set up by scripts/setup.sh).
# The chart uses the built-in layout so that the picture does not depend on whether
# Graphviz is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
read -r -a softplc <<< "${SOFTPLC:-.venv/bin/softplc}"
web=0
if [ "${1:-}" = "--web" ]; then web=1; shift; fi
out="${1:-docs/img}"
mkdir -p "$out"
if [ "$web" = 1 ]; then
  SOFTPLC_PICTURES="$(realpath "$out")" .venv/bin/python -m pytest -q -p no:cacheprovider \
      tests/web/test_browser.py -k "step_becoming_active or force_from_the_page"
fi
trace="$(mktemp --suffix=.jsonl)"
trap 'rm -f "$trace"' EXIT

"${softplc[@]}" draw configs/drawer_tester/drawer_tester.yaml --layout python \
    -o "$out/drawer_tester.svg"
"${softplc[@]}" simulate configs/drawer_tester/plant_sim.yaml \
    --script configs/drawer_tester/story.yaml --trace "$trace"
"${softplc[@]}" chronogram "$trace" --plant configs/drawer_tester/plant_sim.yaml \
    --signals tester1.iMarcha tester1.iParo tester1.iAbierto tester1.iCerrado \
              'tester1.gs*.X' tester1.oAbrir tester1.oCerrar tester1.oParado tester1.oTest \
              tester1.sParo tester1.sCierres \
    --from 0 --to 4s --width 900 \
    --title "Drawer tester 1: start, four strokes, stop at the end of a cycle, restart" \
    -o "$out/drawer_story.svg"
