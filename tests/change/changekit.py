"""Online-change test kit: the drawer story on a virtual clock, and the expected state of a
new plant written by hand (key by key through the programs' slot descriptions), never by
``apply``."""

from __future__ import annotations

import copy
from collections import defaultdict
from pathlib import Path
from typing import Any

from runtime.engine.plant import Plant
from runtime.engine.script import Event, load_script
from runtime.engine.trace import trace_columns
from runtime.language.model import PlantDef
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import version_of

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parent / "data"
DRAWER_PLANT = str(ROOT / "configs/drawer_tester/plant_sim.yaml")


def without_web(text: str) -> str:
    """The demo plant's text without its ``web:`` section (its last): a plant with no feed,
    as the side sections' tests start from."""
    return text.split("\nweb:\n")[0] + "\n"
STORY = str(ROOT / "configs/drawer_tester/story.yaml")


def data_plant(edit: str) -> str:
    """The drawer plant on one of the edited charts of tests/change/data."""
    return str(DATA / f"plant_{edit}.yaml")


def version(path: str, old: Plant) -> PlantDef:
    """The plant file ``path`` loaded as a new version of ``old``'s plant, as ``softplc
    diff`` and ``reload`` load one: its ``${RUNTIME_DIR}`` is the running plant's, wherever
    the file is kept (tests/change/data holds edited copies of the drawer plant)."""
    with version_of(old.pdef.path):
        return load_plant(path)


def sim_plant(path: str) -> Plant:
    plant = Plant(load_plant(path), sim=True, virtual=True)
    plant.open()
    return plant


class Story:
    """A plant driven by the drawer story: scan k at t = k·cycle; a change at time t is
    seen by the first scan at t or later."""

    def __init__(self, plant: Plant, script: str = STORY) -> None:
        self.plant = plant
        self.k = 0
        self.by_scan: dict[int, list[Event]] = defaultdict(list)
        self.bind(plant, script)

    def bind(self, plant: Plant, script: str = STORY) -> None:
        """Write the story's changes into ``plant`` from now on (after a swap)."""
        self.plant = plant
        self.by_scan.clear()
        cyc = plant.cycle_ns
        for e in load_script(script, plant)[2]:
            self.by_scan[-(-e.at_ns // cyc)].append(e)

    def run(self, n: int) -> list[dict[str, Any]]:
        """``n`` scans; the trace row (every instance value and point) of each."""
        cols = trace_columns(self.plant)
        rows = []
        for _ in range(n):
            for e in self.by_scan.get(self.k, ()):
                e.apply()
            self.plant.cycle(self.k * self.plant.cycle_ns)
            rows.append({"k": self.k, **{key: get() for key, get in cols}})
            self.k += 1
        return rows


def write_state(old: Plant, new: Plant) -> None:
    """By hand: every slot of ``new`` whose key the old program has takes the old value
    (a copy of a block), every driver image and the program time are copied."""
    for name, inst in new.instances.items():
        o = old.instances.get(name)
        if o is None:
            continue
        oslots = {s.key: s for s in o.program.slots}
        for s in inst.program.slots:
            os_ = oslots.get(s.key)
            if os_ is not None and os_.block == s.block:
                v = o.m[os_.index]
                inst.m[s.index] = copy.copy(v) if s.block else v
    for name, d in new.drivers.items():
        od = old.drivers[name]
        d.inputs.update({p: v for p, v in od.inputs.items() if p in d.inputs})
        d.outputs.update({p: v for p, v in od.outputs.items() if p in d.outputs})
    new.start = old.start
    new.last_up = old.last_up
    new.scans = old.scans


def state(plant: Plant) -> dict[str, list[Any]]:
    """Every instance's state list, blocks as their attribute dicts (comparable)."""
    out = {}
    for name, inst in plant.instances.items():
        out[name] = [_plain(v) for v in inst.m]
    return out


def _plain(v: Any) -> Any:
    if hasattr(v, "__dict__"):
        return (type(v).__name__, dict(vars(v)))
    if hasattr(v, "__slots__"):
        return (type(v).__name__, {k: getattr(v, k) for k in v.__slots__ if hasattr(v, k)})
    return v
