"""Simulation scripts: timed changes of a plant's inputs (``softplc simulate``, ``run
--script``, ``softplc check``).

``read_script`` checks a script against a plant's names (a PlantNames, from the plant
definition alone); ``load_script`` also binds each change to a built plant's process image.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from runtime.engine.instance import coerce
from runtime.engine.names import PlantNames, ScriptInput, UnknownName
from runtime.errors import Loc, SourceError
from runtime.language import ast as A
from runtime.language.filekind import SCRIPT_KEYS
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.yamlsrc import YList, YMap, load_yaml

if TYPE_CHECKING:
    from runtime.engine.plant import Plant

T = A.Type


@dataclass(frozen=True, slots=True)
class Change:
    """One scripted change: at ``at_ns``, ``key`` takes ``value`` (of the input's type, or
    a raw number for a driver point)."""

    at_ns: int
    key: str
    value: Any
    target: ScriptInput


@dataclass(frozen=True, slots=True)
class Script:
    duration_ns: int | None
    cycles: int | None
    changes: list[Change]  # sorted by time, file order kept at equal times


@dataclass
class Event:
    at_ns: int
    key: str
    value: Any
    apply: Callable[[], None]


def read_script(path: str, names: PlantNames, need_length: bool = True) -> Script:
    """The script at ``path``, every name and value checked; SourceError at the first
    fault. ``need_length``: refuse a script with neither 'duration:' nor 'cycles:'."""
    doc = load_yaml(path)
    if not isinstance(doc, YMap):
        raise SourceError(Loc(path, 1, 1), "expected a mapping with 'duration:' or 'cycles:'")
    return script_of(doc, names, need_length)


def script_of(doc: YMap, names: PlantNames, need_length: bool = True,
              keys: tuple[str, ...] = SCRIPT_KEYS, what: str = "a simulation script"
              ) -> Script:
    """The script of a loaded document: ``read_script``'s checks, the document's keys
    among ``keys`` (a scenario's are more: runtime/scenario), ``what`` naming it."""
    check_keys(doc, keys, what)
    duration = cycles = None
    if "duration" in doc:
        duration = time_value(doc["duration"], doc.val_locs["duration"], "duration")
    if "cycles" in doc:
        cycles = expect_type(doc["cycles"], doc.val_locs["cycles"], int, "a number of cycles")
    if need_length and duration is None and cycles is None:
        raise SourceError(doc.loc, "the script needs 'duration:' or 'cycles:'")
    changes: list[Change] = []
    items = doc.get("set") or YList()
    if items:
        expect_type(items, doc.val_locs["set"], YList, "a list of {at: TIME, name: value}")
    for item, loc in zip(items, getattr(items, "locs", []), strict=True):
        item = expect_type(item, loc, YMap, "{at: TIME, instance.input: value, ...}")
        if "at" not in item:
            raise SourceError(item.loc, "a 'set' entry needs 'at: TIME'")
        at = time_value(item["at"], item.val_locs["at"], "at")
        for key, value in item.items():
            if key == "at":
                continue
            changes.append(_change(names, at, key, value, item.key_locs[key],
                                   item.val_locs[key]))
    changes.sort(key=lambda e: e.at_ns)
    return Script(duration, cycles, changes)


def _change(names: PlantNames, at: int, key: str, value: Any, kloc: Loc, vloc: Loc
            ) -> Change:
    try:
        target = names.script_input(key)
    except UnknownName as exc:
        raise SourceError(kloc, str(exc)) from None
    var = target.variable
    if var is not None:
        try:
            logical = coerce(var.type, value)
        except ValueError as exc:
            raise SourceError(vloc, f"bad value for '{key}': {exc}") from None
        if target.bound_to is not None:
            raise SourceError(kloc, f"'{key}' is bound to '{target.bound_to}': drive that "
                                    "instead")
        return Change(at, key, logical, target)
    if isinstance(value, bool):
        value = int(value)
    if not isinstance(value, int | float):
        raise SourceError(vloc, f"expected a number for '{key}', found {value!r}")
    return Change(at, key, value, target)


def load_script(path: str, plant: Plant) -> tuple[int | None, int | None, list[Event]]:
    """Returns (duration_ns, cycles, events sorted by time, file order kept at equal times),
    each event writing its change into ``plant``. The length may be absent (None, None):
    the caller decides whether it needs one (``simulate --cycles`` does not)."""
    script = read_script(path, plant.names, need_length=False)
    return script.duration_ns, script.cycles, bind(plant, script.changes)


def bind(plant: Plant, changes: list[Change]) -> list[Event]:
    """The events writing ``changes`` (in their order) into ``plant``'s process image."""
    return [Event(c.at_ns, c.key, c.value, _apply(plant, c)) for c in changes]


def _apply(plant: Plant, c: Change) -> Callable[[], None]:
    """The write of change ``c`` into the plant's process image."""
    t, value = c.target, c.value
    if t.driver is None:  # an unbound chart input or flag: written into the instance
        inst, rest = plant.instances[t.instance or ""], c.key.partition(".")[2]

        def apply() -> None:
            inst.set(rest, value)
        return apply
    drv, point = plant.drivers[t.driver], t.point or ""
    if t.variable is not None:  # a bound chart input: the physical value, inverted here
        logical = value
        phys = (not logical if t.invert else logical) if t.variable.type is T.BOOL else logical
        value = int(phys) if isinstance(phys, bool) else phys

    # by position in the driver's input image (resolved once, fixed for its life); a bit
    # of the image holds a bool (drivers/image.py)
    vals, pos = drv.inputs.vals, drv.inputs.index[point]
    if pos in plant.bits[t.driver]:
        value = bool(value)

    def apply_point() -> None:
        vals[pos] = value
    return apply_point
