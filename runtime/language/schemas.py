"""The JSON Schemas of configs/schema/ that editors read (completion and checks while
typing), generated from the declaration of each section (``runtime/language/shape.py``):
the grafcet file from ``grafcetfile.GRAFCET``, the plant file from ``plantfile.PLANT``
(its drivers from ``drivers/registry.py`` through ``drivershape.DRIVER``), the simulation
script from ``filekind.SCRIPT``, the scenario from ``filekind.SCENARIO`` (its expectations
``filekind.EXPECTATION``).

``scripts/make-schemas.sh`` writes them (``python -m runtime.language.schemas DIR``);
``tests/test_schemas.py`` fails when a committed file differs from what this generates.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from pathlib import Path

from runtime.language.filekind import SCENARIO, SCRIPT
from runtime.language.grafcetfile import GRAFCET, INNER_STEP
from runtime.language.plantfile import PLANT
from runtime.language.shape import Def, Schema, Section

#: the file kinds, each with its top-level section, the titles editors show, and the
#: definitions only referred to by name (a macro-step's inner steps)
KINDS: dict[str, tuple[Section, str, tuple[Def, ...]]] = {
    "grafcet": (GRAFCET, "softplc grafcet file", (INNER_STEP,)),
    "plant": (PLANT, "softplc plant file", ()),
    "script": (SCRIPT, "softplc simulation script", ()),
    "scenario": (SCENARIO, "softplc scenario", ()),
}


def _definitions(top: Section, extra: Iterable[Def]) -> dict[str, Schema]:
    """Every definition the document refers to, by name, in the order first met; one name
    given two different shapes is a defect of the declarations."""
    found: dict[str, Schema] = {}
    pending = [*top.defs(), *(d2 for d in extra for d2 in d.defs())]
    for d in pending:
        shape = d.definition()
        if d.name in found and found[d.name] != shape:
            raise ValueError(f"two shapes named '{d.name}' in the declarations")
        found[d.name] = shape
    return found


def document(kind: str) -> Schema:
    """The JSON Schema (draft 2020-12) of the files of ``kind`` (grafcet, plant, script,
    scenario)."""
    top, title, extra = KINDS[kind]
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "$id": f"urn:softplc:schema:{kind}:v1", "title": title, **top.schema(),
            "$defs": _definitions(top, extra)}


def render(kind: str) -> str:
    """``document(kind)`` as the text of its file, ``KIND.schema.json``."""
    return json.dumps(document(kind), indent=2, ensure_ascii=False) + "\n"


def write(directory: Path) -> list[Path]:
    """Write every kind's schema into ``directory``; the paths written."""
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for kind in KINDS:
        path = directory / f"{kind}.schema.json"
        path.write_text(render(kind), encoding="utf-8")
        written.append(path)
    return written


def main(argv: list[str]) -> int:
    """``python -m runtime.language.schemas DIR``: write the schemas into DIR."""
    if len(argv) != 1:
        sys.stderr.write("usage: python -m runtime.language.schemas DIR\n")
        return 2
    write(Path(argv[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
