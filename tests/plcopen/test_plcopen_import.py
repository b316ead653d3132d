"""Import: the Beremiz-style and CODESYS-style files of tests/plcopen/data as the charts they
mean (every SFC element, every qualifier, CODESYS's vendor data), one note per element left
out naming its localId, and the same chart whatever the order of the file's elements."""

from __future__ import annotations

import random
import textwrap
import xml.etree.ElementTree as ET  # noqa: S405 - our own test files, to shuffle them
from pathlib import Path

import pytest

from runtime.errors import SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.plcopen.importer import import_file
from tests.plcopen.plcopenkit import DATA, import_back, shape

MIXER = DATA / "beremiz_mixer.xml"
PRESS = DATA / "codesys_press.xml"

#: what beremiz_mixer.xml means, written by hand: names as declared (the file writes some
#: in other cases), located %IX0.5 an input, POU action and transition bodies in place,
#: P1 on a variable as P, the contacts and the inVariable as expressions
MIXER_CHART = """\
grafcet: Mixer
description: "Mixing tank: fill, heat and stir, drain"
inputs: [Start, Stop, LevelHigh, LevelLow, {Temp: {type: int, iec_type: INT}}, Emergency]
outputs: [Pump, Heater, Stirrer, Drain, Alarm, Lamp, Horn,
          {Batches: {type: int, iec_type: DINT}}]
memory:
  Cycles: {init: 0, iec_type: INT}
  Done: false
steps:
  Idle:
    initial: true
    actions: [N Lamp, R Alarm]
  Filling:
    actions: [N Pump, "P1 Cycles := Cycles + 1;", L T#2s Horn]
  Heating:
    actions: [N Heater, D T#1s Lamp, SD t#3s Alarm]
  Draining:
    actions: [N Drain, "P (* action CountUp *) Batches := Batches + 1;", "P0 Done := TRUE;",
              DS T#500ms Alarm, SL T#1s Horn]
  Fault:
    actions: [S Alarm, P Drain]
  Stir:
    macro:
      steps:
        StirOn: {entry: true, actions: [N Stirrer]}
        StirDone: {exit: true}
      transitions:
        - {from: StirOn, to: StirDone, when: "StirOn.T >= T#2s"}
transitions:
  - {from: Idle, to: Filling, when: Start AND NOT Stop}
  - {from: Filling, to: Idle, when: Stop OR Emergency, name: Abort}
  - {from: Filling, to: [Heating, Stir], when: NOT Emergency AND LevelHigh}
  - {from: [Heating, Stir], to: Draining, when: Temp >= 60}
  - {from: Draining, to: Idle, when: LevelLow, name: Empty}
  - {from: Draining, to: Fault, when: Temp > 90}
  - {from: Fault, to: Idle, when: FE Stop}
"""

#: the notes of beremiz_mixer.xml: (line, text) - each element left out, by its localId,
#: and the comment kept (a note that loses nothing)
MIXER_NOTES = [
    (113, "variable 'Note' of type string left out"),
    (204, "localId 31: comment kept in the chart's description"),
    (480, "localId 5 (action block of step 'Filling'), action 1: indicator 'PumpOn' left "
          "out"),
    (496, "localId 5 (action block of step 'Filling'), action 4: qualifier DL left out"),
    (703, "localId 24 (action block of step 'Fault'), action 1: action 'Legacy' left out: it "
          "is written in IL"),
    (715, "localId 24 (action block of step 'Fault'), action 4: P0 Lamp left out"),
]

#: what codesys_press.xml means: names, the initial step, min/max and the step actions
#: from CODESYS's vendor data, the transitions leaving Up in CODESYS's priority order
PRESS_CHART = """\
grafcet: Press
scan: codesys
inputs: [bStart, bStop, bAtBottom, bAtTop]
outputs: [bMotorDown, bMotorUp, bLamp, {nCount: {type: int, iec_type: UDINT}}]
memory:
  nTicks: {init: 0, iec_type: DINT}
steps:
  Init:
    initial: true
    actions: [N bLamp]
  Down:
    min: 300ms
    max: 2s
    description: Motor down to the bottom
    actions: ["P1 (* action Down_entry *) nCount := nCount + 1;",
              "N (* action Down_main *) nTicks := nTicks + 1;", N bMotorDown]
  Up:
    description: Motor up to the top
    actions: ["P0 (* action Up_exit *) nTicks := 0;", N bMotorUp]
  Halt: {}
transitions:
  - {from: Init, to: Down, when: bStart AND NOT bStop}
  - {from: Down, to: Up, when: bAtBottom, name: trDown}
  - {from: Up, to: Halt, when: bStop}
  - {from: Up, to: Init, when: bAtTop}
  - {from: Halt, to: Init, when: NOT bStop}
"""


