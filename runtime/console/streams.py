"""The console's streams (``watch``, ``trace``): the images the scan thread queues for
them, and the code that turns them into watch/trace lines.

The scan thread copies the process image once after each cycle while any stream runs,
whatever their number (``StreamTap``: one ``Catalogue.capture``, queued for every stream);
the diffing and formatting happen in each session's own thread (``Stream.poll``), a few
times a second. A poll reads a name only where the raw values it is read from changed
(``Changes``: one list compare per image, then one per instance and driver list that
differs), so its work follows what changed, not the number of names.
"""

from __future__ import annotations

import json
import threading
from collections import deque
from collections.abc import Callable, Sequence
from itertools import chain, compress
from operator import call, itemgetter, ne
from typing import TYPE_CHECKING, Any, Literal

from runtime.console.protocol import STREAM_LINES_PER_POLL, STREAM_SCANS
from runtime.engine.names import Catalogue, Image, Signal

if TYPE_CHECKING:
    from runtime.console.service import Controller

StreamKind = Literal["watch", "trace"]
#: the texts of (name, value) pairs a stream keeps for its lines, about at most: each
#: name keeps PARTS_KEPT // names of them, within TEXTS_PER_NAME
PARTS_KEPT = 20_000
#: the texts one name keeps, at most and at least (a bool's two, a counter's last ones):
#: past that they go together, a name's at a time
TEXTS_PER_NAME = (2, 64)


def logical_value(raw: Any, inverted: bool) -> int:
    """The value a chart input bound to a raw point sees: 0 or 1."""
    return int((raw != 0) != inverted)


def feeds_text(signal: Signal, raw: Any) -> str:
    """A physical input's chart inputs with the value they see: ``t1.iMarcha=1, t2.iX=0
    inverted``."""
    return ", ".join(f"{sig}={logical_value(raw, inv)}" + (" inverted" if inv else "")
                     for sig, inv in signal.feeds)


def _getter(slots: Sequence[int]) -> Callable[[Sequence[Any]], tuple[Any, ...]]:
    """A C-level getter of ``slots`` of a list, as a tuple (``itemgetter`` for two or
    more)."""
    if len(slots) == 1:
        i = slots[0]
        return lambda xs: (xs[i],)
    return itemgetter(*slots)


def _picked(lists: Callable[[Image], Sequence[Any]],
            pick: Callable[[Sequence[Any]], tuple[Any, ...]]
            ) -> Callable[[Image], Sequence[Any]]:
    """The lists of an image's part (``img.m``...) that ``pick`` takes."""
    return lambda img: pick(lists(img))


