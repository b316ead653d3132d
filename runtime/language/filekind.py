"""What a YAML file of the project is, from its top-level keys: a grafcet (chart), a plant,
a simulation script or a scenario (``softplc test``). The one place that tells them apart
(compile, check, draw)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal

from runtime.language.plantpaths import PATH
from runtime.language.shape import (
    Bool,
    Doc,
    Int,
    Key,
    ListOf,
    MapOf,
    Number,
    Section,
    Text,
    Time,
    any_of,
)
from runtime.language.yamlsrc import YMap, load_yaml

#: an entry of a simulation script's ``set:`` (runtime/engine/script.py reads it)
SET_ENTRY = Section((
    Key("at", Time(), "When the values are written.", required=True),
), other=Doc(any_of(Number(), Bool()),
             "instance.input = logical value (after inversion; instance.SFCPause and the "
             "other chart flags too), or driver.point = physical value (before inversion)."),
   extra={"minProperties": 2, "propertyNames": {"pattern": r"^(at|[^.\s]+\.[^\s]+)$"}})
#: a simulation script (runtime/engine/script.py reads it)
SCRIPT = Section((
    Key("duration", Time(), "Simulated time: scans at t = 0, cycle, 2·cycle, ... while t < "
                            "duration."),
    Key("cycles", Int(0), "Number of scans (instead of duration; --cycles overrides both). "
                          "With neither, 'softplc simulate' needs --cycles N."),
    Key("set", ListOf(SET_ENTRY), "Input changes: {at: TIME, key: value, ...}."),
    Key("description", Text(), "Free text."),
), "a simulation script",
    "Input changes for 'softplc simulate PLANT --script SCRIPT' (docs/language.md, 'The "
    "simulation script'). Scan k runs at t = k·cycle; a change at time t is seen by the "
    "first scan at t or later. The length is --cycles N if given, else 'cycles:', else "
    "'duration:': a script meant for --cycles may have neither (it then needs 'set:').",
    extra={"anyOf": [{"required": ["duration"]}, {"required": ["cycles"]},
                     {"required": ["set"]}]})
#: the keys that make a YAML file a simulation script (with no other keys than SCRIPT's)
_SCRIPT_MARKS = ("duration", "cycles", "set")
#: a name of the trace an expectation reads (instance.variable, driver.point)
TRACE_NAME = r"^[^.\s]+\.[^\s]+$"
_NAMES = MapOf(Doc(any_of(Bool(), Number(), Text()),
                   "instance.variable, instance.STEP.X, instance.STEP.T (a time), "
                   "instance.BLOCK.OUTPUT or driver.point, with the value the trace must hold: "
                   "0/1 (or true/false) for a bool, a number, a time (250ms) for a time, a "
                   "step's name for SFCCurrentStep; or a comparison in quotes: '>= 300ms', "
                   "'!= 0', '< 4' (== and != for bools and texts)."),
               min_properties=1, names=TRACE_NAME)
#: the keys of an expectation, each declared once (runtime/scenario/spec.py reads them)
_EXPECT_KEY = {k.name: k for k in (
    Key("at", Time(), "Check expect: in the first scan at or after this time (with within:, "
                      "in some scan up to within later)."),
    Key("cycle", Int(0), "Check expect: in this scan (cycle 0 is the first)."),
    Key("within", Time(), "With at: the expectation holds in some scan from at to at + "
                          "within."),
    Key("from", Time(), "The window's start (default 0): scans with from <= t < to."),
    Key("to", Time(), "The window's end, not included (default: the end of the run)."),
    Key("expect", _NAMES, "Names and the values they hold, all in the same scan."),
    Key("never", _NAMES, "In no scan of the window do all these names hold these values "
                         "together."),
    Key("always", _NAMES, "In every scan of the window all these names hold these values."),
    Key("on_rise", Text(TRACE_NAME), "A bool name: expect: holds in every scan of the window "
                                     "where it rises (0 in the scan before, 1 in this one); it "
                                     "must rise at least once."),
    Key("on_fall", Text(TRACE_NAME), "A bool name: expect: holds in every scan of the window "
                                     "where it falls; it must fall at least once."),
    Key("rises", MapOf(Doc(any_of(Int(0), Text()), "The number of rising edges (0 to 1 from "
                                                   "one scan to the next), or a comparison: "
                                                   "'>= 3', '< 10'."),
                       min_properties=1, names=TRACE_NAME),
        "Bool names and how many times each rises in the window: a count, or a comparison "
        "in quotes ('>= 3')."),
    Key("name", Text(), "The expectation's name in the report and the JUnit XML (default: "
                        "what it checks and when)."),
)}


def _kind(keys: tuple[str, ...], what: str) -> Section:
    return Section(tuple(_EXPECT_KEY[k] for k in keys), what)


#: the kinds of expectation: the key that names what is expected, and the section of the
#: keys each allows
SHAPES: dict[str, Section] = {
    "at": _kind(("at", "cycle", "within", "expect", "name"),
                "an expectation at a time or a cycle"),
    **{kind: _kind((kind, "from", "to", "expect", "name"), f"an expectation with '{kind}:'")
       for kind in ("on_rise", "on_fall")},
    **{kind: _kind((kind, "from", "to", "name"), f"an expectation with '{kind}:'")
       for kind in ("never", "always", "rises")},
}
#: every key an expectation may have
EXPECT_KEYS = tuple(dict.fromkeys(k for shape in SHAPES.values() for k in shape.names))
#: for editors, each form of an expectation: the keys it needs, and those it may have (an
#: ``at`` or a ``cycle``, the kinds of SHAPES that need ``expect``: the loader's rules)
_FORMS = (
    (("at", "expect"), set(SHAPES["at"].names) - {"cycle"}),
    (("cycle", "expect"), set(SHAPES["at"].names) - {"at", "within"}),
    *(((kind, "expect"), set(SHAPES[kind].names)) for kind in ("on_rise", "on_fall")),
    *(((kind,), set(SHAPES[kind].names)) for kind in ("never", "always", "rises")),
)
#: an expectation, as editors check it (the loader reads it by SHAPES)
EXPECTATION = Section(tuple(_EXPECT_KEY.values()), "an expectation", extra={"oneOf": [
    {"required": list(needs), "not": {"anyOf": [{"required": [k]} for k in EXPECT_KEYS
                                                 if k not in may]}}
    for needs, may in _FORMS]})
#: a scenario (a script with expectations: docs/testing-charts.md; runtime/scenario/spec.py
#: reads it): the loader's keys, and the editors' schema configs/schema/scenario.schema.json
#: (runtime/language/schemas.py)
SCENARIO = Section((
    Key("plant", PATH, "The plant file the scenario runs (on simulated I/O), relative to the "
                       "scenario.", required=True),
    SCRIPT["description"],
    Key("script", PATH, "A simulation script (relative to the scenario) whose set: the "
                        "scenario plays, and whose duration: or cycles: it takes unless it "
                        "gives its own."),
    SCRIPT["duration"],
    replace(SCRIPT["cycles"], doc="Number of scans (instead of duration)."),
    SCRIPT["set"],
    Key("expect", ListOf(EXPECTATION, min_items=1),
        "The expectations, each checked against the trace: {at: TIME, expect: {...}}, "
        "{cycle: N, expect: {...}}, {at: TIME, within: TIME, expect: {...}}, {from: T1, to: "
        "T2, never: {...}}, {from: T1, to: T2, always: {...}}, {on_rise: NAME, expect: "
        "{...}}, {on_fall: NAME, expect: {...}}, {from: T1, to: T2, rises: {NAME: COUNT}}.",
        required=True),
), "a scenario",
    "A scenario for 'softplc test' (docs/testing-charts.md): a simulation script's inputs "
    "(set:, or the script: it names) with expectations (expect:) checked against the trace "
    "of the run on the virtual clock. Named NAME.test.yaml beside the plant, it is found by "
    "'softplc test DIR'. Scan k runs at t = k·cycle; a time names the first scan at or after "
    "it.",
    extra={"anyOf": [{"required": ["duration"]}, {"required": ["cycles"]},
                     {"required": ["script"]}]})

FileKind = Literal["grafcet", "plant", "script", "scenario", "other"]


def file_kind(path: str) -> FileKind:
    """'grafcet', 'plant', 'script' (a simulation script), 'scenario' or 'other', from the
    top-level keys (SourceError if the file is not YAML)."""
    return doc_kind(load_yaml(path))


def read_document(path: str) -> tuple[FileKind, Any]:
    """The file's kind and its document, read once: pass the document on to
    ``load_grafcet(path, doc=...)`` or ``load_plant(path, doc=...)``."""
    doc = load_yaml(path)
    return doc_kind(doc), doc


def doc_kind(doc: Any) -> FileKind:
    """The kind of an already loaded document (``load_yaml``'s result), as ``file_kind``."""
    if isinstance(doc, YMap):
        if "grafcet" in doc or "steps" in doc:
            return "grafcet"
        if "instances" in doc or "drivers" in doc or "plc" in doc:
            return "plant"
        if "expect" in doc and set(doc) <= set(SCENARIO.names):
            return "scenario"
        if set(doc) <= set(SCRIPT.names) and set(doc) & set(_SCRIPT_MARKS):
            return "script"
    return "other"
