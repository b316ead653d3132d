"""The edge node through outages, seen by the independent host application: the broker
stopped and restarted (NDEATH from the broker, store and forward, births with the next
bdSeq), the broker killed, the node's network cut in a network namespace (the Will fires),
and a flood of 1000 DCMDs a second (bounded, the scan untouched)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.mqtt.hostcheck import check
from tests.mqtt.kit import (
    EDGE,
    GROUP,
    Broker,
    Host,
    processes,
    softplc,
    topic,
    wait_until,
    write_plant,
)
from tests.mqtt.test_sparkplug import births_seen, edge
from tests.opcua.feedkit import FeedReader


def bdseqs(host: Host, kind: str = "NBIRTH") -> list[int]:
    return [m["value"] for r in host.of(kind) for m in r["metrics"] if m["name"] == "bdSeq"]


def history_after_last_birth(host: Host) -> list[dict[str, object]]:
    """t1's historical metrics since the last NBIRTH."""
    rows = list(host.rows)
    last = max(i for i, r in enumerate(rows) if r.get("kind") == "NBIRTH")
    return [m for r in rows[last:] if r.get("kind") == "DDATA" and r["device"] == "t1"
            for m in r["metrics"] if m["historical"]]


@pytest.mark.parametrize("how", ["stopped", "killed"])
def test_broker_restarted_store_and_forward_and_rebirth(tmp_path: Path, how: str) -> None:
    """The host is the primary host: after the restart the node births only once the host
    is back online (its STATE), so the forwarded history reaches it."""
    with edge(tmp_path, primary=True, host_id="SCADA", mqtt="  primary_host: SCADA\n") as e:
        births_seen(e)
        n_before = len(e.host.of("DDATA"))
        e.host.wait(lambda _r: len(e.host.of("DDATA")) > n_before + 10, 20, "reports")
        t_down = time.time()
        e.broker.kill(signal.SIGTERM if how == "stopped" else signal.SIGKILL)
        if how == "stopped":  # mosquitto sends the Wills of its clients as it stops
            e.host.wait(lambda _r: len(e.host.of("NDEATH")) == 1, 20, "the NDEATH")
            assert bdseqs(e.host, "NDEATH") == [0]
        wait_until(lambda: "mqtt: broker" in e.log() or "ended" in e.log(), 20,
                   "the node noticing")
        time.sleep(2.0)  # the chart runs on: sN counts, the changes are kept
        t_up = time.time()
        e.broker.restart()
        births_seen(e, 2)
        bd = bdseqs(e.host)
        assert bd[0] == 0 and bd[1] >= 1, bd  # each CONNECT has the next bdSeq
        assert f"bdSeq {bd[1]})" in e.log()
        # the chart counts sN about every 80 ms: a second of outage is a dozen values
        e.host.wait(lambda _r: len([m for m in history_after_last_birth(e.host)
                                    if m["name"] == "Memory/sN"]) >= 12, 20, "history")
        time.sleep(1.0)  # the rest of it
        hist = history_after_last_birth(e.host)
        sn = [m for m in hist if m["name"] == "Memory/sN"]
        values = [int(str(m["value"])) for m in sn]
        assert values == sorted(values) and len(set(values)) == len(values)
        stamps = [int(str(m["timestamp"])) for m in sn]
        assert stamps == sorted(stamps)
        # from just before the outage (what the broker was not seen to take before it
        # went comes again as history: a probe's period, 0.5 s, and its answer) on
        assert t_down - 3 <= stamps[0] / 1000 and stamps[-1] / 1000 <= t_up + 5, (
            t_down, t_up, stamps)
        assert "buffered value(s) forwarded as history" in e.log()
        views = check(e.host.rows)
        assert [p for v in views.values() for p in v.problems] == []
        assert views[(GROUP, EDGE)].births == 2
        e.alive()


# -- the network cut ---------------------------------------------------------------------


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=30)


@contextmanager
def two_namespaces() -> Iterator[tuple[str, str, str, str]]:
    """Namespace B (broker, host application) and N (the edge node) joined by a veth pair:
    (B, N, B's address, N's link). Made here, removed at the end."""
    if os.geteuid() != 0:
        pytest.skip("network namespaces need root (CI runs as root)")
    tag = f"{os.getpid() % 100000}"
    b, n, vb, vn = f"spb{tag}", f"spn{tag}", f"vb{tag}", f"vn{tag}"
    try:
        _ip("netns", "add", b)
    except (subprocess.CalledProcessError, FileNotFoundError) as exc:
        if os.environ.get("CI"):
            raise
        pytest.skip(f"ip netns not permitted here: {exc}")
    try:
        _ip("netns", "add", n)
        _ip("link", "add", vb, "type", "veth", "peer", "name", vn)
        _ip("link", "set", vb, "netns", b)
        _ip("link", "set", vn, "netns", n)
        # addresses of this test's own namespaces only: no traffic leaves them
        _ip("-n", b, "addr", "add", "10.203.28.1/30", "dev", vb)
        _ip("-n", n, "addr", "add", "10.203.28.2/30", "dev", vn)
        for ns, dev in ((b, vb), (n, vn), (b, "lo"), (n, "lo")):
            _ip("-n", ns, "link", "set", dev, "up")
        yield b, n, "10.203.28.1", vn
    finally:
        for ns in (b, n):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


