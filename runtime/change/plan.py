"""Online change in two halves: ``prepare`` (any thread, the heavy work) and ``apply`` (the
scan thread, between two cycles: checks, then the state carried, all or nothing).

State carries by name through the programs' slot descriptions (``Program.slots``: key,
kind, type, index; values read and written as ``instance.m[slot.index]``): variables (their
new name when ``renamed_from:``), each step's X and the times its ``.T`` is made of with the
chart clock (so ``.T`` goes on exactly), function blocks of the same kind, and the scan's own
memory (edges, stored actions, pending CODESYS evolutions, the flags' history), whose keys
the compiler makes from what they belong to. Everything else starts at its initial value
and is reported.
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

from drivers.sim import SimDriver
from runtime.change.diff import ChangeSet, InstanceChange, diff_plants
from runtime.compiler.codebook import CodeBook
from runtime.compiler.program import Program, Slot, SlotKind
from runtime.engine.instance import Instance
from runtime.engine.plant import Plant
from runtime.language.model import PlantDef, VarKind
from runtime.language.safefile import UnfitFile, read_bounded
from runtime.language.yamlsrc import MAX_FILE_BYTES


@dataclass
class _Carry:
    """How one instance's state goes from the old program to the new one, worked out in
    ``prepare`` so that ``apply`` only copies."""

    name: str
    old_program: Program
    #: (new index, old index, whether a block object to copy) for each carried slot
    copies: list[tuple[int, int, bool]] = field(default_factory=list)
    #: (new index, old index) of the retained variables (kept by a restart)
    retained: list[tuple[int, int]] = field(default_factory=list)
    #: (old index of X, step) of the old steps the new chart has not
    removed_steps: list[tuple[int, str]] = field(default_factory=list)
    #: (old index, key) of pending CODESYS evolutions the new chart has not
    lost_pending: list[tuple[int, str]] = field(default_factory=list)
    #: what starts at its initial value (reported when applied)
    reset: list[str] = field(default_factory=list)
    #: (new index of an edge's memory, new index of its input) for the edges the old
    #: chart had not, on a chart input: the memory takes the input's value of the last
    #: scan, so that the edge is seen exactly as a running chart would have seen it
    new_edges: list[tuple[int, int]] = field(default_factory=list)
    #: the X of the steps the old chart had not: a new step starts inactive, an initial
    #: one too (its X starts true only in a fresh state)
    new_steps: list[int] = field(default_factory=list)


@dataclass
class Prepared:
    """A new plant ready to take over from a running one (built outside the scan)."""

    changes: ChangeSet
    #: the new plant: programs compiled, cycle generated, instance states fresh; built with
    #: the old plant's open driver objects for the drivers it keeps; not yet running
    plant: Plant
    #: sha256 (hex) of every file of the new plant (the plant file and each chart), by path
    hashes: dict[str, str]
    _carries: dict[str, _Carry] = field(default_factory=dict)
    #: drivers of the new plant that are new objects (added, or config/points changed)
    _fresh: list[str] = field(default_factory=list)
    #: old drivers not handed over (removed or replaced): the caller closes them
    _dropped: list[str] = field(default_factory=list)
    #: (driver, point) output points of kept drivers that nothing drives any more
    _unbound: list[tuple[str, str]] = field(default_factory=list)
    _applied: bool = False


@dataclass
class Applied:
    """What ``apply`` did (or why it did nothing)."""

    #: what was done: carried, reset to init, reported removed, forces released
    lines: list[str] = field(default_factory=list)
    #: non-empty: nothing was changed at all
    refusals: list[str] = field(default_factory=list)
    #: instances restarted from their initial situation
    restarted: list[str] = field(default_factory=list)
    #: drivers of the new plant the caller must open (new objects: added, bus config or
    #: points changed); their outputs are off until then
    reopened: list[str] = field(default_factory=list)
    #: drivers of the OLD plant the caller must put in their safe state and close (removed,
    #: or replaced by a reopened one: close the old before opening the new)
    closed: list[str] = field(default_factory=list)
    #: instances the new plant holds in fault (no active step left), with why
    instance_faults: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.refusals


def file_hashes(pdef: PlantDef) -> dict[str, str]:
    """sha256 (hex) of the plant file and of each chart file, by path ("" for one that
    cannot be read as a source file: ``safefile.read_bounded``, never blocking)."""
    paths = [pdef.path] + [idef.grafcet.path for idef in pdef.instances.values()]
    out: dict[str, str] = {}
    for p in paths:
        if p and p not in out:
            try:
                raw = read_bounded(p, MAX_FILE_BYTES - 1, follow_links=True)
                out[p] = hashlib.sha256(raw).hexdigest()
            except (OSError, UnfitFile):
                out[p] = ""
    return out


def _is_sim(plant: Plant) -> bool:
    """Whether ``plant`` runs on simulated I/O in place of its real drivers."""
    return plant.virtual or any(
        isinstance(d, SimDriver) and plant.pdef.drivers[n].type != "sim"
        for n, d in plant.drivers.items())


def prepare(old: Plant, new_pdef: PlantDef, book: CodeBook | None = None) -> Prepared:
    """Diff, compile and build the new plant, and work out how its state carries. Any
    thread: reads the old plant's definition and programs, never its state. ``book``: the
    code objects compiled apart (runtime/compiler/codebook.py), so that no long compile
    holds the GIL here."""
    cs = diff_plants(old.pdef, new_pdef)
    keep = {n: d for n, d in old.drivers.items()
            if n in new_pdef.drivers and n not in cs.drivers_changed and n not in cs.new_points}
    plant = Plant(new_pdef, sim=_is_sim(old), drivers=keep, virtual=old.virtual, book=book,
                  handover=True)
    prep = Prepared(cs, plant, file_hashes(new_pdef))
    prep._fresh = [n for n in plant.drivers if n not in keep]
    prep._dropped = [n for n in old.drivers if n not in keep]
    now_out = {(b.driver, b.point) for idef in new_pdef.instances.values()
               for b in idef.outputs.values()}
    for idef in old.pdef.instances.values():
        for b in idef.outputs.values():
            if b.driver in keep and (b.driver, b.point) not in now_out:
                prep._unbound.append((b.driver, b.point or ""))
    for name, ic in cs.instances.items():
        prep._carries[name] = _carry(ic, old.instances[name], plant.instances[name])
    return prep


def _old_key(s: Slot, ic: InstanceChange) -> str | None:
    """The key in the old program of what new slot ``s`` holds, None if it is new."""
    if s.kind is SlotKind.VARIABLE:
        return ic.variables.get(s.name)
    if s.kind in (SlotKind.STEP_X, SlotKind.STEP_START, SlotKind.STEP_LAST):
        was = ic.steps.get(s.name)
        return None if was is None else was + s.key[len(s.name):]
    return _renamed_key(s.key, ic)


def _renamed_key(key: str, ic: InstanceChange) -> str:
    """The old program's key of the scan memory ``key``, its steps and target variable
    named as the old chart named them (``renamed_from:``): ``#pending:A,B->C``,
    ``#edge:WHERE:[TEXT]``, ``#cq:STEP:Q``, ``#SD:STEP:TARGET``, ``#S.TARGET``."""
    steps = {n: o for n, o in ic.steps.items() if n != o}
    var = {n: o for n, o in ic.variables.items() if n != o}
    if not (steps or var) or not key.startswith("#"):
        return key
    if key.startswith("#S."):
        return "#S." + var.get(key[3:], key[3:])
    head, sep, rest = key.partition(":")
    if not sep:
        return key
    where, colon, tail = rest.partition(":")
    if head == "#edge":  # WHERE:[TEXT]...: the text is kept as written
        pass
    elif head not in ("#pending", "#cq") and colon:  # #SD:STEP:TARGET[#n][.F|.T]
        target, dot, suffix = tail.partition(".")
        name, hash_, num = target.partition("#")
        tail = var.get(name, name) + hash_ + num + dot + suffix
    suffix = ""
    if not colon:  # #pending:WHERE[#n]
        where, hash_, num = where.partition("#")
        suffix = hash_ + num
    arrow = where.split("->")
    where = "->".join(",".join(steps.get(x, x) for x in side.split(",")) for side in arrow)
    return f"{head}:{where}{suffix}{colon}{tail}"


