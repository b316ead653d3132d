"""The process image in shared memory: written by the controller's scan thread, read by
the processes beside it (``softplc opcua``, ``mqtt``, ``web``, ``modbus``) in theirs.

The controller (``ImageWriter``) creates one file per plant object, ``<feed path>.image``
(mode 0640: its owner writes, the plant's group reads), maps it, and every sample packs
the image into it: per instance the state slots its names need, per driver its input and
output values, every driver's ok flag. One generated function reads them all, a tuple
per region (a state's slots from the very cells its scan closure uses), and a region is
packed by its precompiled ``struct.Struct`` (``pack_into``, a C call) only when its
values differ from those it was last packed with (a C tuple compare): the file, which
this writer alone writes, still holds them. Each chart clock (``#ct``, advanced every
scan) is packed on its own every write, so that a waiting instance's other slots are
skipped. The layout is fixed for the plant object; an online change makes a new file (a new
generation, renamed over the old one), and the feed's schema says which
(``ImageWriter.describe``).

File layout (little-endian, no padding):

- header, 80 bytes: magic ``b"SPLCIMG1"``, version (u32), generation (u32), token (16
  random bytes, made per file: what the schema names), seqlock counter (u64 at 32),
  CRC32 (u32 at 40, then 4 bytes of padding) of every byte from 48 to the end of the
  file, scan (i64), wall time ns (i64), CLOCK_MONOTONIC ns of the write (i64), lossy
  (u64: how many writes had a value that did not fit its slot);
- per instance, its numeric slots (BOOL ``?``, INT/TIME ``q``, REAL ``d``);
- per driver, its input values then its output values (BOOL point ``?``, register ``q``);
- every driver's ok flag (``?``);
- per instance, its STRING slots, each ``STR_BYTES`` bytes (``p``: a length byte and
  UTF-8, cut to STR_BYTES - 1 bytes), packed only when one changed (a tuple compare);
- one byte per numeric region (instances, then each driver's inputs and outputs): 1 while
  a value of that region did not fit (an INT beyond 64 bits: the region is then packed
  value by value, ``_fit``): it is stored saturated, and a
  reader shows a saturated value of that region one beyond the 64-bit range (2**63, or
  -2**63 - 1), so that it stays out of range to whoever checks (OPC UA: BadOutOfRange);
  its exact value is not carried.

Seqlock with a checksum: the single writer makes the counter odd, packs, stamps, stores
the CRC32 of the stamp and data, makes the counter even; a reader copies the bytes and
keeps the copy only if the counter was even and unchanged around the copy AND the copy's
CRC32 matches its stamp and data (``ImageReader.snapshot``: bounded retries, else None:
the next sample is used). Readers never write the file. Python has no memory barrier: on
a weakly ordered CPU (ARM, the Raspberry Pi) another core may see the counter's final
store before the data's, so the counter alone could pass a copy mixing two writes; the
checksum refuses such a copy whatever the order the stores become visible in
(docs/architecture.md: why and what it costs).

A reader (``ImageReader``) is built from the schema's ``image`` (plain data: offsets,
formats, slots, validated) and the names' specs (``Signal.spec``, runtime/engine/names.py:
plain data too, never code), and computes every name's value in its own process.
"""

from __future__ import annotations

import logging
import mmap
import os
import re
import struct
import time
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from functools import partial
from itertools import repeat
from types import CellType, CodeType, FunctionType
from typing import TYPE_CHECKING, Any, TypeVar

from runtime.compiler.guard import GeneratedCodeRefused, checked_code, restricted_builtins
from runtime.errors import SoftplcError

if TYPE_CHECKING:
    from runtime.engine.names import Catalogue

log = logging.getLogger(__name__)

MAGIC = b"SPLCIMG1"
VERSION = 2
#: magic, version, generation, token
HEAD = struct.Struct("<8sII16s")
SEQ_AT = 32
SEQ = struct.Struct("<Q")
#: CRC32 (zlib.crc32) of the bytes from STAMP_AT to the end, 4 bytes of padding
CRC_AT = 40
CRC = struct.Struct("<I4x")
STAMP_AT = 48
#: scan, wall ns, monotonic ns, lossy
STAMP = struct.Struct("<qqqQ")
DATA_AT = 80
#: bytes per STRING slot (a length byte and at most STR_BYTES - 1 bytes of UTF-8)
STR_BYTES = 64
#: copies a reader tries before it gives up on this sample (the writer kept writing)
RETRIES = 8
T = TypeVar("T")
#: numeric regions compared at once (one C compare), then one by one if they differ
BLOCK = 16
#: a chart clock's slot (packed on its own, every write)
_CLOCK = struct.Struct("<q").pack_into
#: runs an iterator to its end, keeping nothing (a loop in C)
_consume: Callable[[Iterable[Any]], None] = deque(maxlen=0).extend
INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1