def expected(tmp_path: Path, text: str) -> dict[str, object]:
    p = tmp_path / "expected.yaml"
    p.write_text(text, encoding="utf-8")
    return shape(load_grafcet(str(p)))


def test_beremiz_file_imports_as_the_chart_it_means(tmp_path: Path) -> None:
    g, result = import_back(MIXER, tmp_path / "Mixer.yaml")
    assert shape(g) == expected(tmp_path, MIXER_CHART)
    c = result.charts[0]
    assert (c.instance, c.cycle_ns) == ("tank", 100_000_000)  # the task running it
    assert [v.address for v in c.interface.inputs] == ["", "", "", "", "", "%IX0.5"]


def test_beremiz_file_notes_each_element_left_out(tmp_path: Path) -> None:
    notes = import_file(str(MIXER)).notes
    assert [(n.loc.line, n.message[:len(want)]) for n, (_, want) in
            zip(notes, MIXER_NOTES, strict=True)] == MIXER_NOTES
    assert [n.lost for n in notes] == [True, False, True, True, True, True]
    assert all(n.loc.file == str(MIXER) for n in notes)
    assert all(str(n).startswith(f"{MIXER}:{n.loc.line}:") and (
        ": warning: " if n.lost else ": note: ") in str(n) for n in notes)


def test_codesys_file_imports_with_its_vendor_data(tmp_path: Path) -> None:
    g, result = import_back(PRESS, tmp_path / "Press.yaml")
    assert shape(g) == expected(tmp_path, PRESS_CHART)
    (note,) = result.notes
    assert not note.lost and "imported with 'scan: codesys'" in note.message
    assert str(note).startswith(f"{PRESS}:29:7: note: ")


def _shuffled(src: Path, dst: Path, seed: int) -> None:
    """``src`` with the elements of every SFC body in a random order (actions inside an
    action block keep theirs: that order is the chart's)."""
    ns = "{http://www.plcopen.org/xml/tc6_0201}"
    ET.register_namespace("", ns[1:-1])
    ET.register_namespace("xhtml", "http://www.w3.org/1999/xhtml")
    tree = ET.parse(src)  # noqa: S314 - our own file
    rng = random.Random(seed)
    for sfc in tree.getroot().iter(f"{ns}SFC"):
        kids = list(sfc)
        rng.shuffle(kids)
        sfc[:] = kids
    for group in ("actions", "transitions", "interface"):
        for e in tree.getroot().iter(f"{ns}{group}"):
            if group != "interface":
                kids = list(e)
                rng.shuffle(kids)
                e[:] = kids
    tree.write(dst, encoding="utf-8", xml_declaration=True)


@pytest.mark.parametrize("source", [MIXER, PRESS], ids=["beremiz", "codesys"])
@pytest.mark.parametrize("seed", range(6))
def test_the_order_of_the_elements_does_not_matter(source: Path, seed: int,
                                                   tmp_path: Path) -> None:
    g, _ = import_back(source, tmp_path / "a.yaml")
    _shuffled(source, tmp_path / "shuffled.xml", seed)
    assert (tmp_path / "shuffled.xml").read_bytes() != source.read_bytes()
    h, _ = import_back(tmp_path / "shuffled.xml", tmp_path / "b.yaml")
    assert shape(h) == shape(g)
    assert (tmp_path / "a.yaml").read_text().splitlines()[1:] == (
        tmp_path / "b.yaml").read_text().splitlines()[1:]


