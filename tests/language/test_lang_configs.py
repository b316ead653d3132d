"""Every grafcet and plant file in configs/ compiles (``softplc compile``), and ``--show``
prints readable generated source: one scan function per chart, with the chart's names."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.cli import main
from runtime.language.filekind import file_kind
from runtime.language.grafcetfile import load_grafcet

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted(p for p in (ROOT / "configs").glob("*/*.yaml")
               if file_kind(str(p)) in ("grafcet", "plant"))


def test_the_configs_hold_charts_and_plants() -> None:
    kinds = [file_kind(str(p)) for p in FILES]
    assert kinds.count("grafcet") >= 6 and kinds.count("plant") >= 8


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(ROOT)) for p in FILES])
def test_config_compiles(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["compile", str(path)]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"{path}: ok: ") and " compiled in " in err


@pytest.mark.parametrize("path", [p for p in FILES if file_kind(str(p)) == "grafcet"],
                         ids=lambda p: p.name)
def test_show_prints_the_scan_with_the_charts_names(path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["compile", str(path), "--show"]) == 0
    src = capsys.readouterr().out
    g = load_grafcet(str(path))
    # one factory per chart, one scan closure per instance (docs/semantics.md)
    assert src.count("def make(m, init):") == 1 and src.count("    def scan(now, up") == 1
    assert f"grafcet {g.name}" in src
    for step in g.steps:
        assert step in src
    for t in g.transitions:  # each transition is commented with its condition as written
        assert t.text.replace("\n", " ") in src
    compile(src, str(path), "exec")  # what is printed is the Python that runs
