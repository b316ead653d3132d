"""Shared fixtures: small charts and plants written to a temporary directory."""

from __future__ import annotations

import os
import textwrap
from collections.abc import Callable
from pathlib import Path

import pytest

# the disk cache of compiled code (runtime/compiler/codecache.py) is off for the suite and
# the processes it starts: nothing written in the home of whoever runs the tests;
# tests/engine/test_code_cache.py turns it on in a temporary directory
os.environ["SOFTPLC_CODE_CACHE"] = "off"

DRAWER = """\
grafcet: DrawerTester
inputs: [iParo, iMarcha, iAbierto, iCerrado]
outputs: [oAbrir, oCerrar, oParado, oTest]
memory:
  sParo: false
  sCierres: {init: 0, retain: true}
pre:
  - sParo.Set(1, iParo)
  - tAveriaAbrir := gsAbrir.T >= 10s
  - tAveriaCerrar := gsCerrar.T >= 10s
  - tParo := iCerrado·sParo + (sCierres >= 1000)
steps:
  gsParado: {initial: true, actions: ["P1 sParo := 0"]}
  gsAbrir:  {actions: [oAbrir, oTest]}
  gsCerrar: {actions: [oCerrar, oTest, "P1 sCierres := sCierres + 1"]}
  gsAveria: {}
transitions:
  - {from: gsParado, to: gsAbrir, when: "↑iMarcha·iParo'"}
  - {from: gsAbrir, to: gsCerrar, when: iAbierto}
  - {from: gsAbrir, to: gsAveria, when: tAveriaAbrir}
  - {from: gsCerrar, to: gsParado, when: tParo}
  - {from: gsCerrar, to: gsAbrir, when: iCerrado}
  - {from: gsCerrar, to: gsAveria, when: tAveriaCerrar}
  - {from: gsAveria, to: gsParado, when: "↑iMarcha·iParo'"}
post:
  - oParado := gsParado.X + sParo·Clock_1Hz
"""


@pytest.fixture
def write(tmp_path: Path) -> Callable[[str, str], str]:
    """write(name, text) -> path of a file in tmp_path (text is dedented)."""

    def _write(name: str, text: str) -> str:
        p = tmp_path / name
        p.write_text(textwrap.dedent(text), encoding="utf-8")
        return str(p)

    return _write


@pytest.fixture
def drawer(write: Callable[[str, str], str]) -> str:
    return write("drawer.yaml", DRAWER)


#: a chart with a BOOL and an INT input (a point read as a bool or as a number)
LEVEL = """\
grafcet: Level
inputs: [iOn, iLevel: int]
outputs: [oHigh]
steps:
  s0: {initial: true}
  s1: {actions: [oHigh]}
transitions:
  - {from: s0, to: s1, when: "iOn·(iLevel > 3)"}
  - {from: s1, to: s0, when: "iLevel <= 3"}
"""


@pytest.fixture
def level(write: Callable[[str, str], str]) -> str:
    return write("level.yaml", LEVEL)