def _carry(ic: InstanceChange, old: Instance, new: Instance) -> _Carry:
    c = _Carry(ic.name, old.program)
    oslots = {s.key: s for s in old.program.slots}
    for s in new.program.slots:
        key = _old_key(s, ic)
        o = oslots.get(key) if key is not None else None
        if o is None and key is not None and key.endswith(".TA"):
            # a step given its first L, D or DS: its delays count from its activation,
            # which .T's start tells (unless a rule-5 re-entry restarted it before)
            o = oslots.get(key[:-3] + ".T0")
        if o is None:
            edge_input = _edge_input(s, new)
            if edge_input is not None:
                c.new_edges.append((s.index, edge_input))
            if s.kind is SlotKind.STEP_X:
                c.new_steps.append(s.index)
            continue
        if s.kind is SlotKind.VARIABLE and s.name in ic.undriven:
            continue  # at its initial value, as after a cold start (the diff's line says so)
        if s.kind is SlotKind.VARIABLE and s.name in ic.types_changed:
            c.reset.append(f"{ic.name}: variable {s.name} starts at its init value (type "
                           f"changed)")
            continue
        if s.kind is not o.kind or s.block != o.block or s.type != o.type:
            what = s.name or s.key
            c.reset.append(f"{ic.name}: {s.kind.value} {what} starts from its initial state "
                           f"(was {o.block or o.kind.value})")
            continue
        c.copies.append((s.index, o.index, s.block is not None))
        if s.kind is SlotKind.VARIABLE and ic.new.variables[s.name].retain \
                and ic.old.variables[o.name].retain:
            c.retained.append((s.index, o.index))
    for step in ic.steps_removed:
        c.removed_steps.append((old.program.x_index(step), step))
    carried = {o for _, o, _ in c.copies}
    for o in old.program.slots:
        if o.key.startswith("#pending") and o.index not in carried:
            c.lost_pending.append((o.index, o.key[len("#pending:"):]))
    return c


