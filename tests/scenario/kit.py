"""Helpers of the scenario tests: scenario files written beside the test, run in this
process or through ``softplc test``."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from runtime.cli import main
from runtime.scenario.run import Outcome, run_scenario

ROOT = Path(__file__).resolve().parents[2]
DRAWER = ROOT / "configs" / "drawer_tester"
PLANT = DRAWER / "plant_sim.yaml"

#: tester1 started at 500 ms, one opening stroke (500-800 ms), one closing (800-1100 ms),
#: opening again from 1100 ms to the end (2 s); tester2 stays stopped (PARO held)
STORY = f"""plant: {PLANT}
duration: 2s
set:
  - {{at: 0ms, sim.I0: 1, tester1.iCerrado: 1}}
  - {{at: 500ms, tester1.iMarcha: 1}}
  - {{at: 600ms, tester1.iCerrado: 0}}
  - {{at: 700ms, tester1.iMarcha: 0}}
  - {{at: 800ms, tester1.iAbierto: 1}}
  - {{at: 900ms, tester1.iAbierto: 0}}
  - {{at: 1100ms, tester1.iCerrado: 1}}
expect:
"""


def write(tmp: Path, expect: list[str], head: str = STORY, name: str = "s.test.yaml"
          ) -> tuple[Path, list[int]]:
    """The scenario ``head`` + ``expect`` (one entry a line) at ``tmp/name``, and the line
    of each entry."""
    path = tmp / name
    first = head.count("\n") + 1
    path.write_text(head + "".join(f"  - {e}\n" for e in expect), encoding="utf-8")
    return path, list(range(first, first + len(expect)))


def run(tmp: Path, expect: list[str], head: str = STORY) -> tuple[Outcome, Path, list[int]]:
    path, lines = write(tmp, expect, head)
    return run_scenario(str(path)), path, lines


def cli(*argv: str) -> tuple[int, str]:
    """``softplc ARGV`` in this process: (exit status, standard output)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = main(list(argv))
    return status, out.getvalue()
