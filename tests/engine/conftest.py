"""Fixtures of the engine tests (the kit itself is enginekit.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.engine.enginekit import Chart, build


@pytest.fixture
def chart(tmp_path: Path):  # type: ignore[no-untyped-def]
    """chart(yaml_text, cycle_ms=10) -> Chart, not yet scanned."""

    def make(text: str, cycle_ms: int = 10) -> Chart:
        return Chart(build(tmp_path, text), cycle_ms)

    return make
