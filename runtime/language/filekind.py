"""What a YAML file of the project is, from its top-level keys: a grafcet (chart), a plant,
a simulation script or a scenario (``softplc test``). The one place that tells them apart
(compile, check, draw)."""

from __future__ import annotations

from typing import Any, Literal

from runtime.language.plantpaths import PATH
from runtime.language.shape import (
    Anything,
    Bool,
    Doc,
    Int,
    Key,
    ListOf,
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
#: a scenario (a script with expectations: docs/testing-charts.md; runtime/scenario/spec.py
#: reads it and declares its expectations): the loader's keys. Its editors' schema,
#: configs/schema/scenario.schema.json, is written by hand; tests/test_schemas.py holds its
#: keys to these.
SCENARIO = Section((
    Key("plant", PATH, "The plant file the scenario runs (on simulated I/O), relative to the "
                       "scenario.", required=True),
    SCRIPT["description"],
    Key("script", PATH, "A simulation script (relative to the scenario) whose set: the "
                        "scenario plays, and whose duration: or cycles: it takes unless it "
                        "gives its own."),
    SCRIPT["duration"],
    SCRIPT["cycles"],
    SCRIPT["set"],
    Key("expect", ListOf(Anything(), min_items=1), "The expectations, each checked against the "
                                                "trace.", required=True),
), "a scenario")

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
