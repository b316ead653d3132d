"""Function block instances in FBD/LD networks, in the three places Beremiz draws them: a
transition's condition drawn in the SFC body, a POU transition's FBD body, a POU action's LD
body. Every block the language has (TON TOF TP CTU CTD CTUD R_TRIG F_TRIG SR RS), each input
wired to its parameter, each output read by its name; blocks of conditions are called in
``post`` (every scan, after the actions: what Beremiz generates for matiec, an S action of
the initial step), blocks of an action where the action runs (only while it runs).

The two behaviours that reading implies, against hand-worked scans: a condition's block runs
while its transition is not enabled (a TON times from power-up though its step is entered
later), and a transition reads the outputs its blocks had at the end of the previous scan
(an R_TRIG's edge fires the transition one scan after the edge); an action's block runs only
while the action does (a CTU does not count a part seen while its step is inactive):
test_plcopen_editor.py's press cell holds all three; the tests below isolate them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.engine.simulate import Simulation
from runtime.errors import SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.plcopen.importer import import_file

#: block -> its inputs wired to (parameter, inVariable expression), and the bool output a
#: condition or a coil reads
WIRING: dict[str, tuple[list[tuple[str, str]], str]] = {
    "TON": ([("IN", "a"), ("PT", "T#300ms")], "Q"),
    "TOF": ([("IN", "a"), ("PT", "T#300ms")], "Q"),
    "TP": ([("IN", "a"), ("PT", "T#300ms")], "Q"),
    "CTU": ([("CU", "a"), ("R", "b"), ("PV", "2")], "Q"),
    "CTD": ([("CD", "a"), ("LD", "b"), ("PV", "2")], "Q"),
    "CTUD": ([("CU", "a"), ("CD", "b"), ("R", "c"), ("LD", "FALSE"), ("PV", "2")], "QU"),
    "R_TRIG": ([("CLK", "a")], "Q"),
    "F_TRIG": ([("CLK", "a")], "Q"),
    "SR": ([("S1", "a"), ("R", "b")], "Q1"),
    "RS": ([("S", "a"), ("R1", "b")], "Q1"),
}

HEAD = """<?xml version="1.0" encoding="utf-8"?>
<project xmlns="http://www.plcopen.org/xml/tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml">
<fileHeader companyName="t" productName="t" productVersion="1"
 creationDateTime="2024-01-01T00:00:00"/>
<contentHeader name="b"><coordinateInfo><fbd><scaling x="0" y="0"/></fbd><ld><scaling x="0"
 y="0"/></ld><sfc><scaling x="0" y="0"/></sfc></coordinateInfo></contentHeader>