def _edge_input(s: Slot, inst: Instance) -> int | None:
    """The slot of the chart input whose edge ``s`` remembers (``#edge:WHERE:[↑iX].prev``),
    None if ``s`` is no such memory."""
    if not (s.key.startswith("#edge:") and s.key.endswith(".prev")):
        return None
    text = s.key[s.key.find("[") + 1:s.key.rfind("]")]
    v = inst.grafcet.variables.get(text[1:])
    if text[:1] not in ("↑", "↓") or v is None or v.kind is not VarKind.INPUT:
        return None
    return inst.program.var_index(v.name)


def apply(old: Plant, prepared: Prepared, *, restart: Collection[str] = (),
          force: bool = False) -> Applied:
    """Between two cycles, in the scan thread: check what the running state forbids, then
    carry everything or nothing. On success ``prepared.plant`` is the plant to cycle from
    the next cycle on (after the caller has closed ``closed`` and opened ``reopened``).

    O(state size): no compile, no code generation. ``restart``: instances restarted from
    their initial situation (retained values kept) instead of carried; ``force``: override
    the refusals that can be (never a type change of a retained variable). An instance
    whose last active steps ``force`` drops is put in fault (``Plant.fault_instance``:
    not scanned, its outputs off), never left running dead; one in fault stays so."""
    res = Applied()
    new = prepared.plant
    cs = prepared.changes
    if prepared._applied:
        res.refusals.append("this change was applied already: prepare it again")
        return res
    if old.pdef is not cs.old:
        res.refusals.append("the running plant changed since this change was prepared")
        return res
    for name, c in prepared._carries.items():
        if old.instances[name].program is not c.old_program:
            res.refusals.append("the running plant changed since this change was prepared")
            return res
    unknown = [r for r in restart if r not in new.instances]
    for r in unknown:
        res.refusals.append(f"--restart {r}: no such instance in the new plant")
    for why in cs.refusals:
        if not why.forceable or not force:
            res.refusals.append(why.line)
    # state-dependent checks: read the old state only
    for name, c in prepared._carries.items():
        m = old.instances[name].m
        if name in restart:
            continue
        for ix, step in c.removed_steps:
            if m[ix] and not force:
                res.refusals.append(f"{name}: step {step} removed while it is active "
                                    f"(--restart {name} restarts that instance)")
        for ix, key in c.lost_pending:
            if m[ix] and not force:
                res.refusals.append(f"{name}: the pending evolution {key} would be lost")
    if res.refusals:
        return res
    # commit: write the new plant only
    res.lines += cs.lines()
    for name, c in prepared._carries.items():
        om, nm = old.instances[name].m, new.instances[name].m
        if name in restart:
            for ni, oi in c.retained:
                nm[ni] = om[oi]
            res.restarted.append(name)
            res.lines.append(f"{name}: restarted from its initial situation (retained "
                             f"values kept)")
            continue
        for ni, oi, block in c.copies:
            v: Any = om[oi]
            nm[ni] = copy.copy(v) if block else v
        for ni, vi in c.new_edges:
            nm[ni] = bool(nm[vi])
        for ni in c.new_steps:
            nm[ni] = False
        res.lines += c.reset
        dropped = [step for ix, step in c.removed_steps if om[ix]]
        res.lines += [f"{name}: active step {step} dropped (forced)" for step in dropped]
        # a chart may empty its situation itself (a sink transition: SFCReset brings it
        # back), but never by a change: one that dropped its last active steps leaves it
        # in fault, as does one that carries an instance in fault
        if name in old.instance_faults or (
                dropped and not new.instances[name].active_steps()):
            gone = old.instance_faults.get(name) or (
                f"no active step left (the forced change dropped {', '.join(dropped)})")
            new.fault_instance(name, gone)
            res.instance_faults[name] = gone
            res.lines.append(f"{name}: in fault, its outputs off: {gone}; ack, or reload "
                             f"--restart {name}, starts it again from its initial situation")
    for d, p in prepared._unbound:
        new.drivers[d].outputs[p] = 0
        res.lines.append(f"{d}.{p}: no longer driven: off")
    res.lines += new.take_over(old, _renamer(cs))
    res.reopened = list(prepared._fresh)
    res.closed = list(prepared._dropped)
    prepared._applied = True
    return res


def _renamer(cs: ChangeSet) -> Callable[[str], str | None]:
    """Old plant name -> new plant name (None: gone), for forces."""
    def rename(name: str) -> str | None:
        head, _, rest = name.partition(".")
        if head in cs.new.drivers:
            return name if head not in cs.drivers_removed else None
        ic = cs.instances.get(head)
        if ic is None:
            return None
        back = {was: now for now, was in ic.variables.items()}
        now = back.get(rest)
        return None if now is None else f"{head}.{now}"
    return rename
