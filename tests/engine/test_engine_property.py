"""Property tests: the compiled engine agrees, scan by scan, with engine_reference.py on random
charts (OR/AND divergences, source/sink transitions, self loops, min times, every action
qualifier) under random inputs and an irregular virtual clock."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.compiler.codegen import compile_grafcet
from runtime.compiler.evolution import UnstableChart
from runtime.engine.instance import Instance
from runtime.language.grafcetfile import load_grafcet
from tests.engine.engine_reference import Assoc, Cond, RefChart, Reference, Trans, Unstable
from tests.engine.enginekit import BOOT, MS

INPUTS = ("a", "b", "c")
OUTPUTS = ("o0", "o1", "o2")
_serial = itertools.count()


def conditions(steps: list[str], edges: bool = True) -> st.SearchStrategy:
    leaves = [st.sampled_from(INPUTS).map(lambda i: ("in", i)),
              st.sampled_from(steps).map(lambda s: ("X", s)),
              st.tuples(st.just("T"), st.sampled_from(steps),
                        st.sampled_from([0, 10, 20, 40]).map(lambda t: t * MS)),
              st.booleans().map(lambda b: ("k", b))]
    if edges:
        leaves.append(st.tuples(st.sampled_from(["re", "fe"]), st.sampled_from(INPUTS)))
    return st.recursive(
        st.one_of(*leaves),
        lambda inner: st.one_of(inner.map(lambda c: ("not", c)),
                                st.tuples(st.sampled_from(["and", "or"]), inner, inner)),
        max_leaves=3)


@st.composite
def charts(draw: st.DrawFn, model: str) -> RefChart:
    n = draw(st.integers(2, 5))
    steps = [f"s{i}" for i in range(n)]
    initial = {"s0"} | {s for s in steps[1:] if draw(st.integers(0, 5)) == 0}
    min_ns = {s: draw(st.sampled_from([10, 20, 30])) * MS for s in steps
              if draw(st.integers(0, 4)) == 0}
    trans = []
    for _ in range(draw(st.integers(1, 7))):
        source = draw(st.integers(0, 6)) == 0  # a source transition: no upstream step
        sink = not source and draw(st.integers(0, 6)) == 0  # a sink: no downstream step
        src = [] if source else draw(st.lists(st.sampled_from(steps), min_size=1, max_size=2,
                                              unique=True))
        dst = [] if sink else draw(st.lists(st.sampled_from(steps), min_size=1, max_size=2,
                                            unique=True))
        trans.append(Trans(src, dst, draw(conditions(steps))))
    actions: list[Assoc] = []
    k = itertools.count(1)
    for s in steps:
        for _ in range(draw(st.integers(0, 3))):
            kind = draw(st.sampled_from(["N", "S", "R", "L", "D", "P", "SD", "DS", "SL", "Nif",
                                         "sN", "sL", "sD", "sP", "sP1", "sP0", "sEV"]))
            time = draw(st.sampled_from([10, 20, 30])) * MS
            if kind.startswith("s"):
                q = kind[1:]
                if q == "EV":
                    ev: Cond = draw(st.tuples(st.sampled_from(["re", "fe"]),
                                              st.sampled_from(INPUTS)))
                    if draw(st.booleans()):
                        ev = ("and", ev, draw(conditions(steps, edges=False)))
                    actions.append(Assoc("EVENT", s, event=ev, k=next(k)))
                else:
                    actions.append(Assoc(q, s, time=time, k=next(k)))
            else:
                target = draw(st.sampled_from(OUTPUTS))
                if kind == "Nif":
                    actions.append(Assoc("N", s, target, cond=draw(conditions(steps, False))))
                else:
                    actions.append(Assoc(kind, s, target, time=time))
    return RefChart(steps, initial, trans, actions, min_ns, INPUTS, OUTPUTS, model)


NO_FLAG = {"SFCInit": False, "SFCReset": False, "SFCPause": False}
FLAGS = [NO_FLAG] * 12 + [{**NO_FLAG, f: True} for f in NO_FLAG]
scans = st.lists(st.tuples(st.sampled_from([5, 10, 10, 20]),
                           st.fixed_dictionaries({i: st.booleans() for i in INPUTS}),
                           st.sampled_from(FLAGS)),
                 min_size=1, max_size=25)


def check(tmp_path_factory: pytest.TempPathFactory, chart: RefChart, seq: list) -> None:
    text = chart.yaml()
    path = tmp_path_factory.getbasetemp() / f"rnd{next(_serial)}.yaml"
    path.write_text(text, encoding="utf-8")
    inst = Instance("rnd", compile_grafcet(load_grafcet(str(path))))
    ref = Reference(chart)
    up = 0
    for k, (delta, inputs, flags) in enumerate(seq):
        for name, value in {**inputs, **flags}.items():
            inst.set(name, value)
        now = BOOT + up
        try:
            ref.scan(now, inputs, flags)
        except Unstable:
            with pytest.raises(UnstableChart):
                inst.scan(now, up)
            return
        inst.scan(now, up)
        want = ref.snapshot()
        got = {key: inst.get(key) for key in want}
        on = [f for f, v in flags.items() if v]
        assert got == want, f"scan {k} at {up // MS} ms, inputs {inputs} {on}\n{text}"
        up += delta * MS


SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@SETTINGS
@given(chart=charts("immediate"), seq=scans)
def test_immediate_engine_agrees_with_the_reference(tmp_path_factory, chart, seq):
    check(tmp_path_factory, chart, seq)


@SETTINGS
@given(chart=charts("codesys"), seq=scans)
def test_codesys_engine_agrees_with_the_reference(tmp_path_factory, chart, seq):
    check(tmp_path_factory, chart, seq)


@SETTINGS
@given(chart=charts("stable"), seq=scans)
def test_stable_engine_agrees_with_the_reference(tmp_path_factory, chart, seq):
    check(tmp_path_factory, chart, seq)
