"""Bad input on the line never stops or slows the scan: a client floods the serial
console (1000 lines/s of commands, 2000-byte lines, binary garbage) while another streams
``trace on`` from a chart that changes every scan; eight TCP clients pipeline ``stats``
(or ``help``) as fast as the replies come. The cycle statistics are compared with a quiet
run of the same daemon (its scan thread SCHED_FIFO where permitted, the default). And
sixteen local clients pipelining ``stats`` at normal priority never block the scan thread
(the time its own process kept it waiting, schedprobe.py).

The clients are separate processes (flooder.py), as a laptop at the other end of the
cable would be. The bounds are generous on purpose (a loaded, shared 2-core VM): at most
one overrun more than the quiet run (none at a 10 ms cycle on an idle machine), every
cycle ran, lateness p99 at most twice the quiet run's or 2.5 ms more. The figures
themselves are measured by bench/console.py."""

from __future__ import annotations

import functools
import json
import random
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from runtime.console.server import ConsoleServer
from runtime.controller.stats import ScanStats
from runtime.language.model import ConsoleEntry
from tests.console import schedprobe
from tests.console.consolekit import Rig
from tests.console.schedprobe import SchedProbe

FLOODER = str(Path(__file__).with_name("flooder.py"))
SECONDS = 3.0


def window(rig: Rig, run: Callable[[], Any]) -> dict[str, Any]:
    """Cycle statistics of the daemon while ``run()`` runs (reset at the start, in the
    scan thread)."""
    stats = rig.daemon.scan_stats
    rig.daemon.call(stats.reset)
    t0 = time.monotonic()
    extra = run()
    elapsed = time.monotonic() - t0
    count, overruns = rig.daemon.call(lambda: (stats.count, stats.overruns))
    late = stats.lateness()
    return {"cycles": count, "expected": elapsed / 0.010, "overruns": overruns,
            "p99_us": late.p99 / 1e3, "max_us": late.max / 1e3, "extra": extra}


