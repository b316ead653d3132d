"""Bounded waits in asyncio that never lose a cancellation.

Python 3.11's ``wait_for`` of asyncio returns the awaited result instead of raising
CancelledError when its task is cancelled in the very loop iteration where the awaited
thing completes (fixed in Python 3.12): the cancellation is lost. A loop around such a
wait (a watch, a publisher, a connection's reader) then runs on after its task group or
``asyncio.run`` cancelled it once, and they wait for it forever: the process does not end
on SIGTERM. Every bounded wait of the side processes goes through ``within``
(``asyncio.timeout``: a cancellation from outside always propagates), and a library that
takes its own timeout (aiomqtt, which uses ``wait_for``) is given ``NO_TIMEOUT`` and
bounded by ``within`` around it. ``tests/test_architecture.py`` refuses ``wait_for`` of
asyncio anywhere in ``runtime/``.

And should a task still never end, ``run_until_signal`` (the event loop of every side
process) ends the process a bounded time after its stop signal, with every thread's
stack in its log: a side process always ends on SIGTERM.
"""

from __future__ import annotations

import asyncio
import faulthandler
import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Awaitable, Callable
from types import FrameType
from typing import TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")

#: what a library that bounds a wait itself is given: no bound of its own (``within``
#: bounds it)
NO_TIMEOUT = math.inf


async def within(aw: Awaitable[T], seconds: float | None) -> T:
    """``await aw``, TimeoutError after ``seconds`` (None: no bound). A cancellation of
    the calling task always raises CancelledError, whatever ``aw`` did meanwhile."""
    if seconds is None:
        return await aw
    async with asyncio.timeout(seconds):
        return await aw


#: a side process not ended this long after its first stop signal says so in one line,
#: writes every thread's stack to its log and exits with status 1, seconds: before the
#: units' TimeoutStopSec (10 s) would kill it without a word
STOP_BOUND_S = 8.0

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)


def run_until_signal(serve: Callable[[asyncio.Event], Awaitable[None]],
                     bound_s: float = STOP_BOUND_S) -> None:
    """``serve(stop)`` in an event loop until SIGTERM, SIGINT or SIGHUP sets ``stop``;
    the process then ends within ``bound_s`` seconds whatever its tasks do.

    The handler is Python's own (``signal.signal``), not the loop's: it runs even while
    the loop is stuck in a Python loop, and arms the bound before it hands the stop to
    the loop."""
    stopping: list[str] = []

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()

        def on_signal(signum: int, _frame: FrameType | None) -> None:
            if not stopping:
                stopping.append(signal.Signals(signum).name)
                _arm(bound_s, stopping[0])
            loop.call_soon_threadsafe(stop.set)

        for s in STOP_SIGNALS:
            signal.signal(s, on_signal)
        await serve(stop)

    asyncio.run(main())


def _arm(bound_s: float, why: str) -> None:
    """The bound on stopping: a daemon thread that ends the process after ``bound_s``
    (one line, every thread's stack, status 1), and faulthandler's own watchdog a
    second later should even that thread not get to run."""

    def bail() -> None:
        log.error("not stopped %g s after %s: every thread's stack follows; exiting",
                  bound_s, why)
        for h in logging.getLogger().handlers:
            h.flush()
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        os._exit(1)

    t = threading.Timer(bound_s, bail)
    t.daemon = True
    t.name = "stop-bound"
    t.start()
    faulthandler.dump_traceback_later(bound_s + 1.0, exit=True, file=sys.stderr)