_NUMERIC = re.compile(r"<[?qd]*\Z")
_STRINGS = re.compile(rf"<(?:{STR_BYTES}p)*\Z")
_CODE = {"bool": "?", "int": "q", "time": "q", "real": "d"}
#: the whole text ``_reader_of`` may generate: cells ``c<k>`` set to None, then one
#: function returning a tuple of regions, each a tuple of terms (a cell, a cell's
#: ``get()``, ``bool`` of a cell's ``ok``) or of one starred cell (a value list copied)
_TERM = r"(?:c\d+|c\d+\.get\(\)|bool\(c\d+\.ok\))"
_READER_TEXT = re.compile(
    r"def make\(\):\n(?: c\d+ = None\n)*"
    rf" def read\(\):\n  return \((?:\((?:\*c\d+, |(?:{_TERM}, )*)\), )*\)\n"
    r" return read\n\Z")


class ImageError(SoftplcError):
    """The image file cannot be used (missing, unreadable, another's, malformed): the
    message says why in one line."""


def image_path(feed_path: str) -> str:
    """Where the image of the feed at ``feed_path`` lives."""
    return feed_path + ".image"


def _fit(code: str, value: Any) -> tuple[Any, bool]:
    """``value`` made to fit a slot of struct code ``code``: (the value, whether it was
    changed: saturated to 64 bits, or not a number)."""
    if code == "?":
        return bool(value), False
    if code == "d":
        try:
            return float(value), False
        except (TypeError, ValueError, OverflowError):
            return float("nan"), True
    if isinstance(value, int):
        fitted = min(INT64_MAX, max(INT64_MIN, value))
        return fitted, fitted != value
    try:
        return min(INT64_MAX, max(INT64_MIN, int(value))), True
    except (TypeError, ValueError, OverflowError):
        return 0, True


def _layout(cat: Catalogue) -> tuple[list[tuple[list[int], str, list[int], int | None]],
                                      list[tuple[str, str]]]:
    """Per instance (numeric slots, their codes, string slots, its chart clock's slot or
    None) and per driver (input codes, output codes), from the names' specs."""
    plant = cat.plant
    need: list[dict[int, str]] = [{} for _ in plant.instances]
    clock: list[int | None] = [None for _ in plant.instances]
    for s in cat.names.values():
        spec = s.spec
        kind = spec[0] if spec else ""
        if kind == "slot":
            need[spec[1]].setdefault(spec[2], "s" if s.type.value == "string"
                                     else _CODE[s.type.value])
        elif kind == "steptime":
            _, i, x, ct, t0, tk = spec
            need[i].setdefault(x, "?")
            clock[i] = ct
            for k in (ct, t0, tk):
                need[i].setdefault(k, "q")
        elif kind == "current":
            for _step, x in spec[2]:
                need[spec[1]].setdefault(x, "?")
    insts = []
    for slots, ct in zip(need, clock, strict=True):
        nums = sorted(k for k, c in slots.items() if c != "s")
        insts.append((nums, "".join(slots[k] for k in nums),
                      sorted(k for k, c in slots.items() if c == "s"), ct))
    drivers = []
    from drivers.base import PointKind  # the point kinds: the controller's side only

    for d in plant.drivers.values():
        codes = []
        for img in (d.inputs, d.outputs):
            by_pos = sorted(img.index.items(), key=lambda kv: kv[1])
            codes.append("".join("?" if d.kinds.get(p) is PointKind.BOOL else "q"
                                 for p, _ in by_pos))
        drivers.append((codes[0], codes[1]))
    return insts, drivers


