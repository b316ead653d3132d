"""The shape of the YAML files, declared once per section, and the checks of that shape.

A section (``plc:``, ``opcua: limits:``, a step, a transition ...) is one ``Section``: its
keys in the order the loader's messages list them, each key a ``Key`` with the kind of its
value (``Text``, ``Int``, ``Number``, ``Bool``, ``Time``, ``Choice``, lists, mappings, other
sections), the value's bounds and the words editors show. The section's loader takes its
key list (``Section.check``), each value's type (``Section.value``) and bounds (``Key``'s
``low``/``high``) from it, and ``runtime/language/schemas.py`` generates the JSON Schemas
of configs/schema/ from the same declarations (``Value.schema``): a key cannot reach the
loader and miss the editors' schema. What a loader checks beyond the shape (a name the
chart declares, a path the system takes) stays in the loader, in its own words.

The checks every loader makes of a mapping's keys (``check_keys``) and of a value's shape
(``expect_type``, ``time_value``, ``description_text``) are here too, each with the words
of its refusal at the value's ``FILE:LINE:COL``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

from drivers.durations import format_ns, parse_literal, strip_time_prefix
from runtime.errors import Loc, SourceError, suggest
from runtime.language.lexer import time_space_message
from runtime.language.yamlsrc import TIME_MAX_NS, YList, YMap

#: a JSON Schema (draft 2020-12) as a dict
Schema = dict[str, Any]
#: the longest description of a variable, step or binding, characters (one line)
DESCRIPTION_MAX = 200


# --------------------------------------------------------------------- the checks of a shape


def check_keys(m: YMap, allowed: tuple[str, ...], what: str,
               misplaced: Callable[[str], str | None] | None = None) -> None:
    """Raise on the first key of ``m`` not in ``allowed``, suggesting the closest one, or
    saying where the key belongs if ``misplaced(key)`` knows (a key of another level)."""
    for k in m:
        if k not in allowed:
            where = misplaced(k) if misplaced is not None else None
            if where is not None and where.startswith(":"):
                raise SourceError(m.key_locs[k], f"unknown key '{k}' in {what}{where}")
            raise SourceError(m.key_locs[k], f"unknown key '{k}' in {what}: expected one of "
                                             f"{', '.join(allowed)}{suggest(k, allowed)}"
                                             f"{where or ''}")


def expect_type(value: Any, loc: Loc, types: type | tuple[type, ...], what: str) -> Any:
    """``value`` if it is one of ``types`` (a YAML bool is no int here); SourceError at
    ``loc`` saying ``expected WHAT, found ...`` otherwise."""
    if isinstance(value, bool) and bool not in (types if isinstance(types, tuple) else (types,)):
        raise SourceError(loc, f"expected {what}, found {str(value).lower()}")
    if not isinstance(value, types):
        found = "nothing" if value is None else f"{type(value).__name__} {value!r}"
        if isinstance(value, str):
            found = f"the text '{value}'"
            if bool in (types if isinstance(types, tuple) else (types,)):
                found += yaml11_bool_note(value)
        if isinstance(value, YMap):
            found = "a mapping"
            if types is str or (isinstance(types, tuple) and str in types):
                found += (" (YAML reads 'text: more' as a key and a value: quote the text or "
                          "use a block scalar '|')")
        elif isinstance(value, YList):
            found = "a list"
        raise SourceError(loc, f"expected {what}, found {found}")
    return value


#: what YAML 1.1 read as bools; these files are YAML 1.2, where they are text
_YAML11_BOOLS = ("yes", "no", "on", "off", "y", "n")


def yaml11_bool_note(text: str) -> str:
    """Why a yes/no/on/off the user meant as a bool is text here, or nothing."""
    if text.strip().lower() in _YAML11_BOOLS:
        return " (yes, no, on and off are text in these files: write false or true)"
    return ""


def description_text(value: Any, loc: Loc) -> str:
    """A ``description:`` (of a chart, step, variable, instance or binding): one line of
    text, at most DESCRIPTION_MAX characters; a number is taken as its text."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = str(value)
    text = str(expect_type(value, loc, str, "a text for description")).strip()
    if "\n" in text or any(ord(c) < 32 for c in text):
        raise SourceError(loc, "description: expected one line of text, found a line break "
                               "or a control character")
    if len(text) > DESCRIPTION_MAX:
        raise SourceError(loc, f"description: expected at most {DESCRIPTION_MAX} characters, "
                               f"found {len(text)}")
    return text


