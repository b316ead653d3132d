"""Properties over generated charts and generated PLCopen files.

- import(export(chart)) is the chart, for random charts of tests/engine's generator (OR/AND
  divergences and convergences, source and sink transitions, self loops, min times, every
  qualifier, the three scan models), and the export is valid against the schema.
- export(import(file)) keeps every element of the file, for random PLCopen files written
  here the way editors write them (divergences, convergences, jump steps, priorities,
  conditions inline, by reference, drawn with contacts or variables, actions inline, on
  variables or POU actions, every qualifier), their elements in a random order: the file's
  steps, transitions and action associations are all in the imported chart, and importing
  the chart's export gives the same chart again.
"""

from __future__ import annotations

import itertools
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.language.grafcetfile import load_grafcet
from tests.engine.engine_reference import RefChart
from tests.engine.test_engine_property import charts
from tests.plcopen.plcopenkit import export_file, import_back, shape

#: PLCOPEN_PROP_EXAMPLES=2000 for a longer search
SETTINGS = settings(max_examples=int(os.environ.get("PLCOPEN_PROP_EXAMPLES", "60")), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])
_serial = itertools.count()


def _dir(factory: pytest.TempPathFactory) -> Path:
    d = factory.getbasetemp() / f"prop{next(_serial)}"
    d.mkdir()
    return d


@SETTINGS
@given(chart=st.sampled_from(["immediate", "codesys", "stable"]).flatmap(charts))
def test_import_of_the_export_is_the_chart(tmp_path_factory: pytest.TempPathFactory,
                                           tc6: Any, chart: RefChart) -> None:
    d = _dir(tmp_path_factory)
    (d / "c.yaml").write_text(chart.yaml(), encoding="utf-8")
    g = load_grafcet(str(d / "c.yaml"))
    xml = export_file(g, d / "c.xml")
    tc6.validate(str(xml))
    back, _ = import_back(xml, d / "back.yaml")
    assert shape(back) == shape(g)


# -- generated PLCopen files ---------------------------------------------------------------
INPUTS = ("a", "b", "c")
OUTPUTS = ("o0", "o1", "o2")
TIMED = ("L", "D", "SD", "DS", "SL")


@dataclass
class GenChart:
    """What a generated file holds, to check the import against."""

    steps: list[str]
    initial: set[str]
    trans: list[tuple[list[str], list[str]]]
    actions: dict[str, list[str]]  # step -> qualifiers, in order
    xml: str = ""
    ids: itertools.count = field(default_factory=lambda: itertools.count(1))  # type: ignore[type-arg]


def _cond(draw: st.DrawFn, gen: GenChart, net: list[str], pou: list[str]) -> str:
    kind = draw(st.sampled_from(["inline", "variable", "contacts", "reference"]))
    if kind == "inline":
        expr = draw(st.sampled_from(["a", "NOT b", "a AND c", "b OR NOT c", "TRUE"]))
        return f'<inline name=""><ST><xhtml:p><![CDATA[{expr}]]></xhtml:p></ST></inline>'
    if kind == "variable":
        i = next(gen.ids)
        net.append(f'<inVariable localId="{i}"><position x="0" y="0"/><connectionPointOut/>'
                   f'<expression>{draw(st.sampled_from(["a OR b", "c", "NOT a"]))}'
                   '</expression></inVariable>')
        return f'<connectionPointIn><connection refLocalId="{i}"/></connectionPointIn>'
    if kind == "contacts":
        rail, c1, c2 = next(gen.ids), next(gen.ids), next(gen.ids)
        neg = draw(st.booleans())
        net.append(f'<leftPowerRail localId="{rail}"><position x="0" y="0"/>'
                   '<connectionPointOut formalParameter=""/></leftPowerRail>'
                   f'<contact localId="{c1}" negated="{str(neg).lower()}"><position x="0" '
                   f'y="0"/><connectionPointIn><connection refLocalId="{rail}"/>'
                   '</connectionPointIn><connectionPointOut/><variable>a</variable></contact>'
                   f'<contact localId="{c2}"><position x="0" y="0"/><connectionPointIn>'
                   f'<connection refLocalId="{c1}"/></connectionPointIn><connectionPointOut/>'
                   '<variable>b</variable></contact>')
        return f'<connectionPointIn><connection refLocalId="{c2}"/></connectionPointIn>'
    name = f"Tr{len(pou)}"
    pou.append(f'<transition name="{name}"><body><ST><xhtml:p><![CDATA[{name} := '
               f'{draw(st.sampled_from(["a", "b AND c"]))};]]></xhtml:p></ST></body>'
               '</transition>')
    return f'<reference name="{name}"/>'


