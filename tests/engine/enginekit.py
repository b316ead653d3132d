"""Engine-test kit: small charts on a virtual clock (never sleeping)."""

from __future__ import annotations

import itertools
import textwrap
from pathlib import Path
from typing import Any

from runtime.compiler.codegen import compile_grafcet
from runtime.engine.instance import Instance
from runtime.language.grafcetfile import load_grafcet

MS = 1_000_000
S = 1_000_000_000
#: monotonic time of the controller's start: deliberately not 0
BOOT = 123_456_789_000
_serial = itertools.count()


class Chart:
    """One instance of a chart and a virtual clock: scan k at ``up`` = k·cycle by default."""

    def __init__(self, inst: Instance, cycle_ms: int = 10) -> None:
        self.inst = inst
        self.cycle = cycle_ms * MS
        self.up = 0  # time of the next scan since start (ns)
        self.k = 0  # number of scans done

    def set(self, **values: Any) -> Chart:
        for k, v in values.items():
            self.inst.set(k, v)
        return self

    def scan(self, **values: Any) -> Chart:
        """Set ``values``, run one scan at the current virtual time, then advance the clock."""
        self.set(**values)
        self.inst.scan(BOOT + self.up, self.up)
        self.up += self.cycle
        self.k += 1
        return self

    def scan_at(self, t_ms: float, **values: Any) -> Chart:
        """One scan at ``t_ms`` since start (the clock jumps there)."""
        self.up = int(t_ms * MS)
        return self.scan(**values)

    def run(self, n: int, **values: Any) -> Chart:
        for _ in range(n):
            self.scan(**values)
        return self

    def __getitem__(self, key: str) -> Any:
        return self.inst.get(key)

    @property
    def steps(self) -> list[str]:
        return self.inst.active_steps()

    @property
    def now_ms(self) -> float:
        """Time of the last scan (ms since start)."""
        return (self.up - self.cycle) / MS

    def t_ms(self, step: str) -> float:
        return self.inst.get(f"{step}.T") / MS


def build(tmp_path: Path, text: str, name: str = "inst") -> Instance:
    p = tmp_path / f"chart{next(_serial)}.yaml"
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return Instance(name, compile_grafcet(load_grafcet(str(p))))
