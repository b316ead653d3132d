"""Plant files: driver points (G303-G305).

Signals left unbound (G301) and physical outputs bound twice (G302) are the plant loader's
own checks: it reports them as diagnostics (runtime/language/plantfile.py), and
runtime/checker/check.py prints them.
"""

from __future__ import annotations

from typing import Any

from runtime.checker.diag import Diag, diag
from runtime.language import ast as A
from runtime.language.model import PlantDef

T = A.Type


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
