"""Property: for a random chart (tests/engine's generator) run a random while, and a random
compatible edit (a new step with a transition into it at any priority, a time constant, an
action added or changed, bool actions removed, a new variable), carrying the state then
scanning equals scanning the new chart from that state, in the three scan models. The
expected side is engine_reference.py on the new chart, its state handed over by hand by
name; the engine side is prepare + apply. An output whose last action an edit removes is
what a cold start of the new chart makes it, from the swap on (never latched at its last
value): compared with the reference from the initial situation too."""

from __future__ import annotations

import copy
import itertools
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.change.diff import chart_plant
from runtime.change.plan import apply, prepare
from runtime.compiler.evolution import UnstableChart
from runtime.engine.plant import Plant
from runtime.language.grafcetfile import load_grafcet
from tests.change.changekit import state
from tests.engine.engine_reference import Assoc, Cond, RefChart, Reference, Trans, Unstable
from tests.engine.enginekit import BOOT, MS
from tests.engine.test_engine_property import charts, conditions, scans

_serial = itertools.count()


@st.composite
def edits(draw: st.DrawFn, chart: RefChart) -> tuple[str, RefChart]:
    """(what, the edited chart): each edit keeps every step and transition; only
    ``unaction`` removes actions (bool ones: one, or every one of a target)."""
    new = copy.deepcopy(chart)
    bools = [a for a in chart.actions if a.target is not None]
    kind = draw(st.sampled_from(["step", "time", "action", "variable"]
                                + (["unaction", "unaction"] if bools else [])))
    if kind == "step":
        s = "sNew"
        into = Trans([draw(st.sampled_from(chart.steps))], [s], draw(conditions(chart.steps)))
        new.trans.insert(draw(st.integers(0, len(new.trans))), into)
        new.steps.append(s)
        new.trans.append(Trans([s], [draw(st.sampled_from(chart.steps))],
                               draw(conditions(chart.steps + [s]))))
    elif kind == "time":
        timed = [a for a in new.actions if a.qual in ("L", "D", "SD", "DS", "SL")]
        where = draw(st.sampled_from(["min", "action"] if timed else ["min"]))
        if where == "action":
            a = draw(st.sampled_from(timed))
            a.time = draw(st.sampled_from([5, 15, 25, 50])) * MS
        else:
            s = draw(st.sampled_from(chart.steps))
            new.min_ns[s] = draw(st.sampled_from([5, 15, 25, 50])) * MS
    elif kind == "action":
        stmts = [a for a in new.actions if a.target is None]
        change_one: bool = draw(st.booleans())
        if stmts and change_one:
            one: Assoc = draw(st.sampled_from(stmts))
            one.k = draw(st.integers(100, 200))
        else:
            s = draw(st.sampled_from(chart.steps))
            at = max([i + 1 for i, a in enumerate(new.actions) if a.step == s]
                     or [next((i for i, a in enumerate(new.actions)
                               if chart.steps.index(a.step) > chart.steps.index(s)),
                              len(new.actions))])
            new.actions.insert(at, draw(st.sampled_from([
                Assoc("N", s, "o1"), Assoc("S", s, "o2"), Assoc("R", s, "o0"),
                Assoc("P1", s, k=77), Assoc("N", s, k=55)])))
    elif kind == "unaction":
        target = draw(st.sampled_from(sorted({a.target for a in bools if a.target})))
        mine = [i for i, a in enumerate(new.actions) if a.target == target]
        gone = set(mine) if draw(st.booleans()) else {draw(st.sampled_from(mine))}
        new.actions = [a for i, a in enumerate(new.actions) if i not in gone]
    return kind, new


def hand_over(old: Reference, chart: RefChart) -> Reference:
    """The reference on ``chart`` from ``old``'s state, by name: steps, times, clock, edges
    (per input), stored actions and their timers (per step, qualifier and target, in order),
    the pending CODESYS evolution (per source and target steps)."""
    ref = Reference(chart)
    for f in ("first", "prev", "stored", "out", "n", "ct", "last_now", "was_paused",
              "init_pending", "reset_prev"):
        setattr(ref, f, copy.deepcopy(getattr(old, f)))
    ref.X = set(old.X)
    ref.t_act.update(old.t_act)
    ref.t_on.update(old.t_on)
    ref.t_kept.update(old.t_kept)
    pairs: list[tuple[dict[int, Any], dict[int, Any], str]] = [
        (ref.ff, old.ff, "all"), (ref.ff_start, old.ff_start, "all"),
        (ref.codesys_q, old.codesys_q, "stmt")]
    for mine, theirs, acts in pairs:
        new_ids, old_ids = _ids(chart, acts), _ids(old.c, acts)
        for i, v in theirs.items():
            if old_ids[i] in new_ids:
                mine[new_ids.index(old_ids[i])] = v
    by_steps = {(tuple(t.src), tuple(t.dst)): t for t in chart.trans}
    ref.pending = [by_steps[(tuple(t.src), tuple(t.dst))] for t in old.pending]
    for o in chart.outputs:  # the memory of S is the target's while some S sets it
        if not any(a.target == o and a.qual == "S" for a in chart.actions):
            ref.stored[o] = False
        if not any(a.target == o for a in chart.actions):  # its value of a cold start,
            ref.out[o] = False  # also through a pause (docs/online-change.md)
    return ref


def _ids(chart: RefChart, which: str) -> list[tuple]:
    acts = chart.actions if which == "all" else [a for a in chart.actions if a.target is None]
    seen: dict[tuple, int] = {}
    out = []
    for a in acts:
        key = (a.step, a.qual, a.target)
        seen[key] = seen.get(key, 0) + 1
        out.append((*key, seen[key]))
    return out