# -- the other forms a condition may take ------------------------------------------------------
POU = """\
<?xml version="1.0" encoding="utf-8"?>
<project xmlns="http://www.plcopen.org/xml/tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml">
  <fileHeader companyName="t" productName="t" productVersion="1"
              creationDateTime="2025-01-01T00:00:00"/>
  <contentHeader name="t"><coordinateInfo><fbd><scaling x="0" y="0"/></fbd><ld>
<scaling x="0" y="0"/></ld><sfc><scaling x="0" y="0"/></sfc></coordinateInfo></contentHeader>
  <types><dataTypes/><pous>
    <pou name="P" pouType="program">
      <interface><inputVars>
        <variable name="a"><type><BOOL/></type></variable>
        <variable name="b"><type><BOOL/></type></variable>
        <variable name="c"><type><BOOL/></type></variable>
      </inputVars></interface>
      {transitions}
      <body><SFC>
        <step localId="1" name="S0" initialStep="true"><position x="0" y="0"/></step>
        <transition localId="2"><position x="0" y="50"/>
          <connectionPointIn><connection refLocalId="1"/></connectionPointIn>
          <condition{negated}>{condition}</condition>
        </transition>
        <step localId="3" name="S1"><position x="0" y="100"/>
          <connectionPointIn><connection refLocalId="2"/></connectionPointIn></step>
        {network}
      </SFC></body>
    </pou>
  </pous></types>
  <instances><configurations/></instances>
</project>
"""


def condition_of(tmp_path: Path, condition: str, network: str = "", transitions: str = "",
                 negated: bool = False) -> str:
    p = tmp_path / "p.xml"
    p.write_text(POU.format(condition=condition, network=network, transitions=transitions,
                            negated=' negated="true"' if negated else ""), encoding="utf-8")
    return import_file(str(p)).charts[0].grafcet.transitions[0].text


FBD_OR = """\
<inVariable localId="10"><position x="0" y="0"/><connectionPointOut/><expression>a</expression>
</inVariable>
<inVariable localId="11"><position x="0" y="0"/><connectionPointOut/><expression>B</expression>
</inVariable>
<inVariable localId="12" negated="true"><position x="0" y="0"/><connectionPointOut/>
<expression>c</expression></inVariable>
<block localId="13" typeName="OR"><position x="0" y="0"/>
  <inputVariables>
    <variable formalParameter="IN1"><connectionPointIn><connection refLocalId="14"/>
</connectionPointIn></variable>
    <variable formalParameter="IN2" edge="rising"><connectionPointIn>
<connection refLocalId="12"/></connectionPointIn></variable>
  </inputVariables><inOutVariables/><outputVariables><variable formalParameter="OUT">
<connectionPointOut/></variable></outputVariables>
</block>
<block localId="14" typeName="AND"><position x="0" y="0"/>
  <inputVariables>
    <variable formalParameter="IN1"><connectionPointIn><connection refLocalId="10"/>
</connectionPointIn></variable>
    <variable formalParameter="IN2"><connectionPointIn><connection refLocalId="11"/>
</connectionPointIn></variable>
  </inputVariables><inOutVariables/><outputVariables><variable formalParameter="OUT">
<connectionPointOut/></variable></outputVariables>
</block>
"""

LD_PARALLEL = """\
<leftPowerRail localId="20"><position x="0" y="0"/><connectionPointOut formalParameter=""/>
</leftPowerRail>
<contact localId="21"><position x="0" y="0"/><connectionPointIn><connection refLocalId="20"/>
</connectionPointIn><connectionPointOut/><variable>a</variable></contact>
<contact localId="22" negated="true"><position x="0" y="0"/><connectionPointIn>
<connection refLocalId="20"/></connectionPointIn><connectionPointOut/><variable>b</variable>
</contact>
<contact localId="23" edge="rising"><position x="0" y="0"/><connectionPointIn>
<connection refLocalId="21"/><connection refLocalId="22"/></connectionPointIn>
<connectionPointOut/><variable>c</variable></contact>
<connector name="k" localId="24"><position x="0" y="0"/><connectionPointIn>
<connection refLocalId="23"/></connectionPointIn></connector>
<continuation name="K" localId="25"><position x="0" y="0"/><connectionPointOut/></continuation>
"""

ST_TRANSITION = """\
<transitions><transition name="Go"><body><ST><xhtml:p><![CDATA[
  (* IEC 61131-3's form *)
  GO := a AND b;
]]></xhtml:p></ST></body></transition></transitions>
"""


def test_a_condition_from_fbd_gates(tmp_path: Path) -> None:
    cond = '<connectionPointIn><connection refLocalId="13"/></connectionPointIn>'
    assert condition_of(tmp_path, cond, FBD_OR) == "(a AND b) OR (RE (NOT c))"


def test_a_condition_from_ld_contacts_in_series_and_in_parallel(tmp_path: Path) -> None:
    cond = '<connectionPointIn><connection refLocalId="25"/></connectionPointIn>'
    assert condition_of(tmp_path, cond, LD_PARALLEL) == "(a OR NOT b) AND RE c"


