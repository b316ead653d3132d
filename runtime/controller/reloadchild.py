"""The reload's child process: the plant file and its charts loaded, and their code
compiled, in a process of its own, under limits, its answer handed back as data.

Why a child: the YAML parser and ``compile()`` hold the GIL for long stretches on a large
plant (measured 64 ms and 16 ms for 100 drawer testers, seconds for a chart of thousands of
steps), and the scan thread would wait that long; a child holds its own GIL. What it hands
back, on its standard output, in frames (one byte of kind, four of length, the payload):

- ``H``: a JSON header, ``{"error": null}`` or ``{"error": "the line saying why not"}``
  (a load or compile error, the limit it hit); nothing follows an error;
- ``J``: the loaded ``PlantDef`` as JSON records, in chunks (runtime/language/modeldata.py:
  only the model's own classes, never pickle), when the child loaded the files;
- ``C``: one code object per frame, the sha256 key of its source (64 hex digits) then the
  code ``marshal``-led (runtime/compiler/codebook.py), for every source the plant compiles.

An operator reads its refusal lines (``softplc reload``, the console's ``reload``): a child
that fails inside (an exception that is no load or compile error: a defect of softplc)
says so in those words, ``INTERNAL``, and the traceback goes to the child's standard error,
which the controller writes to its log; the exception's own text is never the line.

How it runs (``CHILD_COMMAND``): ``python -I`` (isolated: neither the working directory nor
``PYTHON*`` variables reach ``sys.path``; the directory of this installation's ``runtime``
package is put first, as the controller itself imports it) in the working directory ``/``,
so that a module planted in the controller's working directory (``/tmp`` when it was started
by hand there) is never imported, least of all as root. It sets its own limits first
(``resource.setrlimit``): ``CHILD_MEMORY_BYTES`` of address space and ``CHILD_TIME_S`` of
CPU, and runs ``CHILD_NICE`` lower than the controller; the controller waits
``CHILD_TIME_S`` at most. A child that fails, whatever the way, is
a refused reload with its reason: the controller never loads "here" instead.

The code objects are the one thing that is not plain data: ``marshal`` builds code objects
and runs nothing when it reads them, and the controller runs them as the child compiled
them, as it runs the modules of the installation the child imported: the child is trusted
as the controller's own code is, isolated from everything else.
"""

from __future__ import annotations

import json
import logging
import os
import resource
import signal
import subprocess
import sys
import traceback
from collections.abc import Iterator
from contextlib import nullcontext
from typing import IO

from runtime.compiler.codebook import CodeBook
from runtime.controller.realtime import leave_a_lone_processor
from runtime.engine.plant import Plant
from runtime.errors import SoftplcError
from runtime.language import modeldata, runtimedir
from runtime.language.model import PlantDef
from runtime.language.plantfile import load_plant

log = logging.getLogger(__name__)

#: the address space the child may use, bytes (``RLIMIT_AS``): a load past it fails with
#: MemoryError and the reload is refused (a plant of 100 drawer testers loads within 64 MiB,
#: a chart of 2000 steps within 256 MiB)
CHILD_MEMORY_BYTES = 1024 * 1024 * 1024
#: the CPU time the child may use (``RLIMIT_CPU``), and how long the controller waits for
#: its answer, s
CHILD_TIME_S = 60
#: how much lower the child runs than the controller (``os.nice``): on a board of two
#: cores the load is background work, the scan thread comes first
CHILD_NICE = 10
#: the largest code object the controller reads from the child, bytes: reading one (``marshal``)
#: is a single call holding the GIL, about 5 ms per MiB on the 2-core build machine; a
#: chart whose code is larger (some 10 000 steps) is refused online: restart to load it
MAX_CODE_BYTES = 8 * 1024 * 1024
#: the directory holding this installation's ``runtime`` package
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: what ``python -I -c`` runs: this installation's ``runtime`` first on the path (only
#: it: isolated mode puts neither the working directory nor PYTHONPATH there), then main
BOOT = ("import sys; sys.path.insert(0, sys.argv[1]); "
        "from runtime.controller.reloadchild import main; sys.exit(main(sys.argv[2:]))")

#: the end of the line of a child that failed inside (its traceback in the controller's log)
INTERNAL = "an internal error of softplc, its report in the controller's log"
#: the most of a child's standard error written to the controller's log, characters
STDERR_LOGGED = 20_000

