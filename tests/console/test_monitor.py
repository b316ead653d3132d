"""``softplc monitor``: its link, its JSON client and its view against a real daemon, and
the curses screen in a pseudo-terminal."""

from __future__ import annotations

import fcntl
import os
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from runtime import cli
from runtime.console.client import ConsoleClient
from runtime.console.links import MonitorError, SerialLink, SocketLink, open_link
from runtime.console.server import ConsoleServer
from runtime.console.view import View
from runtime.language.model import ConsoleEntry
from tests.console.consolekit import DEADLINE_S, ROOT, Rig, TermScreen, wait_for


@pytest.fixture
def client(rig: Rig) -> Iterator[ConsoleClient]:
    assert rig.socket_path is not None
    c = ConsoleClient(open_link(rig.socket_path))
    c.start()
    yield c
    c.close()


def test_open_link_picks_socket_tcp_or_serial(rig: Rig, tmp_path: Path) -> None:
    assert rig.socket_path is not None and rig.modem is not None
    link = open_link(rig.socket_path)
    assert isinstance(link, SocketLink)
    link.close()
    tcp = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    tcp.start()
    try:
        link = open_link(tcp.addresses[0])
        assert isinstance(link, SocketLink)
        c = ConsoleClient(link)
        c.start()
        assert c.request("status")["state"] == "running"
        c.close()
    finally:
        tcp.stop()
    rig.serial().close()  # the daemon's serial session is up
    link = open_link(rig.modem.peer_port)
    assert isinstance(link, SerialLink)
    link.close()
    with pytest.raises(MonitorError, match="no such socket or serial port"):
        open_link(str(tmp_path / "nothing"))
    with pytest.raises(MonitorError, match="cannot connect to 127.0.0.1:1"):
        open_link("127.0.0.1:1")
    (tmp_path / "file").write_text("not a tty")
    with pytest.raises(MonitorError, match="cannot open serial port"):
        open_link(str(tmp_path / "file"))


def test_client_requests_and_streams(rig: Rig, client: ConsoleClient) -> None:
    st = client.request("status")
    assert st["ok"] and st["steps"] == {"t1": ["gsParado"], "t2": ["gsParado"]}
    bad = client.request("frobnicate")
    assert bad == {"ok": False, "error": "unknown command 'frobnicate' (try help)"}
    assert client.request("watch rio.I1")["ok"]
    rig.set_input("I1", 1)
    seen: list[dict[str, object]] = []

    def watched() -> bool:
        seen.extend(client.poll_streams(0.1))
        return any(o.get("watch") == {"rio.I1": 1} for o in seen)

    wait_for(watched, "the watch object")
    assert seen[0] == {"watch": {"rio.I1": 0}, "logical": {"t1.iMarcha": 0}}
    client.send_line("")  # stops the stream, no reply
    assert client.request("status")["steps"]["t1"] == ["gsAbrir"]


def test_client_takes_over_a_serial_line_and_gives_it_back(rig: Rig) -> None:
    assert rig.modem is not None
    person = rig.serial()
    person.send(b"force t1.iMarcha 1")  # half a line, then the person leaves picocom
    wait_for(lambda: any(s._buf for s in rig.server.sessions), "the half line")
    person.close()
    client = ConsoleClient(open_link(rig.modem.peer_port))
    client.start()  # Ctrl-C drops the half line before 'json on'
    assert client.request("get t1.iMarcha")["values"] == {"t1.iMarcha": 0}
    assert not rig.plant.forced
    client.close()
    again = rig.serial()
    assert again.cmd("status")[0] == "state running"  # text mode again


