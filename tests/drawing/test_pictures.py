"""The README's pictures can be regenerated: scripts/make-pictures.sh writes the drawer
tester's chart and a chronogram of tester1 in its story (what the pictures show is checked,
not their bytes), and README.md shows the committed ones."""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from runtime.language.grafcetfile import load_grafcet

ROOT = Path(__file__).resolve().parents[2]
SVG = "{http://www.w3.org/2000/svg}"


def texts(path: Path) -> list[str]:
    root = ET.parse(path).getroot()
    assert root.tag == f"{SVG}svg"
    return ["".join(t.itertext()) for t in root.iter(f"{SVG}text")]


def signal_keys(path: Path) -> list[str]:
    root = ET.parse(path).getroot()
    return [t.get("data-key", "") for t in root.iter(f"{SVG}text") if t.get("class") == "signal"]


def test_make_pictures_regenerates_both(tmp_path: Path) -> None:
    env = dict(os.environ, SOFTPLC=f"{sys.executable} -m runtime.cli")
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "make-pictures.sh"), str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    chart, story = tmp_path / "drawer_tester.svg", tmp_path / "drawer_story.svg"
    found = texts(chart)
    g = load_grafcet(str(ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml"))
    assert all(s in found for s in g.steps)
    assert all(t.text in found for t in g.transitions)
    keys = signal_keys(story)
    assert keys[:4] == ["tester1.iMarcha", "tester1.iParo", "tester1.iAbierto",
                        "tester1.iCerrado"]
    assert {f"tester1.{s}.X" for s in g.steps} <= set(keys)
    assert not [k for k in keys if not k.startswith("tester1.")]
    ticks = [t for t in texts(story) if t == "0" or t.endswith((" ms", " s"))]
    assert ticks[0] == "0" and ticks[-1] == "4 s"  # the window of the script
    # the committed pictures are what the script writes (same content, whatever the bytes)
    for name in ("drawer_tester.svg", "drawer_story.svg"):
        assert texts(ROOT / "docs" / "img" / name) == texts(tmp_path / name), name


def test_readme_shows_the_pictures() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme.split("## Pictures", 1)[1].split("\n## ", 1)[0]
    assert "](docs/img/drawer_tester.svg)" in section
    assert "](docs/img/drawer_story.svg)" in section
    assert "scripts/make-pictures.sh" in section
    assert readme.index("## Pictures") < readme.index("## Performance")
