"""``softplc monitor`` when the controller goes away: a real controller process
(``softplc run --sim``) killed and started again under a monitor running in a pty."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from runtime import cli
from runtime.console import server
from runtime.console.client import RETRY_MAX_S, Connection, ConsoleClient
from runtime.console.links import REQUEST_TIMEOUT_S, Target, open_link
from runtime.console.monitor import MIN_REFRESH_S, Monitor
from runtime.console.protocol import HELP
from runtime.console.view import View, fold
from tests.console.consolekit import DEADLINE_S, ROOT, NullModem, Rig, plant_yaml, wait_for
from tests.console.test_monitor import Pty

#: a controller process takes a second or two to start on a loaded machine: a failure
#: deadline, never a speed assertion
START_S = 30.0


class Controller:
    """``softplc run PLANT --sim`` with its console on a Unix socket, started and killed
    at will (each start a new process on the same socket path)."""

    def __init__(self, serial_port: str | None = None) -> None:
        self.tmp = tempfile.mkdtemp(prefix="mr", dir="/tmp")  # socket paths <= 107
        self.sock = os.path.join(self.tmp, "c.sock")
        self.plant = Path(self.tmp) / "plant.yaml"
        self.plant.write_text(plant_yaml(serial_port, self.sock), encoding="utf-8")
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        env.pop("NOTIFY_SOCKET", None)
        self.proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run",
                                      str(self.plant), "--sim"], cwd=self.tmp, env=env,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_for(self.answers, "the controller's console", START_S)

    def answers(self) -> bool:
        with socket.socket(socket.AF_UNIX) as s:
            try:
                s.connect(self.sock)
            except OSError:
                return False
        return True

    def kill(self, sig: int = signal.SIGKILL) -> None:
        assert self.proc is not None
        self.proc.send_signal(sig)
        self.proc.wait(timeout=START_S)
        self.proc = None

    def close(self) -> None:
        if self.proc is not None:
            self.kill()


@pytest.fixture
def controller() -> Iterator[Controller]:
    c = Controller()
    c.start()
    yield c
    c.close()


def monitor(target: str) -> Pty:
    return Pty([sys.executable, "-m", "runtime.cli", "monitor", target, "--interval", "0.1"])


def running(s: str) -> bool:
    """The whole view is on the screen: the state, both instances and the prompt."""
    lines = s.splitlines()
    return "state RUNNING" in s and "t2  gsParado" in s and any(
        x.startswith(">") for x in lines[-1:])


def test_monitor_survives_a_kill_and_a_restart_of_the_controller(
        controller: Controller) -> None:
    term = monitor(controller.sock)
    try:
        term.expect(running, "the running controller")
        controller.kill()
        screen = term.expect(lambda s: "connection lost" in s, "that the connection was lost")
        assert term.proc.poll() is None, "the monitor ended with the controller"
        assert "Traceback" not in screen
        controller.start()
        screen = term.expect(lambda s: "controller restarted" in s and running(s)
                             and "connection lost" not in s.splitlines()[0],
                             "the controller again, and that it restarted")
        assert "Traceback" not in screen
        # and once more, stopped in order this time (SIGTERM removes the socket)
        controller.kill(signal.SIGTERM)
        term.expect(lambda s: "connection lost" in s.splitlines()[0], "the second loss")
        controller.start()
        term.expect(lambda s: s.count("controller restarted") == 2 and running(s),
                    "the second restart")
        term.type("q\r")
        assert term.proc.wait(timeout=DEADLINE_S) == 0
    finally:
        term.close()


def test_monitor_on_a_serial_line_survives_a_restart_of_the_controller() -> None:
    """On a serial line nothing breaks when the controller dies: its silence does (no
    reply within REQUEST_TIMEOUT_S), and the new controller's session is in text mode
    until the monitor takes it over again."""
    modem = NullModem()
    controller = Controller(modem.daemon_port)
    term: Pty | None = None
    try:
        controller.start()
        term = Pty([sys.executable, "-m", "runtime.cli", "monitor", modem.peer_port,
                    "--interval", "0.2"])
        term.expect(running, "the running controller")
        controller.kill()
        term.expect(lambda s: "connection lost" in s.splitlines()[0] and "connection lost: "
                    "no reply to 'status' within 5 s" in s, "that the connection was lost, "
                    "and why", REQUEST_TIMEOUT_S + DEADLINE_S)
        controller.start()
        term.expect(lambda s: "controller restarted" in s and running(s),
                    "the controller again, and that it restarted", RETRY_MAX_S + DEADLINE_S)
        term.type("q\r")
        assert term.proc.wait(timeout=DEADLINE_S) == 0
        assert "Traceback" not in term.screen.text()
    finally:
        if term is not None:
            term.close()
        controller.close()
        modem.close()


@pytest.mark.parametrize("key", ["q", "\x03"], ids=["q", "ctrl-c"])
def test_monitor_quits_while_waiting_for_the_controller(controller: Controller,
                                                        key: str) -> None:
    term = monitor(controller.sock)
    try:
        term.expect(running, "the running controller")
        controller.kill()
        term.expect(lambda s: "connection lost" in s, "that the connection was lost")
        term.type(key)  # a single key: nothing can be typed to a controller that is gone
        assert term.proc.wait(timeout=DEADLINE_S) == 0
        assert "Traceback" not in term.screen.text()
    finally:
        term.close()


# -- reconnection without a terminal ----------------------------------------------------
class VirtualClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_connection_retries_with_back_off_until_the_socket_is_back(rig: Rig,
                                                                   tmp_path: Path) -> None:
    assert rig.socket_path is not None
    path = str(tmp_path / "c.sock")
    os.symlink(rig.socket_path, path)  # connect() follows it to the rig's socket
    clock = VirtualClock()
    conn = Connection(Target.parse(path), clock=clock)
    first = conn.connect()
    assert first.request("status")["ok"]
    os.unlink(path)  # the controller is gone: its socket with it
    conn.lost("the controller closed the connection")
    assert conn.client is None
    tries = []
    for _ in range(200):  # 20 s of virtual time in steps of 0.1 s
        before = conn.attempts
        assert conn.retry() is None
        if conn.attempts != before:
            tries.append(round(clock.now - 1000.0, 1))
        clock.now += 0.1
    # 0.5 s after the loss, then doubling up to RETRY_MAX_S
    assert tries == [0.5, 1.5, 3.5, 7.5, 12.5, 17.5]
    assert "No such file or directory" in conn.reason
    os.symlink(rig.socket_path, path)
    clock.now += RETRY_MAX_S
    client = conn.retry()
    assert client is not None and client.request("status")["ok"]
    assert conn.attempts == 0 and conn.client is client
    conn.close()


def ticking(mon: Monitor, cond: Callable[[], bool], what: str) -> None:
    """Run the monitor's rounds, as its screen does, until ``cond``."""
    def tick_then() -> bool:
        mon.tick()
        return cond()

    wait_for(tick_then, what, DEADLINE_S + 2.0)


