"""A loaded plant crosses between processes as data (runtime/language/modeldata.py): every
plant of configs/ comes back field for field (the load-only ``locate`` functions left out),
with the charts its instances share still shared, and compiles to the very same code; data
that names anything but the model's own classes is refused, never run."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from bench.divergence import chain_text
from runtime.engine.plant import Plant
from runtime.language import modeldata
from runtime.language.filekind import file_kind
from runtime.language.grafcetfile import load_grafcet
from runtime.language.modeldata import CHUNK_RECORDS, LEFT_OUT, ModelDataError, dump, load
from runtime.language.plantfile import load_plant
from tests.language.plantgen import plant_docs, write

ROOT = Path(__file__).resolve().parents[2]
PLANTS = sorted(str(p) for p in (ROOT / "configs").glob("*/*.yaml")
                if file_kind(str(p)) == "plant")


def same(a: Any, b: Any, where: str = "") -> None:
    """``a`` and ``b`` equal field by field (the syntax tree's nodes compare by identity,
    so they are walked too), the fields left out excepted."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            if f.name not in LEFT_OUT:
                same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert type(b) is dict and list(a) == list(b), where
        for k in a:
            same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, list | tuple):
        assert type(b) is (list if isinstance(a, list) else tuple) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{where}[{i}]")
    else:
        assert a == b and type(b) in (type(a), str), (where, a, b)


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: p.split("configs/")[1])
def test_every_plant_comes_back_and_compiles_the_same(path: str) -> None:
    pdef = load_plant(path)
    back = load(dump(pdef))
    same(pdef, back)
    charts = {id(i.grafcet) for i in pdef.instances.values()}
    assert len({id(i.grafcet) for i in back.instances.values()}) == len(charts)
    a, b = Plant(pdef, sim=True), Plant(back, sim=True)
    assert a.source == b.source
    assert [p.source for p in a.programs] == [p.source for p in b.programs]


def test_a_large_chart_is_read_in_short_chunks(tmp_path: Path) -> None:
    """Each chunk a few thousand records: reading one holds the GIL about a millisecond."""
    path = tmp_path / "chain.yaml"
    path.write_text(chain_text(2000), encoding="utf-8")
    g = load_grafcet(str(path))
    chunks = list(dump(g))
    assert len(chunks) > 10
    assert all(len(json.loads(c)) <= CHUNK_RECORDS for c in chunks)
    same(g, load(chunks))


@pytest.mark.parametrize("data, why", [
    ('[["o","Popen",["rm","-rf","/"]]]', "unknown record"),
    ('[["o","system","id"]]', "unknown record"),
    ('[["o","Loc","f",1]]', "2 fields, expected 3"),
    ('[["e","VarKind","nothing"]]', "has no member"),
    ('[["l",[5]]]', "bad reference"),
    ('[["l",{"__class__":"x"}]]', "bad value"),
    ('[["l"],["d",[0],1]]', "not hashable"),
    ('{"a": 1}', "not a list of records"),
    ("not json", "not JSON"),
])
def test_data_naming_anything_else_is_refused(data: str, why: str) -> None:
    with pytest.raises(ModelDataError, match=why):
        load([data])


def test_what_is_not_of_the_model_does_not_cross() -> None:
    with pytest.raises(ModelDataError, match="not part of the model"):
        list(dump({"x": object()}))
    assert set(modeldata.CLASSES) >= {"PlantDef", "Grafcet", "Loc", "Binary", "VarKind"}


