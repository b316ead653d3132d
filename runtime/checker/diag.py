"""A diagnostic of ``softplc check``: ``FILE:LINE:COL: error|warning|note GCODE: message``."""

from __future__ import annotations

import os
from dataclasses import dataclass

from runtime.errors import Diagnostic, Loc


@dataclass(frozen=True, order=True)
class Diag:
    file: str
    line: int
    col: int
    severity: str  # error | warning | note
    code: str
    message: str

    def __str__(self) -> str:
        return f"{show_path(self.file)}:{self.line}:{self.col}: {self.severity} {self.code}: " \
               f"{self.message}"


def show_path(path: str) -> str:
    if os.path.isabs(path):
        rel = os.path.relpath(path)
        if not rel.startswith(".."):
            return rel
    return path


def diag(loc: Loc, severity: str, code: str, message: str) -> Diag:
    return Diag(loc.file, loc.line, loc.col, severity, code, message)


def from_loader(d: Diagnostic) -> Diag:
    """A loader's diagnostic (a rule error of seed 000) as ``softplc check`` prints it."""
    return diag(d.loc, "error", d.code, d.message)