def test_an_idle_connection_closed_by_the_console_is_opened_again(
        rigs: Callable[..., Rig], monkeypatch: pytest.MonkeyPatch) -> None:
    """A watch sends nothing: an untrusted session is closed after IDLE_TIMEOUT_S. The
    monitor says so, connects again, and does not take it for a restart."""
    rig = rigs(trusted=False, serial_port=False)
    assert rig.socket_path is not None
    monkeypatch.setattr(server, "IDLE_TIMEOUT_S", 1.0)
    view = View(target=rig.socket_path)
    mon = Monitor(Target.parse(rig.socket_path), view, refresh_s=0.1)
    mon.connect()
    try:
        ticking(mon, lambda: "t1" in view.status.get("steps", {}), "a view")
        assert mon.enter("watch t1.iMarcha")
        assert mon.streaming
        ticking(mon, lambda: any("connection lost" in x for x in view.log),
                "the idle connection closed")
        lost = next(x for x in view.log if "connection lost" in x)
        assert lost.endswith("the controller closed the connection (error idle timeout (1 s "
                             "without input, not unlocked))"), lost
        assert not mon.streaming
        ticking(mon, lambda: mon.connection.client is not None and view.offline is None,
                "the monitor connected again")
        done = view.refreshes
        ticking(mon, lambda: view.refreshes >= done + 3, "refreshes again")
        assert not any("restarted" in x for x in view.log)
    finally:
        mon.close()


