"""Errors in users' files, reported as ``FILE:LINE:COL: error: message`` (1-based)."""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Loc:
    """A place in a user's file: path, 1-based line and column."""

    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


class SourceError(Exception):
    """A fault in a user's file: where it is, what was expected and what was found."""

    def __init__(self, loc: Loc, message: str) -> None:
        super().__init__(f"{loc}: error: {message}")
        self.loc = loc
        self.message = message


def suggest(name: str, candidates: Iterable[str]) -> str:
    """Return `` (did you mean 'x'?)`` for the closest candidate, or an empty string."""
    best = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    if not best:
        lowered = {c.lower(): c for c in candidates}
        if name.lower() in lowered:
            best = [lowered[name.lower()]]
    return f" (did you mean '{best[0]}'?)" if best else ""
