"""The Structured Text an export writes (``language/unparse.py``'s ``st_text`` and
``st_statements``), as docs/plcopen.md shows it."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.language.grafcetfile import load_grafcet
from runtime.language.unparse import st_statements, st_text

CHART = """\
grafcet: St
inputs: [iMarcha, iParo, iCerrado, {iNivel: real}]
outputs: [oA]
memory:
  sParo: false
  sCierres: 0
  sR: 0.0
timers: [timeTest]
steps:
  s0:
    initial: true
    actions:
      - |
        P1
        IF sCierres >= 1000 THEN sCierres := 0 ELSIF iParo THEN sCierres := -1 END_IF
        CASE sCierres OF 1, 2..3: oA := 1 ELSE oA := 0 END_CASE
        FOR tI := 1 TO 10 BY 2 DO sCierres := sCierres + tI END_FOR
        timeTest.Ini(1m30s)
transitions:
  - {from: s0, to: s0, when: "↑iMarcha·iParo'"}
  - {from: s0, to: s0, when: "iCerrado·sParo + (sCierres >= 1000)"}
  - {from: s0, to: s0, when: "(iMarcha + iParo)·(s0.T > 2s) XOR ↓iCerrado"}
  - {from: s0, to: s0, when: "-(sCierres MOD 3) * 2 < 5 - 1"}
  - {from: s0, to: s0, when: "iNivel * 1.5e3 > 1e-05 + sR"}
  - {from: s0, to: s0, when: "(sCierres + 1 > 2) = (sR > 1.0)"}
"""


@pytest.fixture
def st(tmp_path: Path) -> list[str]:
    p = tmp_path / "st.yaml"
    p.write_text(CHART, encoding="utf-8")
    g = load_grafcet(str(p))
    return [st_text(t.cond) for t in g.transitions] + [
        st_statements(a.body or []) for a in g.actions()]


def test_conditions_in_structured_text(st: list[str]) -> None:
    assert st[:6] == [
        "RE iMarcha AND NOT iParo",
        "iCerrado AND sParo OR sCierres >= 1000",
        "(iMarcha OR iParo) AND s0.T > T#2s XOR FE iCerrado",
        "-(sCierres MOD 3) * 2 < 5 - 1",
        "iNivel * 1500.0 > 1.0E-05 + sR",
        "(sCierres + 1 > 2) = (sR > 1.0)",
    ]


def test_statements_in_structured_text(st: list[str]) -> None:
    assert st[6] == """\
IF sCierres >= 1000 THEN
    sCierres := 0;
ELSIF iParo THEN
    sCierres := -1;
END_IF;
CASE sCierres OF
    1, 2..3:
        oA := TRUE;
ELSE
    oA := FALSE;
END_CASE;
FOR tI := 1 TO 10 BY 2 DO
    sCierres := sCierres + tI;
END_FOR;
timeTest.Ini(T#1m30s);"""


def test_initial_values_in_iec_form(tmp_path: Path) -> None:
    from runtime.plcopen.export import export_chart

    p = tmp_path / "v.yaml"
    p.write_text("grafcet: V\nmemory: {sR: 1.0e-5, sB: true, sT: 1m30s, sN: -3}\n"
                 "steps: {s0: {initial: true}}\n", encoding="utf-8")
    xml = export_chart(load_grafcet(str(p)))
    assert [v for v in ('value="1.0E-05"', 'value="TRUE"', 'value="T#1m30s"', 'value="-3"')
            if v not in xml] == []
