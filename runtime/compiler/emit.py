"""The lines of a generated scan function as they are written, and the local that holds
each chart name in it."""

from __future__ import annotations


def ident(prefix: str, name: str) -> str:
    """The local of a chart name: ``v_`` variable, ``x_`` ``t0_`` ``tk_`` a step's X and
    times, ``a_`` ``l_`` entered / left this scan, ``b_`` a block, ``s_`` a set target."""
    return f"{prefix}_{name}"


class Emitter:
    """Collects the lines of the scan function's body, indented four spaces a level."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.level = 1

    def __call__(self, line: str) -> None:
        self.lines.append("    " * self.level + line)

    def indent(self) -> None:
        self.level += 1

    def dedent(self) -> None:
        self.level -= 1