def test_the_nodes_network_cut_fires_its_will(tmp_path: Path) -> None:
    with two_namespaces() as (ns_b, ns_n, addr, link):
        broker = Broker(tmp_path, bind=addr).start(netns=ns_b)
        host = Host(broker, netns=ns_b)
        plant = write_plant(tmp_path, [broker.url])
        ctl = softplc("run", str(plant), "--sim", cwd=tmp_path, log=tmp_path / "ctl.log")
        mqtt = softplc("mqtt", str(plant), cwd=tmp_path, netns=ns_n,
                       log=tmp_path / "mqtt.log")
        try:
            with processes(ctl, mqtt):
                host.wait(lambda rows: len([r for r in rows if r.get("kind") == "DBIRTH"])
                          >= 2, 30, "births")
                t_cut = time.monotonic()
                _ip("-n", ns_n, "link", "set", link, "down")  # the cable pulled
                # keepalive 2 s: the broker gives up on the node after 3 s, sends its Will
                host.wait(lambda _r: len(host.of("NDEATH")) == 1, 20, "the Will")
                waited = time.monotonic() - t_cut
                assert bdseqs(host, "NDEATH") == bdseqs(host) == [0]
                _ip("-n", ns_n, "link", "set", link, "up")
                host.wait(lambda _r: len(host.of("NBIRTH")) == 2, 60, "the rebirth")
                assert bdseqs(host)[1] >= 1
                views = check(host.rows)
                assert [p for v in views.values() for p in v.problems] == []
                assert views[(GROUP, EDGE)].deaths == 1
                assert mqtt.poll() is None and ctl.poll() is None
                sys.stderr.write(f"the Will came {waited:.1f} s after the cut (keepalive "
                                 "2 s)\n")
        finally:
            host.close()
            broker.kill()


# -- a flood of commands -------------------------------------------------------------------


@pytest.mark.slow
def test_a_flood_of_dcmds_is_bounded_and_the_scan_untouched(tmp_path: Path) -> None:
    """1000 DCMDs a second for 10 s to a writable name: the edge node stays bounded (writes
    waiting at most MAX_PENDING_WRITES, the rest refused busy, its memory), the controller
    keeps every deadline (the scan thread real-time, as softplc.service runs it)."""
    with edge(tmp_path, plc=", realtime: {priority: 20}") as e:
        births_seen(e)
        watch = FeedReader(str(tmp_path / "feed.sock"))
        wait_until(lambda: bool(watch.statuses), 20)
        before = dict(watch.statuses[-1])
        scan0 = watch.frames[-1][0]
        acks = e.host.acks
        e.host.send({"flood": topic("DCMD", "t1"), "metrics": [["Memory/sRate", "DOUBLE",
                                                               2.5]],
                     "rate": 1000, "seconds": 10})
        rss = []
        while e.host.acks == acks:
            rss.append(_rss_mib(e.mqtt.pid))
            time.sleep(0.5)
            assert e.mqtt.poll() is None, e.log()
        wait_until(lambda: watch.frames[-1][0] > scan0 + 1200, 30, "the scans went on")
        after = dict(watch.statuses[-1])
        missed = {k: after[k] - before[k] for k in ("overruns", "skipped", "freezes")}
        assert missed == {"overruns": 0, "skipped": 0, "freezes": 0}, (before, after)
        assert after["state"] == "running"
        watch.close()
        log = e.log()
        assert max(rss) < 200, rss  # MiB: nothing kept per command
        assert len(log.splitlines()) < 200, "the log flooded"
        assert e.host.latest("t1", "Memory/sRate") == 2.5  # and they were applied
        n = len(e.host.rows)
        e.host.wait(lambda rows: len(rows) > n + 5, 20, "reports go on")
        e.alive()
        sys.stderr.write(f"flood: mqtt RSS peak {max(rss):.0f} MiB, lateness p99 "
                         f"{before['lateness_us'].get('p99')} -> "
                         f"{after['lateness_us'].get('p99')} us, log lines "
                         f"{len(log.splitlines())}\n")


def _rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0