<types><dataTypes/><pous><pou name="B" pouType="program"><interface>
<inputVars><variable name="a"><type><BOOL/></type></variable><variable name="b"><type><BOOL/>
</type></variable><variable name="c"><type><BOOL/></type></variable></inputVars>
<outputVars><variable name="o"><type><BOOL/></type></variable></outputVars>
<localVars><variable name="X"><type><derived name="KIND"/></type></variable></localVars>
</interface>
"""
TAIL = """</pou></pous></types><instances><configurations><configuration name="config">
<resource name="resource1"><task name="t" priority="0" interval="T#100ms">
<pouInstance name="b" typeName="B"/></task></resource></configuration></configurations>
</instances></project>
"""


def block(kind: str, first: int, out_id: int) -> str:
    """Block X of type ``kind`` (localId ``first``) with its inputs from inVariables (the
    next localIds), and an output connection point per output."""
    ins, _ = WIRING[kind]
    xml = [f'<block localId="{first}" typeName="{kind}" instanceName="X"><position x="100" '
           'y="100"/><inputVariables>']
    for k, (param, _) in enumerate(ins):
        xml.append(f'<variable formalParameter="{param}"><connectionPointIn><connection '
                   f'refLocalId="{first + 1 + k}"/></connectionPointIn></variable>')
    xml.append("</inputVariables><inOutVariables/><outputVariables>")
    for param in ("Q", "ET", "CV", "QU", "QD", "Q1"):
        xml.append(f'<variable formalParameter="{param}"><connectionPointOut/></variable>')
    xml.append("</outputVariables></block>")
    for k, (_, expr) in enumerate(ins):
        xml.append(f'<inVariable localId="{first + 1 + k}"><position x="0" y="{100 + 20 * k}"/>'
                   f'<connectionPointOut/><expression>{expr}</expression></inVariable>')
    del out_id
    return "\n".join(xml)


def sfc(condition: str, actions: str = "") -> str:
    """S0 (initial) -> S1 on ``condition``, S1 -> S0 on c; S1's action block ``actions``."""
    return f"""<body><SFC>
<step localId="1" name="S0" initialStep="true"><position x="0" y="0"/>
<connectionPointIn/><connectionPointOut/></step>
<transition localId="2"><position x="0" y="50"/><connectionPointIn><connection
refLocalId="1"/></connectionPointIn><connectionPointOut/><condition>{condition}</condition>
</transition>
<step localId="3" name="S1"><position x="0" y="100"/><connectionPointIn><connection
refLocalId="2"/></connectionPointIn><connectionPointOut/></step>
<actionBlock localId="5"><position x="50" y="100"/><connectionPointIn><connection
refLocalId="3"/></connectionPointIn>{actions}</actionBlock>
<transition localId="4"><position x="0" y="150"/><connectionPointIn><connection
refLocalId="3"/></connectionPointIn><connectionPointOut/><condition><inline name=""><ST>
<xhtml:p>c</xhtml:p></ST></inline></condition></transition>
<jumpStep localId="6" targetName="S0"><position x="0" y="200"/><connectionPointIn>
<connection refLocalId="4"/></connectionPointIn></jumpStep>
{"BLOCKS"}</SFC></body>
"""


def project(kind: str, place: str) -> str:
    out = WIRING[kind][1]
    if place == "condition":  # drawn in the SFC body, the condition connected to it
        body = sfc(f'<connectionPointIn><connection refLocalId="20" formalParameter="{out}"/>'
                   '</connectionPointIn>', '<action localId="7"><reference name="o"/></action>')
        return HEAD.replace("KIND", kind) + body.replace("BLOCKS", block(kind, 20, 0)) + TAIL
    if place == "transition":  # a POU transition in FBD: an output variable of its name
        pou = (f'<transitions><transition name="Ready"><body><FBD>{block(kind, 20, 0)}'
               f'<outVariable localId="40"><position x="300" y="100"/><connectionPointIn>'
               f'<connection refLocalId="20" formalParameter="{out}"/></connectionPointIn>'
               '<expression>Ready</expression></outVariable></FBD></body></transition>'
               '</transitions>')
        body = sfc('<reference name="Ready"/>', '<action localId="7"><reference name="o"/>'
                   '</action>')
        return HEAD.replace("KIND", kind) + pou + body.replace("BLOCKS", "") + TAIL
    # a POU action in LD: the block's output on a coil
    pou = (f'<actions><action name="Act"><body><LD>{block(kind, 20, 0)}'
           f'<coil localId="40"><position x="300" y="100"/><connectionPointIn><connection '
           f'refLocalId="20" formalParameter="{out}"/></connectionPointIn><connectionPointOut/>'
           '<variable>o</variable></coil></LD></body></action></actions>')
    body = sfc('<inline name=""><ST><xhtml:p>b</xhtml:p></ST></inline>',
               '<action localId="7"><reference name="Act"/></action>')
    return HEAD.replace("KIND", kind) + pou + body.replace("BLOCKS", "") + TAIL


def call(kind: str) -> str:
    return "X(" + ", ".join(f"{p} := {e}" for p, e in WIRING[kind][0]) + ")"


