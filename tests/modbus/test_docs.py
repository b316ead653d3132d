"""docs/modbus.md's map of the drawer tester is what ``softplc modbus --map`` prints for
configs/drawer_tester/plant_sim.yaml with the section the page gives."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = (ROOT / "docs" / "modbus.md").read_text(encoding="utf-8")


def blocks(lang: str) -> list[str]:
    """The page's fenced blocks of language ``lang`` ("" for none), in order."""
    out: list[str] = []
    current: list[str] | None = None
    kind = ""
    for line in DOC.splitlines(keepends=True):
        if line.startswith("```"):
            if current is None:
                current, kind = [], line[3:].strip()
            else:
                if kind == lang:
                    out.append("".join(current))
                current = None
        elif current is not None:
            current.append(line)
    return out


def test_the_pages_map_of_the_drawer_tester_is_the_commands(tmp_path: Path) -> None:
    section = next(b for b in blocks("yaml") if "tester1.sCierres: IR0" in b)
    shown = next(b for b in blocks("") if b.startswith("ref "))
    d = ROOT / "configs" / "drawer_tester"
    shutil.copy(d / "drawer_tester.yaml", tmp_path / "drawer_tester.yaml")
    text = (d / "plant_sim.yaml").read_text(encoding="utf-8")
    (tmp_path / "plant_sim.yaml").write_text(text + section, encoding="utf-8")
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "modbus", "--map",
                        str(tmp_path / "plant_sim.yaml")], capture_output=True, text=True,
                       cwd=ROOT, timeout=120, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout == shown
