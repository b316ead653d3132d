"""Code objects compiled elsewhere and handed over, by the source they were compiled from.

``compile()`` of a large generated source is one C call that holds the GIL: 16 ms for the
plant cycle of 100 drawer testers. An online change builds the new plant while the scan
runs, so the reload compiles the sources in a child process, which records each code
object (``CodeBook(record=True)``) and hands the book back marshalled; the controller's
process then unmarshals them (0.3 ms for the same cycle) instead of compiling. A source
the book does not hold, or holds for another text, is compiled here as always: the book
changes how long a load takes, never what it loads.
"""

from __future__ import annotations

import hashlib
import marshal
from collections.abc import Collection
from types import CodeType

from runtime.compiler.guard import check_code, checked_code


def _key(source: str, filename: str) -> str:
    return hashlib.sha256(f"{filename}\0{source}".encode()).hexdigest()


class CodeBook:
    """Code objects by (source, filename): ``compile`` looks a source up, compiles it when
    it is not there and, recording, keeps what it compiled in ``blobs``.

    A source compiled here passes :func:`runtime.compiler.guard.checked_code`; a code
    object found in the book is checked here too (:func:`runtime.compiler.guard.check_code`:
    the code that runs is checked in the process that runs it, whoever compiled it)."""

    def __init__(self, blobs: dict[str, bytes] | None = None, *, record: bool = False) -> None:
        #: sha256 of filename and source -> ``marshal.dumps`` of the code object
        self.blobs: dict[str, bytes] = dict(blobs or {})
        self.record = record
        #: how many sources were found in the book, and how many were compiled
        self.hits = 0
        self.misses = 0

    def compile(self, source: str, filename: str, names: Collection[str]) -> CodeType:
        """``source`` checked and compiled (``names``: the globals it is given), or the code
        object the book holds."""
        key = _key(source, filename)
        blob = self.blobs.get(key)
        if blob is not None:
            code = marshal.loads(blob)  # noqa: S302 - the book of our own child process
            if isinstance(code, CodeType):
                check_code(code, filename, names)
                self.hits += 1
                return code
        self.misses += 1
        code = checked_code(source, filename, names)
        if self.record:
            self.blobs[key] = marshal.dumps(code)
        return code


def compile_code(source: str, filename: str, names: Collection[str],
                 book: CodeBook | None = None) -> CodeType:
    """Check and compile ``source`` (a module's text; ``names``: the globals it is given),
    through ``book`` when one is given."""
    if book is None:
        return checked_code(source, filename, names)
    return book.compile(source, filename, names)
