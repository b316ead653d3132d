"""Issue 13 §10: the socat commands docs/console.md gives work with the socat Debian ships.

Each documented command is run as written (the socket path replaced by a real console's) in
a pseudo-terminal, as a user at a shell would: ``status`` typed with a slip erased by
Backspace gets its reply, and the key the docs name for leaving ends the program.
"""

from __future__ import annotations

import os
import pty
import re
import select
import shlex
import shutil
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.console.consolekit import Rig, make_rig

ROOT = Path(__file__).resolve().parents[2]
#: the console socket of an installed plant NAME, as docs/console.md writes it
DOC_SOCKET = "/run/softplc/NAME/console.sock"
#: generous: the machine is shared; every wait ends as soon as its condition holds
DEADLINE_S = 30.0


def documented_commands() -> list[tuple[str, str]]:
    """(command, the key that leaves it) for each socat line of the local-socket block."""
    text = (ROOT / "docs" / "console.md").read_text(encoding="utf-8")
    block = text.split("**A local socket:**", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    out = []
    for line in block.splitlines():
        command, _, comment = line.partition("#")
        key = "Ctrl-]" if "Ctrl-]" in comment else "Ctrl-D"
        out.append((command.strip(), key))
    return out


def test_the_docs_give_no_readline_address() -> None:
    """Debian's socat is built without readline: the docs must not send users there."""
    commands = [c for c, _ in documented_commands()]
    assert commands and all(c.split()[0] in ("socat", "rlwrap") for c in commands)
    assert not any(re.search(r"\bREADLINE\b", c) for c in commands)


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = make_rig(serial_port=False)
    try:
        yield r
    finally:
        r.close()


class Terminal:
    """A program on a pseudo-terminal of 80 x 24, read as bytes."""

    def __init__(self, argv: list[str]) -> None:
        self.pid, self.fd = pty.fork()
        if self.pid == 0:  # pragma: no cover - the child
            try:
                os.execvp(argv[0], argv)
            finally:  # never back into pytest in a forked child
                os._exit(127)
        import fcntl
        import struct
        import termios

        fcntl.ioctl(self.fd, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
        self.seen = b""

    def type(self, data: bytes) -> None:
        os.write(self.fd, data)

    def wait_for(self, pattern: bytes) -> bytes:
        end = time.monotonic() + DEADLINE_S
        while not re.search(pattern, self.seen):
            left = end - time.monotonic()
            assert left > 0, f"timed out waiting for {pattern!r}, seen {self.seen!r}"
            ready, _, _ = select.select([self.fd], [], [], min(left, 0.5))
            if ready:
                try:
                    self.seen += os.read(self.fd, 4096)
                except OSError:  # the program ended
                    break
        return self.seen

    def wait_exit(self) -> int:
        end = time.monotonic() + DEADLINE_S
        while time.monotonic() < end:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                os.close(self.fd)
                return os.waitstatus_to_exitcode(status)
            select.select([self.fd], [], [], 0.1)
            try:
                os.read(self.fd, 4096)
            except OSError:
                pass
        raise AssertionError("the program did not end")

    def kill(self) -> None:
        try:
            os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass


@pytest.mark.parametrize("command, leave", documented_commands())
def test_documented_socat_command_talks_to_the_console(rig: Rig, command: str,
                                                        leave: str) -> None:
    assert DOC_SOCKET in command, f"the documented command names no {DOC_SOCKET}: {command}"
    argv = shlex.split(command.replace(DOC_SOCKET, str(rig.socket_path)))
    missing = [p for p in dict.fromkeys(argv[:2]) if p in ("socat", "rlwrap")
               and shutil.which(p) is None]
    if missing:
        pytest.skip(f"{' '.join(missing)} not installed (apt install {' '.join(missing)})")
    term = Terminal(argv)
    try:
        term.type(b"stx\x7fatus\r")  # a slip erased with Backspace, then Enter
        # the whole status reply, up to its "ok" (its lines depend on the controller's
        # state: a CI run once saw it faulted by a 571 ms CPU starvation, with a fault line
        # after the steps); the Backspace worked if "status" ran, not "stxatus"
        seen = term.wait_for(rb"(?s)state \w+.*?\r\nok\r")
        assert b"unknown command" not in seen and b"\nt2: " in seen
        term.type(b"\x1d" if leave == "Ctrl-]" else b"\x04")
        assert term.wait_exit() == 0
    finally:
        term.kill()
