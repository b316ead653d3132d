"""The keys of ``web:`` that bound what a page may do to the operator (docs/web.md):
``page_timeout`` (how long a page that answers nothing keeps what it holds) and ``hosts``
(the names besides its own the page answers to). The loader and the JSON schema agree;
a wrong value is one line at its place."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.errors import SourceError
from runtime.language.plantfile import load_plant
from tests.test_schemas import errors, read
from tests.web.kit import write_plant


def test_page_timeout_and_hosts_are_read(tmp_path: Path) -> None:
    default = load_plant(str(write_plant(tmp_path))).web
    assert default is not None
    assert default.page_timeout_ns == 30_000_000_000 and default.hosts == []
    given = load_plant(str(write_plant(tmp_path, web="  page_timeout: 3s\n  hosts: ["
                                                     "plc.bench.lan, '*.bench.lan', "
                                                     "192.168.1.20, '[fe80::1]']\n"))).web
    assert given is not None and given.page_timeout_ns == 3_000_000_000
    assert given.hosts == ["plc.bench.lan", "*.bench.lan", "192.168.1.20", "[fe80::1]"]


@pytest.mark.parametrize(("web", "where", "message"), [
    ("  page_timeout: 1s\n", "page_timeout", "web page_timeout: expected 3s to 10m"),
    ("  page_timeout: 11m\n", "page_timeout", "web page_timeout: expected 3s to 10m"),
    ("  hosts: plc\n", "hosts", "expected a list of host names"),
    ("  hosts: [plc, 'evil.example/x']\n", "evil", "web hosts: expected a host name or "
                                                   "address"),
])
def test_a_wrong_value_is_one_line_at_its_place(tmp_path: Path, web: str, where: str,
                                                message: str) -> None:
    plant = write_plant(tmp_path, web=web)
    lines = plant.read_text(encoding="utf-8").splitlines()
    line = next(k for k, text in enumerate(lines, 1) if where in text
                and text.startswith("  ") and not text.startswith("  users"))
    col = lines[line - 1].index(where) + 1 if where == "evil" else None  # the item
    with pytest.raises(SourceError) as exc:
        load_plant(str(plant))
    text = str(exc.value)
    assert "\n" not in text and message in text, text
    assert f"plant.yaml:{line}:" in text, text
    if col is not None:
        assert f"plant.yaml:{line}:{col}:" in text, text


def test_the_schema_takes_what_the_loader_takes() -> None:
    base = {"instances": {"t1": {"grafcet": "g.yaml"}}}
    good = read("web: {page_timeout: 30s, hosts: [plc.bench.lan, '*.bench.lan', "
                "192.168.1.20, '[::1]']}\n")
    assert not errors("plant", {**base, **good})
    for bad in ("web: {hosts: ['evil.example/x']}\n", "web: {hosts: plc}\n",
                "web: {page_timeout: soon}\n"):
        assert errors("plant", {**base, **read(bad)}), bad
