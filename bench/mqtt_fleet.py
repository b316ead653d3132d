"""Benchmark: a fleet of controllers on one broker (issue 28). Not a test: prints figures.

``--nodes`` controllers (default 20), each ``softplc run --sim`` of the two-instance plant
of tests/mqtt (a blinker that counts, changing every few scans; cycle 10 ms) with its
``softplc mqtt`` (its own edge node id, report by exception every 100 ms), against one
Debian mosquitto; the independent host application of tests/mqtt (pysparkplug), the nodes'
primary host (they birth once its STATE says online), reads everything, and every birth,
sequence number and death is checked (tests/mqtt/hostcheck.py).

The run: all nodes start; once every node and device is born, ``--seconds`` of steady
reporting; then the broker is stopped and started again (its clients' Wills: an NDEATH per
node) and the time until every node is born again is measured (the birth storm after a
broker restart); then every edge node is stopped (each publishes its NDEATH).

    python -m bench.mqtt_fleet [--nodes 20] [--seconds 60]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.opcua import out, proc_cpu_s, proc_mem_mib
from tests.mqtt.hostcheck import check
from tests.mqtt.kit import Broker, Host, wait_until
from tests.opcua.kit import CHART

GROUP = "Fleet"
#: the host application is the nodes' primary host: they birth once its STATE is online
HOST_ID = "fleet-host"


def plant(directory: Path, node: str, broker: str) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "blink.yaml").write_text(CHART, encoding="utf-8")
    path = directory / "plant.yaml"
    path.write_text(
        "plc: {cycle: 10ms, watchdog: 5s}\ndrivers:\n  io: {type: sim}\ninstances:\n"
        "  t1: {grafcet: blink.yaml, inputs: {iGo: io.I0}, outputs: {oLamp: io.Q0}}\n"
        "  t2: {grafcet: blink.yaml, inputs: {iGo: io.I1}, outputs: {oLamp: io.Q1}}\n"
        f"mqtt:\n  brokers: [{broker}]\n  group_id: {GROUP}\n  edge_node_id: {node}\n"
        f"  feed: {directory}/feed.sock\n  keepalive: 10s\n  primary_host: {HOST_ID}\n",
        encoding="utf-8")
    return path


def start(args: list[str], cwd: Path, log: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "XDG_RUNTIME_DIR": str(cwd)}
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", *args], cwd=str(cwd),
                            env=env, text=True, stdout=subprocess.DEVNULL,
                            stderr=open(log, "w"))  # noqa: SIM115


def births(host: Host) -> int:
    return len(host.of("NBIRTH"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bf", dir="/tmp"))
    broker = Broker(tmp, name="broker").start()
    host = Host(broker, host_id=HOST_ID, primary=True)
    ctls: list[subprocess.Popen[str]] = []
    edges: list[subprocess.Popen[str]] = []
    n = args.nodes
    try:
        t0 = time.monotonic()
        for k in range(n):
            d = tmp / f"node{k:02d}"
            path = plant(d, f"node{k:02d}", broker.url)
            ctls.append(start(["run", str(path), "--sim"], d, d / "ctl.log"))
            edges.append(start(["mqtt", str(path)], d, d / "mqtt.log"))
        wait_until(lambda: len(host.of("DBIRTH")) >= 2 * n, 300, "every birth")
        born_s = time.monotonic() - t0
        out(f"{n} controllers and {n} edge nodes started, every node and device born in "
            f"{born_s:.1f} s ({os.cpu_count()} cores, all on this machine)")
        rows0 = len(host.rows)
        cpu0 = [proc_cpu_s(e.pid) for e in edges]
        bcpu0 = proc_cpu_s(broker.proc.pid) if broker.proc else 0.0
        time.sleep(args.seconds)
        steady = host.rows[rows0:]
        cpu = [proc_cpu_s(e.pid) - c for e, c in zip(edges, cpu0, strict=True)]
        bcpu = (proc_cpu_s(broker.proc.pid) if broker.proc else 0.0) - bcpu0
        rss = [proc_mem_mib(e.pid)[0] for e in edges]
        data = [r for r in steady if r.get("kind") in ("NDATA", "DDATA")]
        values = sum(len(r["metrics"]) for r in data)
        out(f"steady: {len(data) / args.seconds:.0f} messages/s in all "
            f"({len(data) / args.seconds / n:.1f} per node), {values / args.seconds:.0f} "
            f"metric values/s; edge node CPU {100 * sum(cpu) / len(cpu) / args.seconds:.1f} "
            f"% of a core each (max {100 * max(cpu) / args.seconds:.1f} %), RSS "
            f"{sum(rss) / len(rss):.0f} MiB each; broker CPU "
            f"{100 * bcpu / args.seconds:.1f} %")
        # the broker restarts: Wills, then every node born again
        b0 = births(host)
        broker.kill(signal.SIGTERM)
        time.sleep(2.0)
        deaths = len(host.of("NDEATH"))
        t1 = time.monotonic()
        broker.restart()
        wait_until(lambda: births(host) >= b0 + n and len(host.of("DBIRTH")) >= 4 * n, 300,
                   "every node born again")
        storm_s = time.monotonic() - t1
        out(f"broker stopped (the host got {deaths} of the {n} NDEATHs the broker sent as it "
            f"stopped) and restarted: every node and device born again in {storm_s:.1f} s "
            "(the host's reconnection and STATE included)")
        for e in edges:
            e.send_signal(signal.SIGTERM)
        late = 0
        for e in edges:
            try:
                e.wait(60)
            except subprocess.TimeoutExpired:
                late += 1
                e.kill()
        time.sleep(16.0)  # the last NDEATHs (a node killed: its Will after 1.5 keepalives)
        out(f"every edge node stopped: {n - late} by itself, {late} killed after 60 s; "
            f"NDEATHs seen since {len(host.of('NDEATH')) - deaths}")
        views = check(host.rows)
        problems = [f"{node}: {p}" for node, v in views.items() for p in v.problems]
        out(f"host check: {len(views)} nodes; births {sum(v.births for v in views.values())}"
            f", device births {sum(v.device_births for v in views.values())}, deaths "
            f"{sum(v.deaths for v in views.values())}, data messages "
            f"{sum(v.data for v in views.values())}, historical values "
            f"{sum(v.historical for v in views.values())}; problems: {len(problems)}")
        for problem in problems[:20]:
            out(f"  {problem}")
    finally:
        for p in (*edges, *ctls):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in (*edges, *ctls):
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
        host.close()
        broker.kill()


if __name__ == "__main__":
    main()