def free_text(value: Any, loc: Loc, what: str) -> str:
    """Free text (a chart's description, a transition's name): text, or a number taken as
    its text; a list, a mapping or a bool is refused (``expected WHAT``). None is ""."""
    if value is None:
        return ""
    return str(expect_type(value, loc, (str, int, float), what))


def time_value(value: Any, loc: Loc, what: str) -> int:
    """A time given in YAML: ``10s``, ``T#10s``, or 0; at most TIME_MAX_NS, in ns."""
    if value == 0 and not isinstance(value, bool):
        return 0
    if isinstance(value, str):
        ns = parse_literal(strip_time_prefix(value.strip()))  # exact, however long
        if ns is not None and ns > TIME_MAX_NS:
            shown = value if len(value) <= 24 else f"{value[:10]}...{value[-6:]}"
            raise SourceError(loc, f"time out of range for {what}: expected at most "
                                   f"{format_ns(TIME_MAX_NS)} (64-bit nanoseconds), found "
                                   f"'{shown}'")
        if ns is not None:
            return ns
        spaced = time_space_message(value)
        if spaced is not None:
            raise SourceError(loc, f"{spaced} for {what}")
    raise SourceError(loc, f"bad time literal '{value}' for {what}: expected e.g. 10s, 250ms, "
                           "1m30s or T#10s")


# ------------------------------------------------------------------ the kinds of a value


class Value:
    """The kind of a key's value: the JSON Schema editors check it with (``schema``), the
    Python types the loader's ``expect_type`` takes for it (``types``), its bounds."""

    #: the Python types of the value as ``load_yaml`` reads it
    TYPES: ClassVar[tuple[type, ...]] = (object,)

    @property
    def types(self) -> tuple[type, ...]:
        """What ``expect_type`` takes for the value."""
        return self.TYPES

    def schema(self) -> Schema:
        raise NotImplementedError

    def defs(self) -> Iterator[Def]:
        """The named definitions this value refers to (``$defs`` of the document)."""
        return iter(())

    @property
    def low(self) -> Any:
        """The least value (a time's in ns), None if unbounded."""
        return None

    @property
    def high(self) -> Any:
        """The greatest value (a time's in ns), None if unbounded."""
        return None


@dataclass(frozen=True)
class Text(Value):
    """Text; ``pattern`` is a JSON Schema regular expression (anchored with ^ and $)."""

    pattern: str | None = None
    min_length: int | None = None
    max_length: int | None = None
    TYPES = (str,)

    def schema(self) -> Schema:
        s: Schema = {"type": "string"}
        if self.min_length is not None:
            s["minLength"] = self.min_length
        if self.max_length is not None:
            s["maxLength"] = self.max_length
        if self.pattern is not None:
            s["pattern"] = self.pattern
        return s


@dataclass(frozen=True)
class _Bounded(Value):
    minimum: Any = None
    maximum: Any = None

    @property
    def low(self) -> Any:
        return self.minimum

    @property
    def high(self) -> Any:
        return self.maximum

    def _bounds(self, s: Schema) -> Schema:
        if self.minimum is not None:
            s["minimum"] = self.minimum
        if self.maximum is not None:
            s["maximum"] = self.maximum
        return s


@dataclass(frozen=True)
class Int(_Bounded):
    """A whole number (a YAML bool is none), from ``minimum`` to ``maximum``."""

    TYPES = (int,)

    def schema(self) -> Schema:
        return self._bounds({"type": "integer"})


@dataclass(frozen=True)
class Number(_Bounded):
    """A number, whole or not, from ``minimum`` to ``maximum``."""

    TYPES = (int, float)

    def schema(self) -> Schema:
        return self._bounds({"type": "number"})


@dataclass(frozen=True)
class Bool(Value):
    """true or false."""

    TYPES = (bool,)

    def schema(self) -> Schema:
        return {"type": "boolean"}


@dataclass(frozen=True)
class Anything(Value):
    """Any value: its shape is the concern of the loader that reads it (a scenario's
    expectations, runtime/scenario/spec.py, declare theirs)."""

    def schema(self) -> Schema:
        return {}


@dataclass(frozen=True)
class Null(Value):
    """An empty value (``key:`` with nothing after it)."""

    TYPES = (type(None),)

    def schema(self) -> Schema:
        return {"type": "null"}


@dataclass(frozen=True)
class Choice(Value):
    """One of ``choices``."""

    choices: tuple[Any, ...]

    @property
    def types(self) -> tuple[type, ...]:
        return tuple(dict.fromkeys(type(c) for c in self.choices))

    def schema(self) -> Schema:
        return {"enum": list(self.choices)}


