"""Two traps users fell into, found on one chart: G210 a stored action that nothing resets,
G211 a transition under ``scan: stable`` reading a timer that its own source step starts.

Both are warnings (docs/check.md gives the rationale and the fix of each).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from runtime.checker.diag import Diag, diag
from runtime.errors import Loc
from runtime.language import ast as A
from runtime.language.model import Action, Grafcet, Qualifier, ScanModel, Transition

#: qualifiers that store their target until an R: without one it stays set for good (S,
#: SD, DS), or, for SL, the flip-flop stays set so only the first activation drives it
STORED = (Qualifier.S, Qualifier.SD, Qualifier.DS, Qualifier.SL)
#: chart flags that clear every stored action when the chart writes them itself
CLEARING_FLAGS = ("SFCInit", "SFCReset")
#: what a transition may read of a timer: the seed timer's methods, an IEC timer's outputs
TIMER_READS = ("End", "Val")
TIMER_BLOCKS = ("TON", "TOF", "TP")
BLOCK_READS = ("Q", "ET")


# -- every statement of a chart ------------------------------------------------------------
def _action_nodes(a: Action) -> Iterator[A.Node]:
    for root in a.body or []:
        yield from A.walk(root)


def _all_statement_nodes(g: Grafcet) -> Iterator[A.Node]:
    for st in [*g.pre, *g.post]:
        yield from A.walk(st.node)
    for a in g.actions():
        yield from _action_nodes(a)


def _written(n: A.Node) -> str | None:
    """The variable a node writes: ``x := ...`` or ``x.Set(v, c)``."""
    if isinstance(n, A.Assign):
        return n.target.name
    if isinstance(n, A.MethodCall) and n.method == "Set":
        return n.obj
    return None


# -- G210 --------------------------------------------------------------------------------
def latched_targets(g: Grafcet) -> list[Diag]:
    """G210: a bool target stored by S (SD, DS, SL) that no R of the chart ever resets.

    What counts as a reset: an ``R target`` action in any step, or the chart writing
    SFCInit or SFCReset itself (both clear every stored action). An assignment
    (``target := FALSE``) does not: the action control stores the S and writes the target
    again in the next scan. A reset by the plant (a chart flag bound to another instance or
    a point) is not seen from the chart: the fix, an R in the initial step, costs nothing
    then."""
    writes = [w for n in _all_statement_nodes(g) if (w := _written(n)) is not None]
    flag_targets = {a.target for a in g.actions() if a.target in CLEARING_FLAGS}
    if any(w in CLEARING_FLAGS for w in writes) or flag_targets:
        return []
    by_target: dict[str, list[Action]] = {}
    for a in g.actions():
        if a.target is not None:
            by_target.setdefault(a.target, []).append(a)
    out: list[Diag] = []
    for target, assocs in by_target.items():
        if any(a.qualifier is Qualifier.R for a in assocs):
            continue
        stored = [a for a in assocs if a.qualifier in STORED]
        if not stored:
            continue
        first = stored[0]
        steps = ", ".join(dict.fromkeys(f"'{a.step}'" for a in stored))
        quals = "/".join(dict.fromkeys(a.qualifier.value for a in stored))
        if all(a.qualifier is Qualifier.SL for a in stored):
            what = ("the SL flip-flop stays set, so only the first activation drives "
                    f"'{target}' for its time, never the next ones")
        else:
            what = f"once set, '{target}' stays true for good (until the chart restarts)"
        assign = (f"; the assignment to '{target}' in a statement does not reset it: the "
                  "stored action sets it again in the next scan"
                  if target in writes else "")
        out.append(diag(first.loc, "warning", "G210", f"'{target}' is stored by {quals} "
                        f"in step {steps} and no 'R {target}' resets it: {what}{assign}; "
                        f"add 'R {target}' to the step that ends it (the initial step, "
                        "at least), or use N if it should follow the step"))
    return out


# -- G211 --------------------------------------------------------------------------------
@dataclass(frozen=True)
class TimerRead:
    timer: str  # a seed timer or an IEC timer block
    text: str  # as written in the condition (or in the temporary's definition)
    loc: Loc


def _timer_reads(g: Grafcet, t: Transition, defs: Mapping[str, A.Node]) -> list[TimerRead]:
    """The timers ``t``'s condition reads, through the temporaries of pre it reads."""
    blocks = {n for n, b in g.blocks.items() if b.kind in TIMER_BLOCKS}
    out: list[TimerRead] = []

    def visit(n: A.Node, via: A.Name | None, seen: frozenset[str]) -> None:
        for x in A.walk(n):
            if isinstance(x, A.Name) and x.name in defs and x.name not in seen:
                visit(defs[x.name], via or x, seen | {x.name})
                continue
            name = None
            if isinstance(x, A.MethodCall) and x.obj in g.timers and x.method in TIMER_READS:
                name, text = x.obj, f"{x.obj}.{x.method}()"
            elif isinstance(x, A.Member) and x.obj in blocks and x.member in BLOCK_READS:
                name, text = x.obj, f"{x.obj}.{x.member}"
            if name is not None:
                where = t.at(x.start) if via is None else t.at(via.start)
                shown = text if via is None else f"{via.name} (= ...{text}...)"
                out.append(TimerRead(name, shown, where))

    visit(t.cond, None, frozenset())
    return out


def _starts(a: Action, timer: str) -> bool:
    """Does action ``a`` start (or run) ``timer``: ``timer.Ini(...)``, ``timer(IN := ...)``?"""
    for x in _action_nodes(a):
        if isinstance(x, A.MethodCall) and x.obj == timer and x.method == "Ini":
            return True
        if isinstance(x, A.FbCall) and x.block == timer:
            return True
    return False


def stale_timer_reads(g: Grafcet, defs: Mapping[str, A.Node]) -> list[Diag]:
    """G211: under ``scan: stable``, a transition reading a timer that an action of one of
    its own source steps starts. No action runs during the search for a stable situation,
    so when the search enters the step, the transition reads the timer as the last run
    left it (ended) and passes through the step in the same scan. ``defs``: the
    temporaries of pre that stand for their definition (runtime/checker/logic.py)."""
    if g.scan is not ScanModel.STABLE:
        return []
    out: list[Diag] = []
    for t in g.transitions:
        sources = list(dict.fromkeys([*t.src_steps, *t.sources]))
        done: set[str] = set()
        for r in _timer_reads(g, t, defs):
            if r.timer in done:
                continue
            starter = next(((s, a) for s in sources if s in g.steps
                            for a in g.steps[s].actions if _starts(a, r.timer)), None)
            if starter is None:
                continue
            done.add(r.timer)
            step, a = starter
            out.append(diag(r.loc, "warning", "G211", f"under scan: stable, the transition "
                            f"{', '.join(t.sources)} → {', '.join(t.targets) or '(sink)'} "
                            f"reads {r.text}, which the action '{a.text}' (line "
                            f"{a.loc.line}) of its source step '{step}' starts: no action "
                            "runs during the search for a stable situation, so when the "
                            f"search enters '{step}' the transition sees the timer as the "
                            "last run left it and, once it has ended, passes through "
                            f"'{step}' in the same scan; read the step's own time "
                            f"('{step}.T >= ...'), or run the timer in pre (IN := "
                            f"{step}.X)"))
    return out