class Changes:
    """Which of a stream's names an image may have changed since the last image seen.

    Each name is traced to the raw values it is read from (``Signal.raw``): the slots of
    an instance's state list, the positions of a driver's value lists, a driver's
    health. An image's raw values are picked by C-level getters, one tuple per instance
    and driver list, and compared as one list with the last image's: equal, nothing to
    read; else only the tuples that differ are compared slot by slot, and only the
    names of the slots that differ are read. The work per image follows the number of
    instances and drivers and what changed, not the number of names. A name that cannot
    be traced to slots (a step time) is among the changed at every image."""

    def __init__(self, names: Sequence[Signal]) -> None:
        found: dict[tuple[str, int], dict[int, list[int]]] = {}
        #: positions in ``names`` read at every image
        self.volatile: list[int] = []
        for p, n in enumerate(names):
            raw = n.raw()
            if raw is None:
                self.volatile.append(p)
                continue
            for source, slot in raw:
                found.setdefault(source, {}).setdefault(slot, []).append(p)
        #: per part of an image: its lists of the names' sources, their slot getters
        self._parts: list[tuple[Callable[[Image], Sequence[Any]],
                                list[Callable[[Sequence[Any]], tuple[Any, ...]]]]] = []
        #: per source, in the order of the raw list: per slot, the names read from it
        #: (tuples of ints: kept for the stream's life, nothing for the collector)
        self._names_at: list[tuple[tuple[int, ...], ...]] = []
        parts: dict[str, Callable[[Image], Sequence[Any]]] = {
            "m": lambda img: img.m, "in": lambda img: img.inputs,
            "out": lambda img: img.outputs, "ok": lambda img: (img.ok,)}
        for part, lists in parts.items():
            ks = sorted(k for p, k in found if p == part)
            if not ks:
                continue
            getters = []
            for k in ks:
                slots = sorted(found[part, k])
                getters.append(_getter(slots))
                self._names_at.append(tuple([tuple(found[part, k][s]) for s in slots]))
            self._parts.append((lists if part == "ok" else _picked(lists, _getter(ks)),
                                getters))
        self._seen: list[tuple[Any, ...]] = []

    def _raw(self, img: Image) -> list[tuple[Any, ...]]:
        return list(chain.from_iterable(map(call, getters, lists(img))
                                        for lists, getters in self._parts))

    def start(self, img: Image) -> None:
        """``img`` is the image whose values are shown: changes count from it."""
        self._seen = self._raw(img)

    def changed(self, img: Image) -> list[int]:
        """The positions (ascending) of the names whose raw values differ in ``img`` from
        the last image seen, and the volatile names; ``img`` is then the last seen."""
        now, seen = self._raw(img), self._seen
        self._seen = now
        if now == seen:
            return self.volatile
        found: list[int] = []
        names_at = self._names_at
        for s in compress(range(len(now)), map(ne, now, seen)):
            a, at = now[s], names_at[s]
            for k in compress(range(len(a)), map(ne, a, seen[s])):
                found += at[k]
        if len(found) > 1 or self.volatile:
            return sorted({*found, *self.volatile})
        return found


class StreamTap:
    """The scan thread's side of the running streams of a console service: after each
    cycle one copy of the image (``Catalogue.capture``) queued for every stream, which
    only read it; the cost per scan does not grow with the number of streams. Its
    listener is registered while a stream runs."""

    def __init__(self, ctl: Controller) -> None:
        self.ctl = ctl
        self.streams: tuple[Stream, ...] = ()
        self._lock = threading.Lock()

    def add(self, stream: Stream) -> None:
        """Queue an image for ``stream`` after each cycle from now (any thread)."""
        with self._lock:
            if not self.streams:
                self.ctl.add_listener(self.on_scan)
            self.streams = (*self.streams, stream)

    def remove(self, stream: Stream) -> None:
        """No image more for ``stream`` (any thread; nothing if it had none)."""
        with self._lock:
            if stream not in self.streams:
                return
            self.streams = tuple(s for s in self.streams if s is not stream)
            if not self.streams:
                self.ctl.remove_listener(self.on_scan)

    def on_scan(self, scan: int) -> None:
        """Scan thread, after each cycle: one capture, queued for every stream (one more
        per change of catalogue in the list: only while a reload ends the streams of the
        replaced plant)."""
        cat: Catalogue | None = None
        img: Image | None = None
        for stream in self.streams:
            if stream.catalogue is not cat:
                cat = stream.catalogue
                img = cat.capture(scan)
            assert img is not None
            stream.images.append(img)
            if len(stream.images) > STREAM_LINES_PER_POLL:
                stream.drop_oldest()