class ImageWriter:
    """The controller's side: the file of one plant object, written by the scan thread
    (``write``); ``retire`` removes it."""

    def __init__(self, cat: Catalogue, path: str, generation: int) -> None:
        """Create the file at ``path`` (a new one renamed over whatever was there: an
        image left by a crashed controller is never reused). OSError if it cannot."""
        self.path = path
        self.generation = generation
        #: the plant object it is the image of (written only while it runs)
        self.plant = cat.plant
        self.token = os.urandom(16)
        self.lossy = 0
        self._seq = 0
        insts, drivers = _layout(cat)
        plant = cat.plant
        at = DATA_AT
        #: the packed regions: (offset, pack_into, codes, flag, kept) (flag: its byte in
        #: the flags area, -1 none; kept: its last values are kept, to skip it while they
        #: stay equal); the numeric ones first, in the order the generated reader gives
        #: their values, then the chart clocks, then the instances' strings
        self._regions: list[tuple[int, Callable[..., None], str, int, bool]] = []
        #: what the reader reads, region by region: (kind, what), kind "slots" (a list
        #: of (state, slot)), "list" (a value list) or "ok" (the drivers)
        parts: list[tuple[str, Any]] = []
        #: (state, slot, offset, flag) of each instance's chart clock packed on its own
        clocks: list[tuple[Any, int, int, int]] = []
        flag = 0
        self._desc_inst: list[list[Any]] = []
        for (nums, codes, _strs, ct), inst in zip(insts, plant.instances.values(),
                                                  strict=True):
            st = struct.Struct("<" + codes)
            self._desc_inst.append([at, st.format, nums])
            if ct is not None and nums[-1] == ct:
                # the chart clock advances every scan: packed on its own, so that the
                # rest of a waiting instance's slots is skipped (the engine's layout
                # puts it after the variables and steps: the last numeric slot)
                clocks.append((inst.m, ct, at + st.size - 8, flag))
                nums, codes = nums[:-1], codes[:-1]
            if nums:
                self._regions.append((at, struct.Struct("<" + codes).pack_into, codes,
                                      flag, True))
                parts.append(("slots", [(inst.m, k) for k in nums]))
            flag += 1
            at += st.size
        self._desc_drv: list[list[Any]] = []
        for (cin, cout), d in zip(drivers, plant.drivers.values(), strict=True):
            row: list[Any] = []
            for codes, vals in ((cin, d.inputs.vals), (cout, d.outputs.vals)):
                st = struct.Struct("<" + codes)
                row += [at, st.format]
                if codes:
                    self._regions.append((at, st.pack_into, codes, flag, True))
                    parts.append(("list", vals))
                flag += 1
                at += st.size
            self._desc_drv.append(row)
        drvs = list(plant.drivers.values())
        ok = struct.Struct("<" + "?" * len(drvs))
        self._regions.append((at, ok.pack_into, "?" * len(drvs), -1, True))
        parts.append(("ok", drvs))
        self._desc_ok = [at, ok.format]
        at += ok.size
        self._numeric = range(len(self._regions))
        #: per numeric region, the positions of its REAL values: 0.0 == -0.0, packed
        #: apart, so such a region equal to its last values is packed all the same when
        #: one of them is another object
        self._reals = [tuple(i for i, c in enumerate(r[2]) if c == "d")
                       for r in self._regions]
        #: per numeric region, its pack_into bound to the mapping and its offset (set
        #: once the file is mapped)
        self._packs: list[Callable[..., None]] = []
        #: the numeric regions by blocks of BLOCK, compared at once: (first, end, whether
        #: one has a REAL: then compared region by region every write), and the values
        #: each block was last written with
        self._blocks = [(a, min(a + BLOCK, len(self._numeric)),
                         any(self._reals[a:a + BLOCK]))
                        for a in range(0, len(self._numeric), BLOCK)]
        self._kept_blocks: list[Any] = [None] * len(self._blocks)
        self._regions += [(c_at, _CLOCK, "q", c_flag, False)
                          for _m, _k, c_at, c_flag in clocks]
        #: the clocks' regions and offsets: all packed every write
        self._clocks = range(len(self._numeric), len(self._regions))
        self._clock_ats = [c_at for _m, _k, c_at, _f in clocks]
        parts.append(("slots", [(m, k) for m, k, _a, _f in clocks]))
        #: per instance with strings: its region's index and its values' slice of the
        #: strings' tuple (all read as one tuple: compared at once)
        self._texts: list[tuple[int, slice]] = []
        texts: list[tuple[Any, int]] = []
        for desc, (_nums, _codes, strs, _ct), inst in zip(self._desc_inst, insts,
                                                          plant.instances.values(),
                                                          strict=True):
            ss = struct.Struct("<" + f"{STR_BYTES}p" * len(strs))
            desc += [at, ss.format, strs]
            if strs:
                self._texts.append((len(self._regions),
                                    slice(len(texts), len(texts) + len(strs))))
                self._regions.append((at, ss.pack_into, "", -1, True))
                texts += [(inst.m, k) for k in strs]
            at += ss.size
        parts.append(("slots", texts))
        #: every region's values as one tuple of tuples, in one call: the state's slots
        #: read from the very cells its scan closure uses
        self._read = _reader_of(parts)
        #: per region, the values it was last packed with (None: pack it next write);
        #: last of all, the strings' tuple
        self._last: list[Any] = [None] * (len(self._regions) + 1)
        #: the regions holding a value that did not fit now
        self._lossy: set[int] = set()
        #: the flags set now
        self._flagged: set[int] = set()
        self._flags_at = at
        self._desc_flags = [at, flag]
        at += flag
        self.size = at
        self._mm = _create(path, self.size, HEAD.pack(MAGIC, VERSION, generation,
                                                      self.token))
        self._packs = [partial(self._regions[k][1], self._mm, self._regions[k][0])
                       for k in self._numeric]

    def describe(self) -> dict[str, Any]:
        """The schema's ``image``: what a reader needs (plain data)."""
        return {"path": self.path, "version": VERSION, "generation": self.generation,
                "token": self.token.hex(), "size": self.size,
                "instances": self._desc_inst, "drivers": self._desc_drv,
                "ok": self._desc_ok, "flags": self._desc_flags}

    def write(self, scan: int, wall_ns: int) -> None:
        """The image of ``scan`` into the file: :meth:`read` then :meth:`publish`."""
        self.publish(self._read(), scan, wall_ns)

    def read(self) -> tuple[tuple[Any, ...], ...]:
        """The values of the image now, as one tuple of immutable tuples (one generated
        function reading the very cells the scans use): what :meth:`publish` takes. The
        caller makes sure no scan runs meanwhile (the feed thread: ``Scheduler.seq``)."""
        return self._read()

    def publish(self, got: tuple[tuple[Any, ...], ...], scan: int, wall_ns: int) -> None:
        """``got`` (:meth:`read`'s), the image of ``scan``, into the file (seqlock). A
        region whose values equal those it was last packed with is not packed again:
        the file still holds them (this writer alone writes its file, from one thread at
        a time, and it starts zeroed with nothing kept)."""
        mm, seq = self._mm, self._seq + 1
        SEQ.pack_into(mm, SEQ_AT, seq)  # odd: a write under way
        last, regions, lossy = self._last, self._regions, self._lossy
        kept_blocks, all_reals, packs = self._kept_blocks, self._reals, self._packs
        for j, (a, b, real) in enumerate(self._blocks):
            block = got[a:b]
            # a C compare of BLOCK regions at once: equal items are mostly the very
            # same objects
            if block == kept_blocks[j] and not real:
                continue
            for k in range(a, b):
                vals, old, reals = got[k], last[k], all_reals[k]
                if vals != old or (reals and _moved(vals, old, reals)):
                    try:
                        packs[k](*vals)  # a partial: the mapping and offset, no copy
                    except struct.error:
                        self._fitted(k, vals)
                    else:
                        if lossy and k in lossy:
                            self._fitted(k, vals)
                    last[k] = vals
            kept_blocks[j] = block
        nclock = len(self._numeric)
        clocks = got[nclock]
        try:
            if lossy:
                raise struct.error("a clock may be flagged")
            _consume(map(_CLOCK, repeat(mm), self._clock_ats, clocks))
        except struct.error:
            for k, v in zip(self._clocks, clocks, strict=True):
                self._fitted(k, (v,))
        texts = got[-1]
        if texts != last[-1]:
            for k, part in self._texts:
                vals = texts[part]
                if vals != last[k]:
                    at, pack = regions[k][:2]
                    pack(mm, at, *[str(v).encode()[:STR_BYTES - 1] for v in vals])
                    last[k] = vals
            last[-1] = texts
        if lossy:
            self.lossy += 1
        STAMP.pack_into(mm, STAMP_AT, scan, wall_ns, time.monotonic_ns(), self.lossy)
        with memoryview(mm) as view:
            CRC.pack_into(mm, CRC_AT, zlib.crc32(view[STAMP_AT:]))
        self._seq = seq + 1
        SEQ.pack_into(mm, SEQ_AT, seq + 1)  # even: done

    def _fitted(self, k: int, vals: Sequence[Any]) -> None:
        """Region ``k`` packed value by value, each made to fit (``_fit``: an INT beyond
        64 bits saturated, a list grown or shrunk); its flag set while one of the
        regions of its flag holds a value that did not fit."""
        at, pack, codes, flag, _kept = self._regions[k]
        if self._slow(at, pack, vals, codes):
            self._lossy.add(k)
        else:
            self._lossy.discard(k)
        on = any(self._regions[j][3] == flag for j in self._lossy)
        if flag >= 0 and on != (flag in self._flagged):
            self._flag(flag, on)

    def _flag(self, flag: int, on: bool) -> None:
        (self._flagged.add if on else self._flagged.discard)(flag)
        self._mm[self._flags_at + flag] = int(on)

    def _slow(self, at: int, pack: Callable[..., None], vals: Sequence[Any],
              codes: str) -> bool:
        """A region with a value that does not fit: each value made to fit (``_fit``);
        True if one was changed."""
        fitted = [_fit(c, v) for c, v in zip(codes, vals, strict=False)]
        fitted += [(False if c == "?" else 0, True) for c in codes[len(fitted):]]
        pack(self._mm, at, *[v for v, _ in fitted])
        changed = any(ch for _, ch in fitted)
        if changed and self.lossy == 0:
            log.warning("image %s: a value beyond 64 bits is shown out of range to the "
                        "processes beside the controller", self.path)
        return changed

    def retire(self) -> None:
        """Remove the file if it is still this one. Idempotent. The mapping stays (the
        scan thread may be writing it this very moment): freed with the object."""
        try:
            with open(self.path, "rb") as f:
                head = f.read(HEAD.size)
            if len(head) == HEAD.size and HEAD.unpack(head)[3] == self.token:
                os.unlink(self.path)
        except OSError:
            pass