#: what ``load_apart``/``compile_apart`` hand back: the plant and the code compiled for it
Loaded = tuple[PlantDef, CodeBook]


# -- the controller's side -----------------------------------------------------------------
def load_apart(path: str, version_of: str | None = None) -> Loaded | str:
    """The plant file at ``path`` and its charts loaded, and their code compiled, by the
    child; or the one line saying why not (a load error, a compile error, a limit).
    ``version_of``: the running plant's file, whose ``${RUNTIME_DIR}`` the new version's
    paths are expanded in (``runtimedir.version_of``)."""
    got = _run(["load", os.path.abspath(path),
                *([os.path.abspath(version_of)] if version_of else [])], None)
    if isinstance(got, str):
        return got
    pdef, book = got
    if pdef is None:
        return "the reload's child process answered without the plant"
    pdef.path = path  # the file as the controller names it (the child got it absolute)
    return pdef, book


def compile_apart(pdef: PlantDef) -> Loaded | str:
    """The code of ``pdef`` (``reload --back``: the previous program, already loaded)
    compiled by the child, ``pdef`` handed to it as data; or why not. The plant returned is
    ``pdef`` itself."""
    data = b"".join(_frame(b"J", chunk.encode()) for chunk in modeldata.dump(pdef))
    got = _run(["compile"], data)
    return got if isinstance(got, str) else (pdef, got[1])


def child_command(args: list[str]) -> list[str]:
    """The command line of a child doing ``args`` (``load PATH`` or ``compile``)."""
    return [sys.executable, "-I", "-c", BOOT, ROOT, str(CHILD_MEMORY_BYTES),
            str(CHILD_TIME_S), *args]


