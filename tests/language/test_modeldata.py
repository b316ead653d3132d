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

from bench.divergence import chain_text
from runtime.engine.plant import Plant
from runtime.language import modeldata
from runtime.language.filekind import file_kind
from runtime.language.grafcetfile import load_grafcet
from runtime.language.modeldata import CHUNK_RECORDS, LEFT_OUT, ModelDataError, dump, load
from runtime.language.plantfile import load_plant

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
