"""Test parts for ``softplc web``: a drawer-tester plant with a ``web:`` section, the
controller and the web view as two real processes, Debian's chromium driven by playwright,
and a console line to press the plant's buttons."""

from __future__ import annotations

import os
import re
import resource
import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from runtime.controller.pin import hash_pin
from runtime.language.runtimedir import runtime_dir
from tests.opcua.feedkit import FeedReader, wait_until

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
#: the flags the browser runs with (never a download, nothing reaching out)
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]
#: the user the acting tests log in as; a cheap hash (the cost is tested with the console's)
USER, PASSWORD = "op", "op-secret"
USER_HASH = hash_pin(PASSWORD, n=16, r=1, p=1)
#: the feed's sample in the tests, ms (5 scans of 10 ms)
SAMPLE_MS = 50


def write_plant(tmp: Path, web: str = "", users: bool = True) -> Path:
    """The drawer tester of configs/ (two instances on sim I/O), a console socket, and a
    ``web:`` section listening on a free port of 127.0.0.1 (port 0). In the directory
    ``tmp/p``: the plant's name is its runtime directory's (``${RUNTIME_DIR}`` is
    ``tmp/softplc/p-HASH``), short enough for its sockets below a test's tmp path."""
    tmp = tmp / "p"
    tmp.mkdir(exist_ok=True)
    shutil.copy(ROOT / "configs/drawer_tester/drawer_tester.yaml", tmp / "drawer_tester.yaml")
    text = (ROOT / "configs/drawer_tester/plant_sim.yaml").read_text(encoding="utf-8")
    text = text[:text.index("\nmonitor:")] + "\n"
    text = text.replace("watchdog: 100ms", "watchdog: 5s").replace(
        "retain: ${RUNTIME_DIR}/drawer_tester_sim.retain.json", "retain: null")
    text += ("monitor:\n  socket: {path: '${RUNTIME_DIR}/console.sock'}\n"
             f"web:\n  listen: 127.0.0.1:0\n  sample: {SAMPLE_MS}ms\n")
    if users:
        text += f"  users: {{{USER}: '{USER_HASH}'}}\n"
    text += web
    plant = tmp / "plant.yaml"
    plant.write_text(text, encoding="utf-8")
    return plant


def rundir_of(tmp: Path, plant: Path) -> Path:
    """``${RUNTIME_DIR}`` of ``plant`` run with the environment of ``start`` (``_env``)."""
    return Path(runtime_dir({"XDG_RUNTIME_DIR": str(tmp)}, plant=str(plant)))


def _env(tmp: Path) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(tmp)}
    env.pop("JOURNAL_STREAM", None)
    return env


@dataclass
class Proc:
    """A softplc process whose stderr is kept line by line."""

    popen: subprocess.Popen[str]
    lines: list[str] = field(default_factory=list)

    def follow(self) -> None:
        assert self.popen.stderr is not None
        for line in self.popen.stderr:
            self.lines.append(line.rstrip("\n"))

    def log(self) -> str:
        return "\n".join(self.lines)


def start(tmp: Path, *args: str, nofile: int | None = None, nice: int = 0) -> Proc:
    """``softplc ARGS`` in ``tmp``; ``nofile``: its open-file limit (RLIMIT_NOFILE), as a
    unit's ``LimitNOFILE=`` sets it; ``nice``: its nice level (``Nice=``)."""
    def limit() -> None:
        if nofile is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))
        if nice:
            os.nice(nice)
    p = subprocess.Popen([sys.executable, "-m", "runtime.cli", *args], cwd=str(tmp),
                         env=_env(tmp), text=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, preexec_fn=limit)
    proc = Proc(p)
    threading.Thread(target=proc.follow, daemon=True).start()
    return proc


def stop(*procs: Proc | None) -> None:
    for p in procs:
        if p is not None and p.popen.poll() is None:
            p.popen.send_signal(signal.SIGTERM)
    for p in procs:
        if p is not None:
            try:
                p.popen.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.popen.kill()
                p.popen.wait()


