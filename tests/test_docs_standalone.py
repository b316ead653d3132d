"""The documentation stands on its own: it cites nothing outside the repository.

A user of the repository has docs/, README.md and configs/schema/ and nothing else, so none
of them may send the reader to the project's working notes (``spec/...``, ``../shared/...``,
``../seeds/...``), and every relative link in docs/ and README.md must lead to a file of the
repository (and, with ``#anchor``, to a heading of that file).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: references to files that live outside the repository
OUTSIDE = re.compile(r"\bspec/|\.\./shared|\bshared/spec|\.\./seeds|/work/shared")
#: an inline link or image, ``[text](target)`` / ``![alt](target)``, the text may span lines
INLINE_LINK = re.compile(r"\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
#: a reference definition, ``[label]: target``
REFERENCE_LINK = re.compile(r"^\s{0,3}\[[^\]]+\]:\s+<?(\S+?)>?(?:\s|$)", re.M)
FENCE = re.compile(r"^\s*(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


def documents() -> list[Path]:
    """Every file the user reads: docs/ (text files), README.md, configs/schema/*.json."""
    files = [p for p in sorted((ROOT / "docs").rglob("*")) if p.is_file()]
    files.append(ROOT / "README.md")
    files.extend(sorted((ROOT / "configs" / "schema").glob("*.json")))
    return files


def markdown_files() -> list[Path]:
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def prose(text: str) -> str:
    """The text outside fenced code blocks (a link inside a code block is not a link)."""
    kept: list[str] = []
    fenced = False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            kept.append(line)
    return "\n".join(kept)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]{2,}|`", "", heading).strip().lower()
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a markdown text's headings (a repeated heading gets -1, -2 ...)."""
    seen: dict[str, int] = {}
    found: set[str] = set()
    for line in prose(text).splitlines():
        m = HEADING.match(line)
        if not m:
            continue
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        found.add(base if n == 0 else f"{base}-{n}")
    return found


def broken_links(path: Path, text: str) -> list[str]:
    """The relative links of a markdown text that do not lead into the repository."""
    body = prose(text)
    targets = INLINE_LINK.findall(body) + REFERENCE_LINK.findall(body)
    broken: list[str] = []
    for target in targets:
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target):  # http:, https:, mailto: ...
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.is_relative_to(ROOT) or not dest.exists():
            broken.append(f"{path.relative_to(ROOT)}: {target} (no such file)")
            continue
        if anchor and dest.suffix == ".md":
            text_of_dest = text if dest == path else dest.read_text(encoding="utf-8")
            if anchor.lower() not in anchors(text_of_dest):
                broken.append(f"{path.relative_to(ROOT)}: {target} (no such heading)")
    return broken


def test_no_document_refers_to_files_outside_the_repository() -> None:
    found = []
    for path in documents():
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue  # a picture
        for n, line in enumerate(text.splitlines(), 1):
            if OUTSIDE.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert found == []


def test_every_relative_link_leads_to_a_file_of_the_repository() -> None:
    broken = []
    for path in markdown_files():
        broken += broken_links(path, path.read_text(encoding="utf-8"))
    assert broken == []


def test_the_docs_are_checked_at_all() -> None:
    """The two checks above see the files and the links they are meant to see."""
    names = {p.relative_to(ROOT).as_posix() for p in documents()}
    assert {"README.md", "docs/language.md", "docs/semantics.md", "docs/console.md",
            "configs/schema/plant.schema.json"} <= names
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "docs/img/drawer_tester.svg" in INLINE_LINK.findall(prose(readme))


def test_the_link_check_finds_what_it_is_meant_to_find() -> None:
    """A missing file, a link out of the repository and a missing heading are reported;
    a good file, a heading of this or of another file, and a web address are not."""
    page = ROOT / "docs" / "semantics.md"
    text = (
        "# Semantics\n\n## Program time: console pause, `cycle N`\n\n"
        "[a](language.md) [b](../README.md) [c](#semantics) "
        "[d](#program-time-console-pause-cycle-n) [e](https://example.org/x) "
        "[f](daemon.md#signals)\n"
        "[g](nowhere.md) [h](../../outside.md) [i](#no-such-heading) "
        "[j\n](language.md#no-such-heading)\n"
        "```\n[k](in-a-code-block.md)\n```\n"
        "[l]: missing/ref.md\n"
    )
    assert broken_links(page, text) == [
        "docs/semantics.md: nowhere.md (no such file)",
        "docs/semantics.md: ../../outside.md (no such file)",
        "docs/semantics.md: #no-such-heading (no such heading)",
        "docs/semantics.md: language.md#no-such-heading (no such heading)",
        "docs/semantics.md: missing/ref.md (no such file)",
    ]
    assert OUTSIDE.search("see `spec/language.md`")
    assert OUTSIDE.search("(`shared/spec/console.md`)")
    assert OUTSIDE.search("`../shared/spec/semantics.md`")
    assert not OUTSIDE.search("docs/semantics.md, a bool target shared by two steps")


YAML_BLOCK = re.compile(r"^```yaml\n(.*?)^```", re.M | re.S)


def test_the_reference_examples_of_each_file_kind_match_their_schema() -> None:
    """The grafcet, plant and script examples of docs/language.md are files softplc's
    schemas accept (the same check as every file in configs/)."""
    pytest.importorskip("jsonschema")
    from tests.test_schemas import errors, kind_of, read

    text = (ROOT / "docs" / "language.md").read_text(encoding="utf-8")
    kinds = []
    for block in YAML_BLOCK.findall(text):
        doc = read(block, "docs/language.md")
        kind = kind_of(doc)
        if kind == "unknown":
            continue  # a fragment (steps:, pre: ...), not a whole file
        kinds.append(kind)
        assert errors(kind, doc) == [], block
    assert {"grafcet", "plant", "script"} <= set(kinds)


def test_the_reference_simulation_script_does_what_its_comments_say(tmp_path: Path) -> None:
    """The script of docs/language.md, run on the plant it names: the NC stop button set
    physically, the start edge seen at 20 ms, the pause, and the stop written logically
    and inverted into the physical point."""
    from runtime.engine.simulate import Simulation
    from runtime.language.yamlsrc import load_yaml

    text = (ROOT / "docs" / "language.md").read_text(encoding="utf-8")
    scripts = [b for b in YAML_BLOCK.findall(text)
               if "set" in (load_yaml("docs/language.md", b) or {})]
    assert len(scripts) == 1
    script = tmp_path / "script.yaml"
    script.write_text(scripts[0], encoding="utf-8")
    plant = ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"
    rows = {r["t_ms"]: r for r in Simulation(str(plant), str(script)).run()}
    assert len(rows) == 200  # duration: 2s at a 10 ms cycle
    assert (rows[0]["sim.I0"], rows[0]["tester1.iParo"]) == (1, 0)
    assert rows[10]["tester1.gsParado.X"] == 1
    assert rows[20]["tester1.gsAbrir.X"] == 1  # the rising edge of iMarcha, at once
    assert rows[1000]["tester1.SFCPause"] == 1
    assert rows[1490]["tester1.gsAbrir.T_ms"] == rows[1000]["tester1.gsAbrir.T_ms"]
    assert (rows[1500]["tester1.iParo"], rows[1500]["sim.I0"]) == (1, 0)


def test_the_readme_lists_every_command() -> None:
    """README's "The command line" names every subcommand the parser has (``softplc
    iolist`` was missing)."""
    import argparse

    from runtime.cli import build_parser

    parser = build_parser(None)
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## The command line"):]
    block = section[section.index("```"):section.index("```", section.index("```") + 3)]
    listed = set(re.findall(r"^softplc ([a-z-]+)", block, re.M))
    assert sorted(set(sub.choices) - listed) == []