def test_a_condition_from_a_pou_transition_in_st_negated(tmp_path: Path) -> None:
    text = condition_of(tmp_path, '<reference name="go"/>', transitions=ST_TRANSITION,
                        negated=True)
    assert text == "NOT (a AND b)"  # the comment before GO := is left with it


@pytest.mark.parametrize(("kind", "message"), [
    ("SEL", "localId 14: a block SEL: softplc carries variables, contacts, coils, the gates "
            "AND OR XOR NOT, comparisons and arithmetic, and the blocks TON TOF TP CTU CTD "
            "CTUD R_TRIG F_TRIG SR RS; write it in ST (in a transition's condition)"),
    ("TON", "localId 14: block TON instance '': expected a TON declared by that name in the "
            "POU's variables"),
])
def test_a_condition_network_with_a_block_it_cannot_carry_is_refused_at_the_block(
        tmp_path: Path, kind: str, message: str) -> None:
    """A block of a type the language lacks, or a function block the POU does not
    declare (function blocks it declares are carried: test_plcopen_blocks.py)."""
    net = FBD_OR.replace('typeName="AND"', f'typeName="{kind}"')
    cond = '<connectionPointIn><connection refLocalId="13"/></connectionPointIn>'
    with pytest.raises(SourceError) as e:
        condition_of(tmp_path, cond, net)
    lines = (tmp_path / "p.xml").read_text().splitlines()
    assert e.value.loc.line == 1 + next(i for i, ln in enumerate(lines)
                                        if 'localId="14"' in ln)
    assert e.value.message == message


def test_an_st_fault_is_reported_in_the_xml_file(tmp_path: Path) -> None:
    cond = ('<inline name=""><ST><xhtml:p><![CDATA[a AND\n   (b OR]]></xhtml:p></ST>'
            '</inline>')
    with pytest.raises(SourceError) as e:
        condition_of(tmp_path, cond)
    line = POU.count("\n", 0, POU.index("{condition}")) + 1
    assert (e.value.loc.line, e.value.loc.col) == (line + 1, 9)  # just past 'b OR'
    assert "expected" in e.value.message


@pytest.mark.parametrize(("pou", "message"), [
    ("Nope", "no POU named 'Nope' in the file (POUs: P)"),
])
def test_pou_selection(tmp_path: Path, pou: str, message: str) -> None:
    p = tmp_path / "p.xml"
    p.write_text(POU.format(condition='<reference name="a"/>', network="", transitions="",
                            negated=""), encoding="utf-8")
    with pytest.raises(SourceError) as e:
        import_file(str(p), pou)
    assert e.value.message == message


def test_a_file_without_sfc_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "st.xml"
    p.write_text(textwrap.dedent("""\
        <project xmlns="http://www.plcopen.org/xml/tc6_0201">
          <types><pous><pou name="Q" pouType="program"><body><ST>
            <p xmlns="http://www.w3.org/1999/xhtml">x := 1;</p></ST></body></pou></pous></types>
        </project>"""), encoding="utf-8")
    with pytest.raises(SourceError) as e:
        import_file(str(p))
    assert "no POU written in SFC" in e.value.message
    with pytest.raises(SourceError) as e:
        import_file(str(p), "Q")
    assert e.value.message == "POU 'Q' is not written in SFC"


def test_fbd_elements_of_no_condition_are_noted(tmp_path: Path) -> None:
    p = tmp_path / "p.xml"
    stray = ('<inVariable localId="40"><position x="0" y="0"/><connectionPointOut/>'
             '<expression>b</expression></inVariable>')
    p.write_text(POU.format(condition='<reference name="a"/>', network=stray, transitions="",
                            negated=""), encoding="utf-8")
    (note,) = import_file(str(p)).notes
    assert note.message == ("localId 40: inVariable left out: it is part of no transition's "
                            "condition")


