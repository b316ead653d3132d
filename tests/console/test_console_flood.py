"""Bad input on the line never stops or slows the scan: a client floods the serial
console (1000 lines/s of commands, 2000-byte lines, binary garbage) while another streams
``trace on`` from a chart that changes every scan; eight TCP clients pipeline ``stats``
(or ``help``) as fast as the replies come. The cycle statistics are compared with a quiet
run of the same daemon (its scan thread SCHED_FIFO where permitted, the default). And
sixteen local clients pipelining ``stats`` at normal priority never block the scan thread
(the time its own process kept it waiting, schedprobe.py).

The clients are separate processes (flooder.py), as a laptop at the other end of the
cable would be. What is held is what the console does to the scan, whatever else the
machine runs: the wake-ups of the scan thread *blocked* by its own process (the GIL held
by a console thread; schedprobe.py) for more than 1 ms, at most twice those of a control
at the same time, plus 5: a thread paced the same way, at the same priority, in a process
of its own beside a thread that works in short bursts (schedprobe.control's neighbour). On
a loaded machine that neighbour is kept from the processor while it holds the GIL, and
the paced thread waits: at a load of 18 on 2 cores, 60-70 of 1000 wake-ups blocked over
1 ms (none without the neighbour). Overruns and lateness compared with a quiet run before
the flood said as much about the other jobs of a loaded machine as about the console (2
overruns against 0 at a load of 2 to 7: another job's burst in the flooded window). The
figures themselves are measured by bench/console.py."""

from __future__ import annotations

import functools
import json
import random
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from runtime.console.server import ConsoleServer
from runtime.controller.realtime import set_fifo_priority
from runtime.controller.stats import ScanStats
from runtime.language.model import ConsoleEntry
from tests.console import schedprobe
from tests.console.consolekit import Rig
from tests.console.schedprobe import SchedProbe, Wakes, lone_thread

FLOODER = str(Path(__file__).with_name("flooder.py"))
SECONDS = 3.0


needs_schedstat = pytest.mark.skipif(
    not schedprobe.available(), reason="the kernel keeps no per-thread scheduler "
    "statistics (/proc/thread-self/schedstat, CONFIG_SCHED_INFO)")


def fifo_permitted() -> bool:
    """Whether this process may make a thread SCHED_FIFO (tried on a thread of its own)."""
    got: list[bool] = []
    t = threading.Thread(target=lambda: got.append(set_fifo_priority(50)[0]))
    t.start()
    t.join()
    return got[0]


@dataclass
class Probed:
    """What a window of the daemon's scan saw (``wakes``) against a lone thread paced the
    same way at the same time (``machine``), and what ``run()`` returned."""

    wakes: Wakes
    machine: Wakes
    extra: Any

    def console_blocked_the_scan(self) -> bool:
        """The console's own doing: more wake-ups blocked over 1 ms by the daemon's process
        than twice the control's (a paced thread beside a well-behaved busy one: the
        machine's load and its host count there too), plus 5; or more time blocked in all
        than twice the control's, plus 100 ms (a long hold, once)."""
        return (self.wakes.blocked_over_1ms > 2 * self.machine.blocked_over_1ms + 5
                or self.wakes.blocked_ms > 2 * self.machine.blocked_ms + 100)


def probed(rig: Rig, probe: SchedProbe, run: Callable[[], Any], priority: int) -> Probed:
    """The scan thread's wake-ups (``probe``, wrapped in by the rig) while ``run()`` runs,
    and those of a control meanwhile: a thread paced the same way at the scan thread's
    ``priority`` (0: normal), beside a busy neighbour (``schedprobe.lone_thread``)."""
    with lone_thread(10, priority, neighbour="bursts") as lone:
        probe.start()
        try:
            extra = run()
        finally:
            wakes = probe.stop()
    return Probed(wakes, lone[0], extra)


#: the watchdog of the flooded daemons: a fault is the scan blocked this long. What the
#: console does to the scan is held by its blocked wake-ups against a control's; on a
#: loaded machine a thread of the daemon kept from the processor while it held the GIL
#: blocked the scan 348 ms once (its control 58 ms), which a 300 ms watchdog took for a
#: fault: the machine's doing
FLOOD_WATCHDOG = "5s"


def scan_priority() -> int:
    """The scan thread's priority as the rig leaves it: SCHED_FIFO 50 where permitted."""
    return 50 if fifo_permitted() else 0


