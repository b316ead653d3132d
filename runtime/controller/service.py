"""The controller in the foreground: ``serve`` runs a ``Daemon`` until a stop signal."""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from types import FrameType

from runtime.controller.daemon import Daemon

log = logging.getLogger(__name__)

#: signals that stop the controller in order (safe state, retained data saved)
STOP_SIGNALS = (signal.SIGHUP, signal.SIGINT, signal.SIGTERM, signal.SIGQUIT)


def serve(daemon: Daemon, for_ns: int | None = None,
          started: Callable[[], None] | None = None,
          stopping: Callable[[], None] | None = None) -> int:
    """Run ``daemon`` in the foreground until a stop signal (or ``for_ns``).

    SIGHUP, SIGINT, SIGTERM and SIGQUIT each stop the controller in order (every output
    off, retained data saved, one line naming the signal); a SIGHUP that was ignored when
    the process started (``nohup``) stays ignored. SIGPIPE stays ignored, as Python sets
    it: a client or reader gone is an ``EPIPE`` error where it was written to.

    ``started`` is called once the scan runs and ``stopping`` before the orderly stop:
    the console lives between the two, so it never sees a plant that has not restored
    its retained data nor one whose drivers are closed.

    Returns the exit status: 0 after an orderly stop, 1 if the scan loop itself died
    (systemd's ``Restart=on-failure`` then restarts the service, which comes up in fault
    if a fault was recorded)."""
    stop = threading.Event()
    why = ["end of --for"]

    def on_signal(signum: int, frame: FrameType | None) -> None:
        if not stop.is_set():  # the first signal names the stop; more change nothing
            why[0] = signal.Signals(signum).name
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS
           if not (s is signal.SIGHUP and signal.getsignal(s) is signal.SIG_IGN)}
    status = 0
    try:
        why[0] = "the start failed"  # until the start is complete
        daemon.ready_held = True
        daemon.start()
        if started is not None:
            started()
        daemon.release_ready()
        if why[0] == "the start failed":  # (a signal during the start keeps its name)
            why[0] = "end of --for"
        end = None if for_ns is None else time.monotonic() + for_ns / 1e9
        while not stop.is_set():
            left = 0.5 if end is None else min(0.5, end - time.monotonic())
            if left <= 0:
                break
            stop.wait(left)
            if not daemon.wait(0):
                continue
            why[0], status = "the scan loop ended", 1
            break
    finally:
        if stopping is not None:
            try:
                stopping()
            except Exception:  # noqa: BLE001 - the plant must still stop safely
                log.exception("while stopping")
        daemon.stop(why[0])
        for s, h in old.items():
            signal.signal(s, h)
    return status