@pytest.mark.slow
def test_a_flood_on_the_console_does_not_disturb_the_scan(rigs: Callable[..., Rig]) -> None:
    flooder = subprocess.Popen([sys.executable, FLOODER, "flood", str(SECONDS), "1000"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert flooder.stdout is not None and flooder.stdin is not None
        port = json.loads(flooder.stdout.readline())["port"]
        rig = rigs(serial_path=port, blink=True)
        assert rig.socket_path is not None
        quiet = window(rig, lambda: time.sleep(SECONDS))

        def flood() -> Any:
            assert rig.socket_path is not None
            tracer = subprocess.Popen([sys.executable, FLOODER, "trace", rig.socket_path,
                                       str(SECONDS)], stdout=subprocess.PIPE, text=True)
            flooder.stdin.write("go\n")  # type: ignore[union-attr]
            flooder.stdin.flush()  # type: ignore[union-attr]
            out, _ = flooder.communicate(timeout=60)
            traced, _ = tracer.communicate(timeout=60)
            return json.loads(out), json.loads(traced)
        loud = window(rig, flood)
    finally:
        if flooder.poll() is None:
            flooder.kill()
            flooder.wait()
    sent, traced = loud["extra"]
    msg = f"quiet {quiet}, flooded {loud}"
    # the flood reached the console and was answered, and so was the trace client
    assert sent["rate"] >= 800 and sent["sent_lines"] >= 0.8 * 1000 * SECONDS, msg
    assert sent["errors"] > 1000 and sent["ok"] > 50, msg
    assert sent["answers_after"], msg
    assert traced["trace_lines"] > 0.5 * SECONDS * 100, msg
    # and the scan did not notice
    # A console thread can delay a cycle by the GIL's switch interval (5 ms) at most, never
    # by a whole 10 ms cycle; one late cycle may still come from another job on the shared
    # VM in either window, so one is tolerated, a second is not.
    assert loud["overruns"] <= quiet["overruns"] + 1, msg
    assert loud["cycles"] >= 0.95 * loud["expected"], msg
    assert loud["p99_us"] < max(2 * quiet["p99_us"], quiet["p99_us"] + 2500), msg
    # nothing changed on the machine, and the console still answers
    assert not rig.plant.forced and not rig.plant.forced_points
    assert rig.state() == "running" and rig.steps("t1") == ["gsParado"]
    assert rig.read("t1.sParo") is False and rig.read("t1.sCierres") == 0
    assert rig.connect().cmd("status")[0] == "state running"


class Pipelining:
    """One flooder process per address (at ``nice``), started and connected now, that
    pipeline ``commands`` for ``seconds`` from ``go()``; ``results()`` waits for them and
    returns what each saw."""

    def __init__(self, addresses: list[str], commands: list[str], seconds: float,
                 nice: int = 10) -> None:
        self.seconds = seconds
        self.procs = [subprocess.Popen([sys.executable, FLOODER, "--nice", str(nice),
                                        "pipeline", a, str(seconds), *commands],
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                       text=True)
                      for a in addresses]
        for p in self.procs:
            assert p.stdout is not None and "connected" in json.loads(p.stdout.readline())

    def go(self) -> None:
        for p in self.procs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()

    def results(self) -> list[dict[str, Any]]:
        return [json.loads(p.communicate(timeout=self.seconds + 60)[0])
                for p in self.procs]


def pipelining(addresses: list[str], commands: list[str], seconds: float, nice: int = 10
               ) -> Callable[[], list[dict[str, Any]]]:
    """``Pipelining`` as one function: start them, and return what each saw."""
    clients = Pipelining(addresses, commands, seconds, nice)

    def run() -> list[dict[str, Any]]:
        clients.go()
        return clients.results()
    return run


@pytest.mark.slow
@pytest.mark.parametrize("command", ["stats", "help"])
def test_eight_tcp_clients_pipelining_do_not_starve_the_scan(
        rigs: Callable[..., Rig], command: str) -> None:
    """The attack of issue 12: eight local clients sending ``stats`` (or ``help``), no PIN
    needed, as fast as the replies come. The scan keeps its cycle: no watchdog fault, no
    more overruns than a quiet run, every cycle ran; and every client is answered. The
    garbage collector is run as the daemon runs it (in the scan's idle time): a collection
    triggered by a console thread's allocations would hold the GIL for tens of ms."""
    rig = rigs(serial_port=False, manage_gc=True)
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    server.start()
    try:
        quiet = window(rig, lambda: time.sleep(SECONDS))
        loud = window(rig, pipelining([server.addresses[0]] * 8, [command], SECONDS))
        faults = list(rig.daemon.faults)
    finally:
        server.stop()
    msg = f"quiet {quiet}, flooded {loud}"
    assert not faults and rig.state() == "running", f"{faults}; {msg}"
    for client in loud["extra"]:
        assert not client["closed_by_server"] and client["ok"] > 0, msg
        assert client["replies"] == client["sent"], msg  # throttled lines are answered too
    assert loud["overruns"] <= quiet["overruns"] + 1, msg
    assert loud["cycles"] >= 0.95 * loud["expected"], msg
    assert loud["p99_us"] < max(2 * quiet["p99_us"], quiet["p99_us"] + 2500), msg


@pytest.mark.slow
def test_pipelining_clients_share_the_console_fairly(rigs: Callable[..., Rig]) -> None:
    """Six clients pipelining ``get`` (each reply waits for a scan boundary) get about
    the same share of the console: the one connected last is not starved by the first.
    Found by the 60 s bench of issue 12: the socket thread began every round with the
    first connection, so while the first ones kept it busy the others got 2 replies/s
    against 100 for the first, and 155 lines were still unanswered 10 s after the end."""
    rig = rigs(serial_port=False, manage_gc=True)
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    server.start()
    try:
        seen = pipelining([server.addresses[0]] * 6, ["get t1.iMarcha"], SECONDS)()
    finally:
        server.stop()
    ok = sorted(c["ok"] for c in seen)
    assert all(c["replies"] == c["sent"] for c in seen), seen
    assert ok[0] >= ok[-1] / 2, f"replies per client {ok}: not a fair share"


#: the attack of issue 31 lasts this long
ATTACK_S = 8.0


def fill(stats: ScanStats, samples: list[tuple[int, int]]) -> None:
    """Record ``samples`` (scan time, lateness; ns) as cycles that ran."""
    for scan_ns, late_ns in samples:
        stats.record(scan_ns, late_ns)


@pytest.mark.slow
@pytest.mark.skipif(not schedprobe.available(),
                    reason="the kernel keeps no per-thread scheduler statistics "
                           "(/proc/thread-self/schedstat, CONFIG_SCHED_INFO)")
def test_sixteen_local_clients_pipelining_stats_do_not_block_the_scan(
        rigs: Callable[..., Rig]) -> None:
    """The attack of issue 31: sixteen local clients (8 TCP, 8 Unix socket, at nice 0 as a
    local user's) pipelining ``stats``, the scan thread at normal priority (``realtime:
    false``; the default is SCHED_FIFO), the statistics window full (as after 82 s at 10 ms;
    filled here at once). Before: overruns in every run of the attack, once a watchdog
    fault; here, in 4 runs of 6 s of 4, wake-ups of the scan thread blocked by its own
    process for up to 4.0, 5.4, 6.8 and 18.5 ms (1 to 17 of them over 1 ms): a console
    thread held the GIL across the scan's deadline (a full window's sort in one call; work
    anywhere in the window and on every client's bytes, and a thread the busy machine took
    the processor from while it held the GIL; a window anchored on the end of a late scan).

    What is held to: the time each wake-up of the scan thread was blocked by its own
    process (its lateness less the time it waited for a CPU: schedprobe.py), which is
    the console's doing whatever else loads the machine. None may reach a quarter of the
    cycle (2.5 ms), and the 99th percentile stays under 0.5 ms; with no client at all
    this VM shows up to 1.4 ms (its own hiccups), and after the fix the flood up to
    0.5 ms. Overruns and lateness are the machine's at normal priority (other jobs on a
    shared 2-core VM make them without any client): bench/console.py measures them, and
    the daemon runs the scan thread SCHED_FIFO by default (docs/daemon.md)."""
    probe = SchedProbe()
    rig = rigs(serial_port=False, manage_gc=True, tcp=True, probe=probe, priority=0)
    stats = rig.daemon.scan_stats
    rng = random.Random(31)
    samples = [(rng.randrange(30_000, 90_000), rng.randrange(20_000, 4_000_000))
               for _ in range(stats.window)]
    for start in range(0, len(samples), 512):  # a full window, a slice per scan boundary
        rig.daemon.call(functools.partial(fill, stats, samples[start:start + 512]))
    assert rig.socket_path is not None
    clients = Pipelining([rig.tcp_address] * 8 + [rig.socket_path] * 8, ["stats"],
                         ATTACK_S, nice=0)
    faults = len(rig.daemon.faults)
    clients.go()
    # the flood's middle: its start (16 connections at once) and its end (16 processes
    # exiting) are no attack; the test's own thread sleeps meanwhile (it would hold the
    # GIL of the daemon's process too)
    time.sleep(1.0)
    probe.start()
    time.sleep(ATTACK_S - 2.0)
    wakes = probe.stop()
    seen = clients.results()
    msg = f"{wakes}; clients {seen}"
    assert len(rig.daemon.faults) == faults and rig.state() == "running", msg
    assert sum(c["ok"] for c in seen) > 16 * 10 * ATTACK_S, msg  # the console answered
    assert all(c["replies"] == c["sent"] and not c["closed_by_server"] for c in seen), msg
    assert wakes.count > 0.9 * (ATTACK_S - 2.0) / 0.010, msg
    assert wakes.blocked_max < 2500.0 and wakes.blocked_p99 < 500.0, msg
