"""One declaration per section (runtime/language/shape.py): the loaders take their key
lists, types and bounds from it, and configs/schema/ is generated from it
(tests/test_schemas.py holds the committed files to it). Here: no loader lists keys of its
own, and the loader and the editors' schema agree on every declared bound and type."""

from __future__ import annotations

import ast
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from runtime.errors import SourceError
from runtime.language import plantfile
from runtime.language.plantfile import load_plant
from runtime.language.shape import (
    Bool,
    Choice,
    Int,
    Key,
    Number,
    OneOf,
    Section,
    Text,
    Time,
    check_keys,
)
from runtime.language.yamlsrc import load_yaml

jsonschema = pytest.importorskip("jsonschema")

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = json.loads((ROOT / "configs/schema/plant.schema.json").read_text(encoding="utf-8"))
VALIDATOR = jsonschema.Draft202012Validator(SCHEMA)

CHART = """\
grafcet: G
inputs: [iA]
memory: {sN: 0}
steps:
  s0: {initial: true}
  s1: {}
transitions:
  - {from: s0, to: s1, when: iA}
  - {from: s1, to: s0, when: "iA'"}
"""
BASE: dict[str, Any] = {"drivers": {"sim": {"type": "sim"}},
                        "instances": {"t1": {"grafcet": "g.yaml", "inputs": {"iA": "sim.I0"}}}}
#: the keys a section cannot go without, as the tests give them
NEEDED: dict[tuple[str, ...], dict[str, Any]] = {
    ("mqtt",): {"brokers": "mqtt://127.0.0.1:1883", "group_id": "line1",
                "edge_node_id": "node1"},
}
#: the other keys a value at a bound needs beside it (a limit per session never above the
#: limit of all sessions): (path, bound) -> siblings
PARTNERS: dict[tuple[tuple[str, ...], str], dict[str, Any]] = {
    (("opcua", "limits", "items"), "high"): {"items_total": 10_000_000},
    (("opcua", "limits", "items_total"), "low"): {"items": 1},
    (("opcua", "limits", "publish_rate"), "high"): {"publish_rate_total": 100_000},
    (("opcua", "limits", "publish_rate_total"), "low"): {"publish_rate": 0.1},
    (("opcua", "limits", "abandoned"), "high"): {"session_timeout": "1h"},
    (("opcua", "limits", "session_timeout"), "low"): {"abandoned": "1s"},
}


def scalar_keys(section: Section, path: tuple[str, ...] = ()
                ) -> Iterator[tuple[tuple[str, ...], Key]]:
    """Every key of ``section`` and of the sections under it (a mapping form of a value
    included) whose value is no section, with its path from the plant file's top."""
    for key in section.keys:
        options = key.value.options if isinstance(key.value, OneOf) else (key.value,)
        nested = [o for o in options if isinstance(o, Section)]
        for o in nested:
            yield from scalar_keys(o, (*path, key.name))
        if not nested:
            yield (*path, key.name), key


def document(path: tuple[str, ...], value: Any, siblings: dict[str, Any] | None = None
             ) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(json.dumps(BASE))
    node = doc
    for k, name in enumerate(path[:-1]):
        node = node.setdefault(name, dict(NEEDED.get(path[:k + 1], {})))
    node.update(siblings or {})
    node[path[-1]] = value
    return doc


def loads(tmp_path: Path, doc: dict[str, Any]) -> str | None:
    """None if the plant loads, else the loader's message."""
    (tmp_path / "g.yaml").write_text(CHART, encoding="utf-8")
    plant = tmp_path / "plant.yaml"
    plant.write_text(json.dumps(doc), encoding="utf-8")  # JSON is YAML
    try:
        load_plant(str(plant))
    except SourceError as exc:
        return str(exc)
    return None


def editors_accept(doc: dict[str, Any]) -> bool:
    return not list(VALIDATOR.iter_errors(json.loads(json.dumps(doc))))


def literal(key: Key, n: int | float) -> Any:
    """``n`` written as ``key`` takes it: a time in ns, else the number."""
    return f"{n}ns" if isinstance(key.value, Time) else n


BOUNDED = [(path, key) for path, key in scalar_keys(plantfile.PLANT)
           if key.low is not None or key.high is not None]


def test_the_bounded_keys_are_found() -> None:
    names = {".".join(p) for p, _ in BOUNDED}
    assert {"plc.cycle", "plc.realtime.priority", "monitor.tcp.port", "opcua.limits.items",
            "mqtt.buffer", "web.max_pages", "alarms.severity.fault",
            "alarms.overruns.count"} <= names


@pytest.mark.parametrize("path, key", BOUNDED, ids=[".".join(p) for p, _ in BOUNDED])
def test_a_declared_bound_is_the_loaders_and_the_editors(path: tuple[str, ...], key: Key,
                                                        tmp_path: Path) -> None:
    """At each bound the loader takes the value, one step beyond it refuses it; the
    schema does the same for numbers (a time's bounds are the loader's alone: a pattern
    cannot hold them)."""
    step = 0.01 if isinstance(key.value, Number) else 1
    numbers = not isinstance(key.value, Time)
    for bound, beyond in (("low", -step), ("high", step)):
        n = getattr(key, bound)
        if n is None:
            continue
        at = document(path, literal(key, n), PARTNERS.get((path, bound)))
        assert loads(tmp_path, at) is None, (bound, n, loads(tmp_path, at))
        past = document(path, literal(key, n + beyond))
        assert loads(tmp_path, past) is not None, (bound, n + beyond)
        if numbers:
            assert editors_accept(at), (bound, n)
            assert not editors_accept(past), (bound, n + beyond)


