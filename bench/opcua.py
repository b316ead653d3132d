"""Benchmark: what the OPC UA server costs the scan (issue 15). Not a test: prints a table.

The controller runs in this process as in bench/jitter.py (the same Daemon, Scheduler and
generated plant cycle as ``softplc run --sim``; the garbage collector in the scan's idle
time, as in production), with ``--testers`` drawer testers (default 100) whose drawers
move, at a 10 ms cycle. Phases, each ``--seconds`` long:

- ``no feed``: the plant without its ``opcua:`` section (no feed socket, no server);
- ``feed only``: the controller's feed served (a snapshot every ``sample``), no server;
- ``server + N clients``: ``softplc opcua PLANT`` in its own process (as its systemd unit
  runs it) and ``--clients`` client processes (asyncua, at nice 10), each subscribed to
  every variable of the plant (ns=2) at a 100 ms publishing interval and to the events of
  the Server object (the alarms, runtime/opcua/conditions.py). With ``--alarms R``
  (default 10), alarms come and go meanwhile: every 1/R s one tester's SFCError is set
  (its ``SFCError`` alarm raised), and cleared 0.5 s later (SFCQuitError for a scan: the
  alarm inactive), each change an event to every client.

Per phase: the scan's wake-up lateness (p50, p99, max) and overruns over the window, and
the controller's faults in it (watchdog, freeze: a fault stops the charts until ``ack``;
one while the server and its clients started is said and acknowledged before the
window, so that the alarms come and go in it). The scan's statistics are never reset:
the feed and the alarm board pace themselves on their count of scans, and a reset
stopped both for as many scans as had run before (no alarm event reached the clients,
the server showed every value BadOutOfService). For the server phase: the data-change
notifications and the alarm events the clients received per second (all clients
together), and below the table the alarm events each client received against the
changes of the controller's alarm board meanwhile (its ``version``: each alarm raised and
cleared is two, a fault in the window one more; the clients count from before the first
alarm until DRAIN_S after the last one is cleared, so that the last ones arrive: told
"stop" then, not after a time of their own, which a window longer than asked cut short);
the server process's CPU (utime + stime from /proc/PID/stat over the window, percent of
one core) and its resident memory (VmRSS at the end, VmHWM peak, from /proc/PID/status).
All processes share this machine's cores: on a controller the clients run elsewhere, so
the server row here is the harder case.

Clients subscribe one after the other; one that cannot (its requests time out: the server
does not keep up) is left out, and the row says how many did.

    python -m bench.opcua [--seconds 60] [--testers 100] [--clients 10] [--alarms 10]
                          [--secure] [--fifo]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from typing import Any

from bench.jitter import DrawerModel, plant_file
from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.engine.commands import CommandRefused
from runtime.language.plantfile import load_plant

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: how long the server may take to serve its first frame, s (3500 nodes on a loaded core)
START_S = 180.0
#: the clients' health probe period and time-out, s (asyncua's default: 1 s)
WATCHDOG_S = 30.0
#: clock ticks per second of /proc/PID/stat times
TICKS = os.sysconf("SC_CLK_TCK")
#: how long the clients go on counting after they are told to stop (the last alarm
#: cleared): the events of the last alarms (their clearing) arrive, seconds
DRAIN_S = 5.0


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def opcua_plant(directory: str, testers: int, port: int, secure: bool,
                pki: dict[str, str] | None, fifo: bool = False, clients: int = 10) -> str:
    """bench/jitter.py's plant of ``testers`` testers at 10 ms (SCHED_FIFO 50 with
    ``fifo``), plus an ``opcua:`` section (policy None, or SignAndEncrypt with ``pki``)
    whose limits let ``clients`` clients subscribe to every variable."""
    path = plant_file(directory, testers, 10, fifo)
    with open(path, "a", encoding="utf-8") as f:
        f.write(opcua_section(directory, port, secure, pki, clients))
    return path


def opcua_section(directory: str, port: int, secure: bool, pki: dict[str, str] | None,
                  clients: int) -> str:
    """The plant's ``opcua:`` section on 127.0.0.1:``port`` (a snapshot every 50 ms, the
    feed in ``directory``), whose limits let ``clients`` clients subscribe to every
    variable."""
    sec = "  security: {policies: [None]}\n"
    if secure:
        assert pki is not None
        sec = ("  security:\n    policies: [Basic256Sha256_SignAndEncrypt]\n"
               f"    certificate: {pki['server_cert']}\n"
               f"    private_key: {pki['server_key']}\n"
               f"    trusted_clients: {pki['trusted_dir']}\n")
    # the default limits let five clients hold every variable (items_total: 20000):
    # raised so that ten may, as the benchmark's row says
    return (f"opcua:\n  endpoint: opc.tcp://127.0.0.1:{port}\n  sample: 50ms\n"
            f"  feed: {directory}/feed.sock\n{sec}"
            f"  limits: {{sessions: {clients + 4}, items_total: 100000}}\n")


def window(daemon: Daemon, seconds: float) -> dict[str, Any]:
    """The scan's figures over the next ``seconds``: cycles, overruns and faults in the
    window (the counters' differences), the wake-up lateness's p50, p99 and max (µs) over
    its cycles, taken from the scan's own statistics (their last ``window`` cycles, 8192:
    82 s at 10 ms; a longer window's figures are those of its end). Never a reset of
    the statistics: the daemon gives their count to its listeners as the scan number, and
    the feed and the alarm board pace themselves on it (a reset stopped both until the
    count came back where it was: no alarm event, every value BadOutOfService)."""
    stats = daemon.scan_stats
    faults = len(daemon.faults)
    c0, o0 = daemon.call(lambda: (stats.count, stats.overruns))
    time.sleep(seconds)
    c1, o1 = daemon.call(lambda: (stats.count, stats.overruns))
    n = min(c1 - c0, stats.window)
    late = sorted(stats._late[i % stats.window] for i in range(c1 - n, c1)) or [0]
    n = len(late)
    return {"cycles": c1 - c0, "overruns": o1 - o0, "p50": late[n // 2] / 1e3,
            "p99": late[min(n - 1, int(n * 0.99))] / 1e3, "max": late[-1] / 1e3,
            "faults": len(daemon.faults) - faults}


def settled(daemon: Daemon, seconds: float = 5.0) -> None:
    """Wait (at most ``seconds``) until the alarm board shows no active controller fault."""
    end = time.monotonic() + seconds
    while time.monotonic() < end and any(
            a["key"] == "controller.fault" and a["active"] for a in daemon.alarms.as_list()):
        time.sleep(0.05)


def ack_faults(daemon: Daemon, since: int, when: str) -> int:
    """The controller's faults after the first ``since`` said in one line and acknowledged
    (a fault stops the charts until ack: the next window would measure another plant);
    returns the count of faults so far."""
    faults = list(daemon.faults)
    if len(faults) > since:
        try:
            acked = daemon.ack()
        except CommandRefused as exc:
            acked = f"not acknowledged: {exc}"
        out(f"({len(faults) - since} fault(s) {when}: "
            + "; ".join(r for _, r in faults[since:]) + f"; then {acked})")
    return len(faults)


def proc_cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime


def proc_mem_mib(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of ``pid``, MiB."""
    mem = {}
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            key, _, rest = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                mem[key] = int(rest.split()[0]) / 1024
    return mem["VmRSS"], mem["VmHWM"]


# -- the client processes --------------------------------------------------------------


def client_args(url: str, nodes_file: str, seconds: float, pki: dict[str, str] | None,
                nice: int = 10) -> list[str]:
    cfg = {"url": url, "nodes": nodes_file, "seconds": seconds, "pki": pki, "drain": DRAIN_S}
    return ["nice", "-n", str(nice), sys.executable, "-m", "bench.opcua", "--client",
            json.dumps(cfg)]


async def _session(cfg: dict[str, Any]) -> Any:
    from asyncua import Client, ua
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    from runtime.opcua.security import CLIENT_URI

    # asyncua's client probes the server every watchdog_intervall (default 1 s) and drops
    # the connection when a probe is not answered in that time: the server's event loop
    # stalls longer than that while thousands of monitored items are created (seen here)
    client = Client(cfg["url"], timeout=60, watchdog_intervall=WATCHDOG_S)
    pki = cfg.get("pki")
    if pki:
        client.application_uri = CLIENT_URI
        await client.set_security(SecurityPolicyBasic256Sha256, pki["client_cert"],
                                  pki["client_key"], server_certificate=pki["server_cert"],
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
    await client.connect()
    return client


async def run_client(cfg: dict[str, Any]) -> None:
    """One client: subscribe to every node of the file at 100 ms, say "ready", wait for
    "go", count notifications until "stop" (at most ``seconds``) and ``drain`` seconds
    more, print the counts and how long it counted."""
    client = await _session(cfg)
    with open(cfg["nodes"], encoding="utf-8") as f:
        ids = json.load(f)
    counter = {"n": 0, "events": 0, "sfcerror": 0, "counting": False}

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            if counter["counting"]:
                counter["n"] += 1

        def event_notification(self, event: Any) -> None:
            if counter["counting"]:
                counter["events"] += 1
                name = event.get_event_props_as_fields_dict().get("ConditionName")
                if str(getattr(name, "Value", name)).endswith(".SFCError"):
                    counter["sfcerror"] += 1  # the alarms AlarmTraffic raises and clears

        def status_change_notification(self, status: Any) -> None:
            sys.stderr.write(f"client: subscription status {status}\n")

    sub = await client.create_subscription(100, Handler())
    # the alarms first: their filter takes a few hundred browse requests, answered sooner
    # by a server not yet sending this client's data changes (they timed out after them
    # on a loaded machine)
    await sub.subscribe_alarms_and_conditions(client.nodes.server)
    nodes = [client.get_node(i) for i in ids]
    for k in range(0, len(nodes), 500):
        await sub.subscribe_data_change(nodes[k:k + 500], queuesize=1)
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sys.stdin.readline)
    counter["counting"] = True
    t0 = time.monotonic()
    try:
        await asyncio.wait_for(loop.run_in_executor(None, sys.stdin.readline), cfg["seconds"])
    except TimeoutError:  # never told: the bench died or forgot
        pass
    await asyncio.sleep(cfg.get("drain", 0.0))
    counter["counting"] = False
    sys.stdout.write(json.dumps({"notifications": counter["n"], "events": counter["events"],
                                 "sfcerror": counter["sfcerror"],
                                 "seconds": time.monotonic() - t0}) + "\n")
    sys.stdout.flush()
    await client.disconnect()


async def variable_ids(url: str, pki: dict[str, str] | None) -> list[str]:
    """Every Variable NodeId of namespace 2, found by browsing from Objects."""
    from tests.opcua.kit import variables

    client = await _session({"url": url, "pki": pki})
    try:
        return await variables(client)
    finally:
        await client.disconnect()


async def wait_serving(url: str, pki: dict[str, str] | None, deadline: float) -> None:
    while True:
        try:
            client = await _session({"url": url, "pki": pki})
            try:
                dv = await client.get_node("ns=2;s=controller.scan").read_data_value(
                    raise_on_bad_status=False)
                if dv.StatusCode.is_good():
                    return
            finally:
                await client.disconnect()
        except (OSError, TimeoutError):
            pass
        if time.monotonic() > deadline:
            raise TimeoutError(f"{url}: not serving after {START_S} s")
        await asyncio.sleep(0.5)


# -- the phases --------------------------------------------------------------------------


def make_pki(directory: str) -> dict[str, str]:
    import shutil

    from runtime.opcua.security import make_certificate

    sc, sk = make_certificate(os.path.join(directory, "server"), hosts=["127.0.0.1"])
    cc, ck = make_certificate(os.path.join(directory, "client"), hosts=["localhost"],
                              client=True)
    trusted = os.path.join(directory, "trusted")
    os.makedirs(trusted)
    shutil.copy(cc, trusted)
    return {"server_cert": sc, "server_key": sk, "client_cert": cc, "client_key": ck,
            "trusted_dir": trusted}


def start_daemon(path: str, testers: int, feed: bool,
                 setup: Callable[[Daemon, FeedServer | None], None] | None = None
                 ) -> tuple[Daemon, FeedServer | None]:
    """The daemon of ``path`` with the drawer model, its feed served (``feed``: else the
    plant without its side processes' sections); ``setup`` sees the daemon and the feed
    server before they start (bench/observers.py probes and times them)."""
    pdef = load_plant(path)
    if not feed:  # the plant without its side processes' sections: no feed
        pdef.opcua = pdef.mqtt = pdef.web = None
    daemon = Daemon(pdef, sim=True, manage_gc=True)
    daemon.add_listener(DrawerModel(daemon, testers))
    fs = None
    feed_def = pdef.feed()
    if feed_def is not None:
        fs = FeedServer(daemon, feed_def)
    if setup is not None:
        setup(daemon, fs)
    if fs is not None:
        fs.start()
    daemon.start()
    time.sleep(1.0)  # warm-up, not counted
    return daemon, fs


def stop_daemon(daemon: Daemon, fs: FeedServer | None) -> None:
    if fs is not None:
        fs.stop()
    daemon.stop("bench")


class AlarmTraffic:
    """Alarms that come and go (``--alarms``): every 1/rate s one tester's SFCError set,
    cleared 0.5 s later, from a thread of the benchmark through ``Daemon.call`` (between
    two scans, as the console's ``set``)."""

    def __init__(self, daemon: Daemon, testers: int, rate: float) -> None:
        self.daemon, self.testers, self.rate = daemon, testers, rate
        self.stop = threading.Event()
        self.raised = 0
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        k = 0
        pending: list[tuple[float, str]] = []
        while not self.stop.wait(1.0 / self.rate):
            name = f"t{k % self.testers}"
            k += 1
            self._raise(name)
            self.raised += 1
            pending.append((time.monotonic() + 0.5, name))
            while pending and pending[0][0] <= time.monotonic():
                self._clear(pending.pop(0)[1])
        for _, name in pending:
            self._clear(name)

    def _raise(self, name: str) -> None:
        plant = self.daemon.plant
        self.daemon.call(lambda: plant.set(f"{name}.SFCError", True))

    def _clear(self, name: str) -> None:
        plant = self.daemon.plant
        self.daemon.call(lambda: plant.pulse(name, "SFCQuitError"))


def phase_server(path: str, testers: int, clients: int, seconds: float, url: str,
                 tmp: str, pki: dict[str, str] | None, alarms: float = 0.0
                 ) -> dict[str, Any]:
    daemon, fs = start_daemon(path, testers, True)
    faults0 = len(daemon.faults)
    # what the server says (a stale feed, a client dropped) is kept beside the plant
    with open(os.path.join(tmp, "server.log"), "w", encoding="utf-8") as log:
        server = subprocess.Popen([sys.executable, "-m", "runtime.cli", "opcua", path],
                                  cwd=ROOT, stdout=subprocess.DEVNULL, stderr=log)
    procs: list[subprocess.Popen[str]] = []
    try:
        t0 = time.monotonic()
        asyncio.run(wait_serving(url, pki, t0 + START_S))
        ids = asyncio.run(variable_ids(url, pki))
        nodes_file = os.path.join(tmp, "nodes.json")
        with open(nodes_file, "w", encoding="utf-8") as f:
            json.dump(ids, f)
        start_clients(url, [nodes_file] * clients, seconds, pki, tmp, t0, procs)
        ready_s = time.monotonic() - t0
        # a fault while the server started (a freeze of the loaded machine) stops the
        # charts until ack: SFCError would then never clear, nor its alarm
        if ack_faults(daemon, faults0, "while the server and its clients started") > faults0:
            settled(daemon)  # the fault's alarm cleared before the count starts
        traffic = AlarmTraffic(daemon, testers, alarms) if alarms > 0 else None
        cpu0 = proc_cpu_s(server.pid)
        board0 = daemon.alarms.version
        go(procs)  # every client counting before the first alarm
        if traffic is not None:
            traffic.thread.start()
        w = window(daemon, seconds)
        cpu = proc_cpu_s(server.pid) - cpu0
        rss, hwm = proc_mem_mib(server.pid)
        if traffic is not None:
            traffic.stop.set()
            traffic.thread.join(10)
        stop_clients(procs)
        got = collect_clients(procs)
        # every change of the board's alarms (raised, cleared, by traffic or a fault in
        # the window) is one event to each client
        changes = daemon.alarms.version - board0
        count_s = counted_s(got, seconds + DRAIN_S)
        total = sum(g.get("notifications", 0) for g in got)
        events = sum(g.get("events", 0) for g in got)
        w.update(nodes=len(ids), notif_s=total / count_s, events_s=events / count_s,
                 cpu_pct=100 * cpu / seconds, rss=rss, hwm=hwm, ready_s=ready_s,
                 subscribed=len(procs),
                 received=[g.get("events", "-") for g in got], changes=changes,
                 raised=traffic.raised if traffic is not None else 0)
        return w
    finally:
        for p in procs:
            p.wait(60)
        end_process(server)
        stop_daemon(daemon, fs)


def start_clients(url: str, node_files: list[str], window_s: float,
                  pki: dict[str, str] | None, tmp: str, t0: float,
                  procs: list[subprocess.Popen[str]], nice: int = 10) -> None:
    """One client process per file of ``node_files`` (its nodes), subscribed one after the
    other, each appended to ``procs`` once it says "ready" (waiting for "go", then
    counting until ``stop_clients``; a client never told stops by itself after twice the
    window ``window_s`` and a minute). ``t0``: when the server started (monotonic s);
    ``nice``: the clients' nice level."""
    # one client subscribes at a time: ten clients creating 3500 monitored items each
    # at once overload asyncua's event loop until they time out (seen here); a client
    # that cannot subscribe (its requests time out) is left out and counted
    for k, nodes_file in enumerate(node_files):
        # what a client says on stderr is kept beside the plant (why one failed)
        with open(os.path.join(tmp, f"client{k + 1}.err"), "w", encoding="utf-8") as err:
            cap_s = 2 * window_s + 60
            p = subprocess.Popen(client_args(url, nodes_file, cap_s, pki, nice), cwd=ROOT,
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 text=True, stderr=err)
        assert p.stdout is not None
        line = p.stdout.readline()
        if line.strip() != "ready":
            out(f"(client {k + 1} could not subscribe after {time.monotonic() - t0:.0f}"
                f" s: the server does not keep up, {tmp}/client{k + 1}.err says why; "
                "going on with the others)")
            p.kill()
            p.wait()
            break
        procs.append(p)
        out(f"(client {k + 1} subscribed at {time.monotonic() - t0:.0f} s)")


def go(procs: list[subprocess.Popen[str]]) -> None:
    """"go" to each waiting client: it starts counting."""
    for p in procs:
        assert p.stdin is not None
        p.stdin.write("go\n")
        p.stdin.flush()


def stop_clients(procs: list[subprocess.Popen[str]]) -> None:
    """"stop" to each counting client: it counts DRAIN_S more, then says what it got."""
    for p in procs:
        assert p.stdin is not None
        try:
            p.stdin.write("stop\n")
            p.stdin.flush()
        except BrokenPipeError:  # a client that died: collect_clients says {}
            pass


def counted_s(got: list[dict[str, Any]], default: float) -> float:
    """How long the clients counted, s (their mean; ``default`` if none said)."""
    secs = [g["seconds"] for g in got if "seconds" in g]
    return sum(secs) / len(secs) if secs else default


def collect_clients(procs: list[subprocess.Popen[str]]) -> list[dict[str, Any]]:
    """What each client counted (``run_client``'s last line; {} from one that died), once
    ``stop_clients`` told it to stop."""
    got = []
    for p in procs:
        assert p.stdout is not None
        line = p.stdout.readline()
        got.append(json.loads(line) if line else {})
    return got


def end_process(p: subprocess.Popen[Any], seconds: float = 60.0) -> None:
    """SIGTERM, then SIGKILL after ``seconds``."""
    p.send_signal(signal.SIGTERM)
    try:
        p.wait(seconds)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


def scan_row(label: str, r: dict[str, Any], extra: str) -> str:
    """A table row: the phase, the scan's figures of ``window``, then ``extra`` cells."""
    return (f"| {label} | {r['cycles']} | {r['overruns']} | {r['faults']} | {r['p50']:.0f} | "
            f"{r['p99']:.0f} | {r['max']:.0f}{extra}")


def row(label: str, r: dict[str, Any]) -> str:
    extra = " | | | | | |"
    if "notif_s" in r:
        extra = (f" | {r['nodes']} | {r['notif_s']:.0f} | {r['events_s']:.1f} | "
                 f"{r['cpu_pct']:.0f} % | {r['rss']:.0f} ({r['hwm']:.0f}) |")
    return scan_row(label, r, extra)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--alarms", type=float, default=10.0,
                    help="alarms raised (and cleared 0.5 s later) per second during the "
                         "server phase; 0: none")
    ap.add_argument("--secure", action="store_true",
                    help="Basic256Sha256 SignAndEncrypt with trusted client certificates")
    ap.add_argument("--fifo", action="store_true",
                    help="the scan at SCHED_FIFO 50 (plc: realtime: needs root)")
    ap.add_argument("--client", help=argparse.SUPPRESS)
    args = ap.parse_args()
    import logging
    logging.basicConfig(level=logging.ERROR)
    if args.client:
        asyncio.run(run_client(json.loads(args.client)))
        return
    from tests.opcua.kit import free_port

    tmp = tempfile.mkdtemp(prefix="bo", dir="/tmp")
    port = free_port()
    pki = make_pki(tmp) if args.secure else None
    path = opcua_plant(tmp, args.testers, port, args.secure, pki, args.fifo, args.clients)
    url = f"opc.tcp://127.0.0.1:{port}"
    out(f"{args.testers} drawer testers, cycle 10 ms, sample 50 ms, {args.seconds:g} s per "
        f"phase, {os.cpu_count()} cores, policy "
        f"{'Basic256Sha256_SignAndEncrypt' if args.secure else 'None'}, scan "
        f"{'SCHED_FIFO 50' if args.fifo else 'SCHED_OTHER'}")
    out("| phase | cycles | overruns | faults | lateness p50 us | p99 us | max us | nodes | "
        "notifications/s | alarm events/s | server CPU | server RSS MiB (peak) |")
    out("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for label, feed in (("no feed", False), ("feed only", True)):
        daemon, fs = start_daemon(path, args.testers, feed)
        try:
            out(row(label, window(daemon, args.seconds)))
        finally:
            stop_daemon(daemon, fs)
    r = phase_server(path, args.testers, args.clients, args.seconds, url, tmp, pki,
                     args.alarms)
    out(row(f"server + {r['subscribed']} clients", r))
    out(f"({r['subscribed']} of {args.clients} clients subscribed to every variable, "
        f"{r['ready_s']:.0f} s after the server started; {r['raised']} alarms raised and "
        f"cleared during the window; {r['changes']} changes of the alarm board, alarm events "
        "received per client "
        + (", ".join(str(n) for n in r["received"]) or "-") + ")")


if __name__ == "__main__":
    main()