def _action(draw: st.DrawFn, pou_actions: list[str]) -> tuple[str, str]:
    """(qualifier, the action element's content and attributes)."""
    kind = draw(st.sampled_from(["var", "var", "inline", "pou"]))
    if kind == "var":
        q = draw(st.sampled_from(["N", "S", "R", "P", *TIMED]))
        dur = f' duration="T#{draw(st.sampled_from([10, 20, 50]))}ms"' if q in TIMED else ""
        return q, (f'qualifier="{q}"{dur}><relPosition x="0" y="0"/>'
                   f'<reference name="{draw(st.sampled_from(OUTPUTS))}"/>')
    q = draw(st.sampled_from(["N", "P", "P1", "P0", "L", "D"]))
    dur = f' duration="T#{draw(st.sampled_from([10, 20]))}ms"' if q in TIMED else ""
    body = f"n := n + {draw(st.integers(1, 9))};"
    if kind == "inline":
        return q, (f'qualifier="{q}"{dur}><relPosition x="0" y="0"/><inline><ST><xhtml:p>'
                   f'<![CDATA[{body}]]></xhtml:p></ST></inline>')
    name = f"Act{len(pou_actions)}"
    pou_actions.append(f'<action name="{name}"><body><ST><xhtml:p><![CDATA[{body}]]>'
                       '</xhtml:p></ST></body></action>')
    return q, f'qualifier="{q}"{dur}><relPosition x="0" y="0"/><reference name="{name}"/>'


