"""A page's console session: how a logged-in user's page acts on the controller.

Acting from the page goes through the controller's console (docs/web.md, "Acting"): each
page that acts opens its own connection to the plant's console Unix socket, switches it to
JSON (``json on``) and says whom it acts for (``web USER ADDRESS``, refused unless this
process runs as root or as the controller's user). The console then owns what the page
holds (forces, the pause) exactly as it owns a console session's: closing the connection
(the page closed, its WebSocket lost, its login timed out, this process ended) is the end
of a console session, with the console's safe reaction, time limits and log lines.

Only the commands of ``ACTIONS`` are sent, each built from checked words (names of the
feed's schema, values of VALUE_RE): nothing the browser sends reaches the console as text.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
from collections.abc import Callable
from typing import Any

from runtime.controller.aio import within
from runtime.errors import SoftplcError

log = logging.getLogger(__name__)

#: action -> the number of arguments it takes (names and values, checked by the server)
ACTIONS = {"force": 2, "unforce": 1, "set": 2, "pause": 0, "resume": 0, "cycle": 1,
           "ack": 0}
#: what a value may be (a number, TRUE/FALSE, a duration such as 2s or T#1s500ms)
VALUE_RE = re.compile(r"^[A-Za-z0-9_.#:+-]{1,32}$")
#: how long the console may take to answer a command, seconds
REPLY_TIMEOUT_S = 5.0
#: the longest console reply line read, bytes
LINE_MAX = 1 << 20


class ConsoleUnavailable(SoftplcError):
    """The console socket cannot be reached or refused this process (``web``)."""


class ConsoleLink:
    """One console connection acting for one page. ``notice(text)`` gets the console's
    notices and warnings (a force about to reach ``max_force``); ``ended(reason)`` is
    called once when the controller ends the session (it stopped, or restarted)."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                 notice: Callable[[str], None], ended: Callable[[str], None]) -> None:
        self._reader, self._writer = reader, writer
        self._notice, self._ended = notice, ended
        self._lock = asyncio.Lock()
        self._reply: asyncio.Future[dict[str, Any]] | None = None
        self._task: asyncio.Task[None] | None = None
        self.closed = False

    @classmethod
    async def open(cls, path: str, user: str, address: str,
                   notice: Callable[[str], None],
                   ended: Callable[[str], None]) -> ConsoleLink:
        """Connect to the console socket ``path`` and act for ``user`` at ``address``."""
        try:
            reader, writer = await within(
                asyncio.open_unix_connection(path, limit=LINE_MAX), REPLY_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise ConsoleUnavailable(f"the controller's console {path}: "
                                     f"{getattr(exc, 'strerror', None) or exc}") from None
        link = cls(reader, writer, notice, ended)
        link._task = asyncio.create_task(link._read())
        try:
            await link.call("json on")
            await link.call(f"web {user} {address}")
        except ConsoleUnavailable:
            await link.close()
            raise
        return link

    async def call(self, line: str) -> dict[str, Any]:
        """Send one command line, return the console's JSON reply; ConsoleUnavailable
        if the reply is an error of the session itself or does not come."""
        async with self._lock:
            if self.closed:
                raise ConsoleUnavailable("the console session has ended")
            fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
            self._reply = fut
            self._writer.write(line.encode() + b"\n")
            try:
                reply = await within(fut, REPLY_TIMEOUT_S)
            except TimeoutError:
                raise ConsoleUnavailable("the console did not answer in time") from None
            finally:
                self._reply = None
        if line.startswith(("json ", "web ")) and not reply.get("ok"):
            raise ConsoleUnavailable(f"the console refused '{line.split()[0]}': "
                                     f"{reply.get('error')}")
        return reply

    async def close(self) -> None:
        """End the console session (the console then releases what it held)."""
        if self.closed:
            return
        self.closed = True
        self._writer.close()
        if self._task is not None:
            self._task.cancel()

    async def _read(self) -> None:
        reason = "the controller ended the console session"
        try:
            while True:
                line = await self._reader.readline()
                if not line.endswith(b"\n"):
                    break
                text = line.decode("utf-8", "replace").strip()
                if not text:
                    continue
                try:
                    msg = json.loads(text)
                except ValueError:  # the text reply to "json on" itself, or a plain line
                    msg = {"ok": not text.startswith("error"), "text": [text]}
                    if text != "ok" and not text.startswith("error"):
                        continue
                if not isinstance(msg, dict):
                    continue
                if "ok" in msg:
                    if self._reply is not None and not self._reply.done():
                        self._reply.set_result(msg)
                elif "notice" in msg:
                    self._notice(str(msg["notice"]))
        except (OSError, ValueError) as exc:
            reason = f"the console session ended: {exc}"
        except asyncio.CancelledError:
            return
        if not self.closed:
            self.closed = True
            self._writer.close()
            if self._reply is not None and not self._reply.done():
                self._reply.set_exception(ConsoleUnavailable(reason))
            self._ended(reason)