def test_view_shows_steps_io_forced_marks_stats_and_faults(rig: Rig,
                                                           client: ConsoleClient) -> None:
    view = View(target="bench")
    view.refresh(client)
    text = "\n".join(view.lines(100))
    assert text.splitlines()[0] == "softplc monitor bench   state RUNNING"
    # (the layout is checked: a loaded machine may make a scan overrun meanwhile)
    assert re.search(r"^cycle 10 ms   scans \d+   uptime \d+\.\d s   overruns \d+$", text,
                     re.M)
    assert re.search(r"^lateness us  last \d+  mean \d+  p99 \d+  max \d+$", text, re.M)
    assert "drivers  rio ok" in text
    assert "t1  gsParado" in text and "t2  gsParado" in text
    assert re.search(r"^  in  iParo=0 +iMarcha=0 +iAbierto=0 +iCerrado=0$", text, re.M)
    assert re.search(r"^  out oAbrir=0 +oCerrar=0 +oParado=1 +oTest=0$", text, re.M)
    assert "forced   -" in text
    view.command(client, "force t1.iMarcha 1")
    assert list(view.log)[-3:] == ["> force t1.iMarcha 1", "t1.iMarcha forced to 1", "ok"]
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 started by the force")
    view.refresh(client)
    text = "\n".join(view.lines(100))
    assert "t1  gsAbrir" in text and "iMarcha=1*" in text and "iParo=0 " in text
    assert "forced   t1.iMarcha=1" in text
    view.command(client, "pause")
    view.command(client, "nope")
    assert view.log[-1] == "error unknown command 'nope' (try help)"
    rig.driver.broken = "rio: no answer"
    wait_for(lambda: rig.state() == "fault", "the fault")
    view.refresh(client)
    text = "\n".join(view.lines(100))
    assert "state FAULT (driver rio: rio: no answer)" in text
    assert re.search(r"^fault \d\d:\d\d:\d\d driver rio: rio: no answer$", text, re.M)


def test_a_long_cycle_typed_at_the_monitor_does_not_lose_the_connection(
        rig: Rig, client: ConsoleClient) -> None:
    """``cycle 600`` (6 s at 10 ms) typed at the prompt: the monitor waits for its reply
    as long as the console waits for the scans. Before, it gave the reply up after 5 s,
    called the connection lost and connected again: the session that stepped ended, and
    the controller halted."""
    view = View(target="bench")
    view.refresh(client)
    view.command(client, "pause")
    reply = view.command(client, "cycle 600")
    assert reply["ok"] and reply["scans"] == 600, reply
    assert rig.state() == "paused"


def test_monitor_once_from_the_command_line(rig: Rig, capsys: pytest.CaptureFixture[str]
                                            ) -> None:
    assert rig.socket_path is not None
    assert cli.main(["monitor", rig.socket_path, "--once"]) == 0
    out = capsys.readouterr().out
    assert "state RUNNING" in out and "t1  gsParado" in out
    assert cli.main(["monitor", "/nonexistent/console.sock", "--once"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("softplc monitor: error: /nonexistent/console.sock: no such socket "
                          "or serial port (or HOST:PORT for TCP); a controller started by "
                          "hand makes its console socket in ${RUNTIME_DIR}, its plant's own "
                          "directory under "), err
    assert err.count("\n") == 1, err


def _take_terminal() -> None:
    """In the child, before exec: the pty becomes its controlling terminal, and the
    signals a terminal sends get their default actions, as a terminal emulator starts
    its program. A suite launched in the background by a script (``.ci/run &``) ignores
    SIGINT and SIGQUIT, every child inherits that, and Ctrl-C typed to the monitor was
    then a signal ignored: nothing happened."""
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)
    for sig in (signal.SIGINT, signal.SIGQUIT, signal.SIGTSTP):
        signal.signal(sig, signal.SIG_DFL)


class Pty:
    """A program run in a pseudo-terminal of 100x30, its screen kept by TermScreen."""

    def __init__(self, argv: list[str]) -> None:
        self.master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
        env = {**os.environ, "TERM": "xterm", "PYTHONPATH": str(ROOT)}
        # its own session with the pty as controlling terminal, as in a terminal emulator:
        # Ctrl-C typed there is a SIGINT
        self.proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, env=env,
                                     start_new_session=True, close_fds=True,
                                     preexec_fn=_take_terminal)
        os.close(slave)
        self.screen = TermScreen(30, 100)

    def expect(self, pred: Callable[[str], bool], what: str,
               timeout: float = DEADLINE_S) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            ready, _, _ = select.select([self.master], [], [], 0.1)
            if ready:
                try:
                    self.screen.feed(os.read(self.master, 65536))
                except OSError:
                    break
                if pred(self.screen.text()):
                    return self.screen.text()
        raise AssertionError(f"the screen never showed {what}:\n{self.screen.text()}")

    def type(self, text: str) -> None:
        os.write(self.master, text.encode())

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        os.close(self.master)


