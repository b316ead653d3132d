"""Logging for the journal (priority prefixes) and its rate limit; the sd_notify client."""

from __future__ import annotations

import logging
import os
import socket
import sys
from pathlib import Path

import pytest

from runtime.controller.logsetup import JournalFormatter, RateLimit, under_journal
from runtime.controller.notify import Notifier


def record(msg: str, level: int = logging.ERROR, *args: object) -> logging.LogRecord:
    return logging.LogRecord("drivers.base", level, __file__, 1, msg, args, None)


def test_journal_prefixes() -> None:
    f = JournalFormatter("%(name)s: %(message)s")
    assert f.format(record("driver %s: fault: %s", logging.ERROR, "rio", "lost")) == \
        "<3>drivers.base: driver rio: fault: lost"
    assert f.format(record("x", logging.WARNING)).startswith("<4>")
    assert f.format(record("x", logging.INFO)).startswith("<6>")
    assert f.format(record("a\nb", logging.DEBUG)) == "<7>drivers.base: a\n<7>b"


def test_under_journal_matches_the_stream(tmp_path: Path) -> None:
    with open(tmp_path / "log", "w") as stream:
        st = os.fstat(stream.fileno())
        assert under_journal(stream, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"})
        assert not under_journal(stream, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino + 1}"})
        assert not under_journal(stream, {})
    assert not under_journal(sys.stderr, {"JOURNAL_STREAM": "garbage"})


def test_rate_limit_per_template_then_a_summary() -> None:
    now = [0.0]
    rl = RateLimit(burst=3, period_s=10.0, clock=lambda: now[0])
    passed = [rl.filter(record("driver %s: fault: %s", logging.ERROR, "rio", f"try {i}"))
              for i in range(100)]
    assert passed == [True] * 3 + [False] * 97
    assert rl.filter(record("another message"))  # other templates are not limited
    now[0] = 10.5
    r = record("driver %s: fault: %s", logging.ERROR, "rio", "try 100")
    assert rl.filter(r)
    assert r.getMessage() == ("driver rio: fault: try 100 (97 similar messages suppressed "
                              "in the last 10 s)")


def test_notifier_sends_datagrams_to_a_path_and_an_abstract_name(tmp_path: Path) -> None:
    path = str(tmp_path / "notify")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as srv:
        srv.bind(path)
        n = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "3000000",
                      "WATCHDOG_PID": str(os.getpid())})
        assert n.enabled and n.watchdog_interval_ns == 1_500_000_000
        assert n.ready("running")
        assert n.watchdog()
        assert n.status("fault (x)\nsecond line dropped")
        assert n.stopping()
        got = [srv.recv(1024).decode() for _ in range(4)]
        n.close()
    assert got == ["READY=1\nSTATUS=running", "WATCHDOG=1", "STATUS=fault (x)", "STOPPING=1"]
    name = f"softplc-test-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as srv:
        srv.bind("\0" + name)
        n = Notifier({"NOTIFY_SOCKET": "@" + name})
        assert n.send("READY=1")
        assert srv.recv(64) == b"READY=1"
        n.close()


def test_notifier_without_systemd_does_nothing() -> None:
    n = Notifier({})
    assert not n.enabled and not n.ready() and n.watchdog_interval_ns == 0
    # a watchdog meant for another process (WATCHDOG_PID) is not ours
    assert Notifier({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "100",
                     "WATCHDOG_PID": "1"}).watchdog_interval_ns == 0


def test_notifier_survives_a_vanished_socket(tmp_path: Path,
                                              caplog: pytest.LogCaptureFixture) -> None:
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone")})
    assert not n.watchdog()
    assert not n.watchdog()
    assert len([r for r in caplog.records if "notification failed" in r.message]) == 1
    n.close()