@pytest.mark.slow
@needs_schedstat
def test_a_flood_on_the_console_does_not_disturb_the_scan(rigs: Callable[..., Rig]) -> None:
    flooder = subprocess.Popen([sys.executable, FLOODER, "flood", str(SECONDS), "1000"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert flooder.stdout is not None and flooder.stdin is not None
        port = json.loads(flooder.stdout.readline())["port"]
        probe = SchedProbe()
        rig = rigs(serial_path=port, blink=True, probe=probe, watchdog=FLOOD_WATCHDOG)
        assert rig.socket_path is not None

        def flood() -> Any:
            assert rig.socket_path is not None
            tracer = subprocess.Popen([sys.executable, FLOODER, "trace", rig.socket_path,
                                       str(SECONDS)], stdout=subprocess.PIPE, text=True)
            flooder.stdin.write("go\n")  # type: ignore[union-attr]
            flooder.stdin.flush()  # type: ignore[union-attr]
            out, _ = flooder.communicate(timeout=60)
            traced, _ = tracer.communicate(timeout=60)
            return json.loads(out), json.loads(traced)
        faults = len(rig.daemon.faults)
        loud = probed(rig, probe, flood, scan_priority())
        faults = len(rig.daemon.faults) - faults
    finally:
        if flooder.poll() is None:
            flooder.kill()
            flooder.wait()
    sent, traced = loud.extra
    msg = f"{loud}"
    # the flood reached the console and was answered, and so was the trace client
    assert sent["rate"] >= 800 and sent["sent_lines"] >= 0.8 * 1000 * SECONDS, msg
    # answered within the console's tenth of a processor (docs/console.md): some 250 lines
    # a second of this garbage on a quiet machine, where all 1000 were before the budget
    assert sent["errors"] > 450 and sent["ok"] > 25, msg
    assert sent["answers_after"], msg
    assert traced["trace_lines"] > 0.5 * SECONDS * 100, msg
    # and the scan did not notice: no fault, and the console never blocked it (a console
    # thread can hold the GIL for its switch interval, 5 ms, at most: a wake-up blocked
    # over 1 ms is rare, and the control sees what the machine adds). Whether every cycle
    # ran is the machine's to say under load (a scan 268 ms late at a load of 13, its
    # control 58 ms): a cycle the console took shows as a blocked wake-up.
    assert faults == 0, msg
    assert not loud.console_blocked_the_scan(), msg
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
@needs_schedstat
@pytest.mark.parametrize("command", ["stats", "help"])
def test_eight_tcp_clients_pipelining_do_not_starve_the_scan(
        rigs: Callable[..., Rig], command: str) -> None:
    """The attack of issue 12: eight local clients sending ``stats`` (or ``help``), no PIN
    needed, as fast as the replies come. The scan keeps its cycle: no watchdog fault, and
    the console never blocks the scan thread (its wake-ups blocked by its own process,
    against a lone thread's at the same time); and every client is answered. The garbage
    collector is run as the daemon runs it (in the scan's idle time): a collection
    triggered by a console thread's allocations would hold the GIL for tens of ms.

    Before (held to overruns and lateness against a quiet run of the same daemon just
    before), a machine loaded by other work failed it: 2 overruns against 0, lateness up
    to 80 ms, all of it the other jobs' doing."""
    probe = SchedProbe()
    rig = rigs(serial_port=False, manage_gc=True, probe=probe, watchdog=FLOOD_WATCHDOG)
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    server.start()
    try:
        faults = len(rig.daemon.faults)
        loud = probed(rig, probe, pipelining([server.addresses[0]] * 8, [command], SECONDS),
                      scan_priority())
        faults = len(rig.daemon.faults) - faults
    finally:
        server.stop()
    msg = f"{loud}"
    assert faults == 0 and rig.state() == "running", msg
    for client in loud.extra:
        assert not client["closed_by_server"] and client["ok"] > 0, msg
        assert client["replies"] == client["sent"], msg  # throttled lines are answered too
    assert not loud.console_blocked_the_scan(), msg


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


#: the part of the attack of issue 31 that is measured, seconds (its first and last second
#: are not: 16 connections at once, 16 processes exiting)
ATTACK_S = 10.0
#: the attack's clients and addresses
ATTACKERS = 16


def fill(stats: ScanStats, samples: list[tuple[int, int]]) -> None:
    """Record ``samples`` (scan time, lateness; ns) as cycles that ran."""
    for scan_ns, late_ns in samples:
        stats.record(scan_ns, late_ns)


@dataclass
class Attack:
    """What the attack of issue 31 did: the daemon's scan thread's wake-ups, those of a
    control at the same time (the machine's share: a paced thread in a process of its own
    beside a busy one, schedprobe.lone_thread), the faults, and what the clients saw."""

    wakes: Wakes
    machine: Wakes
    faults: int
    clients: list[dict[str, Any]]


def attack(rig: Rig, probe: SchedProbe, machine_priority: int) -> Attack:
    """Sixteen local clients (8 TCP, 8 Unix socket, at nice 0 as a local user's)
    pipelining ``stats`` into ``rig``, its statistics window full (as after 82 s at 10 ms;
    filled here at once); ATTACK_S of it measured, with a control paced as the scan
    (SCHED_FIFO ``machine_priority`` if not 0) in a process of its own beside a busy
    thread meanwhile. The test's own thread sleeps meanwhile: it would hold the daemon's
    GIL too."""
    stats = rig.daemon.scan_stats
    rng = random.Random(31)
    samples = [(rng.randrange(30_000, 90_000), rng.randrange(20_000, 4_000_000))
               for _ in range(stats.window)]
    for start in range(0, len(samples), 512):  # a slice per scan boundary
        rig.daemon.call(functools.partial(fill, stats, samples[start:start + 512]))
    assert rig.socket_path is not None
    clients = Pipelining([rig.tcp_address] * (ATTACKERS // 2)
                         + [rig.socket_path] * (ATTACKERS // 2), ["stats"], ATTACK_S + 2.0,
                         nice=0)
    faults = len(rig.daemon.faults)
    clients.go()
    time.sleep(1.0)
    with lone_thread(10, machine_priority, neighbour="bursts") as lone:
        probe.start()
        time.sleep(ATTACK_S)
        wakes = probe.stop()
    machine = lone[0]
    seen = clients.results()
    done = Attack(wakes, machine, len(rig.daemon.faults) - faults, seen)
    assert done.faults == 0 and rig.state() == "running", done
    assert sum(c["ok"] for c in seen) > ATTACKERS * 10 * ATTACK_S, done  # answered
    assert all(c["replies"] == c["sent"] and not c["closed_by_server"] for c in seen), done
    assert wakes.count > 0.8 * machine.count, done  # the cycles the machine let run
    return done


@pytest.mark.slow
@needs_schedstat
@pytest.mark.skipif(not fifo_permitted(), reason="SCHED_FIFO is not permitted here (not "
                    "root, no CAP_SYS_NICE): the default install's property does not apply")
def test_sixteen_local_clients_pipelining_stats_do_not_delay_the_default_install(
        rigs: Callable[..., Rig]) -> None:
    """The attack of issue 31 on the daemon as installed (the scan thread's priority as
    the plant file leaves it: SCHED_FIFO 50 where permitted). Before (the scan thread at
    normal priority, the console as it was): overruns in every run of the attack, once a
    watchdog fault ("frozen for 117 ms"); here, 62, 29 and 177 wake-ups over 2.5 ms
    late in 10 s, against 2, 2 and 2 for a lone SCHED_FIFO thread at the same time.

    Held to: no fault, and no more wake-ups of the scan thread over a quarter of the cycle
    (2.5 ms) late than twice the control's, plus 5. The control, a SCHED_FIFO thread in a
    process of its own beside a thread that works in short bursts, sees what the machine
    does to a real-time thread whose process has busy threads at that moment (the VM's
    host takes its processors away for up to 30 ms at busy times, a few times in 10 s; a
    loaded machine keeps the busy thread from the processor while it holds the GIL), so
    the bound holds on a quiet machine and on a busy one, and only the daemon's own doing
    can break it. After, against a lone thread without the busy one: 8, 3, 6 against 5, 3,
    5 on a quiet machine; at a load of 10, 25 against 0 (the GIL held by a client thread
    the machine had taken the processor from), hence the busy neighbour."""
    probe = SchedProbe()
    rig = rigs(serial_port=False, manage_gc=True, tcp=True, probe=probe,
               watchdog=FLOOD_WATCHDOG)
    done = attack(rig, probe, machine_priority=50)
    assert done.wakes.late <= 2 * done.machine.late + 5, done


@pytest.mark.slow
@needs_schedstat
def test_sixteen_local_clients_pipelining_stats_do_not_block_the_scan(
        rigs: Callable[..., Rig]) -> None:
    """The same attack, the scan thread at normal priority (``realtime: false``): its
    lateness is then the machine's (it waits for a processor behind every other process,
    the clients' included), but the console must still not *block* it. Held to: the
    wake-ups of the scan thread blocked by its own process (lateness less the time it
    ran or waited for a processor: the GIL, held by a console thread; schedprobe.py) for
    more than 1 ms, at most twice those of a control at normal priority at the same
    time (a paced thread beside a busy one: the VM's host and the machine's load count
    there too), plus 5; and its wake-ups at least 80 % of the control's.

    Before, on a quiet host: 1, 8, 12 and 17 such wake-ups in 6 s, up to 4.0, 5.4, 6.8
    and 18.5 ms (a full window's sort in one call; work anywhere in the window and on
    every client's bytes; a console thread the busy machine took the processor from while
    it held the GIL; a window anchored on the end of a late scan); after, none over
    0.5 ms. On a busy host the lone thread sees as many (3 to 7 in 10 s, up to 30 ms), and
    the difference hides in them: there this test passes before as after."""
    probe = SchedProbe()
    rig = rigs(serial_port=False, manage_gc=True, tcp=True, probe=probe, priority=0,
               watchdog=FLOOD_WATCHDOG)
    done = attack(rig, probe, machine_priority=0)
    assert done.wakes.blocked_over_1ms <= 2 * done.machine.blocked_over_1ms + 5, done
