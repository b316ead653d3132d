"""The process image (drivers/image.py): a dict by behaviour, a list by position.

Dict-equivalence against a real dict on random sequences of operations (hypothesis), no
deletion, positions that never move, the fast views and whole-image operations, and the
drivers' images made of it."""

from __future__ import annotations

import copy
import sys
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.base import Direction
from drivers.image import Image
from drivers.sim import SimDriver

KEYS = st.sampled_from(["I0", "I1", "Q0", "Q7", "B3", "17", "HR4", "x"])
VALUES = st.one_of(st.integers(-3, 3), st.booleans(), st.floats(allow_nan=False))
OPS = st.lists(st.one_of(
    st.tuples(st.just("set"), KEYS, VALUES),
    st.tuples(st.just("get"), KEYS),
    st.tuples(st.just("getdefault"), KEYS, VALUES),
    st.tuples(st.just("contains"), KEYS),
    st.tuples(st.just("update"), st.dictionaries(KEYS, VALUES, max_size=4)),
    st.tuples(st.just("setdefault"), KEYS, VALUES),
    st.tuples(st.just("fill"), VALUES),
), max_size=40)


def _apply(target: Any, op: tuple[Any, ...]) -> Any:
    """One operation on a dict or an Image; returns what a caller would see."""
    kind = op[0]
    if kind == "set":
        target[op[1]] = op[2]
        return None
    if kind == "get":
        try:
            return ("ok", target[op[1]])
        except KeyError:
            return ("KeyError",)
    if kind == "getdefault":
        return target.get(op[1], op[2])
    if kind == "contains":
        return op[1] in target
    if kind == "update":
        target.update(op[1])
        return None
    if kind == "setdefault":
        return target.setdefault(op[1], op[2])
    if isinstance(target, Image):  # fill: the dict's equivalent below
        target.fill(op[1])
    else:
        for k in target:
            target[k] = op[1]
    return None


@settings(max_examples=300, deadline=None)
@given(OPS)
def test_an_image_behaves_as_a_dict(ops: list[tuple[Any, ...]]) -> None:
    d: dict[str, Any] = {}
    img = Image()
    for op in ops:
        assert _apply(img, op) == _apply(d, op), op
        # every view, in the same order as the dict's (insertion order)
        assert list(img) == list(d)
        assert list(img.keys()) == list(d.keys())
        assert list(img.values()) == list(d.values())
        assert list(img.items()) == list(d.items())
        assert len(img) == len(d) == len(img.vals)
        assert img == d and img.copy() == d and type(img.copy()) is dict
        assert dict(img) == d
        assert img == Image(d) and Image(img) == img
        for k in d:
            assert (k, d[k]) in img.items() and d[k] in img.values() and k in img.keys()


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(KEYS, VALUES), max_size=30))
def test_positions_never_move(sets: list[tuple[str, Any]]) -> None:
    """A point keeps the position it got when first set; a new point is appended."""
    img = Image()
    first: dict[str, int] = {}
    for k, v in sets:
        img[k] = v
        first.setdefault(k, len(first))
        assert img.index == first
        assert img.vals[img.index[k]] == v
    assert list(img.index.values()) == list(range(len(img)))


def test_a_point_cannot_be_deleted_and_the_image_is_unchanged() -> None:
    img = Image({"I0": 1, "I1": 0})
    vals = img.vals
    for remove in (lambda: img.__delitem__("I0"), lambda: img.pop("I0"), img.popitem,
                   img.clear):
        with pytest.raises(TypeError, match="cannot delete point .* positions"):
            remove()
    assert img == {"I0": 1, "I1": 0} and img.vals is vals and img.index == {"I0": 0, "I1": 1}
    assert img.pop("nope", 5) == 5  # nothing to delete: as a dict does
    with pytest.raises(KeyError):
        img.pop("nope")


def test_whole_image_operations_keep_the_list_and_the_names_interned() -> None:
    img = Image()
    name = "".join(["Q", "1", "7"])  # a string made at run time: not interned yet
    img[name] = 5
    img["A0"] = True
    vals = img.vals
    img.fill(0)
    assert img.vals is vals and vals == [0, 0]
    img.update({"A0": 1}, Z9=2)
    assert img.vals is vals and img.copy() == {"Q17": 0, "A0": 1, "Z9": 2}
    key = next(iter(img))
    assert key is sys.intern("Q17")
    assert repr(img) == "Image({'Q17': 0, 'A0': 1, 'Z9': 2})"
    assert img != {"Q17": 0, "A0": 1} and img != Image({"Q17": 0, "A0": 1, "Z9": 3})
    assert img.__eq__(3) is NotImplemented
    with pytest.raises(TypeError):
        hash(img)


