"""The console's streams (``watch``, ``trace``): the images the scan thread queues for a
stream, and the code that turns them into watch/trace lines.

The scan thread only copies the process image after each cycle (``Stream.capture``, a few
list copies); the diffing and formatting happen in the session's own thread
(``Stream.poll``), a few times a second.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable
from typing import Any, Literal

from runtime.console.protocol import STREAM_LINES_PER_POLL, STREAM_SCANS
from runtime.console.service import Controller
from runtime.engine.names import Catalogue, Image, Signal

StreamKind = Literal["watch", "trace"]


def logical_value(raw: Any, inverted: bool) -> int:
    """The value a chart input bound to a raw point sees: 0 or 1."""
    return int((raw != 0) != inverted)


def feeds_text(signal: Signal, raw: Any) -> str:
    """A physical input's chart inputs with the value they see: ``t1.iMarcha=1, t2.iX=0
    inverted``."""
    return ", ".join(f"{sig}={logical_value(raw, inv)}" + (" inverted" if inv else "")
                     for sig, inv in signal.feeds)


class Stream:
    """A running watch or trace: what it shows, where it stands, and the images queued
    for it since the last poll (at most STREAM_SCANS: older ones are dropped and the gap
    is reported as scans not shown)."""

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

    def begin(self, ctl: Controller) -> None:
        """Scan thread: the values when the stream starts, and the cycle count then."""
        self.images.append(self.catalogue.capture(-1))
        self.last_scan = int(ctl.status()["scans"])

    def capture(self, scan: int) -> None:
        """Scan thread, after each cycle: copy the image, nothing more."""
        self.images.append(self.catalogue.capture(scan))

    def poll(self, clock: Callable[[], float], as_json: bool) -> list[str]:
        """The stream lines due now, from the images queued since the last poll."""
        if not self.images:
            return []
        images: list[Image] = []
        while self.images:
            images.append(self.images.popleft())
        out = []
        if self.last is None:  # the snapshot taken when the stream started
            first = images.pop(0)
            self.last = {n.text: n.read(first) for n in self.names}
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
        # an even number of scans later)
        for img in images[-STREAM_LINES_PER_POLL:]:
            if self.last_scan is not None:
                self.unshown += max(0, img.scan - self.last_scan - 1)
            self.last_scan = img.scan
            values = {n.text: n.read(img) for n in self.names}
            last = self.last
            if self.kind == "trace":
                changed = {k: v for k, v in values.items() if last.get(k) != v}
                if changed:
                    out.append(self.line("trace", changed, img.scan, self.unshown, as_json))
                    self.unshown = 0
            elif values != last:
                out.append(self.line("watch", values, img.scan, self.unshown, as_json))
                self.unshown = 0
            self.last = values
        return out

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
        parts = []
        for k, v in values.items():
            part = f"{k}={names[k].show(v)}"
            if kind == "watch" and names[k].feeds:
                part += " (" + feeds_text(names[k], v) + ")"
            parts.append(part)
        head = kind + (f" {scan}" if scan >= 0 else "")
        if skipped:
            head += f" ({skipped} scans not shown: the line is too slow)"
        return head + ": " + "  ".join(parts)
