"""The project's errors, and the diagnostics of users' files (``FILE:LINE:COL``, 1-based).

Every error that softplc raises on purpose derives from :class:`SoftplcError`, so a caller
can catch "anything softplc refused" in one place. Errors about a place in a user's file are
:class:`SourceError` and render as ``FILE:LINE:COL: error: message``. A loader given a list
of :class:`Diagnostic` records the rule errors it can go on after instead of raising them
(``softplc check`` reports them all from one load).
"""

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


@dataclass(frozen=True, slots=True)
class Diagnostic:
    """One finding of a loader in a user's file.

    ``code`` is the rule it breaks, as ``softplc check`` prints it (``G101`` no initial
    step, ``G105`` continuous action tied to an activation or an event, ``G106`` edge in the
    condition of a conditional action, ``G301`` unbound signal, ``G302`` physical output
    bound twice: docs/check.md), or ``""`` for an error that is no rule of seed 000 (a
    syntax error, an unknown name ...).
    """

    code: str
    loc: Loc
    message: str

    def __str__(self) -> str:
        return f"{self.loc}: error: {self.message}"


class SoftplcError(Exception):
    """Base of the errors softplc raises on purpose.

    For example: a chart with a syntax error (:class:`SourceError`), a scan that faults
    under simulation, a console command refused, an install that cannot proceed. Drivers do
    not import runtime: their ``ConfigError``/``DriverError`` stand on their own.
    """


class SourceError(SoftplcError):
    """A fault in a user's file: where it is, what was expected and what was found.

    For example ``plant.yaml:7:13: error: unknown driver or instance 'exp2' in 'exp2.A0'``.
    ``code`` names the rule of seed 000 the fault breaks (see :class:`Diagnostic`), or is
    empty.
    """

    def __init__(self, loc: Loc, message: str, code: str = "") -> None:
        message = one_line(message)
        super().__init__(f"{loc}: error: {message}")
        self.loc = loc
        self.message = message
        self.code = code

    @property
    def diagnostic(self) -> Diagnostic:
        return Diagnostic(self.code, self.loc, self.message)


def one_line(text: str) -> str:
    """``text`` with its newlines and other control characters shown escaped (``\\n``,
    ``\\x00``): a message quoting a user's text stays one line."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def suggest(name: str, candidates: Iterable[str]) -> str:
    """Return `` (did you mean 'x'?)`` for the closest candidate, or an empty string."""
    best = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    if not best:
        lowered = {c.lower(): c for c in candidates}
        if name.lower() in lowered:
            best = [lowered[name.lower()]]
    return f" (did you mean '{best[0]}'?)" if best else ""
