"""A plain reference interpreter of semantics.md, for random charts (property tests).

Written from the text of semantics.md, not from the compiler: a chart is a few Python
objects, a scan is a loop over them. It covers what the random charts use: steps (initial,
min time), transitions (OR/AND divergence and convergence, source and sink transitions,
self loops), conditions over inputs, their edges and step flags, bool actions with every
qualifier, statement actions (N, L, D, P, P1, P0, on EVENT) that all update one int ``n``,
for ``scan: immediate``, ``scan: codesys`` and ``scan: stable``, and the chart flags
SFCInit, SFCReset and SFCPause. Time is in ns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

# -- conditions: small tuples ---------------------------------------------------------------
# ("in", "a") ("re", "a") ("fe", "a") ("not", c) ("and", c, c) ("or", c, c)
# ("X", "s1") ("T", "s1", ns) meaning s1.T >= ns, ("k", True/False)
Cond = tuple


def cond_text(c: Cond) -> str:
    op = c[0]
    if op == "in":
        return c[1]
    if op == "re":
        return f"RE {c[1]}"
    if op == "fe":
        return f"FE {c[1]}"
    if op == "not":
        return f"NOT ({cond_text(c[1])})"
    if op in ("and", "or"):
        return f"({cond_text(c[1])} {op.upper()} {cond_text(c[2])})"
    if op == "X":
        return f"{c[1]}.X"
    if op == "T":
        return f"({c[1]}.T >= {c[2] // 1_000_000}ms)"
    return "TRUE" if c[1] else "FALSE"


@dataclass
class Assoc:
    """One action of one step."""

    qual: str  # N S R L D P SD DS SL (bool) | N L D P P1 P0 EVENT (statement)
    step: str
    target: str | None = None  # bool target
    time: int = 0  # ns, for L D SD DS SL
    cond: Cond | None = None  # N x if C
    event: Cond | None = None  # on EVENT do
    k: int = 0  # statement: n := (n * 7 + k) MOD 1000

    def text(self) -> str:
        t = f" {self.time // 1_000_000}ms" if self.qual in ("L", "D", "SD", "DS", "SL") else ""
        if self.target is not None:
            cond = f" if {cond_text(self.cond)}" if self.cond is not None else ""
            return f"{self.qual}{t} {self.target}{cond}"
        body = f"n := (n * 7 + {self.k}) MOD 1000"
        if self.qual == "EVENT":
            return f"on {cond_text(self.event)} do {body}"  # type: ignore[arg-type]
        return f"{self.qual}{t} {body}"


@dataclass
class Trans:
    src: list[str]
    dst: list[str]
    cond: Cond


@dataclass
class RefChart:
    steps: list[str]
    initial: set[str]
    trans: list[Trans]
    actions: list[Assoc]  # file order: steps in order, each step's actions as written
    min_ns: dict[str, int] = field(default_factory=dict)
    inputs: tuple[str, ...] = ("a", "b", "c")
    outputs: tuple[str, ...] = ("o0", "o1", "o2")
    model: str = "immediate"

    def yaml(self) -> str:
        lines = [f"grafcet: Rnd\nscan: {self.model}", f"inputs: [{', '.join(self.inputs)}]",
                 f"outputs: [{', '.join(self.outputs)}]", "memory: {n: 0}", "steps:"]
        for s in self.steps:
            acts = ", ".join(f'"{a.text()}"' for a in self.actions if a.step == s)
            extra = ", initial: true" if s in self.initial else ""
            if s in self.min_ns:
                extra += f", min: {self.min_ns[s] // 1_000_000}ms"
            lines.append(f"  {s}: {{actions: [{acts}]{extra}}}")
        lines.append("transitions:")
        for t in self.trans:
            lines.append(f"  - {{from: [{', '.join(t.src)}], to: [{', '.join(t.dst)}], "
                         f"when: \"{cond_text(t.cond)}\"}}")
        return "\n".join(lines) + "\n"


STABLE_MAX_ROUNDS = 100


class Unstable(Exception):
    """More than STABLE_MAX_ROUNDS rounds of the stable search."""


class Reference:
    """The state of one instance of a RefChart and its scan."""

    def __init__(self, chart: RefChart) -> None:
        self.c = chart
        self.X: set[str] = set(chart.initial)  # before the first scan: initial situation
        self.t_act = {s: 0 for s in chart.steps}  # now of the activating scan
        #: now of the scan X rose in: L, D and DS count from it (a rule-5 re-entry leaves
        #: X TRUE, so IEC's ACTION_CONTROL timers go on)
        self.t_on = {s: 0 for s in chart.steps}
        self.t_kept = {s: 0 for s in chart.steps}  # .T frozen at deactivation
        self.first = True
        self.prev: dict[str, bool] = {}
        self.stored: dict[str, bool] = {o: False for o in chart.outputs}  # S
        self.ff: dict[int, bool] = {}  # SD/DS/SL flip-flops, per association
        self.ff_start: dict[int, int] = {}
        self.codesys_q: dict[int, bool] = {}  # L/D statement actions' Q of the last scan
        self.out: dict[str, bool] = {o: False for o in chart.outputs}
        self.n = 0
        self.pending: list[Trans] = []  # codesys: the evolution decided by the last scan
        self.ct = 0  # the chart clock
        self.last_now = 0
        self.was_paused = False
        self.init_pending = False
        self.reset_prev = False

    # -- values ------------------------------------------------------------------------
    def T(self, s: str, now: int) -> int:
        return now - self.t_act[s] if s in self.X else self.t_kept[s]

    def on_for(self, s: str, now: int) -> int:
        """How long the step has been active without a break (rule 5 is none)."""
        return now - self.t_on[s]

    def ev(self, c: Cond, now: int, inp: dict[str, bool], rise: dict[str, bool],
           fall: dict[str, bool]) -> bool:
        op = c[0]
        if op == "in":
            return inp[c[1]]
        if op == "re":
            return rise[c[1]]
        if op == "fe":
            return fall[c[1]]
        if op == "not":
            return not self.ev(c[1], now, inp, rise, fall)
        if op == "and":
            return self.ev(c[1], now, inp, rise, fall) and self.ev(c[2], now, inp, rise, fall)
        if op == "or":
            return self.ev(c[1], now, inp, rise, fall) or self.ev(c[2], now, inp, rise, fall)
        if op == "X":
            return c[1] in self.X
        if op == "T":
            return self.T(c[1], now) >= c[2]
        return bool(c[1])

    # -- evolution ------------------------------------------------------------------------
    def firing(self, now: int, env: tuple) -> list[Trans]:
        """The transitions that fire on the situation X (file order = priority)."""
        taken: set[str] = set()
        fired = []
        for t in self.c.trans:
            if not all(s in self.X for s in t.src):
                continue
            if taken & set(t.src):
                continue
            if any(self.T(s, now) < self.c.min_ns.get(s, 0) for s in t.src):
                continue
            if self.ev(t.cond, now, *env):
                fired.append(t)
                taken |= set(t.src)
        return fired

    def apply(self, fired: list[Trans], now: int) -> tuple[set[str], set[str]]:
        """Deactivate every source, then activate every target; returns (activated, left)."""
        out = {s for t in fired for s in t.src}
        into = {s for t in fired for s in t.dst}
        activated, left = set(), set()
        for s in out:
            if s in into:  # rule 5: stays active, .T restarts, not "activated"
                self.t_act[s] = now
            else:
                self.X.discard(s)
                self.t_kept[s] = now - self.t_act[s]
                left.add(s)
        for s in into - out:
            if s not in self.X:  # an already active step: nothing changes
                self.X.add(s)
                self.t_act[s] = self.t_on[s] = now
                activated.add(s)
        return activated, left

    def search(self, now: int, env: tuple) -> tuple[set[str], set[str]]:
        """scan: stable: evolve until no transition fires; edges in the first round only."""
        activated: set[str] = set()
        left: set[str] = set()
        inp, rise, fall = env
        no_edge = {k: False for k in inp}
        for rounds in range(1, STABLE_MAX_ROUNDS + 2):
            fired = self.firing(now, env if rounds == 1 else (inp, no_edge, no_edge))
            if not fired:
                break
            if rounds > STABLE_MAX_ROUNDS:
                raise Unstable(fired)
            a, lf = self.apply(fired, now)
            activated |= a
            left |= lf
        return activated, left

    # -- the scan ---------------------------------------------------------------------------
    def to_initial(self, ct: int) -> None:
        """Situation = initial steps, every .T = 0 (SFCInit, SFCReset, cycle 0)."""
        self.X = set(self.c.initial)
        for s in self.c.steps:
            self.t_act[s] = self.t_on[s] = ct
            self.t_kept[s] = 0
        self.pending = []

    def reset_stored(self) -> None:
        self.stored = {o: False for o in self.c.outputs}
        self.ff.clear()
        self.codesys_q.clear()

    def scan(self, now: int, inp: dict[str, bool], flags: dict[str, bool] | None = None) -> None:
        flags = flags or {}
        # the chart clock: step times and action timers do not count paused intervals
        if self.first:
            self.ct = 0
        elif not self.was_paused:
            self.ct += now - self.last_now
        self.last_now = now
        ct = self.ct
        rise = {k: not self.first and v and not self.prev.get(k, False) for k, v in inp.items()}
        fall = {k: not self.first and not v and self.prev.get(k, False) for k, v in inp.items()}
        self.prev = dict(inp)
        env = (inp, rise, fall)
        activated: set[str] = set()
        left: set[str] = set()
        evolve, act, paused = False, True, False
        if flags.get("SFCInit"):  # initial situation, no action, stored actions reset
            self.to_initial(ct)
            self.reset_stored()
            self.init_pending = True
            act = False
        elif self.first or self.init_pending:  # cycle 0, or SFCInit fell: activation
            self.init_pending = False
            self.to_initial(ct)
            activated = set(self.c.initial)
        elif flags.get("SFCReset"):  # initial situation, its actions execute
            self.reset_stored()
            self.to_initial(ct)
            if not self.reset_prev:
                activated = set(self.c.initial)
        elif flags.get("SFCPause"):
            paused = True
        else:
            evolve = True
        self.reset_prev = bool(flags.get("SFCReset"))
        if evolve:
            if self.c.model == "codesys":
                activated, left = self.apply(self.pending, ct)
            elif self.c.model == "stable":
                activated, left = self.search(ct, env)
            else:
                activated, left = self.apply(self.firing(ct, env), ct)
        if act and not paused:
            if self.c.model == "codesys":
                self.codesys_actions(ct, env, activated, left)
            else:
                self.bool_actions(ct, env, activated)
                for a in self.stmt_actions():
                    if self.runs(a, ct, env, activated, left):
                        self.execute(a)
        elif not act:
            self.out = {o: False for o in self.c.outputs}
        if self.c.model == "codesys" and evolve:
            self.pending = self.firing(ct, env)  # a pending evolution waits out a pause
        self.was_paused = paused
        self.first = False

    def snapshot(self) -> dict[str, Any]:
        ct = self.ct
        out: dict[str, Any] = {f"{s}.X": s in self.X for s in self.c.steps}
        out.update({f"{s}.T": self.T(s, ct) for s in self.c.steps})
        out.update(self.out)
        out["n"] = self.n
        return out

    def stmt_actions(self) -> list[Assoc]:
        return [a for a in self.c.actions if a.target is None]

    def execute(self, a: Assoc) -> None:
        self.n = (self.n * 7 + a.k) % 1000

    def passed(self, step: str, activated: set[str]) -> bool:
        """Active, or (stable) activated during this scan's search: for stored actions."""
        return step in self.X or (self.c.model == "stable" and step in activated)

    def runs(self, a: Assoc, now: int, env: tuple, activated: set[str], left: set[str]) -> bool:
        active = a.step in self.X
        q = a.qual
        if q == "N":
            return active
        if q == "L":
            return active and self.on_for(a.step, now) < a.time
        if q == "D":
            return active and self.on_for(a.step, now) >= a.time
        if q in ("P", "P1"):
            return a.step in activated
        if q == "P0":
            return a.step in left
        return self.passed(a.step, activated) and self.ev(a.event, now, *env)  # type: ignore

    def codesys_actions(self, now: int, env: tuple, activated: set[str], left: set[str]) -> None:
        stmts = self.stmt_actions()
        for q in ("P0", "P1"):
            for a in stmts:
                if a.qual == q and self.runs(a, now, env, activated, left):
                    self.execute(a)
        self.bool_actions(now, env, activated)
        for i, a in enumerate(stmts):  # final scan of IEC actions of the steps left
            if a.qual in ("N", "P") and a.step in left:
                self.execute(a)
            if a.qual in ("L", "D") and a.step in left and self.codesys_q.get(i, False):
                self.execute(a)
        for i, a in enumerate(stmts):
            if a.qual in ("P0", "P1"):
                continue
            run = self.runs(a, now, env, activated, left)
            if a.qual in ("L", "D"):
                self.codesys_q[i] = run
            if run:
                self.execute(a)

    def bool_actions(self, now: int, env: tuple, activated: set[str]) -> None:
        for o in self.c.outputs:
            assocs = [(i, a) for i, a in enumerate(self.c.actions) if a.target == o]
            act = [(i, a) for i, a in assocs if self.passed(a.step, activated)]
            reset = any(a.qual == "R" for _, a in act)
            self.stored[o] = (self.stored[o] or any(a.qual == "S" for _, a in act)) and not reset
            q = self.stored[o]
            for i, a in assocs:
                active = a.step in self.X
                t = self.on_for(a.step, now)  # L, D, DS: since X rose
                if a.qual == "N":
                    q |= active and (a.cond is None or self.ev(a.cond, now, *env))
                elif a.qual == "L":
                    q |= active and t < a.time
                elif a.qual == "D":
                    q |= active and t >= a.time
                elif a.qual == "P":
                    q |= a.step in activated
                elif a.qual in ("SD", "SL"):  # RS flip-flop on the step, a timer on it
                    was = self.ff.get(i, False)
                    now_ff = not reset and (was or self.passed(a.step, activated))
                    if now_ff and not was:
                        self.ff_start[i] = now
                    self.ff[i] = now_ff
                    el = now - self.ff_start.get(i, now)
                    q |= now_ff and (el >= a.time if a.qual == "SD" else el < a.time)
                elif a.qual == "DS":  # a timer on the step's X, then an RS flip-flop
                    self.ff[i] = not reset and (self.ff.get(i, False) or (active and t >= a.time))
                    q |= self.ff[i]
            self.out[o] = bool(q) and not reset
