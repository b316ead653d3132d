"""docs/semantics.md's table "Every rule and its tests" names tests that exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_test_named_in_the_rule_table_exists() -> None:
    text = (ROOT / "docs" / "semantics.md").read_text(encoding="utf-8")
    table = text.split("## Every rule and its tests", 1)[1]
    refs = re.findall(r"`(\w+)::(test_\w+)`", table)
    assert len(refs) > 100
    missing = []
    for module, name in refs:
        path = ROOT / "tests" / f"test_{module}.py"
        if not path.exists():
            path = ROOT / "tests" / "engine" / f"test_engine_{module}.py"
        if not path.exists():
            path = ROOT / "tests" / "engine" / f"test_{module}.py"
        if not path.exists() or not re.search(rf"^def {name}\(", path.read_text(
                encoding="utf-8"), re.M):
            missing.append(f"{module}::{name}")
    assert missing == []