#: values of another kind than declared, by kind (a list and a mapping are never a scalar;
#: yes/no are text in these files, never a bool)
WRONG: list[tuple[type, list[Any]]] = [
    (Bool, ["no", 1, [True]]),
    (Int, ["5", 1.5, True, [1]]),
    (Number, ["5", True, [1]]),
    (Time, [10, True, [1], {"a": 1}]),
    (Text, [[1], {"a": 1}]),
    (Choice, [[1], {"a": 1}]),
]
TYPED = [(path, key, wrong) for path, key in scalar_keys(plantfile.PLANT)
         for kind, values in WRONG if isinstance(key.value, kind) for wrong in values]


def test_the_typed_keys_are_found() -> None:
    names = {".".join(p) for p, _, _ in TYPED}
    assert {"plc.realtime.lock_memory", "plc.retain_required", "monitor.pin_hash",
            "opcua.endpoint", "web.read", "mqtt.statistics"} <= names


@pytest.mark.parametrize("path, key, wrong", TYPED,
                         ids=[f"{'.'.join(p)}={w!r}" for p, _, w in TYPED])
def test_a_declared_type_is_the_loaders_and_the_editors(path: tuple[str, ...], key: Key,
                                                       wrong: Any, tmp_path: Path) -> None:
    doc = document(path, wrong)
    assert loads(tmp_path, doc) is not None, f"the loader took {wrong!r}"
    assert not editors_accept(doc), f"the schema took {wrong!r}"


def test_no_loader_lists_keys_of_its_own() -> None:
    """Every key check goes through a declaration: ``Section.check``, or a driver type's
    keys as drivers/registry.py declares them (``drivershape.keys_of``)."""
    found = []
    for path in sorted((ROOT / "runtime").rglob("*.py")):
        if path.name == "shape.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id == "check_keys"):
                allowed = node.args[1:2] and isinstance(node.args[1], ast.Call) and (
                    getattr(node.args[1].func, "id", "") == "keys_of")
                if not allowed:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert found == []


def test_a_section_refuses_a_key_it_does_not_declare() -> None:
    section = Section((Key("a", Int()), Key("beta", Text())), "things")
    doc = load_yaml("f.yaml", "a: 1\nbta: x\n")
    with pytest.raises(SourceError, match=r"f.yaml:2:1: error: unknown key 'bta' in things: "
                                          r"expected one of a, beta \(did you mean 'beta'\?\)"):
        section.check(doc)
    with pytest.raises(SourceError, match="unknown key 'bta' in other"):
        check_keys(doc, section.names, "other")
    with pytest.raises(ValueError, match="declared twice"):
        Section((Key("a", Int()), Key("a", Text())), "twice")
    with pytest.raises(KeyError):
        section.without("c", doc="")
    assert section.without("a", doc="").names == ("beta",)


GRAFCET_SCHEMA = json.loads((ROOT / "configs/schema/grafcet.schema.json").read_text("utf-8"))
GRAFCET_VALIDATOR = jsonschema.Draft202012Validator(GRAFCET_SCHEMA)


def _chart(where: str, key: str, value: Any) -> dict[str, Any]:
    """CHART with ``key: value`` in the chart (``where`` grafcet), in its step s1 (step), in
    its first transition (transition) or in memory sN's mapping (memory)."""
    chart: dict[str, Any] = {"grafcet": "G", "inputs": ["iA"], "memory": {"sN": 0},
                             "steps": {"s0": {"initial": True}, "s1": {}},
                             "transitions": [{"from": "s0", "to": "s1", "when": "iA"},
                                             {"from": "s1", "to": "s0", "when": "iA'"}]}
    node = {"grafcet": chart, "step": chart["steps"]["s1"],
            "transition": chart["transitions"][0]}.get(where)
    if where == "memory":
        node = chart["memory"]["sN"] = {"init": 0}
    assert node is not None
    node[key] = value
    return chart


def _chart_keys() -> Iterator[tuple[str, Key]]:
    from runtime.language import grafcetfile as gf

    for where, section in (("grafcet", gf.GRAFCET), ("step", gf.STEP),
                           ("transition", gf.TRANSITION), ("memory", gf.MEMORY_SPEC)):
        for key in section.keys:
            if key.name not in ("entry", "exit"):  # inside a macro-step only
                yield where, key


CHART_TYPED = [(where, key, wrong) for where, key in _chart_keys()
               for kind, values in WRONG if isinstance(key.value, kind) for wrong in values]


@pytest.mark.parametrize("where, key, wrong", CHART_TYPED,
                         ids=[f"{w}.{k.name}={v!r}" for w, k, v in CHART_TYPED])
def test_a_declared_type_of_a_chart_is_the_loaders_and_the_editors(
        where: str, key: Key, wrong: Any, tmp_path: Path) -> None:
    from runtime.language.grafcetfile import load_grafcet

    chart = _chart(where, key.name, wrong)
    path = tmp_path / "c.yaml"
    path.write_text(json.dumps(chart), encoding="utf-8")
    with pytest.raises(SourceError):
        load_grafcet(str(path))
    assert list(GRAFCET_VALIDATOR.iter_errors(chart)), f"the schema took {wrong!r}"
