"""Hostile and broken PLCopen files: each is refused by ``softplc import`` with exactly one
``FILE:LINE:COL: error:`` line and exit status 2, nothing written, no traceback; entities
are never expanded and nothing outside the file is read."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from runtime.cli import main
from runtime.plcopen.xmltree import MAX_ELEMENTS, MAX_XML_BYTES

HEAD = ('<project xmlns="http://www.plcopen.org/xml/tc6_0201" '
        'xmlns:xhtml="http://www.w3.org/1999/xhtml">\n')


def sfc(body: str) -> str:
    """A project with one SFC POU of inputs a, b whose body is ``body``."""
    return (f'<?xml version="1.0"?>\n{HEAD}<types><dataTypes/><pous>\n'
            '<pou name="P" pouType="program"><interface><inputVars>\n'
            '<variable name="a"><type><BOOL/></type></variable>\n'
            '<variable name="b"><type><BOOL/></type></variable>\n'
            '</inputVars></interface><body><SFC>\n'
            f'{body}\n</SFC></body></pou></pous></types></project>\n')


STEP = '<step localId="{i}" name="{n}"{init}><position x="0" y="0"/>{cin}</step>'


def step(i: int, name: str, source: int | None = None, initial: bool = False) -> str:
    cin = (f'<connectionPointIn><connection refLocalId="{source}"/></connectionPointIn>'
           if source is not None else "")
    return STEP.format(i=i, n=name, init=' initialStep="true"' if initial else "", cin=cin)


def trans(i: int, source: int | None, cond: str = "a", network: int | None = None) -> str:
    cin = (f'<connectionPointIn><connection refLocalId="{source}"/></connectionPointIn>'
           if source is not None else "")
    c = (f'<connectionPointIn><connection refLocalId="{network}"/></connectionPointIn>'
         if network is not None else
         f'<inline name=""><ST><xhtml:p>{cond}</xhtml:p></ST></inline>')
    return (f'<transition localId="{i}"><position x="0" y="0"/>{cin}'
            f'<condition>{c}</condition></transition>')


LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
          + "".join(f' <!ENTITY lol{k} "{(f"&lol{k - 1};" if k > 1 else "&lol;") * 10}">\n'
                    for k in range(1, 10))
          + f']>\n{HEAD}<fileHeader companyName="&lol9;"/></project>\n')

CASES = {
    "billion_laughs": (LAUGHS, 3, "entity declaration 'lol' refused"),
    "external_entity_file": (
        '<?xml version="1.0"?>\n<!DOCTYPE p [\n<!ENTITY x SYSTEM "file:///etc/passwd">\n]>\n'
        f'{HEAD}<fileHeader companyName="&x;"/></project>\n', 3,
        "external entity 'x' (file:///etc/passwd) refused"),
    "external_entity_http": (
        '<?xml version="1.0"?>\n<!DOCTYPE p [<!ENTITY % x SYSTEM "http://127.0.0.1:9/x.dtd"> '
        '%x;]>\n<project/>\n', 2, "external entity 'x' (http://127.0.0.1:9/x.dtd) refused"),
    "not_xml": ("\x89PNG\r\n\x1a\nnot at all XML", 1, "XML syntax: not well-formed"),
    "not_well_formed": (sfc('<step localId="1" name="A">'), 9, "XML syntax: mismatched tag"),
    "not_plcopen": ('<?xml version="1.0"?>\n<svg xmlns="http://www.w3.org/2000/svg"/>\n', 2,
                    "expected a PLCopen TC6 XML v2.01 project"),
    "deep_nesting": ('<?xml version="1.0"?>\n' + HEAD + "<a>" * 20_000 + "</a>" * 20_000
                     + "</project>\n", 3, "XML nested deeper than 100 levels"),
    "dangling_reference": (sfc(step(1, "A", initial=True) + trans(2, 99) + step(3, "B", 2)),
                           8, "dangling reference: refLocalId 99 names no element"),
    "cycle_of_divergences": (sfc(
        step(1, "A", initial=True)
        + '<selectionDivergence localId="5"><position x="0" y="0"/>'
          '<connectionPointIn><connection refLocalId="6"/></connectionPointIn>'
          '</selectionDivergence>'
          '<simultaneousConvergence localId="6"><position x="0" y="0"/>'
          '<connectionPointIn><connection refLocalId="5"/></connectionPointIn>'
          '</simultaneousConvergence>'
        + trans(2, 5) + step(3, "B", 2)), 8, "cycle in refLocalId: 5 -> 6 -> 5"),
    "cycle_of_contacts": (sfc(
        step(1, "A", initial=True) + trans(2, 1, network=10) + step(3, "B", 2)
        + '<contact localId="10"><position x="0" y="0"/><connectionPointIn>'
          '<connection refLocalId="11"/></connectionPointIn><variable>a</variable></contact>'
          '<contact localId="11"><position x="0" y="0"/><connectionPointIn>'
          '<connection refLocalId="10"/></connectionPointIn><variable>b</variable></contact>'),
        8, "cycle in refLocalId: 10 -> 11 -> 10"),
    "duplicate_local_id": (sfc(step(1, "A", initial=True) + step(1, "B")), 8,
                           "localId 1 is given twice in this SFC body"),
    "jump_to_nowhere": (sfc(
        step(1, "A", initial=True) + trans(2, 1)
        + '<jumpStep localId="3" targetName="Nowhere"><position x="0" y="0"/>'
          '<connectionPointIn><connection refLocalId="2"/></connectionPointIn></jumpStep>'),
        8, "localId 3: jump step to 'Nowhere': no step of that name"),
    "transition_after_transition": (sfc(
        step(1, "A", initial=True) + trans(2, 1) + trans(3, 2) + step(4, "B", 3)), 8,
        "localId 3: a transition's input connects to a transition (localId 2)"),
    "unconnected_transition": (sfc(step(1, "A", initial=True) + trans(2, None)
                                   + step(3, "B", 2)), 8,
                               "localId 2: transition with no step above it"),
    "st_syntax": (sfc(step(1, "A", initial=True) + trans(2, 1, "a AND (b") + step(3, "B", 2)),
                  8, "unbalanced parentheses"),
}


def refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], path: Path) -> str:
    out = tmp_path / "out"
    assert main(["import", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert not out.exists()  # nothing written
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_or_broken_file_is_one_error_line(case: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    text, line, words = CASES[case]
    p = tmp_path / f"{case}.xml"
    p.write_bytes(text.encode("utf-8", "surrogateescape"))
    got = refused(tmp_path, capsys, p)
    m = re.match(rf"^{re.escape(str(p))}:(\d+):(\d+): error: (.*)$", got)
    assert m, got
    assert int(m.group(1)) == line, got
    assert words in m.group(3), got


def test_a_100_mb_file_is_refused_before_it_is_read(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "huge.xml"
    with open(p, "wb") as f:
        f.write(sfc("").encode())
        f.truncate(100 * 1024 * 1024)  # sparse: no 100 MB written to the test's disk
    got = refused(tmp_path, capsys, p)
    assert got == (f"{p}:1:1: error: must be a regular file below {MAX_XML_BYTES // 1024} KiB "
                   f"({MAX_XML_BYTES} bytes), found a file of {100 * 1024 * 1024} bytes")


def test_too_many_elements_are_refused_at_the_first_beyond(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "many.xml"
    p.write_text(f'<?xml version="1.0"?>\n{HEAD}' + "<a/>\n" * (MAX_ELEMENTS + 10)
                 + "</project>\n", encoding="utf-8")
    got = refused(tmp_path, capsys, p)
    # the root (line 2) is element 1, element k >= 2 is on line k + 1
    assert got.startswith(f"{p}:{MAX_ELEMENTS + 2}:1: error: the file has more than "
                          f"{MAX_ELEMENTS} XML elements")


def test_a_fifo_or_a_device_is_refused(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    fifo = tmp_path / "pipe.xml"
    os.mkfifo(fifo)
    assert refused(tmp_path, capsys, fifo).endswith("found a FIFO (named pipe)")
    assert refused(tmp_path, capsys, Path("/dev/zero")).endswith(
        "found a character device")


def test_a_file_of_the_limit_size_is_read(tmp_path: Path) -> None:
    """The limit refuses no ordinary project: a file just under it, padded with white
    space, imports (the size alone refuses nothing below MAX_XML_BYTES)."""
    from runtime.plcopen.importer import import_file

    body = sfc(step(1, "A", initial=True) + trans(2, 1) + step(3, "B", 2))
    p = tmp_path / "padded.xml"
    p.write_text(body + " " * (MAX_XML_BYTES - 1 - len(body.encode())), encoding="utf-8")
    assert p.stat().st_size == MAX_XML_BYTES - 1
    assert [s for s in import_file(str(p)).charts[0].grafcet.steps] == ["A", "B"]


# -- texts of networks: only the language's own texts, read by its own parser -----------------
def _ld_action(coil: str = "o", expr: str = "a", comment: str = "") -> str:
    """tests/plcopen/test_plcopen_blocks.py's chart with S1's LD action holding a coil of
    variable ``coil`` fed by an inVariable ``expr``, and a comment ``comment``."""
    from tests.plcopen.test_plcopen_blocks import HEAD as BHEAD
    from tests.plcopen.test_plcopen_blocks import TAIL
    from tests.plcopen.test_plcopen_blocks import sfc as bsfc
    pou = ('<actions><action name="Act"><body><LD>'
           f'<inVariable localId="20"><position x="0" y="0"/><connectionPointOut/>'
           f'<expression><![CDATA[{expr}]]></expression></inVariable>'
           '<coil localId="21"><position x="100" y="0"/><connectionPointIn><connection '
           f'refLocalId="20"/></connectionPointIn><connectionPointOut/><variable><![CDATA['
           f'{coil}]]></variable></coil>'
           + (f'<comment localId="22"><position x="0" y="-40"/><content><xhtml:p>'
              f'{comment}</xhtml:p></content></comment>' if comment else "")
           + '</LD></body></action></actions>')
    body = bsfc('<inline name=""><ST><xhtml:p>b</xhtml:p></ST></inline>',
                '<action localId="7"><reference name="Act"/></action>')
    return BHEAD.replace("KIND", "TON") + pou + body.replace("BLOCKS", "") + TAIL


PAYLOAD = "__import__('os').system('touch MARKER')"


@pytest.mark.parametrize(("coil", "expr", "message"), [
    ("o := TRUE; c", "a", "the coil: expected the name of a variable to assign, found 'o := "
                          "TRUE; c'"),
    ("o", "a; o := b", "the inVariable: expected an expression, found ';'"),
    ("o", "b := a", "the inVariable: expected an expression, found ':='"),
    ("o", "a (* hidden *)", "the inVariable: expected an expression, found a comment "
                            "'(* hidden *)'"),
    ("o", "a // " + PAYLOAD, "the inVariable: expected an expression, found a comment"),
])
def test_texts_of_a_network_are_the_language_s_and_nothing_else(
        coil: str, expr: str, message: str, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A coil's variable is one name, an inVariable one expression: a text that would be
    read as more statements, or hide what follows it in a comment, is refused at its
    place (the statements are made for the language's parser, never for Python)."""
    xml = tmp_path / "h.xml"
    xml.write_text(_ld_action(coil, expr), encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and re.match(rf"{re.escape(str(xml))}:\d+:\d+: error: localId 2\d: ",
                                      err[0]), err
    assert message in err[0]
    assert not (tmp_path / "o").exists()


def test_a_comment_of_an_ld_action_with_line_breaks_and_python_stays_a_comment(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every line break an XML text can hold (CR written &#13;, LF, NEL, U+2028, U+2029;
    XML 1.0 has no other control characters) ends a ``//`` line of the action, and each
    line is a comment of the language: the chart runs, and nothing of the comment runs."""
    marker = tmp_path / "MARKER"
    breaks = ["&#13;", "\n", "\x85", "\u2028", "\u2029", "&#13;\n"]
    comment = "".join(f"x{c}{PAYLOAD.replace('MARKER', str(marker))}" for c in breaks)
    xml = tmp_path / "h.xml"
    xml.write_text(_ld_action(comment=comment), encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o"), "--strict"]) == 0
    chart = (tmp_path / "o" / "B.yaml").read_text(encoding="utf-8")
    assert all(c not in chart for c in "\r\x85\u2028\u2029")
    assert chart.count("// __import__") == len(breaks)
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        assert main(["simulate", str(tmp_path / "o" / "plant.yaml"), "--cycles", "3"]) == 0
    finally:
        os.chdir(cwd)
    assert not marker.exists()
    capsys.readouterr()