def test_the_views_iterate_the_tables_themselves() -> None:
    """items()/values() iterate zip/list iterators (C, no method call per point), keys()
    is the index's own view."""
    img = Image({"a": 1, "b": 2})
    assert type(iter(img.items())) is zip
    assert type(iter(img.values())) is type(iter([]))
    assert type(img.keys()) is type({}.keys())
    items = img.items()
    img["c"] = 3  # views are live, like a dict's
    assert list(items) == [("a", 1), ("b", 2), ("c", 3)]
    d: dict[str, Any] = {"z": 0}
    d.update(img.items())
    assert d == {"z": 0, "a": 1, "b": 2, "c": 3}


def test_a_drivers_images_are_images_with_positions_in_declaration_order() -> None:
    d = SimDriver("sim")
    for p, direction in (("I3", Direction.IN), ("Q1", Direction.OUT), ("I0", Direction.IN),
                         ("Q0", Direction.OUT), ("I3", Direction.IN)):
        d.add_point(p, direction)
    assert isinstance(d.inputs, Image) and isinstance(d.outputs, Image)
    assert d.inputs.index == {"I3": 0, "I0": 1} and d.outputs.index == {"Q1": 0, "Q0": 1}
    d.open()
    d.outputs.vals[1] = 1  # what the plant's cycle does
    d.write()
    assert d.written == {"Q1": 0, "Q0": 1}
    d.inputs["I0"] = 1
    d.read()
    assert d.inputs.vals == [0, 1]
    outs = d.outputs.vals
    d.safe_state()
    assert d.outputs.vals is outs and outs == [0, 0] and d.written == {"Q1": 0, "Q0": 0}


def test_an_image_is_freed_by_reference_counting() -> None:
    """No reference cycle (its views hold its tables, not the image): a dropped driver's
    image goes at once, never left to the cyclic collector (see Plant.dispose)."""
    import gc
    import weakref

    class Box(dict[str, int]):  # a value that can be weakly referenced
        pass

    img = Image({"a": 1})
    img["b"] = 2
    box = Box()
    img["c"] = box
    list(img.items()), list(img.values())  # noqa: B018 - the views used
    ref = weakref.ref(box)
    gc.disable()
    try:
        del img, box
        assert ref() is None
    finally:
        gc.enable()


def test_update_takes_what_dict_update_takes() -> None:
    """A dict, an Image, another mapping (anything with keys()), pairs, keywords."""
    from types import MappingProxyType
    img, d = Image({"a": 0}), {"a": 0}
    for arg, kw in (({"b": 1}, {}), (Image({"a": 2, "c": 3}), {}),
                    (MappingProxyType({"d": 4}), {}), (zip("ef", (5, 6), strict=True), {}),
                    ([("a", 7)], {"g": 8})):
        if isinstance(arg, zip):
            pairs = list(arg)
            img.update(iter(pairs), **kw)
            d.update(iter(pairs), **kw)
        else:
            img.update(arg, **kw)
            d.update(arg, **kw)
        assert img.copy() == d and list(img) == list(d)


def test_a_copy_of_an_image_is_its_own() -> None:
    """``copy.copy`` of an image copied its slots, so the copy shared the driver's tables:
    a write into the copy changed the driver's image (a review found it)."""
    img = Image({"Q0": 0, "Q1": 1})
    for dup in (copy.copy(img), copy.deepcopy(img)):
        assert isinstance(dup, Image) and dup == img
        dup["Q0"] = 5
        dup["Q9"] = 1
        assert img.copy() == {"Q0": 0, "Q1": 1}


def test_bits_hold_bools_whatever_stores_them() -> None:
    img = Image({"a": 0, "b": 1, "n": 0})
    img.declare_bits([0, 1])
    assert img.vals == [False, True, 0] and [type(v) for v in img.vals] == [bool, bool, int]
    img["a"] = 1
    img.update({"b": 0, "n": 5})
    assert [(type(v), v) for v in img.vals] == [(bool, True), (bool, False), (int, 5)]
    img.fill(1)
    assert [(type(v), v) for v in img.vals] == [(bool, True), (bool, True), (int, 1)]
    img.fill(0)
    assert [(type(v), v) for v in img.vals] == [(bool, False), (bool, False), (int, 0)]
    for twin in (copy.copy(img), copy.deepcopy(img)):
        assert twin.bits == img.bits and twin.vals is not img.vals
    img.declare_bits([2])  # in place of the bits before
    img["a"] = 3
    img["n"] = 3
    assert img.vals == [3, False, True] and img.bits == {2}
    img["new"] = 1  # a point added later is no bit
    assert img["new"] == 1 and type(img["new"]) is int