class Stream:
    """A running watch or trace: what it shows, where it stands, and the images queued
    for it since the last poll (the newest STREAM_LINES_PER_POLL, the start's snapshot
    aside: older ones are dropped by the scan thread, ``drop_oldest``, and the gap is
    reported as scans not shown). The images may be shared with other streams: a
    stream only reads them."""

    def __init__(self, kind: StreamKind, names: list[Signal], catalogue: Catalogue,
                 every_s: float | None = None) -> None:
        self.kind: StreamKind = kind
        self.names = names
        #: ``watch ... every MS``: seconds between lines; None: a line on every change
        self.every_s = every_s
        self.catalogue = catalogue
        #: the values shown last (None before the first poll)
        self.last: dict[str, Any] | None = None
        self.last_scan: int | None = None
        #: monotonic seconds when the next ``every`` line is due
        self.next_due = 0.0
        self.images: deque[Image] = deque(maxlen=STREAM_SCANS)
        #: scans not shown (the line too slow) since the last line: said by the next line
        self.unshown = 0
        #: which names an image changed (a line on every change)
        self.changes = Changes(names)
        self._texts = [n.text for n in names]
        #: name -> value -> its text in a line (not for floats: 1.0 == 1 == True, a
        #: name's ints and bools show the same text, ``Signal.show``). A name's dict holds
        #: only strings and scalars, so the garbage collector leaves it out: keyed by
        #: (name, value) tuples, 4 traces' texts made a full collection, which the scan
        #: thread runs, take 1.8 to 3.5 ms instead of 0.8 (bench.observers at 1 ms)
        self._shown: dict[str, dict[Any, str]] = {}
        lo, hi = TEXTS_PER_NAME
        #: the texts one name keeps, at most
        self._per_name = max(lo, min(hi, PARTS_KEPT // max(1, len(names))))
        self._reads = [n.read for n in names]
        #: images a poll was told to leave (``poll``'s ``more``), compared first by the
        #: next poll (at most STREAM_LINES_PER_POLL)
        self._held: list[Image] = []

    def drop_oldest(self) -> None:
        """Scan thread: let go of the oldest image queued, the start's snapshot kept
        while no poll has read it. No poll compares more than the newest
        STREAM_LINES_PER_POLL (the scans before them are counted, not shown), so a stream
        polled less often than that (a short cycle, a slow line) keeps no more: kept
        until the poll, the images of a 1 ms cycle (some fifteen objects the collector
        tracks each) had the scan thread run a young garbage collection about ten times
        a second, 0.5 ms each (bench.observers at 1 ms). Letting one go costs about what
        taking it did; the poll may take images meanwhile (an image too few is a scan
        counted as not shown)."""
        images = self.images
        try:
            if self.last is None:
                if len(images) > STREAM_LINES_PER_POLL + 1:
                    del images[1]
            else:
                images.popleft()
        except IndexError:  # a poll took them meanwhile
            pass

    @property
    def behind(self) -> bool:
        """Whether a poll left images to compare (``poll``'s ``more`` said stop)."""
        return bool(self._held)

    def begin(self, ctl: Controller) -> None:
        """Scan thread: the values when the stream starts, and the cycle count then."""
        self.images.append(self.catalogue.capture(-1))
        self.last_scan = int(ctl.status()["scans"])

    def poll(self, clock: Callable[[], float], as_json: bool,
             more: Callable[[], bool] | None = None) -> list[str]:
        """The stream lines due now, from the images queued since the last poll.
        ``more``, asked before each image is compared: whether there is time left (the
        console's window still open); when it says no, the images left wait for the next
        poll (``behind``), which compares them first, so that a poll never holds the GIL
        past its window however many images wait."""
        if not self.images and not self._held:
            return []
        queued = self.images
        # the images no poll will compare (all but the newest STREAM_LINES_PER_POLL, the
        # start's snapshot kept: the scan thread already drops older ones, drop_oldest)
        # are let go here one at a time, the GIL free to pass between two; let go
        # together (once up to STREAM_SCANS, some 200 000 objects at 100 testers) their
        # deallocation held the GIL 40-56 ms, the scan waiting
        snapshot = queued.popleft() if self.last is None and queued else None
        while len(queued) > STREAM_LINES_PER_POLL:
            queued.popleft()
        if snapshot is not None:
            queued.appendleft(snapshot)
        images, self._held = self._held, []
        while queued:
            images.append(queued.popleft())
        out = []
        if self.last is None:  # the snapshot taken when the stream started
            first = images.pop(0)
            self.last = {n.text: n.read(first) for n in self.names}
            self.changes.start(first)
            if self.kind == "watch":
                out.append(self.line("watch", self.last, -1, 0, as_json))
            if self.every_s is not None:
                self.next_due = clock() + self.every_s
        if self.every_s is not None:
            now = clock()
            if not images or now < self.next_due:
                self.images.extendleft(images[-1:])  # the newest waits for its time
                return out
            self.next_due = now + self.every_s
            values = {n.text: n.read(images[-1]) for n in self.names}
            self.last_scan = images[-1].scan
            return [*out, self.line("watch", values, images[-1].scan, 0, as_json)]
        # the first image kept is compared with the last one shown: no change is lost,
        # only the cycles in between are not shown one by one; their count goes with the
        # next line (the first image kept may show no change, e.g. a blinking lamp seen
        # an even number of scans later). Only the names whose raw values changed are
        # read (Changes); a value the same as the one shown (a NaN still a NaN) is no
        # change.
        texts, reads, last = self._texts, self._reads, self.last
        todo = images[-STREAM_LINES_PER_POLL:]
        for k, img in enumerate(todo):
            if more is not None and not more():
                self._held = todo[k:]
                break
            if self.last_scan is not None:
                self.unshown += max(0, img.scan - self.last_scan - 1)
            self.last_scan = img.scan
            changed: dict[str, Any] = {}
            for p in self.changes.changed(img):
                t = texts[p]
                v, was = reads[p](img), last[t]
                if was != v and (was == was or v == v):  # not same(was, v), inlined
                    changed[t] = v
                last[t] = v
            if not changed:
                continue
            if self.kind == "trace":
                out.append(self.line("trace", changed, img.scan, self.unshown, as_json))
            else:
                out.append(self.line("watch", last, img.scan, self.unshown, as_json))
            self.unshown = 0
        return out

    def release(self) -> None:
        """The stream ended: its queued images let go one at a time (a lagging stream
        holds up to STREAM_SCANS; let go together, their deallocation would hold the GIL
        tens of ms)."""
        self._held = []
        while self.images:
            self.images.popleft()

    def line(self, kind: StreamKind, values: dict[str, Any], scan: int, skipped: int,
             as_json: bool) -> str:
        """One stream line: ``watch 12: rio.I1=1 (t1.iMarcha=1)``, or its JSON object.
        ``scan`` -1: the values when the stream started; ``skipped``: scans not shown."""
        names = self.catalogue.names
        if as_json:
            obj: dict[str, Any] = {kind: {k: names[k].plain(v) for k, v in values.items()}}
            logical = {sig: logical_value(v, inv) for k, v in values.items()
                       for sig, inv in names[k].feeds}
            if logical and kind == "watch":
                obj["logical"] = logical
            if scan >= 0:
                obj["scan"] = scan
            if skipped:
                obj["skipped"] = skipped
            return json.dumps(obj, ensure_ascii=False)
        shown = self._shown if kind == self.kind else {}
        most = self._per_name
        parts = []
        for k, v in values.items():
            texts = None
            part = None
            if type(v) is not float:  # 1.0 == 1 == True: a float is never kept
                texts = shown.get(k)
                if texts is None:
                    texts = shown[k] = {}
                part = texts.get(v)
            if part is None:
                part = f"{k}={names[k].show(v)}"
                if kind == "watch" and names[k].feeds:
                    part += " (" + feeds_text(names[k], v) + ")"
                if texts is not None:
                    if len(texts) >= most:  # a counter counting: its old texts go
                        texts.clear()
                    texts[v] = part
            parts.append(part)
        head = kind + (f" {scan}" if scan >= 0 else "")
        if skipped:
            head += f" ({skipped} scans not shown: the line is too slow)"
        return head + ": " + "  ".join(parts)
