"""Plant files: signals left unbound, outputs bound twice, driver points (G301-G305)."""

from __future__ import annotations

import os
from typing import Any

from runtime.checker.diag import Diag, diag
from runtime.errors import Loc, SourceError
from runtime.language import ast as A
from runtime.language.model import PlantDef
from runtime.language.yamlsrc import YMap, load_yaml

T = A.Type


def check_plant_model(p: PlantDef) -> list[Diag]:
    """Driver points of a loaded plant: do they exist on their driver (G303-G305)?"""
    from drivers.base import ConfigError, Direction, PointError, PointKind
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
                        out.append(diag(b.loc, "note", "G305", f"points of driver "
                                        f"'{b.driver}' not checked: {missing[b.driver]}"))
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


def plant_bindings_scan(path: str) -> list[Diag]:
    """Every unbound signal and physical output bound twice, from the YAML text (the
    loader stops at the first)."""
    from runtime.language.grafcetfile import load_grafcet

    out: list[Diag] = []
    try:
        doc = load_yaml(path)
    except SourceError:
        return out
    if not isinstance(doc, YMap) or not isinstance(doc.get("instances"), YMap):
        return out
    drv = doc.get("drivers")
    drivers: dict[str, Any] = drv if isinstance(drv, YMap) else {}
    driven: dict[str, tuple[str, str, Loc]] = {}
    instances = doc["instances"]
    for name, spec in instances.items():
        if not isinstance(spec, YMap) or "grafcet" not in spec:
            continue
        gpath = str(spec["grafcet"])
        if not os.path.isabs(gpath):
            gpath = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)),
                                                  gpath))
        try:
            g = load_grafcet(gpath)
        except SourceError:
            continue
        for key, signals in (("inputs", g.inputs), ("outputs", g.outputs)):
            section = spec.get(key)
            bound = section if isinstance(section, YMap) else {}
            where = spec.key_locs.get(key, instances.key_locs[name])
            for var in signals:
                if var.name not in bound:
                    out.append(diag(where, "error", "G301", f"instance '{name}' leaves "
                                    f"{key[:-1]} '{var.name}' of grafcet {g.name} unbound: "
                                    f"expected a binding '{var.name}: driver.point' in "
                                    f"'{key}', found none"))
            if key != "outputs" or not isinstance(section, YMap):
                continue
            for sig, b in section.items():
                loc = section.val_locs[sig]
                if isinstance(b, YMap):
                    loc = b.val_locs.get("from", loc)
                    b = b.get("from")
                if not isinstance(b, str) or "." not in b:
                    continue
                if b.split(".", 1)[0] not in drivers:
                    continue
                if b in driven:
                    other_inst, other_sig, other_loc = driven[b]
                    out.append(diag(loc, "error", "G302", f"physical output '{b}' is bound "
                                    f"twice: expected one output per point, found "
                                    f"'{name}.{sig}' and '{other_inst}.{other_sig}' (line "
                                    f"{other_loc.line})"))
                else:
                    driven[str(b)] = (name, sig, loc)
    return out