@st.composite
def plcopen_files(draw: st.DrawFn) -> GenChart:
    n = draw(st.integers(2, 6))
    steps = [f"S{i}" for i in range(n)]
    initial = {"S0"} | {s for s in steps[1:] if draw(st.integers(0, 6)) == 0}
    trans = []
    for _ in range(draw(st.integers(1, 8))):
        src = draw(st.lists(st.sampled_from(steps), min_size=1, max_size=2, unique=True))
        dst = draw(st.lists(st.sampled_from(steps), min_size=1, max_size=2, unique=True))
        trans.append((src, dst))
    gen = GenChart(steps, initial, trans, {s: [] for s in steps})
    ids = gen.ids
    sid = {s: next(ids) for s in steps}
    tid = [next(ids) for _ in trans]
    out: list[str] = []
    net: list[str] = []
    pou_t: list[str] = []
    pou_a: list[str] = []
    rnd = draw(st.randoms(use_true_random=False))

    def pos() -> str:
        return f'<position x="{rnd.randint(0, 900)}" y="{rnd.randint(0, 900)}"/>'

    # what each step's outgoing transitions connect to: the step, or its divergence
    outs = {s: [k for k, (src, _) in enumerate(trans) if s in src] for s in steps}
    exit_of = {}
    for s in steps:
        if len(outs[s]) > 1:
            d = next(ids)
            exit_of[s] = d
            out.append(f'<selectionDivergence localId="{d}">{pos()}<connectionPointIn>'
                       f'<connection refLocalId="{sid[s]}"/></connectionPointIn>'
                       + '<connectionPointOut formalParameter=""/>' * len(outs[s])
                       + '</selectionDivergence>')
        else:
            exit_of[s] = sid[s]
    # priorities: distinct among the transitions leaving a step, or none
    prio: dict[int, int] = {}
    if draw(st.booleans()):
        order = list(range(len(trans)))
        rnd.shuffle(order)
        prio = {k: i + 1 for i, k in enumerate(order)}
    direct: dict[str, list[int]] = {s: [] for s in steps}  # producers linked to the step
    for k, (src, dst) in enumerate(trans):
        if len(src) == 1:
            cin = f'<connection refLocalId="{exit_of[src[0]]}"/>'
        else:
            c = next(ids)
            out.append(f'<simultaneousConvergence localId="{c}">{pos()}' + "".join(
                f'<connectionPointIn><connection refLocalId="{exit_of[s]}"/>'
                '</connectionPointIn>' for s in src) + '<connectionPointOut/>'
                '</simultaneousConvergence>')
            cin = f'<connection refLocalId="{c}"/>'
        p = f' priority="{prio[k]}"' if prio else ""
        out.append(f'<transition localId="{tid[k]}"{p}>{pos()}<connectionPointIn>{cin}'
                   f'</connectionPointIn><connectionPointOut/><condition>'
                   f'{_cond(draw, gen, net, pou_t)}</condition></transition>')
        producer = tid[k]
        if len(dst) > 1:
            producer = next(ids)
            out.append(f'<simultaneousDivergence localId="{producer}">{pos()}'
                       f'<connectionPointIn><connection refLocalId="{tid[k]}"/>'
                       '</connectionPointIn>' + '<connectionPointOut formalParameter=""/>'
                       * len(dst) + '</simultaneousDivergence>')
        for s in dst:
            if draw(st.booleans()):
                out.append(f'<jumpStep localId="{next(ids)}" targetName="{s}">{pos()}'
                           f'<connectionPointIn><connection refLocalId="{producer}"/>'
                           '</connectionPointIn></jumpStep>')
            else:
                direct[s].append(producer)
    for s in steps:
        links = direct[s]
        if len(links) > 1:
            c = next(ids)
            out.append(f'<selectionConvergence localId="{c}">{pos()}' + "".join(
                f'<connectionPointIn><connection refLocalId="{p}"/></connectionPointIn>'
                for p in links) + '<connectionPointOut/></selectionConvergence>')
            links = [c]
        cin = (f'<connectionPointIn><connection refLocalId="{links[0]}"/></connectionPointIn>'
               if links else "")
        init = "true" if s in initial else "false"
        out.append(f'<step localId="{sid[s]}" name="{s}" initialStep="{init}">{pos()}{cin}'
                   '<connectionPointOut formalParameter=""/></step>')
        acts = [_action(draw, pou_a) for _ in range(draw(st.integers(0, 3)))]
        if acts:
            gen.actions[s] = [q for q, _ in acts]
            out.append(f'<actionBlock localId="{next(ids)}">{pos()}<connectionPointIn>'
                       f'<connection refLocalId="{sid[s]}"/></connectionPointIn>'
                       + "".join(f'<action localId="0" {a}</action>' for _, a in acts)
                       + '</actionBlock>')
    body = out + net
    rnd.shuffle(body)
    variables = "".join(f'<variable name="{v}"><type><BOOL/></type></variable>'
                        for v in INPUTS)
    outputs = "".join(f'<variable name="{v}"><type><BOOL/></type></variable>'
                      for v in OUTPUTS)
    gen.xml = (
        '<?xml version="1.0" encoding="utf-8"?>\n<project xmlns="http://www.plcopen.org/xml/'
        'tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml"><types><dataTypes/><pous>'
        f'<pou name="Gen" pouType="program"><interface><inputVars>{variables}</inputVars>'
        f'<outputVars>{outputs}</outputVars><localVars><variable name="n"><type><INT/>'
        '</type></variable></localVars></interface>'
        + (f'<actions>{"".join(pou_a)}</actions>' if pou_a else "")
        + (f'<transitions>{"".join(pou_t)}</transitions>' if pou_t else "")
        + '<body><SFC>\n' + "\n".join(body) + '\n</SFC></body></pou></pous></types>'
        '</project>\n')
    return gen


def _qualifier(text: str) -> str:
    q = text.split()[0]
    return q if q in ("N", "S", "R", "P", "P1", "P0", *TIMED) else "N"


@SETTINGS
@given(gen=plcopen_files())
def test_export_of_the_import_keeps_every_element(tmp_path_factory: pytest.TempPathFactory,
                                                  tc6: Any, gen: GenChart) -> None:
    d = _dir(tmp_path_factory)
    (d / "gen.xml").write_text(gen.xml, encoding="utf-8")
    g, result = import_back(d / "gen.xml", d / "gen.yaml")
    assert result.notes == []  # everything generated can be carried
    # every element of the file is in the chart
    assert sorted(g.steps) == sorted(gen.steps)
    assert {s for s in g.steps if g.steps[s].initial} == gen.initial
    assert Counter((frozenset(t.sources), frozenset(t.targets)) for t in g.transitions) == (
        Counter((frozenset(s), frozenset(t)) for s, t in gen.trans))
    assert {s: [_qualifier(a.text) for a in g.steps[s].actions] for s in gen.steps} == (
        gen.actions)
    # and export then import gives it back
    xml = export_file(g, d / "again.xml")
    tc6.validate(str(xml))
    again, _ = import_back(xml, d / "again.yaml")
    assert shape(again) == shape(g)
