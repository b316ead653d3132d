"""A scenario skeleton for a plant (``softplc import --scenario``): every input a scenario
may set, at 0 at the start; the initial steps, active in cycle 0; every output, to be
expected, as comments. It runs and passes as written (``softplc test DIR``): the person
fills in the story (docs/testing-charts.md, "A skeleton for an imported chart").

This module reads a plant and writes text; it imports only the language (so the PLCopen
import, which may not import the engine, can use it)."""

from __future__ import annotations

import os

from runtime.language import ast as A
from runtime.language.model import PlantDef, VarKind
from runtime.language.plantfile import load_plant

T = A.Type
#: the skeleton's file name, beside the plant the import writes (plant.yaml)
SKELETON = "plant.test.yaml"
#: a value of each type a script may write
_ZERO = {T.BOOL: "0", T.INT: "0", T.REAL: "0.0", T.TIME: "0"}


def skeleton_text(pdef: PlantDef, plant_file: str, header: list[str]) -> str:
    """The skeleton of a scenario of ``pdef`` (written as ``plant_file``, relative to the
    scenario), ``header`` its first comment lines."""
    lines = [f"# {h}" for h in header]
    lines += [f"plant: {plant_file}", "duration: 10s", "set:", "  - at: 0ms"]
    inputs, outputs, initial = [], [], []
    for name, idef in pdef.instances.items():
        g = idef.grafcet
        for v in g.variables.values():
            if v.kind is VarKind.INPUT and v.type in _ZERO:
                b = idef.inputs.get(v.name)
                if b is not None and b.driver is None:  # fed by another instance
                    continue
                where = f" <- {b.source}{' (inverted)' if b.invert else ''}" if b else ""
                inputs.append(f"    {name}.{v.name}: {_ZERO[v.type]}  # {v.type.value}{where}")
            elif v.kind is VarKind.OUTPUT:
                outputs.append(f"  #     {name}.{v.name}: {_ZERO.get(v.type, '...')}  "
                               f"# {v.type.value}")
        initial += [f"{name}.{s.name}.X: 1" for s in g.leaf_steps() if s.initial]
    lines += inputs or ["    # (no input to set)"]
    lines += ["  # - {at: 1s, INSTANCE.INPUT: 1}", "expect:"]
    if initial:
        lines.append(f"  - {{cycle: 0, expect: {{{', '.join(initial)}}}}}  "
                     "# the initial situation")
    else:
        lines.append("  - {cycle: 0, expect: {}}  # fill in")
    lines += ["  # - at: 1s", "  #   expect:"] + outputs
    lines += ["  # - {from: 0s, to: 5s, never: {INSTANCE.OUTPUT1: 1, INSTANCE.OUTPUT2: 1}}",
              "  # - {on_rise: INSTANCE.INPUT, expect: {INSTANCE.STEP.X: 1}}",
              "  # - {from: 0s, rises: {INSTANCE.OUTPUT: 3}}"]
    return "\n".join(lines) + "\n"


def write_skeleton(plant_path: str, source: str) -> str:
    """Write the skeleton of the plant at ``plant_path`` beside it (``SKELETON``); returns
    its path. FileExistsError if it is there: a scenario is the person's, never replaced."""
    pdef = load_plant(plant_path)
    path = os.path.join(os.path.dirname(plant_path), SKELETON)
    text = skeleton_text(pdef, os.path.basename(plant_path), [
        f"Scenario skeleton written by softplc import --scenario from {source}: the inputs",
        "to set (at 0 at the start) and the outputs to expect (commented out). Write the",
        "story: when each input changes (set:) and what the chart must do then (expect:),",
        "then run it with softplc test (docs/testing-charts.md). softplc import never",
        "overwrites this file."])
    try:
        with open(path, "x", encoding="utf-8") as f:
            f.write(text)
    except FileExistsError as exc:
        raise FileExistsError(exc.errno, exc.strerror, path) from None
    return path