def _moved(vals: tuple[Any, ...], old: tuple[Any, ...], at: tuple[int, ...]) -> bool:
    """Whether a value at one of the positions ``at`` is not the very object it was."""
    return any(vals[i] is not old[i] for i in at)


def _reader_of(parts: list[tuple[str, Any]]) -> Callable[[], tuple[tuple[Any, ...], ...]]:
    """One function of no argument giving, as one tuple, a tuple of values per part:
    ("slots", [(a state, its slot)...]), ("list", a value list: copied), ("ok", the
    drivers: their ok flags). Generated from names made here (no text of any file): it
    reads a state's slots from the very cells its scan closure uses (a LOAD_DEREF
    each), so the scan thread pays one call for the whole image."""
    cells: list[Any] = []
    regions: list[str] = []
    for kind, what in parts:
        terms: list[str] = []
        if kind == "slots":
            for state, k in what:
                state_cells = getattr(state, "cells", None)
                cells.append(state_cells[k] if state_cells is not None
                             else CellType(_Item(state, k)))
                terms.append(f"c{len(cells) - 1}" if state_cells is not None
                             else f"c{len(cells) - 1}.get()")
        elif kind == "list":
            cells.append(CellType(what))
            terms.append(f"*c{len(cells) - 1}")
        else:
            for d in what:
                cells.append(CellType(d))
                terms.append(f"bool(c{len(cells) - 1}.ok)")
        regions.append("(" + "".join(f"{t}, " for t in terms) + ")")
    free = [f"c{k}" for k in range(len(cells))]
    inner = _reader_code(free, regions)
    by_name = dict(zip(free, cells, strict=True))
    fn: Callable[[], tuple[tuple[Any, ...], ...]] = FunctionType(
        inner, {"bool": bool, "__builtins__": restricted_builtins()}, "read", None,
        tuple(by_name[n] for n in inner.co_freevars))
    return fn