TWO_REFERENCES = """\
<?xml version="1.0" encoding="utf-8"?>
<project xmlns="http://www.plcopen.org/xml/tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml">
  <types><dataTypes/><pous><pou name="R" pouType="program">
    <interface><inputVars><variable name="a"><type><BOOL/></type></variable></inputVars>
    </interface>
    <transitions>
      <transition name="Go"><body><ST><xhtml:p>a</xhtml:p></ST></body></transition>
      <transition name="Back"><body><ST><xhtml:p>NOT a</xhtml:p></ST></body></transition>
    </transitions>
    <body><SFC>
      <step localId="1" name="S0" initialStep="true"><position x="0" y="0"/>
        <connectionPointIn><connection refLocalId="6"/></connectionPointIn></step>
      <transition localId="2"><position x="0" y="50"/>
        <connectionPointIn><connection refLocalId="1"/></connectionPointIn>
        <condition><reference name="Go"/></condition></transition>
      <step localId="3" name="S1"><position x="0" y="100"/>
        <connectionPointIn><connection refLocalId="2"/></connectionPointIn></step>
      <transition localId="4"><position x="0" y="150"/>
        <connectionPointIn><connection refLocalId="3"/></connectionPointIn>
        <condition><reference name="Go"/></condition></transition>
      <step localId="5" name="S2"><position x="0" y="200"/>
        <connectionPointIn><connection refLocalId="4"/></connectionPointIn></step>
      <transition localId="6"><position x="0" y="250"/>
        <connectionPointIn><connection refLocalId="5"/></connectionPointIn>
        <condition><inline name="Back"><ST><xhtml:p>NOT a</xhtml:p></ST></inline></condition>
      </transition>
      <transition localId="7"><position x="50" y="250"/>
        <connectionPointIn><connection refLocalId="5"/></connectionPointIn>
        <condition><inline name="Back"><ST><xhtml:p>a</xhtml:p></ST></inline></condition>
      </transition>
      <jumpStep localId="8" targetName="S1"><position x="50" y="300"/>
        <connectionPointIn><connection refLocalId="7"/></connectionPointIn></jumpStep>
    </SFC></body>
  </pou></pous></types>
</project>
"""


def test_transition_names_stay_unique(tmp_path: Path) -> None:
    """A POU transition named by two transitions names neither; a name given twice is
    kept once, the second noted (a chart's transition names are unique)."""
    p = tmp_path / "r.xml"
    p.write_text(TWO_REFERENCES, encoding="utf-8")
    result = import_file(str(p))
    names = [t.name for t in result.charts[0].grafcet.transitions]
    assert names == ["", "", "Back", ""]
    assert [n.message for n in result.notes] == [
        "localId 7: transition name 'Back' left out: another transition has it (names are "
        "unique in a chart)",
        "transition 'Back' of the POU left out: no transition of the chart refers to it"]


@pytest.mark.parametrize(("declaration", "encoding", "bom"), [
    ('<?xml version="1.0" encoding="ISO-8859-1"?>', "iso-8859-1", b""),
    ('<?xml version="1.0" encoding="utf-8"?>', "utf-8", b"\xef\xbb\xbf"),  # CODESYS writes one
])
def test_encodings_of_the_editors(tmp_path: Path, declaration: str, encoding: str,
                                  bom: bytes) -> None:
    text = POU.format(condition='<inline name=""><ST><xhtml:p>señal</xhtml:p></ST></inline>',
                      network="", transitions="", negated="")
    text = text.replace('<variable name="a">', '<variable name="Señal">').replace(
        '<?xml version="1.0" encoding="utf-8"?>', declaration)
    p = tmp_path / "p.xml"
    p.write_bytes(bom + text.encode(encoding))
    g = import_file(str(p)).charts[0].grafcet
    assert g.transitions[0].text == "Señal"
    assert [v.name for v in g.inputs] == ["Señal", "b", "c"]


@pytest.mark.parametrize(("qualifier", "duration"), [("L", None), ("D", None), ("D", ""),
                                                     ("SD", None)])
def test_a_timed_qualifier_without_a_duration_is_an_error(
        tmp_path: Path, qualifier: str, duration: str | None) -> None:
    """IEC 61131-3 times L, D, SD, DS and SL: without a duration the association has no
    meaning (was: left out with a warning, exit status 0)."""
    text = MIXER.read_text(encoding="utf-8")
    was = '<action localId="0" qualifier="D" duration="T#1s">'
    now = f'<action localId="0" qualifier="{qualifier}"' + (
        f' duration="{duration}">' if duration is not None else ">")
    assert was in text
    xml = tmp_path / "m.xml"
    xml.write_text(text.replace(was, now), encoding="utf-8")
    with pytest.raises(SourceError) as e:
        import_file(str(xml))
    assert e.value.loc.line == 1 + text.splitlines().index(
        next(ln for ln in text.splitlines() if was in ln))
    assert e.value.message == (
        f"localId 12 (action block of step 'Heating'), action 2: qualifier {qualifier} "
        f"without a duration: IEC 61131-3 times {qualifier} (expected duration=\"T#2s\" or "
        "another time)")
