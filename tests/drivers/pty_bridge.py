"""A null-modem of two pseudo-terminals joined by a thread (like ``socat pty pty``), which
can cut the line, garble or inject bytes (pymodbus' NullModem manipulator idea).

The driver opens ``driver_port``, the peer opens ``peer_port``; the bridge keeps its own
descriptor of each terminal open, so a peer that dies and comes back finds the same path.
"""

from __future__ import annotations

import os
import select
import termios
import threading
import time
import tty


class PtyBridge:
    """Two ptys and a copying thread. Use as a context manager, or call close()."""

    def __init__(self) -> None:
        self._ma, self._sa = os.openpty()
        self._mb, self._sb = os.openpty()
        for fd in (self._sa, self._sb):
            tty.setraw(fd)
        for fd in (self._ma, self._mb):
            os.set_blocking(fd, False)
        self.driver_port = os.ttyname(self._sa)
        self.peer_port = os.ttyname(self._sb)
        #: drop every byte both ways (a cut cable)
        self.cut = False
        #: flip a bit in the next N replies (peer -> driver chunks)
        self.garble_replies = 0
        #: every request chunk seen (driver -> peer)
        self.requests: list[bytes] = []
        #: deliver replies slowly, as a slow line does: (bytes per chunk, seconds between)
        self.slow_replies: tuple[int, float] | None = None
        self._inject = b""
        self._lock = threading.Lock()
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="pty-bridge", daemon=True)
        self._thread.start()

    def inject_to_driver(self, data: bytes) -> None:
        """Send noise towards the driver, as if on the line before the next reply."""
        with self._lock:
            self._inject += data

    def flush_peer_side(self) -> None:
        """Drop requests queued for a peer that was not listening (before restarting it)."""
        termios.tcflush(self._sb, termios.TCIFLUSH)

    def _run(self) -> None:
        while True:
            ready, _, _ = select.select([self._ma, self._mb, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            for src, dst in ((self._ma, self._mb), (self._mb, self._ma)):
                if src not in ready:
                    continue
                try:
                    data = os.read(src, 4096)
                except (BlockingIOError, OSError):
                    continue
                if self.cut or not data:
                    continue
                if src == self._ma:
                    self.requests.append(data)
                else:
                    with self._lock:
                        inject, self._inject = self._inject, b""
                    if self.garble_replies > 0:
                        self.garble_replies -= 1
                        i = min(3, len(data) - 1)
                        data = data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:]
                    data = inject + data
                    if self.slow_replies is not None:
                        self._trickle(dst, data, *self.slow_replies)
                        continue
                try:
                    os.write(dst, data)
                except (BlockingIOError, OSError):
                    pass  # nobody reading: the bytes are lost, as on a real line

    def _trickle(self, dst: int, data: bytes, size: int, pause: float) -> None:
        while data:
            try:
                os.write(dst, data[:size])
            except (BlockingIOError, OSError):
                return
            data = data[size:]
            if data:
                time.sleep(pause)

    def close(self) -> None:
        if self._thread.is_alive():
            os.write(self._stop_w, b"x")
            self._thread.join()
        for fd in (self._ma, self._sa, self._mb, self._sb, self._stop_r, self._stop_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PtyBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