# -- every plant the loader accepts crosses (issue: a plant with ``unit:`` could not) ------
@pytest.fixture(scope="module")
def gen_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where the generated plants are written (``${RUNTIME_DIR}`` below it)."""
    return tmp_path_factory.mktemp("gen")


def test_a_plant_with_an_io_list_unit_crosses(tmp_path: Path) -> None:
    """The I/O list's unit (``units.Unit``, a class the model takes from another module)
    crossed nowhere: ``Unit is not part of the model``."""
    (tmp_path / "c.yaml").write_text(
        "grafcet: C\ninputs: [{iLevel: int}]\noutputs: [oRun]\nsteps:\n  s0: {initial: true}\n"
        "  s1: {actions: [oRun]}\ntransitions:\n  - {from: s0, to: s1, when: iLevel > 5}\n"
        "  - {from: s1, to: s0, when: iLevel < 2}\n", encoding="utf-8")
    (tmp_path / "p.yaml").write_text(
        "drivers:\n  io: {type: sim}\ninstances:\n  m:\n    grafcet: c.yaml\n"
        "    inputs: {iLevel: {from: io.IR0, unit: mm, range: [0, 100]}}\n"
        "    outputs: {oRun: io.Q0}\n", encoding="utf-8")
    pdef = load_plant(str(tmp_path / "p.yaml"))
    back = load(dump(pdef))
    same(pdef, back)
    assert back.instances["m"].inputs["iLevel"].unit.symbol == "mm"


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(docs=plant_docs())
def test_every_plant_the_loader_accepts_crosses_unchanged(
        gen_dir: Path, monkeypatch: pytest.MonkeyPatch,
        docs: tuple[dict[str, Any], dict[str, Any]]) -> None:
    """Property: a generated plant (every key of every section may be present) loads, and
    comes back from dump/load field for field, with its shared chart still shared, and
    compiles to the same code."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(gen_dir))
    pdef = load_plant(str(write(gen_dir, docs)))
    back = load(dump(pdef))
    same(pdef, back)
    assert len({id(i.grafcet) for i in back.instances.values()}) == 1
    assert Plant(pdef, sim=True).source == Plant(back, sim=True).source


def schema_paths(schema: dict[str, Any]) -> set[str]:
    """Every key a JSON Schema declares, as a path: ``instances.*.inputs.*.unit`` (``*`` a
    name of the user's, ``[]`` a list's item), each ``$ref`` followed once per path."""
    out: set[str] = set()

    def walk(node: Any, prefix: str, refs: frozenset[str]) -> None:
        if not isinstance(node, dict):
            return
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/") and ref not in refs:
            target: Any = schema
            for part in ref[2:].split("/"):
                target = target[part]
            walk(target, prefix, refs | {ref})
        for key in ("oneOf", "anyOf", "allOf"):
            for sub in node.get(key, []):
                walk(sub, prefix, refs)
        for key in ("then", "else"):
            walk(node.get(key), prefix, refs)
        for name, sub in node.get("properties", {}).items():
            out.add(prefix + name)
            walk(sub, f"{prefix}{name}.", refs)
        walk(node.get("additionalProperties"), prefix + "*.", refs)
        walk(node.get("items"), prefix + "[].", refs)
    walk(schema, "", frozenset())
    return out


def doc_paths(schema: dict[str, Any], doc: Any) -> set[str]:
    """The paths of ``schema_paths`` that the document ``doc`` uses."""
    out: set[str] = set()

    def alternatives(node: Any, refs: frozenset[str] = frozenset()) -> list[dict[str, Any]]:
        if not isinstance(node, dict):
            return []
        found = [node]
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/") and ref not in refs:
            target: Any = schema
            for part in ref[2:].split("/"):
                target = target[part]
            found += alternatives(target, refs | {ref})
        for key in ("oneOf", "anyOf", "allOf"):
            for sub in node.get(key, []):
                found += alternatives(sub, refs)
        for key in ("then", "else"):
            found += alternatives(node.get(key), refs)
        return found

    def walk(nodes: list[dict[str, Any]], value: Any, prefix: str) -> None:
        flat = [a for n in nodes for a in alternatives(n)]
        if isinstance(value, dict):
            for k, v in value.items():
                props = [a["properties"][k] for a in flat if k in a.get("properties", {})]
                if props:
                    out.add(prefix + str(k))
                    walk(props, v, f"{prefix}{k}.")
                else:
                    walk([a["additionalProperties"] for a in flat
                          if isinstance(a.get("additionalProperties"), dict)], v, prefix + "*.")
        elif isinstance(value, list):
            for v in value:
                walk([a["items"] for a in flat if isinstance(a.get("items"), dict)], v,
                     prefix + "[].")
    walk([schema], doc, "")
    return out


@settings(max_examples=5, deadline=None, suppress_health_check=list(HealthCheck))
@given(docs=plant_docs(full=True))
def test_the_generated_plants_use_every_key_of_every_section(
        docs: tuple[dict[str, Any], dict[str, Any]]) -> None:
    """The generator above knows every key the editors' schemas (and so the loaders) know:
    a key added to a section is a key it must learn, or this fails naming it."""
    for doc, kind in zip(docs, ("grafcet", "plant"), strict=True):
        with open(ROOT / "configs" / "schema" / f"{kind}.schema.json", encoding="utf-8") as f:
            schema = json.load(f)
        missing = schema_paths(schema) - doc_paths(schema, doc)
        assert not missing, f"{kind}: keys never generated: {sorted(missing)}"
