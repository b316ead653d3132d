"""Bad input on the line never stops or slows the scan: a client floods the serial
console (1000 lines/s of commands, 2000-byte lines, binary garbage) while another streams
``trace on`` from a chart that changes every scan; eight TCP clients pipeline ``stats``
(or ``help``) as fast as the replies come. The cycle statistics are compared with a quiet
run of the same daemon.

The clients are separate processes (flooder.py), as a laptop at the other end of the
cable would be. The bounds are generous on purpose (a loaded, shared 2-core VM): at most
one overrun more than the quiet run (none at a 10 ms cycle on an idle machine), every
cycle ran, lateness p99 at most twice the quiet run's or 2.5 ms more. The figures
themselves are measured by bench/console.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from runtime.console.server import ConsoleServer
from runtime.language.model import ConsoleEntry
from tests.console.consolekit import Rig

FLOODER = str(Path(__file__).with_name("flooder.py"))
SECONDS = 3.0
#: the scan thread of the pipelining tests runs SCHED_FIFO where the test may (root), as on
#: a controller: the other jobs of a shared test machine then stay out of the figures, and
#: what is left is what the console threads cost (the GIL)
PRIORITY = 50 if os.geteuid() == 0 else None


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


def pipelining(addresses: list[str], commands: list[str], seconds: float
               ) -> Callable[[], list[dict[str, Any]]]:
    """One flooder process per address, started and connected now; the function returned
    has them pipeline ``commands`` for ``seconds`` and returns what each saw."""
    procs = [subprocess.Popen([sys.executable, FLOODER, "pipeline", a, str(seconds),
                               *commands], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
             for a in addresses]
    for p in procs:
        assert p.stdout is not None and "connected" in json.loads(p.stdout.readline())

    def run() -> list[dict[str, Any]]:
        for p in procs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        return [json.loads(p.communicate(timeout=seconds + 60)[0]) for p in procs]
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
    rig = rigs(serial_port=False, manage_gc=True, priority=PRIORITY)
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
    rig = rigs(serial_port=False, manage_gc=True, priority=PRIORITY)
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    server.start()
    try:
        seen = pipelining([server.addresses[0]] * 6, ["get t1.iMarcha"], SECONDS)()
    finally:
        server.stop()
    ok = sorted(c["ok"] for c in seen)
    assert all(c["replies"] == c["sent"] for c in seen), seen
    assert ok[0] >= ok[-1] / 2, f"replies per client {ok}: not a fair share"