def _run(args: list[str], stdin: bytes | None) -> tuple[PlantDef | None, CodeBook] | str:
    """Run a child and read its answer: (the plant if it sent one, the code), or why not."""
    try:
        child = subprocess.run(child_command(args), input=stdin, capture_output=True,
                               cwd="/", timeout=CHILD_TIME_S, check=False,
                               stdin=None if stdin is not None else subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return (f"the new program took longer than {CHILD_TIME_S} s to load (the limit of "
                "the reload's child process)")
    except OSError as exc:
        return f"the reload's child process did not start: {exc}"
    if child.returncode != 0:
        return _failed(child.returncode, child.stderr)
    if child.stderr.strip():  # a traceback of a child that said why in its header
        _log_report(child.stderr)
    try:
        return _answer(child.stdout)
    except (ValueError, modeldata.ModelDataError) as exc:
        log.error("reload: the child process's answer cannot be read: %s", exc)
        return f"the reload's child process answered with data that cannot be read: {INTERNAL}"


def _failed(code: int, stderr: bytes) -> str:
    """The line for a child that ended with exit status ``code`` (negative: a signal); what
    it wrote on its standard error goes to the log, never into the line."""
    if code == -signal.SIGXCPU:
        return (f"the new program took more than {CHILD_TIME_S} s of CPU to load (the limit "
                "of the reload's child process)")
    last = stderr.decode(errors="replace").strip().splitlines()[-1:] or [""]
    if "MemoryError" in last[0]:
        return _memory_line(CHILD_MEMORY_BYTES)
    how = f"signal {-code}" if code < 0 else f"exit {code}"
    if not last[0]:
        return f"the reload's child process failed ({how})"
    _log_report(stderr)
    return f"the reload's child process failed ({how}): {INTERNAL}"


def _log_report(stderr: bytes) -> None:
    text = stderr.decode(errors="replace").strip()
    if len(text) > STDERR_LOGGED:
        text = "...\n" + text[-STDERR_LOGGED:]
    log.error("reload: the child process reported:\n%s", text)


def _memory_line(limit: int) -> str:
    return (f"the new program needs more than {limit // 2**20} MiB to load (the limit of the "
            "reload's child process)")


def _frames(data: bytes) -> Iterator[tuple[bytes, bytes]]:
    """(kind, payload) of each frame of ``data``; ValueError if it is cut short."""
    view, i = memoryview(data), 0
    while i < len(data):
        if i + 5 > len(data):
            raise ValueError("a frame cut short")
        size = int.from_bytes(view[i + 1:i + 5], "big")
        if i + 5 + size > len(data):
            raise ValueError("a frame cut short")
        yield bytes(view[i:i + 1]), bytes(view[i + 5:i + 5 + size])
        i += 5 + size


def _answer(data: bytes) -> tuple[PlantDef | None, CodeBook] | str:
    frames = _frames(data)
    kind, payload = next(frames, (b"", b""))
    header = json.loads(payload) if kind == b"H" else None
    if not isinstance(header, dict):
        raise ValueError("no header")
    if header.get("error") is not None:
        return str(header["error"])
    records: list[bytes] = []
    blobs: dict[str, bytes] = {}
    for kind, payload in frames:
        if kind == b"J":
            records.append(payload)
        elif kind == b"C" and len(payload) > 64:
            if len(payload) - 64 > MAX_CODE_BYTES:
                return (f"the new program's code is too large to be loaded online "
                        f"({(len(payload) - 64) / 2**20:.1f} MiB in one piece, more than "
                        f"{MAX_CODE_BYTES / 2**20:g} MiB): restart the controller to load it")
            blobs[payload[:64].decode("ascii")] = payload[64:]
        else:
            raise ValueError(f"an unknown frame {kind!r}")
    pdef = modeldata.load(records) if records else None
    if pdef is not None and not isinstance(pdef, PlantDef):
        raise ValueError(f"a {type(pdef).__name__}, not a plant")
    return pdef, CodeBook(blobs)


def _frame(kind: bytes, payload: bytes) -> bytes:
    return kind + len(payload).to_bytes(4, "big") + payload


# -- the child's side --------------------------------------------------------------------
def main(argv: list[str]) -> int:
    """The child: ``MEMORY_BYTES CPU_S load PATH [RUNNING_PLANT]`` or ``MEMORY_BYTES CPU_S
    compile`` (the plant as JSON frames on stdin). Writes its frames to stdout; 0 when it
    wrote a header."""
    memory, cpu, mode, *rest = argv
    resource.setrlimit(resource.RLIMIT_AS, (int(memory), int(memory)))
    resource.setrlimit(resource.RLIMIT_CPU, (int(cpu), int(cpu) + 1))
    os.nice(CHILD_NICE)
    leave_a_lone_processor()  # a controller kept to one (plc: realtime: cpu) keeps it
    out = sys.stdout.buffer
    try:
        frames = _safe_work(mode, rest, sys.stdin.buffer)
    except MemoryError:
        frames = [_frame(b"H", json.dumps({"error": _memory_line(int(memory))}).encode())]
    for f in frames:
        out.write(f)
    out.flush()
    return 0


def _safe_work(mode: str, rest: list[str], stdin: IO[bytes]) -> list[bytes]:
    """``_work``, and for an exception that is no load or compile error (a defect of
    softplc) a header saying so in the operator's words; its traceback to standard error,
    for the controller's log."""
    try:
        return _work(mode, rest, stdin)
    except MemoryError:
        raise
    except Exception:  # noqa: BLE001 - said in one line, reported on stderr
        traceback.print_exc()
        return [_frame(b"H", json.dumps({"error": f"the new program could not be prepared "
                                                  f"in the reload's child process: {INTERNAL}"})
                       .encode())]


def _work(mode: str, rest: list[str], stdin: IO[bytes]) -> list[bytes]:
    """The frames of the answer (a header with the error when there is one)."""
    def error(line: str) -> list[bytes]:
        return [_frame(b"H", json.dumps({"error": line}).encode())]

    if mode == "load":
        try:
            with runtimedir.version_of(rest[1]) if len(rest) > 1 else nullcontext():
                pdef = load_plant(rest[0])
        except (SoftplcError, OSError) as exc:
            return error(f"load error: {exc}")
    else:
        got = modeldata.load(p for k, p in _frames(stdin.read()) if k == b"J")
        if not isinstance(got, PlantDef):
            return error(f"the reload's child process was given a {type(got).__name__}")
        pdef = got
    book = CodeBook(record=True)
    try:
        Plant(pdef, sim=True, book=book)
    except SoftplcError as exc:
        return error(f"compile error: {exc}")
    frames = [_frame(b"H", json.dumps({"error": None}).encode())]
    if mode == "load":
        frames += [_frame(b"J", chunk.encode()) for chunk in modeldata.dump(pdef)]
    frames += [_frame(b"C", key.encode("ascii") + blob) for key, blob in book.blobs.items()]
    return frames
