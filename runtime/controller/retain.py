"""Retained memory on disk: atomic, checksummed, typed, generation-numbered, wear-conscious.

A save writes ``PATH.tmp`` completely (every short write continued, every error raised),
fsyncs it, and only then moves the current ``PATH`` to ``PATH.prev``, renames the new file
to ``PATH`` and fsyncs the directory. A save that fails leaves ``PATH`` and ``PATH.prev``
as they were. Whatever moment the power goes, one of the three files holds a complete
generation: loading takes the newest one whose checksum and contents are right and reports
every file it had to pass over, so a torn or corrupt file costs at most one generation.

Nothing is trusted on load: a file must be a regular file (never a symbolic link, a FIFO or
a device: opened with ``O_NOFOLLOW | O_NONBLOCK``), at most ``MAX_FILE_BYTES`` long, plain
JSON (no NaN/Infinity, bounded nesting) of the documented shape, each value of the type the
file records for it. ``reconcile`` then compares the file with the running plant (chart
and type of each retained variable) and says what cannot be reused.

``RetainWriter`` does the saving in its own thread: the scan hands it a snapshot (a small
dict) and never waits for the disk.
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import math
import os
import stat
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from runtime.errors import SoftplcError
from runtime.language.model import PlantDef
from runtime.language.safefile import UnfitFile, read_bounded

log = logging.getLogger(__name__)

FORMAT = "softplc-retain/3"
#: the format before the owner (the plant) was recorded; still loaded, taken over
FORMAT_2 = "softplc-retain/2"
#: the format before types were recorded; still loaded (see ``reconcile``)
FORMAT_1 = "softplc-retain/1"
#: a retain file longer than this is refused unread, bytes
MAX_FILE_BYTES = 4 * 1024 * 1024
#: the greatest generation number, loaded and saved alike: a save after it writes it
#: again (the count stops there; among files of one generation the newest, ``PATH``, is
#: loaded). Only a crafted or foreign file gets there: 292 million years of a save a ms
GENERATION_MAX = 2 ** 63 - 1
#: how a real that is not finite is written (plain JSON has no Infinity or NaN)
NON_FINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}
TYPES = ("bool", "int", "real", "time", "string")


class RetainFileError(SoftplcError):
    """A retain file that is not what softplc writes: torn by a power cut ("not JSON"), a
    flipped bit ("checksum mismatch"), crafted ("m.sN: "abc" is not of type int"), a
    symbolic link or a FIFO. The file is passed over, never the controller stopped."""


class RetainForeign(SoftplcError):
    """The retain file holds another plant's data (``restore`` with an owner): two clones
    of a project whose demo plants name the same file, two installed plants given the same
    ``plc: retain``. Neither restored nor overwritten: the controller does not start."""


class RetainLost(SoftplcError):
    """Retained data that should be there is not (``restore(refuse_if_lost=True)``): both
    generations torn, or every file gone while ``PATH.saved`` records a save."""


@dataclass(frozen=True)
class RetainedVars:
    """What the running plant retains: each instance's chart name and the type name
    (``bool int real time string``) of each of its retained variables."""

    charts: dict[str, str]
    types: dict[str, dict[str, str]]

    @classmethod
    def of(cls, pdef: PlantDef) -> RetainedVars:
        types = {name: {v.name: v.type.value for v in inst.grafcet.variables.values()
                        if v.retain}
                 for name, inst in pdef.instances.items()}
        types = {name: t for name, t in types.items() if t}
        return cls({name: pdef.instances[name].grafcet.name for name in types}, types)


@dataclass
class Loaded:
    """What ``RetainStore.load()`` found: the data of the newest good generation (empty
    if none), its generation number, and one line per file passed over."""

    data: dict[str, Any] = field(default_factory=dict)
    generation: int = 0
    saved_at: float | None = None  # wall-clock time of that save (time.time())
    source: str | None = None  # the file it came from
    problems: list[str] = field(default_factory=list)
    #: chart name and type names recorded with the data; None in a format 1 file
    charts: dict[str, str] | None = None
    types: dict[str, dict[str, str]] | None = None
    raw: bytes = b""  # the source file as read (kept aside when values are dropped)
    #: the plant that saved it ({"name", "path"}: the real path of its directory); None in
    #: a file of format 1 or 2
    owner: dict[str, str] | None = None
    #: (file, contents) of each regular file passed over (kept aside when data is lost)
    bad: list[tuple[str, bytes]] = field(default_factory=list)
    #: why the retained data is lost (files there but none good: ``problems`` say why
    #: each, or files gone while a previous run saved some); None when restored or at a
    #: first start
    lost: str | None = None


@dataclass
class Reconciled:
    """What ``reconcile`` keeps of a loaded file for the running plant."""

    values: dict[str, dict[str, Any]] = field(default_factory=dict)
    dropped: list[str] = field(default_factory=list)  # one line per value not reused
    missing: list[str] = field(default_factory=list)  # retained now, not in the file


def _digest(payload: dict[str, Any]) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(text.encode()).hexdigest()


def _no_constant(name: str) -> Any:
    raise RetainFileError(f"{name} is not a number")


def _type_of(value: Any) -> str:
    """The type name of a value when the caller gave no ``RetainedVars`` (tests, tools)."""
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "real"
    return "string"


def _encode(typ: str, value: Any, where: str) -> Any:
    """``value`` of a variable of type ``typ`` as the file holds it; ValueError if it is
    not one (the save fails: a bug, said in the log and ``status``)."""
    if typ == "bool" and isinstance(value, (bool, int)) and value in (0, 1):
        return bool(value)
    if typ in ("int", "time") and isinstance(value, int):
        return int(value)
    if typ == "real" and isinstance(value, (int, float)):
        value = float(value)
        if not math.isfinite(value):
            return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        return value
    if typ == "string" and isinstance(value, str):
        return value
    raise ValueError(f"{where}: {value!r} is not of type {typ}: not saved")


def _decode(typ: str, value: Any, where: str) -> Any:
    """``value`` as written for a variable of type ``typ``; RetainFileError if it is not
    one (text where a number is expected, a number out of range...)."""
    ok = False
    if typ == "bool":
        ok = isinstance(value, bool)
    elif typ in ("int", "time"):  # ints have no fixed width (language.md)
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif typ == "real":
        if isinstance(value, str) and value in NON_FINITE:
            return NON_FINITE[value]
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and \
            math.isfinite(value)
    elif typ == "string":
        ok = isinstance(value, str)
    if not ok:
        raise RetainFileError(f"{where}: {_short(value)} is not of type {typ}")
    return float(value) if typ == "real" else value


def _short(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=True)
    return text if len(text) <= 40 else text[:37] + "..."


def _mapping(value: Any, what: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise RetainFileError(f"{what} is not a mapping")
    return value


def parse(raw: bytes) -> tuple[dict[str, Any], dict[str, dict[str, str]] | None,
                               dict[str, str] | None, int, float, dict[str, str] | None]:
    """Check a retain file's text: (data, types, charts, generation, saved_at, owner).

    ``types``/``charts`` are None in a format 1 file, ``owner`` in a format 1 or 2 file.
    Raises RetainFileError."""
    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=_no_constant)
    except RecursionError:
        raise RetainFileError("nested too deeply") from None
    except UnicodeDecodeError as exc:
        raise RetainFileError(f"not UTF-8 text ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise RetainFileError(f"not JSON: {exc.msg} at line {exc.lineno}") from None
    except ValueError as exc:  # an integer of thousands of digits
        raise RetainFileError(str(exc).splitlines()[0]) from None
    doc = _mapping(doc, "the file")
    fmt = doc.get("format")
    if fmt not in (FORMAT, FORMAT_2, FORMAT_1):
        raise RetainFileError("not a softplc retain file")
    keys = ("format", "generation", "saved_at", "data") + \
        (("charts", "types") if fmt != FORMAT_1 else ()) + (("plant",) if fmt == FORMAT else ())
    missing = [k for k in keys if k not in doc]
    if missing:
        raise RetainFileError(f"no {', '.join(missing)}")
    payload = {k: doc[k] for k in keys}
    if doc.get("sha256") != _digest(payload):
        raise RetainFileError("checksum mismatch")
    gen, saved_at = payload["generation"], payload["saved_at"]
    if not isinstance(gen, int) or isinstance(gen, bool) or not 0 < gen <= GENERATION_MAX:
        raise RetainFileError(f"generation {_short(gen)} is not a positive integer")
    if not isinstance(saved_at, (int, float)) or isinstance(saved_at, bool) \
            or not math.isfinite(saved_at):
        raise RetainFileError(f"saved_at {_short(saved_at)} is not a time")
    data = _mapping(payload["data"], "data")
    types = charts = owner = None
    if fmt == FORMAT:
        owner = _mapping(payload["plant"], "plant")
        if not all(isinstance(owner.get(k), str) for k in ("name", "path")):
            raise RetainFileError("plant: expected its name and path")
    if fmt != FORMAT_1:
        types = _mapping(payload["types"], "types")
        charts = _mapping(payload["charts"], "charts")
    out: dict[str, dict[str, Any]] = {}
    for inst, values in data.items():
        values = _mapping(values, f"the data of {inst}")
        kinds = None if types is None else _mapping(types.get(inst), f"the types of {inst}")
        if charts is not None and not isinstance(charts.get(inst), str):
            raise RetainFileError(f"no chart name for {inst}")
        out[inst] = {}
        for name, value in values.items():
            where = f"{inst}.{name}"
            if kinds is None:  # format 1: any plain scalar; checked against the plant later
                if isinstance(value, float) and not math.isfinite(value) or \
                        not isinstance(value, (bool, int, float, str)):
                    raise RetainFileError(f"{where}: {_short(value)} is not a value")
                out[inst][name] = value
                continue
            typ = kinds.get(name)
            if typ not in TYPES:
                raise RetainFileError(f"{where}: unknown type {_short(typ)}")
            out[inst][name] = _decode(typ, value, where)
    return out, types, charts, gen, float(saved_at), owner


def _fits(typ: str, value: Any) -> bool:
    """A format 1 value (no recorded type) usable for a variable of type ``typ``."""
    try:
        _decode(typ, value, "")
    except RetainFileError:
        return typ == "real" and isinstance(value, int) and not isinstance(value, bool)
    return True


def reconcile(loaded: Loaded, plant: RetainedVars) -> Reconciled:
    """What of ``loaded`` the running plant may reuse, and what not and why.

    A value is reused only for the same instance running a chart of the same name and a
    retained variable of the same name and type. A format 1 file records no types: a value
    is reused if its JSON kind fits the variable (true/false for a bool, an integer for an
    int or a time, a number for a real, text for a string): a time retyped to an int (or
    back) cannot be told apart there."""
    out = Reconciled()
    for inst, values in loaded.data.items():
        want = plant.types.get(inst)
        names = ", ".join(sorted(values))
        if want is None:
            out.dropped.append(f"instance {inst} retains nothing now: {names} not reused")
            continue
        was = None if loaded.charts is None else loaded.charts.get(inst)
        if was and was != plant.charts[inst]:  # "" when the saver did not know it
            out.dropped.append(f"{inst} now runs chart {plant.charts[inst]}, was {was}: "
                               f"{names} not reused")
            continue
        kinds = None if loaded.types is None else loaded.types.get(inst, {})
        kept = {}
        for name, value in values.items():
            typ = want.get(name)
            if typ is None:
                out.dropped.append(f"{inst}.{name}: no retained variable of that name now "
                                   f"(renamed, removed or no longer retained)")
            elif kinds is not None and kinds.get(name) != typ:
                out.dropped.append(f"{inst}.{name}: was {kinds.get(name)}, now {typ}: "
                                   f"init value")
            elif kinds is None and not _fits(typ, value):
                out.dropped.append(f"{inst}.{name}: {_short(value)} does not fit {typ}: "
                                   f"init value")
            else:
                kept[name] = value
        if kept:
            out.values[inst] = kept
    for inst, want in plant.types.items():
        have = out.values.get(inst, {})
        out.missing += [f"{inst}.{name}" for name in want if name not in have]
    return out


@dataclass
class Restored:
    """What a start restores: the values the plant may reuse, and why it starts without
    its retained data if it does (None when restored, or at a first start)."""

    values: dict[str, dict[str, Any]]
    lost: str | None = None


def restore(store: RetainStore, *, refuse_if_lost: bool = False) -> Restored:
    """Load ``store`` for its plant and say in the log what was passed over, not reused or
    lost; where anything is dropped the file as it was is kept (``keep_orphan``).

    Lost data is one ERROR line (and the bad files kept), or RetainLost if
    ``refuse_if_lost`` (then nothing is logged or written: the caller says it)."""
    loaded = store.load()
    if loaded.lost is not None:  # its one line carries the problems
        if refuse_if_lost:
            raise RetainLost(loaded.lost)
        log.error("retained data LOST (%s): starting with init values", loaded.lost)
        for bad, raw in loaded.bad:
            orphan = store.keep_orphan(raw)
            if orphan is not None:
                log.warning("retain: %s as it was is kept as %s", bad, orphan)
        return Restored({}, loaded.lost)
    _check_owner(store, loaded)
    for problem in loaded.problems:
        log.warning("retain: %s", problem)
    if loaded.source is None:
        log.info("no retained data in %s yet (first start): init values", store.path)
        return Restored({})
    kept = reconcile(loaded, store.plant or RetainedVars({}, {}))
    for line in kept.dropped:
        log.warning("retain: %s", line)
    if kept.dropped:
        orphan = store.keep_orphan(loaded.raw)
        if orphan is not None:
            log.warning("retain: %s as it was is kept as %s", loaded.source, orphan)
        if kept.missing:
            log.info("retain: init value for %s", ", ".join(kept.missing))
    log.info("retained data restored from %s (generation %d)", loaded.source,
             loaded.generation)
    return Restored(kept.values)


def _check_owner(store: RetainStore, loaded: Loaded) -> None:
    """RetainForeign if ``loaded`` was saved by another plant whose directory is still
    there; a plant that is gone (moved) is taken over, with a warning."""
    mine, was = store.owner, loaded.owner
    if mine is None or not was or not was.get("path") or was["path"] == mine["path"]:
        return
    if os.path.lexists(was["path"]):
        raise RetainForeign(f"{store.path} holds the retained data of plant {was['name']} "
                            f"({was['path']}), not of this plant ({mine['path']}): not "
                            "started; give this plant a plc: retain file of its own")
    log.warning("retain: %s was saved by plant %s (%s), which is no longer there: taken "
                "over by this plant (%s)", store.path, was["name"], was["path"], mine["path"])


class RetainStore:
    """The retain file at ``path``, its previous generation at ``path.prev`` and the
    record ``path.saved`` that data was saved here once (to tell lost data from a first
    start)."""

    def __init__(self, path: str, plant: RetainedVars | None = None,
                 owner: dict[str, str] | None = None) -> None:
        self.path = path
        #: the plant whose data this is ({"name", "path"}), recorded with every save and
        #: checked by ``restore``; None for tools (recorded empty)
        self.owner = owner
        self.prev = path + ".prev"
        self.tmp = path + ".tmp"
        self.marker = path + ".saved"
        self.plant = plant
        self.generation = 0
        self._path_bad = False  # PATH is not a good generation: never rotate it to .prev
        self._marked = False  # PATH.saved checked (and written if missing) in this run
        self._marker_failed = False  # ... and its failure said once

    # -- loading -------------------------------------------------------------------
    def load(self) -> Loaded:
        """The newest valid generation among the three files; never raises for bad files."""
        best = Loaded()
        present: list[str] = []
        for candidate in (self.path, self.prev, self.tmp):
            raw = None
            try:
                raw = self._read(candidate)
                if raw is None:
                    continue
                if candidate != self.tmp:
                    present.append(candidate)
                data, types, charts, gen, saved_at, owner = parse(raw)
            except (OSError, RetainFileError) as exc:
                if candidate != self.tmp:  # a torn .tmp is the normal trace of a power cut
                    present.append(candidate)
                    best.problems.append(f"{candidate}: {_reason(exc)}; passed over")
                    if raw is not None:
                        best.bad.append((candidate, raw))
                if candidate == self.path:
                    self._path_bad = True
                continue
            if gen > best.generation:  # among equals the first: PATH (GENERATION_MAX)
                best.data, best.generation, best.saved_at = data, gen, saved_at
                best.source, best.types, best.charts, best.raw = candidate, types, charts, raw
                best.owner = owner
        if best.source is not None and best.source != self.path:
            best.problems.append(f"restored generation {best.generation} from {best.source}")
        if best.source is None:
            if present:
                why = "; ".join(p.removesuffix("; passed over") for p in best.problems)
                best.lost = f"no good generation: {why}"
            elif os.path.lexists(self.marker):
                best.lost = (f"{self.path} and {self.prev} are gone, but {self.marker} "
                             f"records that retained data was saved here")
        self.generation = max(self.generation, best.generation)
        return best

    @staticmethod
    def _read(path: str) -> bytes | None:
        """The bytes of ``path``, None if it does not exist; OSError/RetainFileError if it
        is not a regular file of at most MAX_FILE_BYTES (``safefile.read_bounded``: never
        a symbolic link followed, never blocking)."""
        try:
            return read_bounded(path, MAX_FILE_BYTES)
        except FileNotFoundError:
            return None
        except UnfitFile as exc:
            raise RetainFileError(unfit_reason(exc, MAX_FILE_BYTES)) from None

    def keep_orphan(self, raw: bytes) -> str | None:
        """Keep ``raw`` (a file's contents before the next save replaces it) as
        ``PATH.orphan`` (``.orphan.2``... if that exists: never overwritten). Returns the
        name, None if it could not be written (logged)."""
        n = 1
        while True:
            name = self.path + ".orphan" + (f".{n}" if n > 1 else "")
            try:
                write_new(name, raw, exclusive=True)
                return name
            except FileExistsError:
                n += 1
            except OSError as exc:
                log.error("retain: the old file could not be kept as %s: %s", name, exc)
                return None

    # -- saving --------------------------------------------------------------------
    def save(self, data: dict[str, Any]) -> int:
        """Write ``data`` as the next generation, atomically (at GENERATION_MAX: that one
        again). Returns its number.
        Raises OSError (disk full, I/O error, read-only file system): nothing that was on
        disk before has changed then, and the next save tries again."""
        types = {inst: {name: self._type(inst, name, v) for name, v in values.items()}
                 for inst, values in data.items()}
        charts = {inst: (self.plant.charts.get(inst, "") if self.plant else "")
                  for inst in data}
        gen = min(self.generation + 1, GENERATION_MAX)  # never one that load would refuse
        payload = {"format": FORMAT, "generation": gen, "saved_at": time.time(),
                   "plant": self.owner or {"name": "", "path": ""},
                   "charts": charts, "types": types,
                   "data": {inst: {name: _encode(types[inst][name], v, f"{inst}.{name}")
                                   for name, v in values.items()}
                            for inst, values in data.items()}}
        doc = {**payload, "sha256": _digest(payload)}
        text = json.dumps(doc, ensure_ascii=False, indent=1, allow_nan=False).encode()
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            st = None
        if st is not None and stat.S_ISDIR(st.st_mode):  # never moved away
            raise IsADirectoryError(errno.EISDIR, f"{self.path} is a directory")
        write_new(self.tmp, text, exclusive=False)
        # only now, the new generation complete and on disk, the old ones move; a PATH
        # that is no good generation (torn, a link...) is replaced, not kept as .prev
        if st is not None and stat.S_ISREG(st.st_mode) and not self._path_bad:
            os.replace(self.path, self.prev)
        os.replace(self.tmp, self.path)
        self._path_bad = False
        self.generation = gen  # in place: the next one is gen + 1 even if fsync fails
        self._fsync_dir()
        if not self._marked:  # once per run; retried at each save until written
            try:
                if not os.path.lexists(self.marker):
                    write_new(self.marker, json.dumps(
                        {"first_saved": time.time()}).encode(), exclusive=True)
                self._marked = True
            except OSError as exc:
                if not self._marker_failed:
                    log.warning("retain: %s not written: %s", self.marker, exc)
                self._marker_failed = True
        return gen

    def _type(self, inst: str, name: str, value: Any) -> str:
        if self.plant is not None:
            typ = self.plant.types.get(inst, {}).get(name)
            if typ is not None:
                return typ
        return _type_of(value)

    def _fsync_dir(self) -> None:
        dfd = os.open(os.path.dirname(os.path.abspath(self.path)), os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def write_new(name: str, content: bytes, *, exclusive: bool, sync: bool = True) -> None:
    """Write ``name`` completely (and fsync it if ``sync``), never through a symbolic link:
    a file or link already there is removed first, unless ``exclusive`` (then
    FileExistsError). On any error the partial file is removed and the error raised."""
    if not exclusive:
        try:
            os.unlink(name)  # a leftover (or planted) file or link: never written into
        except FileNotFoundError:
            pass
    fd = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                 0o640)
    try:
        view = memoryview(content)
        while view:
            n = os.write(fd, view)
            if n <= 0:  # no progress: the disk takes nothing more
                raise OSError(errno.ENOSPC, f"{name}: write made no progress")
            view = view[n:]
        if sync:
            os.fsync(fd)
    except BaseException:
        os.close(fd)
        try:
            os.unlink(name)
        except OSError:
            pass
        raise
    os.close(fd)


def unfit_reason(exc: UnfitFile, limit: int) -> str:
    """Why a file beside the retain file was passed over, as the log says it."""
    if exc.found == "a symbolic link":
        return "a symbolic link, never followed"
    if exc.found.startswith("a file of"):
        return f"larger than {limit} bytes ({exc.found})"
    return f"not a regular file ({exc.found})"


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc)


class RetainWriter:
    """A thread that saves the latest submitted snapshot; older unsaved ones are dropped.

    When saving starts failing it logs one ERROR line, when it works again one WARNING
    line; ``failing_since``/``last_error`` say so meanwhile (``status``)."""

    def __init__(self, store: RetainStore) -> None:
        self.store = store
        self._cond = threading.Condition()
        self._pending: dict[str, Any] | None = None
        self._busy = False
        self._stop = False
        self.saves = 0
        self.last_error: str | None = None
        self.failing_since: float | None = None  # wall-clock time of the first failure
        self.last_saved_at: float | None = None
        self._thread = threading.Thread(target=self._run, name="softplc-retain", daemon=True)
        self._thread.start()

    def submit(self, data: dict[str, Any]) -> None:
        """Called by the scan thread: never blocks on the disk."""
        with self._cond:
            self._pending = data
            self._cond.notify()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything submitted is on disk (shutdown). False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._pending is None and not self._busy,
                                       timeout)

    def close(self, timeout: float = 5.0) -> None:
        self.flush(timeout)
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._stop)
                if self._pending is None:
                    return
                data, self._pending = self._pending, None
                self._busy = True
            try:
                self.store.save(data)
                self.saves += 1
                self.last_saved_at = time.time()
                if self.last_error is not None:
                    log.warning("retain file %s written again (generation %d)",
                                self.store.path, self.store.generation)
                self.last_error = self.failing_since = None
            except (OSError, ValueError) as exc:
                if self.last_error is None:
                    log.error("retain file %s not written: %s; the previous generations are "
                              "kept, retried at each interval", self.store.path, exc)
                    self.failing_since = time.time()
                else:
                    log.debug("retain file %s still not written: %s", self.store.path, exc)
                self.last_error = str(exc)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
