"""The console's JSON mode, from the monitor's side: requests, their replies and the
streamed objects (``ConsoleClient``), and the client of one controller, opened again with
back-off after a loss (``Connection``).
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from runtime.console.links import (
    REQUEST_TIMEOUT_S,
    ConnectionLost,
    Link,
    MonitorError,
    Target,
)

#: the same while connecting again (keys wait meanwhile: keep it short), seconds
RECONNECT_TIMEOUT_S = 2.0
#: after a loss, the first try this long after it, then each wait doubled up to the
#: maximum, seconds
RETRY_MIN_S = 0.5
RETRY_MAX_S = 5.0
#: reply lines kept under the view (``View.log``), and streamed objects kept by a client
LOG_LINES = 200


# -- the protocol's JSON mode ------------------------------------------------------------
class ConsoleClient:
    """Requests and replies in the console's JSON mode; streamed objects (watch, trace)
    are kept in ``streamed``."""

    def __init__(self, link: Link, clock: Callable[[], float] = time.monotonic) -> None:
        self.link = link
        self.clock = clock
        self._buf = b""
        self._pending: deque[dict[str, Any]] = deque()
        self.streamed: deque[dict[str, Any]] = deque(maxlen=LOG_LINES)
        #: an ``error ...`` text line after the last JSON line (what the console says as
        #: it closes a connection: idle timeout, too many sessions)
        self.last_error = ""

    def start(self, timeout: float = REQUEST_TIMEOUT_S) -> None:
        """Take over the console: drop a half-typed line and any stream (Ctrl-C), then
        switch this session to JSON."""
        self.link.send(b"\x03")
        reply = self.request("json on", timeout)
        if not reply.get("ok"):
            raise MonitorError(f"the console refused 'json on': {reply.get('error')}")

    def close(self) -> None:
        """Give the line back in text mode (a serial session outlives this client)."""
        try:
            self.link.send(b"\x03json off\r\n")
            end = self.clock() + 1.0  # read its text-mode "ok": leave the line clean
            while b"ok\r\n" not in self._buf and self.clock() < end:
                self._read(0.05)
        except (OSError, MonitorError):
            pass
        self.link.close()

    def abandon(self) -> None:
        """Close a link that broke (nothing is sent on it)."""
        try:
            self.link.close()
        except OSError:
            pass

    def send_line(self, line: str) -> None:
        """Send a line without waiting (an empty line stops a stream; it gets no reply)."""
        self.link.send(line.encode("utf-8") + b"\r\n")

    def request(self, line: str, timeout: float = REQUEST_TIMEOUT_S) -> dict[str, Any]:
        """Send one command; its reply object ({"ok": true, ...} or {"ok": false,
        "error": ...})."""
        self.send_line(line)
        end = self.clock() + timeout
        while True:
            self._parse()
            while self._pending:
                obj = self._pending.popleft()
                if "ok" in obj:
                    return obj
                self.streamed.append(obj)
            left = end - self.clock()
            if left <= 0:
                raise ConnectionLost(f"no reply to '{line}' within {timeout:g} s")
            self._read(min(left, 0.1))

    def poll_streams(self, timeout: float = 0.0) -> list[dict[str, Any]]:
        """Streamed objects that arrived (waiting up to ``timeout`` s for the first)."""
        if not self._pending:
            self._read(timeout)
            self._parse()
        out = [*self.streamed, *(obj for obj in self._pending if "ok" not in obj)]
        self.streamed.clear()
        self._pending.clear()
        return out

    def _read(self, timeout: float) -> None:
        data = self.link.recv(timeout)
        if data is None:
            self._parse()
            why = f" ({self.last_error})" if self.last_error else ""
            raise ConnectionLost(f"{self.link.name}: the controller closed the "
                                 f"connection{why}")
        self._buf += data

    def _parse(self) -> None:
        """Complete JSON lines of the buffer to ``_pending``; anything else (what a text
        mode session left on the line) is skipped."""
        *lines, self._buf = self._buf.split(b"\n")
        for raw in lines:
            text = raw.decode("utf-8", "replace").strip()
            try:
                obj = json.loads(text or "null")
            except ValueError:
                if text.startswith("error "):
                    self.last_error = text
                continue
            self.last_error = ""  # only what came after the last reply says why
            if isinstance(obj, dict):
                self._pending.append(obj)


# -- the connection, kept ------------------------------------------------------------------
class Connection:
    """The monitor's client of one controller: opened, and after a loss opened again
    with back-off (RETRY_MIN_S after the loss, then each wait doubled up to RETRY_MAX_S).

    ``clock`` (monotonic seconds) only schedules the tries."""

    def __init__(self, target: Target, clock: Callable[[], float] = time.monotonic) -> None:
        self.target = target
        self.clock = clock
        self.client: ConsoleClient | None = None
        #: why there is no client: the loss, then the last failed try ("" while connected)
        self.reason = ""
        #: failed tries since the loss
        self.attempts = 0
        #: when the next try is due (clock seconds)
        self.next_try = 0.0
        self._wait = RETRY_MIN_S

    def connect(self, timeout: float = REQUEST_TIMEOUT_S) -> ConsoleClient:
        """Open the link and take over the console (MonitorError if that fails)."""
        client = ConsoleClient(self.target.open(timeout))
        try:
            client.start(timeout)
        except MonitorError:
            client.abandon()
            raise
        self.client, self.reason, self.attempts = client, "", 0
        return client

    def lost(self, reason: str) -> None:
        """The client broke: drop it; the first try comes RETRY_MIN_S from now."""
        if self.client is not None:
            self.client.abandon()
            self.client = None
        self.reason, self.attempts = reason, 0
        self._wait = RETRY_MIN_S
        self.next_try = self.clock() + self._wait

    def retry(self) -> ConsoleClient | None:
        """The new client, when a try is due and succeeds; None otherwise."""
        if self.client is not None or self.clock() < self.next_try:
            return None
        try:
            return self.connect(RECONNECT_TIMEOUT_S)
        except MonitorError as exc:
            self.attempts += 1
            self.reason = str(exc)
            self._wait = min(self._wait * 2, RETRY_MAX_S)
            self.next_try = self.clock() + self._wait
            return None

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None


# -- a typed command's time ---------------------------------------------------------------
def reply_timeout(line: str, cycle_ms: float | None) -> float:
    """How long the reply to a typed command may take, seconds: REQUEST_TIMEOUT_S, and
    for ``cycle N`` as long again as the console waits for its scans (2 s plus twice
    their duration): a reply given up for lost makes the monitor connect again, and the
    end of the session that stepped halts the controller."""
    words = line.split()
    if not words or words[0].lower() != "cycle" or not cycle_ms:
        return REQUEST_TIMEOUT_S
    n = int(words[1]) if len(words) > 1 and words[1].isdigit() else 1
    return REQUEST_TIMEOUT_S + 2.0 + 2 * n * cycle_ms / 1000
