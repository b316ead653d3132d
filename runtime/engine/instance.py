"""Instances: a compiled program with its own state, scanned on an injected clock.

An Instance is what a Siemens DB is to an FB: the grafcet's code is shared, the state is
the instance's own (the cells of its scan closure, seen by outside code through ``m``, a
list-like view by slot index). ``scan(now, up)`` runs one scan (semantics.md) at monotonic
time ``now`` (ns), ``up`` ns after the controller started.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.durations import format_ns, parse_literal
from runtime.compiler.evolution import min_timed
from runtime.compiler.program import Memory, Program, State
from runtime.language import ast as A
from runtime.language.model import Step, Transition, VarKind
from runtime.language.unparse import transition_text

T = A.Type


@dataclass
class TermWhy:
    text: str
    depth: int
    value: Any


@dataclass
class TransitionWhy:
    """Why an outgoing transition of an active step does or does not fire."""

    index: int
    text: str  # "gsAbrir -> gsCerrar when iAbierto"
    condition: bool
    blocked: list[str]  # reasons besides the condition
    terms: list[TermWhy] = field(default_factory=list)


@dataclass
class StepWhy:
    step: str
    time_ns: int
    transitions: list[TransitionWhy]


class Instance:
    """One running instance of a compiled grafcet."""

    def __init__(self, name: str, program: Program) -> None:
        self.name = name
        self.program = program
        self.grafcet = program.grafcet
        #: the state, slot by slot (the same view for the instance's whole life)
        self.m = State()
        #: ``scan_in(now, up, *inputs) -> outputs``, the plant's fast call (Program.Scan)
        self.scan_in, self.scan_state = program.instantiate(self.m)
        self._scan = self.scan_state
        #: slot of each variable, ``step.X`` and function block (for tests and tools)
        self.index = program.public_index()
        self.last_up = 0
        g = self.grafcet
        self._leaf = [s.name for s in g.leaf_steps()]
        self._x = [program.x_index(s) for s in self._leaf]
        self._retained = [v.name for v in g.variables.values() if v.retain]

    def scan(self, now: int, up: int) -> None:
        """One scan at monotonic time ``now`` (ns); ``up`` ns since the controller started."""
        self.last_up = up
        self._scan(now, up)

    # -- reading and writing -------------------------------------------------------
    def step_time(self, step: str) -> int:
        """``step.T`` in ns as the chart sees it now (kept after deactivation)."""
        return self.program.step_time(self.m, step)

    def active_steps(self) -> list[str]:
        m = self.m
        return [s for s, i in zip(self._leaf, self._x, strict=True) if m[i]]

    def current_step(self) -> str:
        """SFCCurrentStep: the last active step in file order, or ''."""
        act = self.active_steps()
        return act[-1] if act else ""

    def get(self, key: str) -> Any:
        """Value of ``var``, ``step.X``, ``step.T`` (ns) or a chart flag."""
        if key.endswith(".T") and key[:-2] in self.grafcet.steps:
            return self.step_time(key[:-2])
        if key == "SFCCurrentStep":
            return self.current_step()
        if key.endswith(".X") and key[:-2] in self.grafcet.steps:
            return self.m[self.program.x_index(key[:-2])]
        return self.program.read(self.m, key)

    def set(self, key: str, value: Any) -> None:
        """Write a variable or chart flag (between scans)."""
        v = self.grafcet.variables.get(key)
        if v is None or v.kind is VarKind.SYSTEM or v.type is T.STRING:
            raise KeyError(key)
        self.program.write(self.m, key, coerce(v.type, value))

    def names(self) -> list[str]:
        """Every readable name: variables, flags, step.X and step.T."""
        g = self.grafcet
        out = [v.name for v in g.variables.values() if v.kind is not VarKind.SYSTEM]
        for s in g.steps:
            out += [f"{s}.X", f"{s}.T"]
        return out

    # -- retain and restart --------------------------------------------------------
    def retain_snapshot(self) -> dict[str, Any]:
        m, read = self.m, self.program.read
        return {name: read(m, name) for name in self._retained}

    def restore_retain(self, data: dict[str, Any]) -> list[str]:
        """Restore retained memory; returns the names that were ignored (unknown, bad type)."""
        ignored = []
        for name, value in data.items():
            v = self.grafcet.variables.get(name)
            if v is None or not v.retain:
                ignored.append(name)
                continue
            try:
                self.program.write(self.m, name, coerce(v.type, value))
            except (TypeError, ValueError):
                ignored.append(name)
        return ignored

    def restart(self) -> None:
        """Back to the initial situation, as at power-up; retained memory is kept."""
        kept = self.retain_snapshot()
        m = self.m
        for i, value in enumerate(self.program.new_state()):
            m[i] = value
        self.restore_retain(kept)

    # -- explain ---------------------------------------------------------------------
    def explain(self) -> list[StepWhy]:
        """For each active step, each outgoing transition and why it does (not) fire.

        Values are those of the last scan (edges as they were sampled in it)."""
        return explain(self.program, self.m, self.last_up)


def explain(prog: Program, m: Memory, up: int) -> list[StepWhy]:
    """``Instance.explain`` on a state ``m``: the live one between two scans, or a copy
    of it (``m.values()``, as the feed captures it; its function blocks are the live
    objects)."""
    g = prog.grafcet
    now = prog.scan_time(m)
    paused = prog.chart_paused(m)
    tipmode = bool(prog.read(m, "SFCTipMode"))
    held = [f for f in ("SFCInit", "SFCReset") if prog.read(m, f)]
    out = []
    values: dict[int, bool] = {}
    for t in g.transitions:
        values[t.index] = bool(prog.probes[t.index][0].fn(m, now, up))

    def early(t: Transition) -> list[Step]:
        """The steps left by ``t`` whose min time is not reached."""
        return [st for st in min_timed(g, t) if prog.step_time(m, st.name) < (st.min_ns or 0)]

    # the firing rule of semantics.md, on the situation and values of the last scan
    fires: dict[int, bool] = {}
    taken: set[str] = set()
    for t in g.transitions:
        src = set(t.src_steps)
        fires[t.index] = (all(prog.step_active(m, s) for s in src) and not (src & taken)
                          and not early(t) and values[t.index])
        if fires[t.index]:
            taken |= src
    for step in [s.name for s in g.leaf_steps() if prog.step_active(m, s.name)]:
        whys = []
        for t in g.transitions:
            if step not in t.src_steps:
                continue
            blocked = [f"{f}: the chart is held in its initial situation" for f in held]
            if paused:
                blocked.append("chart paused (SFCPause/SFCQuitError)")
            if tipmode:
                blocked.append("SFCTipMode: fires only on ↑SFCTip")
            for s in t.src_steps:
                if not prog.step_active(m, s):
                    blocked.append(f"source step {s} not active")
            for st in early(t):
                blocked.append(f"min time of {st.name}: "
                               f"{format_ns(prog.step_time(m, st.name))} of "
                               f"{format_ns(st.min_ns or 0)}")
            for e in g.transitions[:t.index]:
                if set(e.src_steps) & set(t.src_steps) and fires[e.index]:
                    blocked.append(f"earlier transition has priority: "
                                   f"{','.join(e.sources)} -> {','.join(e.targets)} "
                                   f"when {e.text}")
            terms = [TermWhy(p.text, p.depth, _plain(p.fn(m, now, up)))
                     for p in prog.probes[t.index]]
            whys.append(TransitionWhy(t.index, transition_text(t), values[t.index],
                                      blocked, terms))
        out.append(StepWhy(step, prog.step_time(m, step), whys))
    return out


def _plain(v: Any) -> Any:
    return int(v) if isinstance(v, bool) else v


def coerce(t: A.Type, value: Any) -> Any:
    """Convert an external value (script, console, retain file) to a variable's type."""
    if t is T.BOOL:
        if isinstance(value, str):
            if value.strip().lower() in ("1", "true", "on"):
                return True
            if value.strip().lower() in ("0", "false", "off"):
                return False
            raise ValueError(f"expected a bool (0/1/true/false), found '{value}'")
        if value not in (0, 1, True, False):
            raise ValueError(f"expected a bool (0/1), found {value!r}")
        return bool(value)
    if t is T.INT:
        if isinstance(value, float) and not value.is_integer():
            raise ValueError(f"expected an int, found {value!r}")
        return int(value)
    if t is T.REAL:
        return float(value)
    if t is T.TIME:
        if isinstance(value, str):
            text = value.split("#", 1)[-1]
            ns = parse_literal(text)
            if ns is None:
                raise ValueError(f"expected a time like 10s, found '{value}'")
            return ns
        return int(value)
    return value