@dataclass
class Rig:
    """The controller and its web view, running."""

    tmp: Path
    plant: Path
    ctl: Proc
    web: Proc
    url: str
    feed: FeedReader

    @property
    def rundir(self) -> Path:
        """The plant's ``${RUNTIME_DIR}`` (its own, below the test's XDG_RUNTIME_DIR)."""
        return rundir_of(self.tmp, self.plant)

    def console(self, *lines: str, act: bool = True) -> list[str]:
        """The lines on a fresh console session of the plant's socket, first acting for
        the test (``web``: the test runs as the controller's user) unless ``act`` is
        False; the replies' text."""
        out = []
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.connect(str(self.rundir / "console.sock"))
            f = s.makefile("rw", encoding="utf-8", newline="\n")
            for line in (("web test local",) if act else ()) + lines:
                f.write(line + "\n")
                f.flush()
                while True:
                    reply = f.readline()
                    assert reply, "the console closed the session"
                    out.append(reply.rstrip("\r\n"))
                    if reply.startswith(("ok", "error")):
                        break
        return out

    def value(self, name: str) -> Any:
        st = self.feed.state
        return st.values[st.index[name]] if st.values else None

    def status(self) -> dict[str, Any]:
        return self.feed.statuses[-1] if self.feed.statuses else {}


def unit_nofile(unit: str = "softplc-web@.service") -> int:
    """The open-file limit of a side process's unit (``LimitNOFILE=`` of systemd/UNIT, the
    web view's by default), else systemd's default soft limit for a service, 1024."""
    text = (ROOT / "systemd" / unit).read_text(encoding="utf-8")
    found = re.search(r"^LimitNOFILE=(\d+)", text, re.M)
    return int(found.group(1)) if found else 1024


@contextmanager
def rig(tmp: Path, web: str = "", users: bool = True,
        nofile: int | None = None) -> Iterator[Rig]:
    """The controller and its web view (its open-file limit ``nofile`` if given)."""
    plant = write_plant(tmp, web, users)
    ctl = start(tmp, "run", str(plant), "--sim")
    webp = None
    feed = None
    try:
        feed_path = rundir_of(tmp, plant) / "feed.sock"
        wait_until(lambda: feed_path.exists() or ctl.popen.poll() is not None, 30.0,
                   "the feed socket")
        assert ctl.popen.poll() is None, ctl.log()
        webp = start(tmp, "web", str(plant), nofile=nofile)
        found: list[str] = []

        def listening() -> bool:
            found[:] = [m.group(1) for ln in webp.lines
                        if (m := re.search(r"is at (https?://\S+/)", ln))]
            return bool(found) or webp.popen.poll() is not None
        wait_until(listening, 30.0, "the web view's address")
        assert found, webp.log()
        # the web view on its feed before the test begins (a test counting the
        # controller's log lines from here must not see the connection's)
        wait_until(lambda: any("connected to the controller's feed" in ln
                               for ln in webp.lines) or webp.popen.poll() is not None,
                   30.0, "the web view's feed")
        feed = FeedReader(str(feed_path))
        wait_until(lambda: bool(feed.frames) and bool(feed.statuses), 30.0, "feed frames")
        yield Rig(tmp, plant, ctl, webp, found[0], feed)
    finally:
        if feed is not None:
            feed.close()
        stop(webp, ctl)


@contextmanager
def browser() -> Iterator[Any]:
    """Debian's chromium under playwright (skipped where it is not installed: scripts/
    test.sh installs it, so CI runs these tests)."""
    if not os.path.exists(CHROMIUM):
        if os.environ.get("CI"):  # scripts/test.sh installs it: in CI it must run
            pytest.fail("chromium is not installed (apt-get install chromium)")
        pytest.skip("chromium is not installed (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()