@dataclass(frozen=True)
class Const(Value):
    """Exactly ``value``."""

    value: Any

    def schema(self) -> Schema:
        return {"const": self.value}


@dataclass(frozen=True)
class ListOf(Value):
    """A list of ``item``s."""

    item: Value
    min_items: int | None = None
    max_items: int | None = None
    unique: bool = False
    TYPES = (list,)

    def schema(self) -> Schema:
        s: Schema = {"type": "array", "items": self.item.schema()}
        if self.min_items is not None:
            s["minItems"] = self.min_items
        if self.max_items is not None:
            s["maxItems"] = self.max_items
        if self.unique:
            s["uniqueItems"] = True
        return s

    def defs(self) -> Iterator[Def]:
        return self.item.defs()


@dataclass(frozen=True)
class MapOf(Value):
    """A mapping of names (any, or matching ``names``) to ``value``s."""

    value: Value
    min_properties: int | None = None
    max_properties: int | None = None
    #: a JSON Schema regular expression every name matches
    names: str | None = None
    TYPES = (YMap,)

    def schema(self) -> Schema:
        s: Schema = {"type": "object"}
        if self.min_properties is not None:
            s["minProperties"] = self.min_properties
        if self.max_properties is not None:
            s["maxProperties"] = self.max_properties
        if self.names is not None:
            s["propertyNames"] = {"pattern": self.names}
        s["additionalProperties"] = self.value.schema()
        return s

    def defs(self) -> Iterator[Def]:
        return self.value.defs()


@dataclass(frozen=True)
class OneOf(Value):
    """Exactly one of ``options`` (editors' ``oneOf``); the loader tells them apart."""

    options: tuple[Value, ...]
    #: ``anyOf`` rather than ``oneOf``: the options may overlap
    overlap: bool = False

    @property
    def types(self) -> tuple[type, ...]:
        return tuple(dict.fromkeys(t for o in self.options for t in o.types))

    def schema(self) -> Schema:
        return {"anyOf" if self.overlap else "oneOf": [o.schema() for o in self.options]}

    def defs(self) -> Iterator[Def]:
        for o in self.options:
            yield from o.defs()


def any_of(*options: Value) -> OneOf:
    """One or more of ``options`` (editors' ``anyOf``)."""
    return OneOf(options, overlap=True)


def one_of(*options: Value) -> OneOf:
    """Exactly one of ``options`` (editors' ``oneOf``)."""
    return OneOf(options)


@dataclass(frozen=True)
class Doc(Value):
    """``value`` with the words editors show for it (an option of a ``OneOf``)."""

    value: Value
    doc: str

    @property
    def types(self) -> tuple[type, ...]:
        return self.value.types

    def schema(self) -> Schema:
        return {**self.value.schema(), "description": self.doc}

    def defs(self) -> Iterator[Def]:
        return self.value.defs()


@dataclass(frozen=True, eq=False)
class Def(Value):
    """A value with a name, written once under the schema's ``$defs`` and referred to
    (``$ref``) wherever it is used: ``path``, ``time``, a step."""

    name: str
    value: Value
    doc: str = ""
    #: the value when absent, as editors show it (None: none shown)
    default: Any = None

    @property
    def types(self) -> tuple[type, ...]:
        return self.value.types

    @property
    def low(self) -> Any:
        return self.value.low

    @property
    def high(self) -> Any:
        return self.value.high

    def schema(self) -> Schema:
        return {"$ref": f"#/$defs/{self.name}"}

    def definition(self) -> Schema:
        """What ``$defs`` holds under the name."""
        s = {"description": self.doc, **self.value.schema()} if self.doc else (
            self.value.schema())
        if self.default is not None:
            s["default"] = self.default
        return s

    def defs(self) -> Iterator[Def]:
        yield self
        yield from self.value.defs()


@dataclass(frozen=True, eq=False)
class Ref(Value):
    """A definition referred to by name, for a shape that holds itself (a macro-step's
    steps): the document lists the definition among its ``extra`` ones."""

    name: str

    def schema(self) -> Schema:
        return {"$ref": f"#/$defs/{self.name}"}


@dataclass(frozen=True)
class Time(Value):
    """A time literal (``10s``, ``T#250ms``, or 0), from ``minimum_ns`` to ``maximum_ns``
    (the loader's bounds: a schema's pattern cannot hold them)."""

    minimum_ns: int | None = None
    maximum_ns: int | None = None
    TYPES = (str, int)

    @property
    def low(self) -> int | None:
        return self.minimum_ns

    @property
    def high(self) -> int | None:
        return self.maximum_ns

    def schema(self) -> Schema:
        return TIME.schema()

    def defs(self) -> Iterator[Def]:
        return TIME.defs()


