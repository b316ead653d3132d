"""The default ``plc: watchdog`` (a plant without one, as ``softplc import`` writes them) is
the figure docs/daemon.md chose from ``python -m bench.sidestart``: longer than the worst
scan lateness measured while a side process starts on a loaded 2-core machine (694 ms at
normal priority; 100 ms, the default before, faulted such a controller when its OPC UA
server started). The editors' schema and docs/language.md say the same default."""

from __future__ import annotations

import json
from pathlib import Path

from drivers.durations import format_ns
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import CHART

ROOT = Path(__file__).resolve().parents[2]


def test_a_plant_without_a_watchdog_gets_the_measured_default(tmp_path: Path) -> None:
    (tmp_path / "runner.yaml").write_text(CHART, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(
        "drivers:\n  io: {type: sim}\ninstances:\n  m:\n    grafcet: runner.yaml\n"
        "    inputs: {iGo: io.I0}\n    outputs: {oRun: io.Q0, oLamp: io.Q1}\n",
        encoding="utf-8")
    ns = load_plant(str(tmp_path / "plant.yaml")).watchdog_ns
    assert ns == 1_000_000_000
    said = format_ns(ns)
    schema = json.loads((ROOT / "configs/schema/plant.schema.json").read_text("utf-8"))
    assert schema["properties"]["plc"]["properties"]["watchdog"]["description"].endswith(
        f"({said}).")
    language = (ROOT / "docs/language.md").read_text("utf-8")
    assert f"`watchdog` (a longer scan is a fault, default {said}:" in language
    assert f"watchdog is {said} by default" in (ROOT / "docs/daemon.md").read_text("utf-8")
