"""systemd's notify protocol (sd_notify): READY, WATCHDOG, STATUS, STOPPING.

One AF_UNIX datagram per message to ``$NOTIFY_SOCKET`` (a path, or an abstract name
written ``@name``). Sends never block: a full socket buffer drops the message, which
systemd's watchdog then notices as a missed ping, the safe outcome. Each message is one
``sendto``, so two threads may send (the watchdog thread pings, the scan thread sends
READY and STATUS).
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


class Notifier:
    """Talks to systemd when started by it (``Type=notify``); otherwise does nothing."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        self.address: str | None = env.get("NOTIFY_SOCKET") or None
        #: interval at which WATCHDOG=1 must be sent, ns (half of WatchdogSec), or 0
        self.watchdog_interval_ns = 0
        usec = env.get("WATCHDOG_USEC")
        pid = env.get("WATCHDOG_PID")
        if usec and usec.isdigit() and (not pid or pid == str(os.getpid())):
            self.watchdog_interval_ns = int(usec) * 1000 // 2
        self._sock: socket.socket | None = None
        if self.address:
            addr = self.address
            if addr.startswith("@"):
                addr = "\0" + addr[1:]
            self._target = addr
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.setblocking(False)
        self._failed = False

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def send(self, message: str) -> bool:
        """Send one notification (``"READY=1\\nSTATUS=..."``); True if it left."""
        if self._sock is None:
            return False
        try:
            self._sock.sendto(message.encode(), self._target)
        except OSError as exc:
            if not self._failed:
                log.warning("systemd notification failed: %s", exc)
            self._failed = True
            return False
        self._failed = False
        return True

    def ready(self, status: str = "") -> bool:
        return self.send("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={text.splitlines()[0] if text else ''}")

    def stopping(self, status: str = "") -> bool:
        return self.send("STOPPING=1" + (f"\nSTATUS={status}" if status else ""))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
