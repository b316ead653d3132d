"""Plant files: driver points (G303-G305) and the binding traps (G306, G307).

Signals left unbound (G301) and physical outputs bound twice (G302) are the plant loader's
own checks: it reports them as diagnostics (runtime/language/plantfile.py), and
runtime/checker/check.py prints them.
"""

from __future__ import annotations

import re
from typing import Any

from runtime.checker.diag import Diag, diag
from runtime.language import ast as A
from runtime.language.model import Binding, PlantDef, VarKind

T = A.Type


def side_files(p: PlantDef) -> list[Diag]:
    """G308: a file a side process reads at its start that is not there (or not of its
    kind, or not readable): a certificate, key or trusted directory of ``opcua:
    security:``, a certificate or key of ``web: tls:``, ``modbus: tls:``, ``mqtt: tls:``,
    ``mqtt: password_file``. The controller loads without them; the side process would
    refuse to start."""
    from runtime.language.opcuaconf import security_problems
    from runtime.language.tlsconf import side_file_problems

    found = side_file_problems(p)
    if p.opcua is not None:
        found = security_problems(p.opcua.security) + found
    return [diag(e.loc, "error", "G308", e.message) for e in found]


def check_plant_model(p: PlantDef) -> list[Diag]:
    """Driver points of a loaded plant: do they exist on their driver (G303-G305)?"""
    from drivers.base import Direction, PointError, PointKind
    from drivers.config import ConfigError
    from drivers.registry import DriverImportError, driver_class

    out: list[Diag] = []
    drivers: dict[str, Any] = {}
    missing: dict[str, str] = {}
    for name, d in p.drivers.items():
        try:
            cls = driver_class(d.type)
        except DriverImportError as exc:
            missing[name] = str(exc)
            continue
        except KeyError:
            out.append(diag(d.loc, "error", "G304", f"unknown driver type '{d.type}'"))
            continue
        try:
            drivers[name] = cls(name, dict(d.config))
        except (ConfigError, ValueError, TypeError) as exc:
            out.append(diag(d.loc, "error", "G304", f"driver '{name}' ({d.type}): {exc}"))
    one_way = {name for name, drv in drivers.items() if drv.ONE_DIRECTION_PER_POINT}
    out += shared_inputs(p) + outputs_on_inputs(p, one_way) + side_files(p)
    noted: set[str] = set()
    for inst in p.instances.values():
        for direction, section in ((Direction.IN, inst.inputs), (Direction.OUT, inst.outputs)):
            for b in section.values():
                if b.driver is None:
                    continue
                if b.point == "ok":
                    if direction is Direction.OUT:
                        out.append(diag(b.loc, "error", "G303", f"'{b.source}' is the "
                                        "driver's health, a read-only input: it cannot be "
                                        f"bound as output '{b.signal}'"))
                    continue
                if b.driver in missing:
                    if b.driver not in noted:
                        noted.add(b.driver)
                        out.append(diag(b.loc, "note", "G305", f"driver '{b.driver}': "
                                        "point names checked, not whether each is a bit or "
                                        f"a register for its variable: {missing[b.driver]}"))
                    continue
                drv = drivers.get(b.driver)
                if drv is None:
                    continue
                try:
                    kind = drv.add_point(b.point or "", direction)
                except PointError as exc:
                    out.append(diag(b.loc, "error", "G303", f"{exc} (instance "
                                    f"'{inst.name}', {direction.value}put '{b.signal}')"))
                    continue
                var = inst.grafcet.variables.get(b.signal)
                if var is None or p.drivers[b.driver].type == "sim":
                    continue
                want_int = var.type is not T.BOOL
                if want_int != (kind is PointKind.INT):
                    out.append(diag(b.loc, "error", "G303", f"'{b.source}' carries "
                                    f"{'a register (int)' if kind is PointKind.INT else 'a bit'}"
                                    f" but '{inst.name}.{b.signal}' is {var.type}"))
    return out


#: a ``sim`` point named as an input, as the example plants and the bus drivers name them
SIM_INPUT_POINT = re.compile(r"(?i)(I|IR)\d+")


def _point(b: Binding) -> str:
    return f"{b.driver}.{b.point}"


def shared_inputs(p: PlantDef) -> list[Diag]:
    """G306: one physical input point feeding two inputs of the same instance (a copied
    binding line, mostly: the chart then sees one contact as two signals). Chart flags and
    links to other instances are left out; two instances reading one point are fine."""
    out: list[Diag] = []
    for inst in p.instances.values():
        first: dict[str, Binding] = {}
        for b in inst.inputs.values():
            var = inst.grafcet.variables.get(b.signal)
            if b.driver is None or b.point == "ok" or var is None or (
                    var.kind is not VarKind.INPUT):
                continue
            was = first.setdefault(_point(b), b)
            if was is not b:
                out.append(diag(b.loc, "warning", "G306", f"input point '{_point(b)}' feeds "
                                f"both '{inst.name}.{was.signal}' (line {was.loc.line}) and "
                                f"'{inst.name}.{b.signal}': the chart sees one contact as "
                                f"two signals; bind '{b.signal}' to its own point (for a "
                                "signal and its negation, read the negation in the chart)"))
    return out


def outputs_on_inputs(p: PlantDef, one_way: set[str]) -> list[Diag]:
    """G307: an output bound to an input point: a point the plant also binds as an input,
    or a ``sim`` point named as one (``I3``, ``IR0``). Drivers whose points have one
    direction (``one_way``) already refuse the first case (G303)."""
    read: dict[str, tuple[str, Binding]] = {}
    for inst in p.instances.values():
        for b in inst.inputs.values():
            if b.driver is not None:
                read.setdefault(_point(b), (inst.name, b))
    out: list[Diag] = []
    for inst in p.instances.values():
        for b in inst.outputs.values():
            if b.driver is None or b.point in (None, "ok"):
                continue
            key = _point(b)
            why = None
            if key in read and b.driver not in one_way:
                who, ib = read[key]
                why = (f"'{key}' is also bound as input '{who}.{ib.signal}' (line "
                       f"{ib.loc.line}): the input does not read what the output writes; bind "
                       "the output to a point of its own")
            elif p.drivers[b.driver].type == "sim" and SIM_INPUT_POINT.fullmatch(b.point):
                why = (f"'{key}' is named as an input point (I<n>, IR<n>): a simulation "
                       "script sets it, the output's value is not read back; name it "
                       "Q<n>")
            if why is not None:
                out.append(diag(b.loc, "warning", "G307", f"output '{inst.name}.{b.signal}' "
                                f"is bound to an input point: {why}"))
    return out