@pytest.mark.parametrize("place", ["condition", "transition", "action"])
@pytest.mark.parametrize("kind", sorted(WIRING))
def test_every_block_in_every_place(kind: str, place: str, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    xml = tmp_path / "b.xml"
    xml.write_text(project(kind, place), encoding="utf-8")
    result = import_file(str(xml))
    g = result.charts[0].grafcet
    out = WIRING[kind][1]
    assert {b.name: b.kind for b in g.blocks.values()} == {"X": kind}
    if place == "action":
        assert [t.text for t in g.transitions] == ["b", "c"]
        assert [a.text for a in g.steps["S1"].actions] == [
            f"N (* action Act *) {call(kind)}\no := X.{out}"]
        assert g.post == []
    else:
        assert [t.text for t in g.transitions] == [f"X.{out}", "c"]
        assert [a.text for a in g.steps["S1"].actions] == ["N o"]
        assert [s.text for s in g.post] == [call(kind)]
    # and the plant skeleton runs it
    assert main(["import", str(xml), "-o", str(tmp_path / "o"), "--strict"]) == 0
    assert main(["simulate", str(tmp_path / "o" / "plant.yaml"), "--cycles", "5"]) == 0
    capsys.readouterr()


def rows(tmp_path: Path, xml_text: str, script: str) -> list[dict[str, Any]]:
    xml = tmp_path / "b.xml"
    xml.write_text(xml_text, encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o"), "--strict"]) == 0
    s = tmp_path / "s.yaml"
    s.write_text(script, encoding="utf-8")
    return list(Simulation(str(tmp_path / "o" / "plant.yaml"), str(s)).run(trace=True))


def test_a_condition_block_runs_while_its_transition_is_not_enabled(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The TON of S1 -> S0's condition (drawn in the SFC body) times a from scan 0 though
    S1 is entered only at 500: its Q is set by the call at 300 and S1 is left in the first
    scan it can be (600), not 300 ms after it was entered (900)."""
    text = project("TON", "condition")
    # S0 -> S1 on b (inline); S1 -> S0 on the TON's Q (the network)
    text = text.replace('<condition><connectionPointIn><connection refLocalId="20" '
                        'formalParameter="Q"/></connectionPointIn></condition>',
                        '<condition><inline name=""><ST><xhtml:p>b</xhtml:p></ST></inline>'
                        '</condition>', 1)
    text = text.replace('<condition><inline name=""><ST>\n<xhtml:p>c</xhtml:p></ST></inline>'
                        '</condition>', '<condition><connectionPointIn><connection '
                        'refLocalId="20" formalParameter="Q"/></connectionPointIn></condition>')
    got = rows(tmp_path, text, "duration: 1200ms\nset:\n  - {at: 0ms, b.a: 1}\n"
                               "  - {at: 500ms, b.b: 1}\n  - {at: 600ms, b.b: 0}\n")
    capsys.readouterr()
    assert [r["b.S1.X"] for r in got] == [0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0]
    assert [r["b.X.Q"] for r in got] == [0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1]


def test_a_condition_reads_its_blocks_as_the_previous_scan_left_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The R_TRIG of S0 -> S1's condition sees a rise at 200 in that scan's post: S1 is
    entered at 300, a scan after the edge (an ST 'RE a' would fire at 200)."""
    got = rows(tmp_path, project("R_TRIG", "condition"),
               "duration: 600ms\nset:\n  - {at: 200ms, b.a: 1}\n")
    capsys.readouterr()
    assert [r["b.X.Q"] for r in got] == [0, 0, 1, 0, 0, 0]
    assert [r["b.S1.X"] for r in got] == [0, 0, 0, 1, 1, 1]


def test_an_action_block_runs_only_while_its_action_does(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The CTU of S1's LD action counts the rises of a only while S1 is active (entered on
    b at 300): the rise at 100 is not counted, those at 400 and 600 are; left at 800 on c,
    the count stays (the block is not called)."""
    script = """\
duration: 1000ms
set:
  - {at: 100ms, b.a: 1}
  - {at: 200ms, b.a: 0}
  - {at: 300ms, b.b: 1}
  - {at: 400ms, b.a: 1, b.b: 0}
  - {at: 500ms, b.a: 0}
  - {at: 600ms, b.a: 1}
  - {at: 700ms, b.a: 0}
  - {at: 800ms, b.c: 1}
  - {at: 900ms, b.a: 1}
"""
    got = rows(tmp_path, project("CTU", "action"), script)
    capsys.readouterr()
    assert [r["b.S1.X"] for r in got] == [0, 0, 0, 1, 1, 1, 1, 1, 0, 0]
    assert [r["b.X.CV"] for r in got] == [0, 0, 0, 0, 1, 1, 2, 2, 2, 2]
    assert [r["b.o"] for r in got] == [0, 0, 0, 0, 0, 0, 1, 1, 1, 1]  # CV >= PV (2)


def test_a_block_feeding_itself_back_reads_its_last_output(tmp_path: Path) -> None:
    """As Beremiz's traffic light draws it: an SR whose reset is the TON its Q1 starts.
    Each block is called once, the one reached second first (it reads the other's last
    output)."""
    xml = tmp_path / "b.xml"
    net = block("TON", 20, 0).replace('<connection refLocalId="21"/>',
                                      '<connection refLocalId="30" formalParameter="Q1"/>')
    net += ('<block localId="30" typeName="SR" instanceName="Y"><position x="0" y="0"/>'
            '<inputVariables><variable formalParameter="S1"><connectionPointIn><connection '
            'refLocalId="31"/></connectionPointIn></variable><variable formalParameter="R">'
            '<connectionPointIn><connection refLocalId="20" formalParameter="Q"/>'
            '</connectionPointIn></variable></inputVariables><inOutVariables/>'
            '<outputVariables><variable formalParameter="Q1"><connectionPointOut/></variable>'
            '</outputVariables></block><inVariable localId="31"><position x="0" y="0"/>'
            '<connectionPointOut/><expression>b</expression></inVariable>')
    text = project("TON", "condition").replace(block("TON", 20, 0), net).replace(
        '<variable name="X"><type><derived name="TON"/></type></variable>',
        '<variable name="X"><type><derived name="TON"/></type></variable><variable name="Y">'
        '<type><derived name="SR"/></type></variable>')
    xml.write_text(text, encoding="utf-8")
    g = import_file(str(xml)).charts[0].grafcet
    assert [s.text for s in g.post] == ["Y(S1 := b, R := X.Q)", "X(IN := Y.Q1, PT := T#300ms)"]


@pytest.mark.parametrize(("change", "message"), [
    ('instanceName="X"', "localId 20: block TON instance 'Z': expected a TON declared by that "
                         "name in the POU's variables"),
    ('formalParameter="PT"', "localId 20: TON has no input 'PTX': expected IN, PT"),
])
def test_a_block_the_pou_does_not_declare_as_wired_is_refused_at_it(
        tmp_path: Path, change: str, message: str) -> None:
    text = project("TON", "condition")
    text = text.replace(change, change.replace('"X"', '"Z"').replace('"PT"', '"PTX"'))
    xml = tmp_path / "b.xml"
    xml.write_text(text, encoding="utf-8")
    with pytest.raises(SourceError) as e:
        import_file(str(xml))
    assert e.value.message == message


def test_an_ld_action_that_cannot_be_carried_is_one_warning(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A jump in an action's LD body: the action is left out with one line naming the
    element (its steps and its other actions stay)."""
    text = project("TON", "action").replace(
        "</LD>", '<jump localId="50" label="L1"><position x="0" y="0"/><connectionPointIn>'
                 '<connection refLocalId="20" formalParameter="Q"/></connectionPointIn>'
                 '</jump></LD>')
    xml = tmp_path / "b.xml"
    xml.write_text(text, encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert ("warning: localId 5 (action block of step 'S1'), action 1: action 'Act' left "
            "out: localId 50: a jump: softplc's statements have no jumps, labels or returns; "
            "write it in ST") in err
    g = load_grafcet(str(tmp_path / "o" / "B.yaml"))
    assert g.steps["S1"].actions == []