def plant_of(tmp, chart: RefChart, extra: str = "") -> tuple[Plant, str]:
    path = tmp / f"rnd{next(_serial)}.yaml"
    text = chart.yaml()
    if extra:
        text = text.replace("memory: {n: 0}", "memory: {n: 0, " + extra + "}")
    path.write_text(text, encoding="utf-8")
    plant = Plant(chart_plant(load_grafcet(str(path))), sim=True, virtual=True)
    return plant, text


def run(plant: Plant, ref: Reference, seq: list, up: int, what: str,
        cold: Reference | None = None, undriven: tuple[str, ...] = ()) -> int | None:
    """Scan both; assert they agree; the time of the next scan, None if unstable. With
    ``cold`` (the new chart from its initial situation, scanned alongside): the outputs
    ``undriven`` are also what it makes them."""
    inst = plant.instances["Rnd"]
    for k, (delta, inputs, flags) in enumerate(seq):
        for name, value in {**inputs, **flags}.items():
            inst.set(name, value)
        try:
            ref.scan(BOOT + up, inputs, flags)
        except Unstable:
            with pytest.raises(UnstableChart):
                plant.cycle(BOOT + up)
            return None
        plant.cycle(BOOT + up)
        want = ref.snapshot()
        got = {key: inst.get(key) for key in want}
        assert got == want, f"{what}: scan {k} at {up // MS} ms, inputs {inputs} {flags}"
        if cold is not None:
            try:
                cold.scan(BOOT + up, inputs, flags)
            except Unstable:
                cold = None
            else:
                started = {o: cold.out[o] for o in undriven}
                assert {o: inst.get(o) for o in undriven} == started, (
                    f"{what}: scan {k}: not what a cold start makes them")
        up += delta * MS
    return up


def check(tmp, chart: RefChart, edit: tuple[str, RefChart], before: list, after: list) -> None:
    kind, new_chart = edit
    old, old_text = plant_of(tmp, chart)
    ref = Reference(chart)
    up = run(old, ref, before, 0, "before")
    if up is None:
        return
    new, new_text = plant_of(tmp, new_chart, "m2: 5" if kind == "variable" else "")
    was = state(old)
    prep = prepare(old, new.pdef)
    res = apply(old, prep)
    assert res.refusals == [], res.refusals
    assert state(old) == was
    if kind == "variable":
        assert new.instances["Rnd"].get("m2") == 5
    undriven = tuple(o for o in new_chart.outputs
                     if not any(a.target == o for a in new_chart.actions))
    run(prep.plant, hand_over(ref, new_chart), after, up,
        f"after the edit ({kind})\n--- old\n{old_text}--- new\n{new_text}",
        Reference(new_chart), undriven)


SETTINGS = settings(max_examples=200, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


@pytest.mark.parametrize("model", ["immediate", "codesys", "stable"])
@SETTINGS
@given(data=st.data())
def test_carry_then_scan_is_the_new_chart_from_that_state(tmp_path, model, data):
    chart = data.draw(charts(model))
    edit = data.draw(edits(chart))
    check(tmp_path, chart, edit, data.draw(scans), data.draw(scans))


def _without(c: Cond, step: str) -> Cond:
    """Condition ``c`` with every mention of ``step`` replaced by a constant."""
    if c[0] in ("X", "T") and c[1] == step:
        return ("k", False)
    if c[0] == "not":
        return ("not", _without(c[1], step))
    if c[0] in ("and", "or"):
        return (c[0], _without(c[1], step), _without(c[2], step))
    return c


@st.composite
def removals(draw: st.DrawFn, chart: RefChart) -> RefChart:
    """``chart`` with one step (not s0) gone, and what names it."""
    step = draw(st.sampled_from(chart.steps[1:]))
    new = copy.deepcopy(chart)
    new.steps.remove(step)
    new.initial.discard(step)
    new.min_ns.pop(step, None)
    new.trans = [Trans(t.src, t.dst, _without(t.cond, step)) for t in new.trans
                 if step not in t.src and step not in t.dst]
    kept = []
    for a in new.actions:
        if a.step == step:
            continue
        if a.cond is not None:
            a.cond = _without(a.cond, step)
        if a.event is not None:
            a.event = _without(a.event, step)
        kept.append(a)
    new.actions = kept
    if not new.trans:  # a chart has at least one transition
        new.trans = [Trans(["s0"], ["s0"], ("k", False))]
    return new


@pytest.mark.parametrize("model", ["immediate", "codesys", "stable"])
@SETTINGS
@given(data=st.data())
def test_a_refused_change_leaves_both_plants_untouched(tmp_path, model, data):
    """Remove a random step: refused exactly when it is active (or, CODESYS, when the
    pending evolution goes with it), and then neither plant's state has moved."""
    chart = data.draw(charts(model))
    new_chart = data.draw(removals(chart))
    old, _ = plant_of(tmp_path, chart)
    if run(old, Reference(chart), data.draw(scans), 0, "before") is None:
        return
    new, _ = plant_of(tmp_path, new_chart)
    prep = prepare(old, new.pdef)
    was, fresh = state(old), state(prep.plant)
    gone = (set(chart.steps) - set(new_chart.steps)).pop()
    active = gone in old.instances["Rnd"].active_steps()
    res = apply(old, prep)
    if active:
        assert res.refusals[0] == (f"Rnd: step {gone} removed while it is active "
                                   f"(--restart Rnd restarts that instance)")
    if res.refusals:
        assert state(old) == was
        assert state(prep.plant) == fresh
        assert res.lines == [] and res.restarted == []
    else:
        assert not active
        assert state(old) == was