#: a time as the loader's ``time_value`` reads it: a number and units in decreasing order,
#: each at most once, the IEC prefix optional (drivers/durations.py holds the grammar)
TIME_PATTERN = (r"^\s*(?:[Tt]#|[Tt][Ii][Mm][Ee]#)?(?=[0-9])"
                + "".join(rf"(?:[0-9][0-9_]*(?:\.[0-9][0-9_]*)?{unit})?"
                          for unit in ("d", "h", "m(?!s)", "s", "ms", "us", "ns"))
                + r"\s*$")
TIME = Def("time", any_of(Text(TIME_PATTERN), Const(0)),
           "A time: a number and units in decreasing order, each at most once, among d h m s "
           "ms us ns (10s, 250ms, 1m30s, 1d23h30m20s700ms, 1.5s), optionally with the IEC "
           "prefix T# or TIME# (T#10s); or 0. Write it as a plain YAML string: 10s, not 10.")
#: a one-line description (``description_text``)
DESCRIPTION = Text(max_length=DESCRIPTION_MAX)


# -------------------------------------------------------------------- keys and sections


@dataclass(frozen=True)
class Key:
    """One key of a section: its name, the kind of its value, the words editors show."""

    name: str
    value: Value
    doc: str = ""
    required: bool = False
    #: the value when the key is absent, as editors show it (None: none shown)
    default: Any = None

    @property
    def low(self) -> Any:
        """The least value the key takes (a time's in ns), None if unbounded."""
        return self.value.low

    @property
    def high(self) -> Any:
        """The greatest value the key takes (a time's in ns), None if unbounded."""
        return self.value.high

    def schema(self) -> Schema:
        s = self.value.schema()
        if self.default is not None:
            s["default"] = self.default
        if self.doc:
            s["description"] = self.doc
        return s


@dataclass(frozen=True, eq=False)
class Section(Value):
    """A mapping of known keys: a section of a file, or the mapping form of a value.

    ``what`` names it in the loader's messages (``unknown key 'x' in WHAT``); ``null``: an
    empty value stands for the empty mapping; ``other``: what the keys not declared hold
    (None: there are none); ``extra``: further JSON Schema of the mapping, for editors
    only (``dependentSchemas``, ``minProperties``)."""

    keys: tuple[Key, ...]
    what: str = ""
    doc: str = ""
    null: bool = False
    other: Value | None = None
    extra: Schema = field(default_factory=dict)
    TYPES = (YMap,)

    def __post_init__(self) -> None:
        names = [k.name for k in self.keys]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.what}: a key declared twice in {names}")

    @property
    def names(self) -> tuple[str, ...]:
        """The keys, in the order messages list them."""
        return tuple(k.name for k in self.keys)

    def __getitem__(self, name: str) -> Key:
        for k in self.keys:
            if k.name == name:
                return k
        raise KeyError(name)

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def without(self, *names: str, doc: str) -> Section:
        """This section less the keys ``names`` (a step outside a macro-step's expansion
        has no ``entry`` or ``exit``), with the words ``doc``."""
        for name in names:
            self[name]  # noqa: B018 - a KeyError for a key this section does not declare
        return replace(self, keys=tuple(k for k in self.keys if k.name not in names), doc=doc)

    def check(self, m: YMap, what: str | None = None,
              misplaced: Callable[[str], str | None] | None = None) -> None:
        """Raise at the first key of ``m`` this section does not declare (``check_keys``);
        ``what``: the section's name in the message, when it is not always the same."""
        check_keys(m, self.names, self.what if what is None else what, misplaced)

    def value(self, m: YMap, key: str, what: str) -> Any:
        """``m[key]`` if of the declared kind's type, else SourceError at it saying
        ``expected WHAT`` (``expect_type``); the bounds are the loader's to check, in its
        words, from ``self[key].low`` and ``.high``."""
        return expect_type(m[key], m.val_locs[key], self[key].value.types, what)

    def schema(self) -> Schema:
        s: Schema = {"type": ["object", "null"] if self.null else "object"}
        if self.doc:
            s["description"] = self.doc
        required = [k.name for k in self.keys if k.required]
        if required:
            s["required"] = required
        s["additionalProperties"] = False if self.other is None else self.other.schema()
        s["properties"] = {k.name: k.schema() for k in self.keys}
        s.update(self.extra)
        return s

    def defs(self) -> Iterator[Def]:
        for k in self.keys:
            yield from k.value.defs()
        if self.other is not None:
            yield from self.other.defs()