def test_the_screen_in_a_terminal(rig: Rig) -> None:
    assert rig.socket_path is not None
    term = Pty([sys.executable, "-m", "runtime.cli", "monitor", rig.socket_path,
                "--interval", "0.1"])
    try:
        # a screen is drawn in several writes: wait until the whole of it is there
        screen = term.expect(lambda s: "t2  gsParado" in s and "state RUNNING" in s
                             and s.splitlines()[-1:] == [">"], "the steps, I/O and prompt")
        assert "t1  gsParado" in screen
        assert re.search(r"^  in  iParo=0 +iMarcha=0 +iAbierto=0 +iCerrado=0$", screen, re.M)
        assert screen.splitlines()[-1] == ">"  # the prompt on the last line
        rig.set_input("I1", 1)
        term.expect(lambda s: "t1  gsAbrir" in s, "the step change")
        term.type("pause\r")
        wait_for(lambda: rig.state() == "paused", "paused from the monitor's prompt")
        term.expect(lambda s: "state PAUSED" in s and "> pause" in s and "paused: charts "
                    "hold" in s, "the command, its reply and the state")
        term.type("force t2.iMarcha 1\r")
        screen = term.expect(lambda s: "forced   t2.iMarcha=1" in s, "the forced value")
        assert "iMarcha=1*" in screen
        term.type("quit\r")
        assert term.proc.wait(timeout=DEADLINE_S) == 0
    finally:
        term.close()


def test_the_screen_without_a_terminal_is_one_line(rig: Rig) -> None:
    """No terminal (a pipe, a service, a script): one line pointing at --once, where curses
    ended in a traceback."""
    assert rig.socket_path is not None
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "monitor", rig.socket_path],
                       stdin=subprocess.DEVNULL, capture_output=True, text=True,
                       timeout=DEADLINE_S, cwd=ROOT, check=False)
    assert (r.returncode, r.stderr) == (2, "softplc monitor: error: not a terminal (a screen "
                                           "needs one): use --once\n"), r.stderr
    # a terminal curses does not know: one line too
    master, slave = os.openpty()
    try:
        p = subprocess.Popen([sys.executable, "-m", "runtime.cli", "monitor", rig.socket_path],
                             stdin=slave, stdout=slave, stderr=subprocess.PIPE, text=True,
                             cwd=ROOT, env={**os.environ, "TERM": "nosuchterm"})
        os.close(slave)
        _, err = p.communicate(timeout=DEADLINE_S)
    finally:
        os.close(master)
    assert p.returncode == 1 and "Traceback" not in err, err
    assert err.startswith("softplc monitor: error: the terminal cannot show the screen ("), err
    assert err.endswith("): use --once\n") and err.count("\n") == 1, err


def test_a_socket_not_found_is_looked_for_in_the_runtime_directory(tmp_path: Path) -> None:
    """``softplc monitor tank.sock`` in another directory: the controller made it in its
    plant's ${RUNTIME_DIR} (a directory of its own under $XDG_RUNTIME_DIR/softplc); the
    error says where that is, and names the socket found there."""
    import socket

    rdir = tmp_path / "xdg" / "softplc"
    (rdir / "tank-0123abcd").mkdir(parents=True)
    env = {**os.environ, "XDG_RUNTIME_DIR": str(tmp_path / "xdg"), "PYTHONPATH": str(ROOT)}
    env.pop("RUNTIME_DIRECTORY", None)

    def monitor(target: str) -> str:
        r = subprocess.run([sys.executable, "-m", "runtime.cli", "monitor", target, "--once"],
                           capture_output=True, text=True, timeout=DEADLINE_S, env=env,
                           cwd=tmp_path, check=False)
        assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
        return r.stderr
    said = monitor("tank.sock")
    where = (f"a controller started by hand makes its console socket in ${{RUNTIME_DIR}}, "
             f"its plant's own directory under {rdir} (its log says 'console listening on "
             f"PATH'; or name the plant file)")
    assert said == (f"softplc monitor: error: tank.sock: no such socket or serial port (or "
                    f"HOST:PORT for TCP); {where}: no socket there now\n"), said
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(rdir / "tank-0123abcd" / "tank.sock"))
        said = monitor("tank.sock")
        assert said.endswith(f"{where}: did you mean {rdir}/tank-0123abcd/tank.sock?\n"), said
        said = monitor("press.sock")
    assert said.endswith(f"{where}: sockets there: tank-0123abcd/tank.sock\n"), said