# -- what the screen shows ----------------------------------------------------------------
def test_view_lines_wrap_instead_of_being_cut(rig: Rig) -> None:
    assert rig.socket_path is not None
    reason = "rio: no answer from the remote I/O module at address 17 on /dev/ttyAMA0 " \
             "after 3 retries"
    rig.driver.broken = reason
    wait_for(lambda: rig.state() == "fault", "the fault")
    client = ConsoleClient(open_link(rig.socket_path))
    client.start()
    try:
        view = View(target=rig.socket_path)
        view.refresh(client)
        lines = view.lines(60)
        assert all(len(x) <= 60 for x in lines), lines
        text = " ".join(x.strip() for x in lines)
        assert f"state FAULT (driver rio: {reason})" in text
        assert f"driver rio: {reason}" in text.split("fault ", 2)[-1]
    finally:
        client.close()


def test_long_reply_lines_wrap_on_the_screen(rig: Rig) -> None:
    assert rig.socket_path is not None
    term = monitor(rig.socket_path)
    try:
        term.expect(running, "the view")
        term.type("help get\r")  # a reply line of 139 characters, on a screen of 100
        whole = f"get      {HELP['get']}"
        assert len(whole) > 100
        screen = term.expect(lambda s: "all its signals" in s, "the end of the long reply")
        rows = screen.splitlines()
        start = next(i for i, x in enumerate(rows) if x.startswith("get      get NAME"))
        assert " ".join(x.strip() for x in rows[start:start + 2]) == whole
        term.type("quit\r")
        assert term.proc.wait(timeout=DEADLINE_S) == 0
    finally:
        term.close()


def test_monitor_expands_runtime_dir(rig: Rig, monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert rig.socket_path is not None
    monkeypatch.setenv("RUNTIME_DIRECTORY", rig.tmp)  # what ${RUNTIME_DIR} stands for
    assert cli.main(["monitor", "${RUNTIME_DIR}/c.sock", "--once"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"softplc monitor {rig.socket_path}   state RUNNING")
    assert cli.main(["monitor", "${RUN_DIR}/c.sock", "--once"]) == 2
    assert capsys.readouterr().err == (
        "softplc monitor: error: unknown placeholder in '${RUN_DIR}/c.sock': the only one "
        "is ${RUNTIME_DIR}\n")


def test_monitor_finds_the_console_of_a_plant_file(
        rig: Rig, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``${RUNTIME_DIR}`` is each plant's own directory (docs/daemon.md): without systemd's
    ``$RUNTIME_DIRECTORY`` the monitor cannot know which plant's, and says to name the plant
    file, which finds the console as every process of the plant does."""
    assert rig.socket_path is not None
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    assert cli.main(["monitor", f"{rig.tmp}/plant.yaml", "--once"]) == 0
    assert capsys.readouterr().out.startswith(
        f"softplc monitor {rig.socket_path}   state RUNNING")
    assert cli.main(["monitor", "${RUNTIME_DIR}/c.sock", "--once"]) == 2
    assert capsys.readouterr().err == (
        "softplc monitor: error: ${RUNTIME_DIR} is each plant's own directory: name the "
        "plant file instead (it finds the plant's console), or the socket's path as the "
        "controller printed it\n")


def test_monitor_refuses_to_refresh_faster_than_the_console_allows(
        rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    """Three lines a refresh: at 0.05 s that is 60 lines/s, over the console's 50."""
    assert rig.socket_path is not None
    assert cli.main(["monitor", rig.socket_path, "--interval", "0.05"]) == 2
    assert capsys.readouterr().err == ("softplc monitor: error: --interval 0.05 is under "
                                       "0.1 s (the console runs at most 50 lines/s)\n")
    assert 3 / MIN_REFRESH_S < server.LINES_PER_S


def test_fold_breaks_at_spaces_and_cuts_words_longer_than_a_row() -> None:
    assert fold("short", 20) == ["short"]
    assert fold("x" * 20, 20) == ["x" * 20]
    assert fold("alpha beta gamma delta epsilon", 20) == ["alpha beta gamma", "  delta epsilon"]
    assert fold("a" * 45, 20) == ["a" * 20, "  " + "a" * 18, "  " + "a" * 7]
    # a space early in the row: the row is filled rather than broken there
    assert fold("ab " + "c" * 30, 20) == ["ab " + "c" * 17, "  " + "c" * 13]