def _reader_code(free: list[str], terms: list[str]) -> CodeType:
    """The code of ``read`` returning the tuple of ``terms`` (each a region's tuple)
    over the cells ``free``,
    checked twice before anything of it runs: the whole text against the one shape
    ``_reader_of`` makes (``_READER_TEXT``), then the compiled code by the guard every
    generated program passes (runtime/compiler/guard.py: ``bool`` the only global,
    ``get`` and ``ok`` the only attributes). GeneratedCodeRefused (one line) otherwise."""
    src = ("def make():\n"
           + "".join(f" {n} = None\n" for n in free)
           + " def read():\n  return (" + "".join(f"{t}, " for t in terms) + ")\n"
           + " return read\n")
    if not _READER_TEXT.match(src):
        raise GeneratedCodeRefused("<image reader>", len(free) + 3,
                                   "a term outside the image reader's shape")
    code = checked_code(src, "<image reader>", {"bool"}, attributes={"get", "ok"})
    outer = next(c for c in code.co_consts if isinstance(c, CodeType))
    return next(c for c in outer.co_consts if isinstance(c, CodeType))


class _Item:
    """Slot ``k`` of a plain state list (a state without cells)."""

    __slots__ = ("m", "k")

    def __init__(self, m: Any, k: int) -> None:
        self.m, self.k = m, k

    def get(self) -> Any:
        return self.m[self.k]


