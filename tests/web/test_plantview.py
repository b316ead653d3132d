"""The page's I/O list carries each signal's meaning from the plant's I/O list (issue 29)."""

from __future__ import annotations

from pathlib import Path

from runtime.language.plantfile import load_plant
from runtime.web.plantview import describe

ROOT = Path(__file__).resolve().parents[2]


def test_the_io_list_of_the_page_carries_the_descriptions_of_the_plant() -> None:
    """Before, the description column was empty for every signal."""
    plant = describe(load_plant(str(ROOT / "configs/drawer_tester/plant_sim.yaml")))
    rows = {row[0]: row for inst in plant["instances"] for row in inst["io"]}
    assert rows["tester1.iParo"][2] == "sim.I0 (inverted)"
    assert rows["tester1.iParo"][3] == "Pulsador de paro SJP (NC)"
    assert rows["tester1.oAbrir"][3] == "Contactor QAA, abrir el cajón"
    described = [r for r in rows.values() if r[1] in ("in", "out")]
    assert described and all(r[3] for r in described), [r for r in described if not r[3]]
