"""The process image of one direction of one driver: values by position, points by name.

An :class:`Image` is a mapping ``point -> value`` (what a console, a trace or a test reads
and writes by name) kept as two tables: ``vals``, a plain list of the values by position,
and ``index``, point -> position. A position never changes for the image's life: a new
point is appended, and a point is never deleted (``del`` raises TypeError). So the plant's
generated cycle resolves each binding's position once, when it is built, and reads or
writes ``vals[3]`` every cycle (list indexing, no hashing: about 0.5 ns a read and 3 ns a
store against 5 and 16 ns for a dict).

The list is named ``vals``, not ``values``: ``values()`` stays the mapping's method, as for
a dict.

Every per-cycle path runs in C: ``items()`` iterates ``zip(index, vals)``, ``values()``
``iter(vals)``, ``keys()`` is the index's own keys view, ``copy()`` builds a dict with
``dict(zip(index, vals))`` and ``fill(value)`` sets every value at once. ``copy.copy`` and
``copy.deepcopy`` give a new Image; an image is not a dict for ``json.dumps`` (dump its
``copy()``). Point names are
interned on insertion, so a lookup by a name the plant holds matches by identity.

The plant declares the *bits* of an input image (:meth:`Image.declare_bits`): the BOOL points
that only BOOL variables read. Their values are bools, always: a value stored by name
(``img[p] = v``, ``update``, ``fill``) is made one there, and a back-end that assigns
``vals[i]`` stores True or False at a BOOL point. So the plant's binding of a bit reads it
as the variable's value (``IL[3]``, or ``not IL[3]`` where it inverts), with no
conversion per scan.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import ItemsView as _ItemsView
from collections.abc import Iterable, Iterator, KeysView, Mapping, MutableMapping, ValuesView
from typing import Any


class Image(MutableMapping[str, Any]):
    """Process image of one direction of one driver; a dict that keeps positions.

    ``vals[i]`` is the value of the point at position ``i``; ``index[p]`` the position of
    point ``p``. Both are the live tables: a back-end's hot ``_read`` may assign
    ``image.vals[i]`` directly, with positions taken from ``index`` at ``open()``. Never
    rebind ``vals`` or ``index`` (the plant's cycle holds the very list): change values
    in place (``vals[i] = v``, :meth:`fill`)."""

    __slots__ = ("vals", "index", "bits", "_items", "_values")

    def __init__(self, data: Mapping[str, Any] | Iterable[tuple[str, Any]] = ()) -> None:
        #: values by position; never rebound
        self.vals: list[Any] = []
        #: point -> position; append-only
        self.index: dict[str, int] = {}
        #: the positions whose values are bools (see :meth:`declare_bits`)
        self.bits: frozenset[int] = frozenset()
        # the views, made once (live, on the tables, not on the image: no reference
        # cycle, an image is freed by reference counting): items() makes no object
        self._items = _Items(self.index, self.vals)
        self._values = _Values(self.index, self.vals)
        if data:
            self.update(data)

    # -- the mapping -------------------------------------------------------------------
    def __getitem__(self, point: str) -> Any:
        return self.vals[self.index[point]]

    def __setitem__(self, point: str, value: Any) -> None:
        i = self.index.get(point)
        if i is None:  # a new point: appended, its name interned
            point = sys.intern(point)
            self.index[point] = len(self.vals)
            self.vals.append(value)
        else:
            self.vals[i] = bool(value) if i in self.bits else value

    def __delitem__(self, point: str) -> None:
        raise TypeError(f"cannot delete point {point!r} from a process image: the plant's "
                        "cycle holds the positions of its points (set it to 0 instead)")

    def __iter__(self) -> Iterator[str]:
        return iter(self.index)

    def __len__(self) -> int:
        return len(self.vals)

    def __contains__(self, point: object) -> bool:
        return point in self.index

    def get(self, point: str, default: Any = None) -> Any:
        i = self.index.get(point)
        return default if i is None else self.vals[i]

    def keys(self) -> KeysView[str]:
        return self.index.keys()

    def items(self) -> _ItemsView[str, Any]:
        return self._items

    def values(self) -> ValuesView[Any]:
        return self._values

    def update(self, other: Any = (), /, **kw: Any) -> None:
        """As dict.update; points already in the image are stored without a method call
        each."""
        # as dict.update: a thing with keys() is a mapping (no ABC check: a first
        # isinstance(zip, Mapping) costs about 0.1 ms)
        pairs: Iterable[tuple[str, Any]]
        if isinstance(other, (dict, Image)):
            pairs = other.items()
        elif hasattr(other, "keys"):
            pairs = ((k, other[k]) for k in other.keys())
        else:
            pairs = other
        index, vals, bits = self.index, self.vals, self.bits
        for p, v in pairs:
            i = index.get(p)
            if i is None:
                self[p] = v
            else:
                vals[i] = bool(v) if i in bits else v
        for p, v in kw.items():
            self[p] = v

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Image):
            return self.copy() == other.copy()
        if isinstance(other, dict):
            return self.copy() == other
        if isinstance(other, Mapping):
            return self.copy() == dict(other.items())
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # mutable, like a dict

    def __repr__(self) -> str:
        return f"Image({self.copy()!r})"

    # -- fast whole-image operations -------------------------------------------------------
    def copy(self) -> dict[str, Any]:
        """A plain dict of the image (point -> value), in position order."""
        return dict(zip(self.index, self.vals, strict=True))

    def __copy__(self) -> Image:
        """A new image with the same points and values (``copy.copy``): never the same
        tables (a copy that wrote into the driver's image would be a hidden output)."""
        new = Image(zip(self.index, self.vals, strict=True))
        new.bits = self.bits
        return new

    def __deepcopy__(self, memo: dict[int, Any]) -> Image:
        new = Image(zip(self.index, copy.deepcopy(self.vals, memo), strict=True))
        new.bits = self.bits
        return new

    def fill(self, value: Any) -> None:
        """Every point's value set to ``value``, as a bool at a bit (the list kept: same
        object)."""
        vals = self.vals
        vals[:] = [value] * len(vals)
        if self.bits:
            as_bit = bool(value)
            for i in self.bits:
                vals[i] = as_bit

    def declare_bits(self, positions: Iterable[int]) -> None:
        """Make the points at ``positions`` its bits, in place of any declared before:
        their values are made bools now and at every store by name. A bit no longer one
        holds 0 or 1 again (a number it held before it was a bit is not known)."""
        vals, was = self.vals, self.bits
        self.bits = frozenset(positions)
        for i in self.bits:
            vals[i] = bool(vals[i])
        for i in was - self.bits:
            if vals[i].__class__ is bool:
                vals[i] = int(vals[i])


class _Items(_ItemsView[str, Any]):
    """``Image.items()``: iterates ``zip(index, vals)`` in C. It holds the image's tables
    (its base's mapping is the index: same points, same length), never the image."""

    __slots__ = ("_index", "_vals")

    def __init__(self, index: dict[str, int], vals: list[Any]) -> None:
        super().__init__(index)
        self._index, self._vals = index, vals

    def __iter__(self) -> Iterator[tuple[str, Any]]:
        return zip(self._index, self._vals, strict=True)

    def __contains__(self, item: object) -> bool:
        if not isinstance(item, tuple) or len(item) != 2:
            return False
        i = self._index.get(item[0])
        if i is None:
            return False
        v = self._vals[i]
        return v is item[1] or bool(v == item[1])

    def __repr__(self) -> str:
        return f"image_items({list(self)!r})"


class _Values(ValuesView[Any]):
    """``Image.values()``: iterates the ``vals`` list itself."""

    __slots__ = ("_index", "_vals")

    def __init__(self, index: dict[str, int], vals: list[Any]) -> None:
        super().__init__(index)
        self._index, self._vals = index, vals

    def __iter__(self) -> Iterator[Any]:
        return iter(self._vals)

    def __contains__(self, value: object) -> bool:
        return value in self._vals

    def __repr__(self) -> str:
        return f"image_values({self._vals!r})"
