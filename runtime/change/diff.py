"""What an edit of a plant (or of one chart) changes, instance by instance: pure, no state.

A step or a variable is the same thing in both versions when it has the same name, or when
the new one says ``renamed_from:`` the old name (never guessed). Transitions are the same
when they have the same name, else the same source and target steps (in file order when
several join the same steps). ``ChangeSet.lines()`` is what ``softplc diff`` prints;
``static_refusals()`` are the reasons, known without any state, that the change cannot be
applied to a running controller.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from runtime.compiler.layout import written
from runtime.language.feedconf import SIDE_NAMES
from runtime.language.model import (
    Binding,
    Grafcet,
    InstanceDef,
    PlantDef,
    Transition,
    VarKind,
)


@dataclass(frozen=True, slots=True)
class Refusal:
    """One reason not to apply a change; ``forceable``: ``force=True`` overrides it."""

    line: str
    forceable: bool = True


@dataclass
class InstanceChange:
    """How one instance present in both plants changed (names of the NEW chart unless
    told)."""

    name: str
    old: Grafcet
    new: Grafcet
    #: new step name -> old step name, for every step present in both (renames included)
    steps: dict[str, str] = field(default_factory=dict)
    steps_added: list[str] = field(default_factory=list)
    steps_removed: list[str] = field(default_factory=list)  # old names
    #: new variable name -> old name, for every variable present in both
    variables: dict[str, str] = field(default_factory=dict)
    vars_added: list[str] = field(default_factory=list)
    vars_removed: list[str] = field(default_factory=list)  # old names
    #: new name -> (old type, new type) for the variables whose type changed
    types_changed: dict[str, tuple[str, str]] = field(default_factory=dict)
    #: variables the old chart wrote at every scan that the new one does not (or outputs
    #: it no longer writes at all): they take their initial value at the swap, the value
    #: a cold start of the new chart gives them, instead of keeping the last one (an
    #: output latched on by an action removed)
    undriven: list[str] = field(default_factory=list)
    scan_changed: bool = False
    lines: list[str] = field(default_factory=list)

    @property
    def unchanged(self) -> bool:
        return not self.lines


@dataclass
class ChangeSet:
    """Every change between two plant definitions."""

    old: PlantDef
    new: PlantDef
    instances: dict[str, InstanceChange] = field(default_factory=dict)  # in both plants
    instances_added: list[str] = field(default_factory=list)
    instances_removed: list[str] = field(default_factory=list)
    #: driver -> what changed ("type", config keys) for drivers present in both
    drivers_changed: dict[str, list[str]] = field(default_factory=dict)
    drivers_added: list[str] = field(default_factory=list)
    drivers_removed: list[str] = field(default_factory=list)
    #: driver -> points bound in the new plant that the old one did not use (with their
    #: direction): the driver must be reopened to declare them
    new_points: dict[str, list[str]] = field(default_factory=dict)
    _lines: list[str] = field(default_factory=list)
    refusals: list[Refusal] = field(default_factory=list)

    def lines(self) -> list[str]:
        """One human line per change, e.g. ``tester1: step gsX added``."""
        return list(self._lines)

    def static_refusals(self) -> list[str]:
        """The refusals known without state, e.g. ``driver mb: port changed``."""
        return [r.line for r in self.refusals]

    def state_checks(self) -> list[str]:
        """What ``apply`` will refuse depending on the running state, one line each."""
        out = []
        for name, ic in self.instances.items():
            for step in ic.steps_removed:
                out.append(f"{name}: step {step} removed: refused while it is active "
                           f"(--restart {name} restarts that instance)")
            if ic.scan_changed and ic.old.scan.value == "codesys":
                out.append(f"{name}: refused while an evolution is pending (scan model "
                           f"codesys -> {ic.new.scan.value})")
        return out

    @property
    def empty(self) -> bool:
        return not self._lines


def chart_plant(g: Grafcet, instance: str | None = None) -> PlantDef:
    """A one-instance plant around chart ``g``, with no binding (the instance named
    ``instance``, else after the chart): how ``softplc diff`` compares two chart files."""
    name = instance or g.name
    p = PlantDef(path=g.path)
    p.instances[name] = InstanceDef(name, g, g.loc)
    return p


def diff_plants(old: PlantDef, new: PlantDef) -> ChangeSet:
    """Every change from ``old`` to ``new``; pure (reads both, keeps nothing)."""
    cs = ChangeSet(old, new)
    add = cs._lines.append
    if old.cycle_ns != new.cycle_ns:
        add(f"plant: cycle {old.cycle_ns // 1_000_000} ms -> {new.cycle_ns // 1_000_000} ms")
        cs.refusals.append(Refusal("plant: the cycle time changed: restart the controller",
                                   False))
    # what the running controller set up at its start (its watchdog, retained data file,
    # real-time scheduling, the consoles it listens on): refused, never forceable, so that
    # ``softplc diff`` and ``reload`` say the same
    for what, a, b in (("plc: watchdog", old.watchdog_ns, new.watchdog_ns),
                       ("plc: retain", old.retain_path, new.retain_path),
                       ("plc: retain_required", old.retain_required, new.retain_required),
                       ("plc: realtime", (old.realtime_priority, old.lock_memory,
                                          old.realtime_cpu),
                        (new.realtime_priority, new.lock_memory, new.realtime_cpu)),
                       ("monitor: consoles", old.consoles, new.consoles)):
        if a != b:
            add(f"plant: {what} changed")
            cs.refusals.append(Refusal(f"{what} changed: it takes effect only at a restart "
                                       "of the controller", False))
    _sides(cs)
    # what the new plant brings with it (the retain interval is read at each save; the
    # console's PIN, limits and forces policy are applied at the swap, console/service.py;
    # the alarms' severities and overrun threshold when the alarm board takes the new
    # plant, controller/alarms.py)
    brought: tuple[tuple[str, object, object], ...] = (
        ("retain interval", old.retain_interval_ns, new.retain_interval_ns),
        ("alarms", replace(old.alarms, loc=None), replace(new.alarms, loc=None)),
        ("console PIN", old.pin_hash, new.pin_hash),
        ("release_forces_on_disconnect", old.release_forces_on_disconnect,
         new.release_forces_on_disconnect),
        ("console limits", old.console_limits, new.console_limits))
    for setting, was, now in brought:
        if was != now:
            add(f"plant: {setting} changed")
    _drivers(cs)
    for name, idef in new.instances.items():
        if name not in old.instances:
            cs.instances_added.append(name)
            add(f"{name}: instance added (chart {idef.grafcet.name}, starts from its "
                f"initial situation)")
    for name in old.instances:
        if name not in new.instances:
            cs.instances_removed.append(name)
            add(f"{name}: instance removed (its outputs go off)")
    for name, idef in new.instances.items():
        oidef = old.instances.get(name)
        if oidef is None:
            continue
        ic = _instance(name, oidef, idef, cs)
        cs.instances[name] = ic
        cs._lines += ic.lines
    return cs


# -- the side processes' sections (opcua:, mqtt:, web:) ------------------------------------
#: section -> its process and unit, as the diff names them
SIDES = {"opcua": ("OPC UA server", "softplc opcua; systemctl restart softplc-opcua@NAME"),
         "mqtt": ("MQTT edge node", "softplc mqtt; systemctl restart softplc-mqtt@NAME"),
         "web": ("web view", "softplc web; systemctl restart softplc-web@NAME"),
         "modbus": ("Modbus/TCP server",
                    "softplc modbus; systemctl restart softplc-modbus@NAME")}
#: what of ``web:`` is the web view's own (read at its start)
WEB_OWN = ("host", "port", "certificate", "private_key", "users", "read", "idle_logout_ns",
           "max_pages", "page_timeout_ns", "hosts")
#: what of ``modbus:`` is the Modbus/TCP server's own (read at its start)
MODBUS_OWN = ("host", "port", "clients", "unit", "points", "words", "tls", "limits")
#: what of ``mqtt:`` is the edge node's own (read at its start)
MQTT_OWN = ("brokers", "group_id", "edge_node_id", "client_id", "username", "password_file",
            "tls", "primary_host", "publish", "statistics_ns", "keepalive_ns", "buffer")


def _unplaced(value: Any) -> Any:
    """A setting without the places in the file it carries (``loc``), to compare."""
    if isinstance(value, list):
        return [_unplaced(v) for v in value]
    if hasattr(value, "loc"):
        return replace(value, loc=None)
    return value


def _sides(cs: ChangeSet) -> None:
    """``opcua:``, ``mqtt:`` and ``web:``: the controller serves their one feed from its
    start, so
    what changes the feed (its socket, its sample: the shortest of the sections') is
    refused until a restart, and so is a section added to a plant that had no feed; a
    removal applies the fail-safe part at once (that side's writes end, the feed serves
    values until a restart); the writable names are applied at the swap; the rest is the
    side process's own, applied when it restarts."""
    ofeed, nfeed = cs.old.feed(), cs.new.feed()
    feed_changed = (ofeed is not None and nfeed is not None
                    and (ofeed.path, ofeed.sample_ns) != (nfeed.path, nfeed.sample_ns))
    add = cs._lines.append
    sections: tuple[tuple[str, Any, Any], ...] = (
        ("opcua", cs.old.opcua, cs.new.opcua), ("mqtt", cs.old.mqtt, cs.new.mqtt),
        ("web", cs.old.web, cs.new.web), ("modbus", cs.old.modbus, cs.new.modbus))
    for key, old, new in sections:
        process, restart = SIDES[key]
        if old is None and new is None:
            continue
        if old is None:
            add(f"plant: {key}: added")
            if ofeed is None:
                cs.refusals.append(Refusal(f"{key}: added: the feed is served from the "
                                           "controller's start: restart the controller, "
                                           f"then start its {process}", False))
            elif feed_changed:
                cs.refusals.append(Refusal(f"{key}: added: it changes the feed (its sample "
                                           "or socket), set up at the controller's start: "
                                           f"restart the controller, then start its "
                                           f"{process}", False))
            continue
        if new is None and key == "web":  # it acts through the console, never the feed
            add("plant: web: removed: stop its web view (systemctl stop softplc-web@NAME)")
            continue
        if new is None:
            add(f"plant: {key}: removed: {SIDE_NAMES[key]} writes refused from now on; the "
                "feed serves values until the controller restarts")
            continue
        for what, a, b in (("sample", old.sample_ns, new.sample_ns),
                           ("feed", old.feed, new.feed)):
            if a == b:
                continue
            if feed_changed:
                add(f"plant: {key} {what} changed")
                cs.refusals.append(Refusal(f"{key}: {what} changed: it takes effect only at "
                                           "a restart of the controller", False))
            elif key in ("mqtt", "web", "modbus"):  # each sends at most once per its sample
                add(f"plant: {key} {what} changed: applied when the {process} restarts "
                    f"({restart})")
            else:
                add(f"plant: {key} {what} changed: the feed's is the same (the shortest "
                    "of opcua: and mqtt:)")
        if old.writable != new.writable:
            add(f"plant: {key} writable changed: [{', '.join(old.writable)}] -> "
                f"[{', '.join(new.writable)}]")
        if key == "opcua":
            own: list[tuple[str, object, object]] = [
                ("endpoint", old.endpoint, new.endpoint),
                ("security", replace(old.security, loc=None), replace(new.security, loc=None))]
        elif key == "web":
            own = [(f.removesuffix("_ns"), getattr(old, f), getattr(new, f))
                   for f in WEB_OWN]
        elif key == "modbus":  # (the places in the file are no setting)
            own = [(f if f != "points" else "map", _unplaced(getattr(old, f)),
                    _unplaced(getattr(new, f))) for f in MODBUS_OWN]
        else:  # (the TLS files' place in the file is no setting)
            own = [(f.removesuffix("_ns"), getattr(old, f), getattr(new, f))
                   for f in MQTT_OWN if f != "tls"]
            own.append(("tls", old.tls and replace(old.tls, loc=None),
                        new.tls and replace(new.tls, loc=None)))
        for what, a, b in own:
            if a != b:
                add(f"plant: {key} {what} changed: applied when the {process} restarts "
                    f"({restart})")


# -- drivers -------------------------------------------------------------------------------
def _points(p: PlantDef) -> dict[str, set[str]]:
    """driver -> its bound points, as "in:I0" / "out:Q0" (the ``ok`` pseudo-point left out)."""
    out: dict[str, set[str]] = {d: set() for d in p.drivers}
    for idef in p.instances.values():
        for way, section in (("in", idef.inputs), ("out", idef.outputs)):
            for b in section.values():
                if b.driver is not None and b.point != "ok":
                    out.setdefault(b.driver, set()).add(f"{way}:{b.point}")
    return out


def _drivers(cs: ChangeSet) -> None:
    old, new, add = cs.old, cs.new, cs._lines.append
    opoints, npoints = _points(old), _points(new)
    for name, d in new.drivers.items():
        od = old.drivers.get(name)
        if od is None:
            cs.drivers_added.append(name)
            add(f"driver {name}: added ({d.type})")
            cs.refusals.append(Refusal(f"driver {name}: added: it must be opened"))
            continue
        what = []
        if od.type != d.type:
            what.append("type")
        keys = sorted(set(od.config) | set(d.config))
        what += [k for k in keys if od.config.get(k) != d.config.get(k)]
        if what:
            cs.drivers_changed[name] = what
            add(f"driver {name}: {', '.join(what)} changed")
            cs.refusals.append(Refusal(f"driver {name}: {', '.join(what)} changed: the bus "
                                       f"must be reopened"))
            continue
        grown = sorted(npoints.get(name, set()) - opoints.get(name, set()))
        if grown:
            cs.new_points[name] = grown
            pts = ", ".join(p.split(":", 1)[1] + f" ({p.split(':', 1)[0]}put)" for p in grown)
            add(f"driver {name}: new points {pts}")
            cs.refusals.append(Refusal(f"driver {name}: new points {pts}: the driver must be "
                                       f"reopened"))
    for name in old.drivers:
        if name not in new.drivers:
            cs.drivers_removed.append(name)
            add(f"driver {name}: removed (closed, its outputs off)")


# -- one instance ----------------------------------------------------------------------
def _pairs(old_names: list[str], new_items: list[tuple[str, str | None]]
           ) -> tuple[dict[str, str], list[str], list[str], list[tuple[str, str]]]:
    """Match names: (new -> old, added, removed old names, renames (old, new))."""
    same: dict[str, str] = {}
    added: list[str] = []
    renames: list[tuple[str, str]] = []
    olds = set(old_names)
    news = {n for n, _ in new_items}
    for name, was in new_items:
        if name in olds:
            same[name] = name
        elif was is not None and was in olds and was not in news:
            same[name] = was
            renames.append((was, name))
        else:
            added.append(name)
    taken = set(same.values())
    removed = [n for n in old_names if n not in taken]
    return same, added, removed, renames


def _tkey(t: Transition, rename: dict[str, str]) -> str:
    if t.name:
        return t.name
    src = ",".join(rename.get(s, s) for s in t.sources)
    return f"{src} -> {','.join(rename.get(s, s) for s in t.targets)}"


def _transitions(g: Grafcet, rename: dict[str, str]) -> dict[str, Transition]:
    out: dict[str, Transition] = {}
    for t in g.transitions:
        key = _tkey(t, rename)
        n = 1
        while (key if n == 1 else f"{key} #{n}") in out:
            n += 1
        out[key if n == 1 else f"{key} #{n}"] = t
    return out


def _priorities(name: str, ot: dict[str, Transition], nt: dict[str, Transition],
                back: dict[str, str], add: Callable[[str], None]) -> None:
    """The transitions leaving one step, in both charts, taken in another order: the
    first true one in file order wins (an OR divergence), so the swap may change the
    branch taken. ``ot``/``nt`` are in priority order, keyed in the old step names;
    ``back`` maps a new step name to its old one."""
    common = ot.keys() & nt.keys()

    def leaving(ts: dict[str, Transition], rename: dict[str, str]) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for key, t in ts.items():
            if key in common:
                for s in t.sources:
                    out.setdefault(rename.get(s, s), []).append(key)
        return out
    was, now = leaving(ot, {}), leaving(nt, back)
    for step, keys in was.items():
        if len(keys) > 1 and now.get(step, keys) != keys:
            add(f"{name}: transitions from {step}: priority order [{', '.join(keys)}] -> "
                f"[{', '.join(now[step])}] (the first true one is taken)")


def _undriven(ic: InstanceChange, add: Callable[[str], None]) -> None:
    """The variables the new chart no longer drives (``InstanceChange.undriven``): not
    inputs (the plant writes them), not retained (a cold start restores their value), not
    of another type (they start at their initial value anyway)."""
    old_every, old_any = written(ic.old)
    new_every, new_any = written(ic.new)
    for v, was in ic.variables.items():
        nv = ic.new.variables[v]
        if nv.kind is VarKind.INPUT or nv.retain or v in ic.types_changed:
            continue
        if (was in old_every and v not in new_every) or (
                nv.kind is VarKind.OUTPUT and was in old_any and v not in new_any):
            ic.undriven.append(v)
            what = "output" if nv.kind is VarKind.OUTPUT else "variable"
            add(f"{ic.name}: {what} {v} no longer driven by the chart: {nv.init!r} from the "
                "swap on, as after a cold start")


def _short(text: str) -> str:
    one = " ".join(text.split())
    return one if len(one) <= 60 else one[:57] + "..."


def _instance(name: str, oidef: InstanceDef, idef: InstanceDef, cs: ChangeSet
              ) -> InstanceChange:
    og, ng = oidef.grafcet, idef.grafcet
    ic = InstanceChange(name, og, ng)
    add = ic.lines.append
    if og.scan is not ng.scan:
        ic.scan_changed = True
        add(f"{name}: scan model {og.scan.value} -> {ng.scan.value}")
    # steps
    steps, ic.steps_added, ic.steps_removed, renames = _pairs(
        list(og.steps), [(s.name, s.renamed_from) for s in ng.steps.values()])
    ic.steps = steps
    for was, now in renames:
        add(f"{name}: step {now} renamed from {was}")
    for s in ic.steps_added:
        add(f"{name}: step {s} added")
    for s in ic.steps_removed:
        add(f"{name}: step {s} removed")
    for s, was in steps.items():
        a, b = og.steps[was], ng.steps[s]
        if (a.initial, a.min_ns, a.max_ns) != (b.initial, b.min_ns, b.max_ns):
            add(f"{name}: step {s}: initial/min/max changed")
        if (a.macro is None) != (b.macro is None):
            add(f"{name}: step {s}: macro-step changed")
        oa = Counter(x.text.strip() for x in a.actions)
        na = Counter(x.text.strip() for x in b.actions)
        for text in (oa - na):
            add(f"{name}: step {s}: action '{_short(text)}' removed")
        for text in (na - oa):
            add(f"{name}: step {s}: action '{_short(text)}' added")
    # transitions (keys in the old chart's step names)
    back = {now: was for now, was in steps.items()}
    ot, nt = _transitions(og, {}), _transitions(ng, back)
    for key, t in nt.items():
        if key not in ot:
            add(f"{name}: transition {key} added")
        elif " ".join(ot[key].text.split()) != " ".join(t.text.split()):
            add(f"{name}: transition {key}: condition '{_short(ot[key].text)}' -> "
                f"'{_short(t.text)}'")
    for key in ot:
        if key not in nt:
            add(f"{name}: transition {key} removed")
    _priorities(name, ot, nt, back, add)
    for part in ("pre", "post"):
        _equations(name, part, [" ".join(x.text.split()) for x in getattr(og, part)],
                   [" ".join(x.text.split()) for x in getattr(ng, part)], add)
    # variables
    ovars = [v.name for v in og.variables.values()]
    nvars = [(v.name, v.renamed_from) for v in ng.variables.values()]
    ic.variables, ic.vars_added, ic.vars_removed, vren = _pairs(ovars, nvars)
    for was, now in vren:
        add(f"{name}: variable {now} renamed from {was}")
    for v in ic.vars_added:
        nv = ng.variables[v]
        add(f"{name}: variable {v} added ({nv.kind.value} {nv.type.value}, starts at "
            f"{nv.init!r})")
    for v in ic.vars_removed:
        add(f"{name}: variable {v} removed")
    for v, was in ic.variables.items():
        va, vb = og.variables[was], ng.variables[v]
        if va.type is not vb.type:
            ic.types_changed[v] = (va.type.value, vb.type.value)
            add(f"{name}: variable {v}: type {va.type.value} -> {vb.type.value}")
            if va.retain:
                cs.refusals.append(Refusal(
                    f"{name}: retained variable {v} changes type {va.type.value} -> "
                    f"{vb.type.value}", forceable=False))
        if va.kind is not vb.kind:
            add(f"{name}: variable {v}: {va.kind.value} -> {vb.kind.value}")
        if va.retain != vb.retain:
            add(f"{name}: variable {v}: {'now' if vb.retain else 'no longer'} retained")
        if va.init != vb.init and va.type is vb.type:
            add(f"{name}: variable {v}: init {va.init!r} -> {vb.init!r} (the running value "
                f"is kept)")
    _undriven(ic, add)
    # timers and function blocks
    oblocks = {**{t: "timer" for t in og.timers}, **{x.name: x.kind for x in og.blocks.values()}}
    nblocks = {**{t: "timer" for t in ng.timers}, **{x.name: x.kind for x in ng.blocks.values()}}
    for bn, kind in nblocks.items():
        if bn not in oblocks:
            add(f"{name}: block {bn} added ({kind})")
        elif oblocks[bn] != kind:
            add(f"{name}: block {bn}: {oblocks[bn]} -> {kind} (starts from its initial state)")
    for bn in oblocks:
        if bn not in nblocks:
            add(f"{name}: block {bn} removed")
    # bindings
    for way, oold, onew in (("input", oidef.inputs, idef.inputs),
                            ("output", oidef.outputs, idef.outputs)):
        _bindings(name, way, oold, onew, add)
    return ic


def _equations(name: str, part: str, old: list[str], new: list[str],
               add: Callable[[str], None]) -> None:
    """One line per pre/post statement changed (same place), removed or added."""
    if len(old) == len(new):
        for a, b in zip(old, new, strict=True):
            if a != b:
                add(f"{name}: {part} '{_short(a)}' -> '{_short(b)}'")
        return
    for text in Counter(old) - Counter(new):
        add(f"{name}: {part} '{_short(text)}' removed")
    for text in Counter(new) - Counter(old):
        add(f"{name}: {part} '{_short(text)}' added")


def _btext(b: Binding) -> str:
    return b.source + (" inverted" if b.invert else "")


def _bindings(name: str, way: str, old: dict[str, Binding], new: dict[str, Binding],
              add: Callable[[str], None]) -> None:
    for sig, b in new.items():
        ob = old.get(sig)
        if ob is None:
            add(f"{name}: {way} {sig} bound to {_btext(b)}")
        elif _btext(ob) != _btext(b):
            add(f"{name}: {way} {sig}: {_btext(ob)} -> {_btext(b)}")
    for sig, ob in old.items():
        if sig not in new:
            add(f"{name}: {way} {sig} no longer bound (was {_btext(ob)})")