def _create(path: str, size: int, head: bytes) -> mmap.mmap:
    """A new file of ``size`` bytes at ``path`` (mode 0640, renamed over what was
    there), its header written, mapped."""
    tmp = f"{path}.{os.getpid()}.new"
    fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o640)
    try:
        os.fchmod(fd, 0o640)
        os.ftruncate(fd, size)
        mm = mmap.mmap(fd, size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        mm[:HEAD.size] = head
        os.replace(tmp, path)
    except OSError:
        os.close(fd)
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    os.close(fd)
    return mm


def refuse_foreign(path: str) -> str | None:
    """Why the controller may not replace what is at ``path`` (a file that is not an
    image: never overwritten), or None (nothing there, or an image: replaced)."""
    try:
        with open(path, "rb") as f:
            magic = f.read(len(MAGIC))
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{path}: {exc.strerror}"
    if magic != MAGIC:
        return f"{path} is not a softplc image file: left alone"
    return None


# -- the reader's side ---------------------------------------------------------------


class ImageReader:
    """A side process's view of the image described by the schema ``schema``: ``read``
    gives (scan, wall s, every name's value in schema order), or None."""

    def __init__(self, schema: dict[str, Any]) -> None:
        """ImageError (one line) if the description or the file does not hold."""
        desc = schema.get("image")
        if not isinstance(desc, dict):
            raise ImageError("the feed offers no image")
        try:
            self.path = str(desc["path"])
            self.generation = _int(desc["generation"])
            token = bytes.fromhex(str(desc["token"]))
            size = _int(desc["size"])
            if desc["version"] != VERSION:
                raise ImageError(f"image version {desc['version']}, not {VERSION}")
            self._insts = [self._region(r, size) for r in desc["instances"]]
            self._drvs = [(self._numeric(r[0], r[1], size), self._numeric(r[2], r[3], size))
                          for r in desc["drivers"]]
            self._ok = self._numeric(desc["ok"][0], desc["ok"][1], size)
            self._flags_at, nflags = _int(desc["flags"][0]), _int(desc["flags"][1])
            if (nflags != len(self._insts) + 2 * len(self._drvs)
                    or self._flags_at + nflags > size):
                raise ValueError("bad flags area")
            self._readers = [self._reader(spec) for spec in schema["specs"]]
        except (KeyError, IndexError, TypeError, ValueError, struct.error) as exc:
            raise ImageError(f"the feed's image description is malformed ({exc})") from exc
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NOFOLLOW)
        except OSError as exc:
            raise ImageError(f"cannot open the image {self.path}: {exc.strerror}") from exc
        try:
            if os.fstat(fd).st_size < size:
                raise ImageError(f"the image {self.path} is shorter than its description")
            self._mm = mmap.mmap(fd, size, mmap.MAP_SHARED, mmap.PROT_READ)
        finally:
            os.close(fd)
        magic, version, gen, tok = HEAD.unpack_from(self._mm, 0)
        if (magic, version, gen, tok) != (MAGIC, VERSION, self.generation, token):
            self._mm.close()
            raise ImageError(f"the image {self.path} is not the one the feed describes "
                             "(left by another controller, or replaced): not trusted")
        self.size = size

    @staticmethod
    def _numeric(at: Any, fmt: Any, size: int) -> tuple[int, struct.Struct]:
        if not isinstance(fmt, str) or not (_NUMERIC.match(fmt) or _STRINGS.match(fmt)):
            raise ValueError(f"bad format {fmt!r}")
        st = struct.Struct(fmt)
        at = _int(at)
        if not DATA_AT <= at or at + st.size > size:
            raise ValueError(f"region {at}+{st.size} outside the image")
        return at, st

    def _region(self, r: Any, size: int) -> tuple[tuple[int, struct.Struct], list[int],
                                                   tuple[int, struct.Struct], list[int]]:
        num = self._numeric(r[0], r[1], size)
        strs = self._numeric(r[3], r[4], size)
        nums, strslots = [_int(k) for k in r[2]], [_int(k) for k in r[5]]
        if len(num[1].format) - 1 != len(nums) or not _STRINGS.match(strs[1].format):
            raise ValueError("slots and format disagree")
        if strs[1].size != STR_BYTES * len(strslots):
            raise ValueError("string slots and format disagree")
        return num, nums, strs, strslots

    def _reader(self, spec: Any) -> Callable[[list[dict[int, Any]], list[tuple[Any, ...]],
                                              list[tuple[Any, ...]], tuple[Any, ...]], Any]:
        """A function of the decoded regions computing one name, built here from the
        spec's validated ints (nothing received is evaluated)."""
        kind = spec[0]
        if kind == "slot":
            i, idx = self._slot(spec[1], spec[2])
            return lambda m, ins, outs, ok: m[i][idx]
        if kind == "steptime":
            i, x = self._slot(spec[1], spec[2])
            ct, t0, tk = (self._slot(i, k)[1] for k in spec[3:6])

            def steptime(m: list[dict[int, Any]], *_: Any) -> int:
                # runtime/compiler/program.py step_time_code, written plainly: the time
                # since activation while active, else the duration of its last activity
                s = m[i]
                return int(s[ct] - s[t0] if s[x] else s[tk])
            return steptime
        if kind == "current":
            i = _int(spec[1])
            leaf = [(str(step), self._slot(i, x)[1]) for step, x in spec[2]]

            def current(m: list[dict[int, Any]], *_: Any) -> str:
                s = m[i]
                active = [step for step, x in leaf if s[x]]
                return active[-1] if active else ""
            return current
        if kind == "point":
            j, pos = _int(spec[2]), _int(spec[3])
            out = spec[1] == "out"
            if spec[1] not in ("in", "out"):
                raise ValueError(f"bad point direction {spec[1]!r}")
            self._pos(j, pos, out)
            if out:
                return lambda m, ins, outs, ok: outs[j][pos]
            return lambda m, ins, outs, ok: ins[j][pos]
        if kind == "applied":
            j, pos = _int(spec[1]), _int(spec[2])
            invert, typ = bool(spec[3]), str(spec[4])
            self._pos(j, pos, True)
            if typ == "bool":
                if invert:
                    return lambda m, ins, outs, ok: not outs[j][pos]
                return lambda m, ins, outs, ok: bool(outs[j][pos])
            if typ == "real":
                return lambda m, ins, outs, ok: float(outs[j][pos])
            if typ in ("int", "time"):
                return lambda m, ins, outs, ok: int(outs[j][pos])
            return lambda m, ins, outs, ok: outs[j][pos]
        if kind == "ok":
            j = _int(spec[1])
            if not 0 <= j < len(self._ok[1].format) - 1:
                raise ValueError(f"no driver {j}")
            return lambda m, ins, outs, ok: ok[j]
        raise ValueError(f"unknown spec {kind!r}")

    def _slot(self, i: Any, idx: Any) -> tuple[int, int]:
        i, idx = _int(i), _int(idx)
        if not 0 <= i < len(self._insts):
            raise ValueError(f"no instance {i}")
        _num, nums, _strs, strslots = self._insts[i]
        if idx not in nums and idx not in strslots:
            raise ValueError(f"slot {idx} of instance {i} is not in the image")
        return i, idx

    def _pos(self, j: int, pos: int, out: bool) -> None:
        if not 0 <= j < len(self._drvs):
            raise ValueError(f"no driver {j}")
        if not 0 <= pos < len(self._drvs[j][int(out)][1].format) - 1:
            raise ValueError(f"no point {pos} of driver {j}")

    def snapshot(self) -> bytes | None:
        """A consistent copy of the file, or None if none was had in RETRIES tries (the
        writer kept writing, or the copies mixed two writes). Consistent: the counter
        even and unchanged around the copy (seqlock) and the copy's CRC32 that of its
        stamp and data (a copy mixing two writes, which a weakly ordered CPU may show
        with an even, unchanged counter, is refused); a counter of 0 (nothing written
        yet) is taken as it is."""
        got = self._consistent(lambda mm: mm[:self.size],
                               lambda before, data: before == 0 or _sound(data))
        return got[1] if got is not None else None

    def stamp(self) -> tuple[int, int, int, int] | None:
        """(scan, wall ns, monotonic ns, lossy) of the last write, or None if the writer
        kept writing; scan -1 before the first write. The header only, under the counter
        alone (no checksum: the cheap poll of whether the scan advanced, 4 times a
        sample; ``read`` then checks the whole copy, ``age_s`` its own)."""
        got = self._consistent(lambda mm: STAMP.unpack_from(mm, STAMP_AT),
                               lambda _before, _stamp: True)
        if got is None:
            return None
        before, stamp = got
        return stamp if before else (-1, 0, 0, 0)

    def _consistent(self, take: Callable[[mmap.mmap], T],
                    sound: Callable[[int, T], bool]) -> tuple[int, T] | None:
        """(the counter, what ``take`` read of the file) under the seqlock: the counter
        even and unchanged around it, and ``sound(counter, what was read)``; None after
        RETRIES tries (the writer kept writing)."""
        mm = self._mm
        for _ in range(RETRIES):
            before = SEQ.unpack_from(mm, SEQ_AT)[0]
            if before & 1:
                time.sleep(0)
                continue
            got = take(mm)
            if SEQ.unpack_from(mm, SEQ_AT)[0] != before:
                continue
            if sound(before, got):
                return before, got
            time.sleep(0)
        return None

    def decode(self, data: bytes) -> tuple[int, float, list[Any]]:
        """(scan, wall s, the values in schema order) of a snapshot."""
        scan, wall_ns, _mono, _lossy = STAMP.unpack_from(data, STAMP_AT)
        flags = data[self._flags_at:self._flags_at + len(self._insts) + 2 * len(self._drvs)]
        m: list[dict[int, Any]] = []
        for k, ((at, st), nums, (sat, sst), strslots) in enumerate(self._insts):
            vals = st.unpack_from(data, at)
            if flags[k]:
                vals = _beyond(vals, st.format)
            slots = dict(zip(nums, vals, strict=True))
            if strslots:
                slots.update(zip(strslots, (b.decode(errors="replace")
                                            for b in sst.unpack_from(data, sat)),
                                 strict=True))
            m.append(slots)
        n = len(self._insts)
        ins = [_beyond(st.unpack_from(data, at), st.format) if flags[n + 2 * j] else
               st.unpack_from(data, at) for j, ((at, st), _) in enumerate(self._drvs)]
        outs = [_beyond(st.unpack_from(data, at), st.format) if flags[n + 2 * j + 1] else
                st.unpack_from(data, at) for j, (_, (at, st)) in enumerate(self._drvs)]
        ok = self._ok[1].unpack_from(data, self._ok[0])
        return scan, wall_ns / 1e9, [r(m, ins, outs, ok) for r in self._readers]

    def read(self) -> tuple[int, float, list[Any]] | None:
        """``decode(snapshot())``; None if no consistent copy or nothing written yet."""
        data = self.snapshot()
        if data is None or SEQ.unpack_from(data, SEQ_AT)[0] == 0:
            return None
        return self.decode(data)

    def age_s(self) -> float | None:
        """Seconds since the controller last wrote the image (its CLOCK_MONOTONIC stamp),
        None if it never did (or no consistent copy now). From a checked copy
        (``snapshot``: counter and checksum), so that a stamp mixed from two writes never
        decides whether the controller is stale (a copy and a CRC: about 7 µs at 17 KB)."""
        data = self.snapshot()
        if data is None or SEQ.unpack_from(data, SEQ_AT)[0] == 0:
            return None
        mono: int = STAMP.unpack_from(data, STAMP_AT)[2]
        if mono == 0:
            return None
        return max(0.0, (time.monotonic_ns() - mono) / 1e9)

    def close(self) -> None:
        if not self._mm.closed:
            self._mm.close()


def _sound(data: bytes) -> bool:
    """Whether the copy ``data``'s CRC32 is that of its stamp and data."""
    with memoryview(data) as view:
        return int(CRC.unpack_from(data, CRC_AT)[0]) == zlib.crc32(view[STAMP_AT:])


def _beyond(vals: tuple[Any, ...], fmt: str) -> tuple[Any, ...]:
    """The values of a region flagged as saturated: a 64-bit extreme of a ``q`` slot shown
    one beyond the range (what did not fit was beyond it)."""
    out = list(vals)
    for k, code in enumerate(fmt[1:]):
        if code == "q" and out[k] == INT64_MAX:
            out[k] = INT64_MAX + 1
        elif code == "q" and out[k] == INT64_MIN:
            out[k] = INT64_MIN - 1
    return tuple(out)


def _int(v: Any) -> int:
    if type(v) is not int or v < 0:
        raise ValueError(f"expected a non-negative int, got {v!r}")
    return v
