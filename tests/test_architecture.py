"""The import rules of docs/architecture.md, enforced on the real import graph.

Every ``import``/``from ... import`` statement of runtime/ and drivers/ counts, including
the lazy ones inside functions: a rule broken at run time only is still broken.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: the parts of the project, most specific first (a module belongs to the first prefix)
PARTS = (
    "runtime.cli", "runtime.errors", "runtime.language", "runtime.compiler", "runtime.engine",
    "runtime.controller", "runtime.console", "runtime.checker", "runtime.drawing", "drivers",
    "runtime.change", "runtime.opcua", "runtime.plcopen", "runtime.mqtt", "runtime.web",
    "runtime.modbus",
    "runtime.scenario",
)

#: drivers modules with no bus library (the driver contract, lookup by type, durations, and
#: the in-memory driver of simulations): what a layer below the controller may use
DRIVER_CONTRACT = frozenset({"drivers", "drivers.base", "drivers.config", "drivers.registry",
                             "drivers.durations", "drivers.sim", "drivers.image"})

#: part -> the parts it may import (itself always allowed). "drivers.contract" means only the
#: modules of DRIVER_CONTRACT; "drivers" means any driver module.
ALLOWED: dict[str, frozenset[str]] = {
    "drivers": frozenset(),
    "runtime.errors": frozenset(),
    "runtime.language": frozenset({"runtime.errors", "drivers.contract"}),
    "runtime.compiler": frozenset({"runtime.errors", "runtime.language"}),
    "runtime.engine": frozenset({"runtime.errors", "runtime.language", "runtime.compiler",
                                 "drivers.contract"}),
    "runtime.controller": frozenset({"runtime.errors", "runtime.language", "runtime.compiler",
                                     "runtime.engine", "runtime.change", "drivers"}),
    "runtime.console": frozenset({"runtime.errors", "runtime.language", "runtime.compiler",
                                  "runtime.engine", "runtime.change", "runtime.controller",
                                  "drivers.contract"}),
    "runtime.checker": frozenset({"runtime.errors", "runtime.language", "runtime.compiler",
                                  "runtime.engine.names", "runtime.engine.script",
                                  "runtime.scenario.spec", "drivers.contract"}),
    "runtime.drawing": frozenset({"runtime.errors", "runtime.language", "drivers.contract"}),
    "runtime.opcua": frozenset({"runtime.errors", "runtime.language", "runtime.engine.names",
                                "runtime.controller.feed", "runtime.controller.feedclient",
                                "runtime.controller.aio", "runtime.controller.pin",
                                "drivers.contract"}),
    "runtime.mqtt": frozenset({"runtime.errors", "runtime.language",
                               "runtime.controller.feed", "runtime.controller.feedclient",
                               "runtime.controller.aio"}),
    "runtime.plcopen": frozenset({"runtime.errors", "runtime.language", "runtime.drawing",
                                  "runtime.scenario.skeleton", "drivers.contract"}),
    "runtime.web": frozenset({"runtime.errors", "runtime.language", "runtime.drawing",
                              "runtime.controller.feed", "runtime.controller.feedclient",
                              "runtime.controller.aio", "runtime.controller.pin"}),
    "runtime.modbus": frozenset({"runtime.errors", "runtime.language",
                                 "runtime.controller.feed", "runtime.controller.feedclient",
                                 "runtime.controller.aio",
                                 "drivers.modbus_frame"}),
    "runtime.cli": frozenset({"*"}),
    "runtime.change": frozenset({"runtime.errors", "runtime.language", "runtime.compiler",
                                 "runtime.engine", "drivers.contract"}),
    "runtime.scenario": frozenset({"runtime.errors", "runtime.language", "runtime.compiler",
                                   "runtime.engine", "drivers.contract"}),
}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(source: str, here: str, is_package: bool,
               known: Iterable[str]) -> list[tuple[int, str]]:
    """(line, imported module) for every import of a project module in the source of module
    ``here``; ``from a import b`` counts as ``a.b`` when that is a module of ``known``."""
    names = set(known)
    tree = ast.parse(source, here)
    package = here if is_package else here.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            for a in node.names:
                sub = f"{base}.{a.name}"
                found.append((node.lineno, sub if sub in names else base))
    return [(line, m) for line, m in found if m.split(".")[0] in ("runtime", "drivers")]


def part_of(module: str) -> str:
    for p in PARTS:
        if module == p or module.startswith(p + "."):
            return p
    return module  # "runtime" itself


def allowed(src: str, dst: str, rules: Mapping[str, frozenset[str]]) -> bool:
    """May module ``src`` import module ``dst``?"""
    sp, dp = part_of(src), part_of(dst)
    ok = rules[sp]
    if sp == dp or "*" in ok or dst == "runtime":
        return True
    if dp == "drivers":
        return ("drivers" in ok or ("drivers.contract" in ok and dst in DRIVER_CONTRACT)
                or dst in ok)
    return dp in ok or any(dst == o or dst.startswith(o + ".") for o in ok)


def violations(graph: Mapping[str, list[tuple[int, str]]],
               rules: Mapping[str, frozenset[str]]) -> list[str]:
    out = []
    for src, deps in sorted(graph.items()):
        for line, dst in deps:
            if not allowed(src, dst, rules):
                out.append(f"{src}:{line} imports {dst} ({part_of(src)} may import "
                           f"{', '.join(sorted(rules[part_of(src)])) or 'nothing of the project'})")
            for only_cli in ("runtime.console", "runtime.plcopen"):
                if part_of(dst) == only_cli and part_of(src) not in (only_cli, "runtime.cli"):
                    out.append(f"{src}:{line} imports {dst}: only runtime.cli may import "
                               f"{only_cli}")
    return out


def project_graph() -> dict[str, list[tuple[int, str]]]:
    files = sorted([*ROOT.glob("runtime/**/*.py"), *ROOT.glob("drivers/**/*.py")])
    known = {module_name(f) for f in files}
    return {module_name(f): imports_of(f.read_text(), module_name(f), f.name == "__init__.py",
                                       known) for f in files}


def test_every_module_belongs_to_a_part() -> None:
    graph = project_graph()
    assert len(graph) > 40
    loose = [m for m in graph if part_of(m) not in ALLOWED and m != "runtime"]
    assert loose == [], f"modules outside the documented parts: {loose}"


def test_the_import_graph_follows_the_rules() -> None:
    bad = violations(project_graph(), ALLOWED)
    assert bad == [], "import rules broken (docs/architecture.md):\n" + "\n".join(bad)


def test_no_import_cycle_between_parts() -> None:
    graph = project_graph()
    edges: dict[str, set[str]] = {}
    for src, deps in graph.items():
        for _, dst in deps:
            a, b = part_of(src), part_of(dst)
            if a != b and b in ALLOWED:
                edges.setdefault(a, set()).add(b)
    seen: dict[str, int] = {}

    def visit(n: str, path: list[str]) -> None:
        seen[n] = 1
        for m in sorted(edges.get(n, ())):
            assert seen.get(m) != 1, "import cycle between parts: " + " -> ".join([*path, m])
            if m not in seen:
                visit(m, [*path, m])
        seen[n] = 2

    for n in sorted(edges):
        if n not in seen:
            visit(n, [n])


@pytest.mark.parametrize(("src", "dst"), [
    ("drivers.gpio", "runtime.errors"),
    ("runtime.engine.plant", "runtime.controller.daemon"),
    ("runtime.engine.plant", "drivers.canopen_io"),
    ("runtime.drawing.text", "runtime.checker.logic"),
    ("runtime.controller.daemon", "runtime.console.session"),
    ("runtime.language.model", "runtime.compiler.codegen"),
    ("runtime.checker.check", "runtime.engine.plant"),
    ("runtime.opcua.server", "runtime.controller.daemon"),
    ("runtime.controller.feed", "runtime.opcua.server"),
    ("runtime.plcopen.importer", "runtime.compiler.codegen"),
    ("runtime.plcopen.export", "runtime.engine.plant"),
    ("runtime.drawing.chart", "runtime.plcopen.export"),
    ("runtime.checker.check", "runtime.plcopen.importer"),
    ("runtime.mqtt.node", "runtime.controller.daemon"),
    ("runtime.mqtt.node", "runtime.opcua.server"),
    ("runtime.opcua.server", "runtime.mqtt.node"),
    ("runtime.controller.feed", "runtime.mqtt.session"),
    ("runtime.modbus.server", "runtime.controller.daemon"),
    ("runtime.modbus.server", "drivers.modbus_tcp"),
    ("runtime.modbus.server", "runtime.opcua.server"),
    ("runtime.controller.feed", "runtime.modbus.server"),
])
def test_the_rules_catch_a_forbidden_import(src: str, dst: str) -> None:
    """The checker of the rules is itself checked: each of these edges is refused."""
    assert violations({src: [(1, dst)]}, ALLOWED) != []


def test_relative_and_lazy_imports_are_seen() -> None:
    source = (
        "import os\n"
        "from . import names\n"
        "from ..controller import daemon\n"
        "def later():\n"
        "    from runtime.console.session import ConsoleService\n"
    )
    known = {"runtime.engine.names", "runtime.controller.daemon", "runtime.console.session"}
    found = imports_of(source, "runtime.engine.plant", False, known)
    assert found == [(2, "runtime.engine.names"), (3, "runtime.controller.daemon"),
                     (5, "runtime.console.session")]
    assert len(violations({"runtime.engine.plant": found}, ALLOWED)) == 3


def test_no_bounded_wait_can_lose_a_cancellation() -> None:
    """Python 3.11's ``asyncio.wait_for`` loses a cancellation that comes as the awaited
    thing completes (a task that then never ends: a side process that did not end on
    SIGTERM). Every bounded wait goes through ``runtime.controller.aio.within``."""
    found = [f"{path.relative_to(ROOT)}:{n}"
             for path in sorted((ROOT / "runtime").rglob("*.py"))
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if re.search(r"\basyncio\.wait_for\b|from asyncio import .*\bwait_for\b", line)]
    assert found == [], found
