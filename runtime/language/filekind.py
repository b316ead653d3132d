"""What a YAML file of the project is, from its top-level keys: a grafcet (chart), a plant,
a simulation script or a scenario (``softplc test``). The one place that tells them apart
(compile, check, draw)."""

from __future__ import annotations

from typing import Any, Literal

from runtime.language.yamlsrc import YMap, load_yaml

#: the top-level keys of a simulation script
SCRIPT_KEYS = ("duration", "cycles", "set", "description")
#: the top-level keys of a scenario (a script with expectations: docs/testing-charts.md)
SCENARIO_KEYS = ("plant", "description", "script", "duration", "cycles", "set", "expect")

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
        if "expect" in doc and set(doc) <= set(SCENARIO_KEYS):
            return "scenario"
        if set(doc) <= set(SCRIPT_KEYS) and set(doc) & {"duration", "cycles", "set"}:
            return "script"
    return "other"
