"""The command line imports what the command it runs needs: ``softplc compile`` does not
pay for the checker, the drawing, the console or the package metadata (issue 30: building
the argument parser cost 0.48 s of a 1000-step compile)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: modules only other commands need
OTHERS = ("runtime.checker.check", "runtime.drawing.chart", "runtime.drawing.chronogram",
          "runtime.console.monitor", "runtime.controller.install", "importlib.metadata",
          "runtime.console.links", "runtime.console.client", "runtime.console.view")

CHILD = """
import sys
from runtime.cli import main
rc = main(sys.argv[1:])
sys.stderr.write("MODULES " + " ".join(sorted(sys.modules)) + "\\n")
sys.exit(rc)
"""



def imported(*argv: str) -> tuple[int, set[str]]:
    """(exit status, the modules imported) of ``softplc ARGV`` in a fresh interpreter."""
    r = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True,
                       text=True, cwd=ROOT, timeout=120, check=False)
    line = next(x for x in r.stderr.splitlines() if x.startswith("MODULES "))
    return r.returncode, set(line.split()[1:])


def test_compile_imports_no_other_command(level: str) -> None:
    rc, modules = imported("compile", level)
    assert rc == 0
    assert "runtime.compiler.codegen" in modules  # what it needs, it has
    assert sorted(m for m in OTHERS if m in modules) == []


def test_check_imports_its_own_module_only(level: str) -> None:
    rc, modules = imported("check", "-q", level)
    assert rc == 0
    assert "runtime.checker.check" in modules
    assert sorted(m for m in OTHERS[1:] if m in modules) == []


def test_help_and_a_wrong_command_still_list_every_command() -> None:
    for argv in (["--help"], ["chek"]):
        r = subprocess.run([sys.executable, "-m", "runtime.cli", *argv], capture_output=True,
                           text=True, cwd=ROOT, timeout=120, check=False)
        for name in ("compile", "check", "draw", "chronogram", "install-service", "monitor"):
            assert name in r.stdout + r.stderr, (argv, name)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "draw", "--help"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120, check=False)
    assert (r.returncode, "--layout" in r.stdout) == (0, True)
