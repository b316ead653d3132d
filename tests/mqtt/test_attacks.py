"""The edge node attacked from the broker's side, seen by the independent host application,
each attack beside a quiet control phase of the same run: the controller's scans (its
trace, tests/mqtt/scans.py) during the attack hold to the quiet phase's counts, and the
edge node serves on.

- a retained STATE of the primary host from the far future (2^62 ms): refused, one line;
- the newest STATE seen is not carried to the next session (another broker's STATE);
- a DCMD published with retain: refused at every session, one line each, never applied;
- 300 NCMD Rebirth in a twentieth of a second: folded, at most about a rebirth a second;
- a broker that accepts and then stalls (SIGSTOP 10 s): the stall seen, and what was
  published since the broker last answered re-sent as history: no value lost.

The controller runs as softplc.service runs it (its scan thread SCHED_FIFO where
permitted), so that what is measured is what the edge node does to it."""

from __future__ import annotations

import contextlib
import json
import re
import signal
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from runtime.mqtt.payload import Command, DataType, command_payload
from tests.mqtt.hostcheck import check
from tests.mqtt.kit import (
    Broker,
    Host,
    processes,
    softplc,
    topic,
    wait_until,
)
from tests.mqtt.scans import Phase, Scans, TraceWatch
from tests.mqtt.test_sparkplug import Edge, births_seen, edge
from tests.opcua.feedkit import FeedReader
from tests.pairs import held_in_a_pair

#: the controller's scan thread as the installed service runs it
REALTIME = ", realtime: {priority: 20}"
PRIMARY = "  primary_host: SCADA\n"
#: the quiet control phase, seconds (a measuring window, not a wait)
QUIET_S = 6.0
FAR = 1 << 62


def quiet(e: Edge, watch: TraceWatch, seconds: float = QUIET_S) -> Scans:
    """The control phase: the edge node reporting, nothing attacking it."""
    n = len(e.host.rows)
    with watch.phase() as p:
        time.sleep(seconds)  # a measuring window
    assert len(e.host.rows) > n, f"no report in the quiet phase: {e.log()[-1500:]}"
    assert p.scans is not None
    return p.scans


@contextmanager
def attacked(watch: TraceWatch, at_least: float = QUIET_S) -> Iterator[Phase]:
    """The attack's phase, measured for at least as long as the quiet one (the edge node
    serving on meanwhile): a phase shorter than the control would hold one hiccup of the
    shared machine against the attack."""
    t0 = time.monotonic()
    with watch.phase() as p:
        yield p
        time.sleep(max(0.0, at_least - (time.monotonic() - t0)))  # a measuring window


def held(attack: Scans, control: Scans, what: str,
         again: Callable[[], tuple[Scans, Scans]] | None = None) -> None:
    """The attack's scans within the quiet phase's (tests/mqtt/scans.py, ``within``); with
    ``again`` (one more quiet phase and attack: (attack, control)), in one of up to
    tests/pairs.py's PAIRS pairs."""
    held_in_a_pair(what, (attack, control), lambda pair: pair[0].within(pair[1]), again)


def state(online: bool, ts: int) -> bytes:
    return json.dumps({"online": online, "timestamp": ts}).encode()


def reports_go_on(e: Edge, n: int = 5) -> None:
    """Live reports of t1 still reach the host (the edge node serves)."""
    k = len(e.host.of("DDATA", "t1"))
    e.host.wait(lambda _r: len(e.host.of("DDATA", "t1")) >= k + n, 20, "reports go on")


# -- STATE ----------------------------------------------------------------------------------


def test_a_retained_state_from_the_far_future_is_refused(tmp_path: Path) -> None:
    """A STATE of the primary host stamped 2^62 ms, retained: before, every real STATE
    looked older for the life of the process (the node kept publishing while the host said
    offline, and a forged offline one kept it from ever birthing again); now it is refused
    with one line and the host's own STATEs rule."""
    with edge(tmp_path, primary=True, host_id="SCADA", mqtt=PRIMARY, trace=True,
              plc=REALTIME) as e:
        births_seen(e)
        watch = TraceWatch(tmp_path / "trace.jsonl")
        control = quiet(e, watch)
        where = "spBv1.0/STATE/SCADA"
        with attacked(watch) as p:
            acks = e.host.acks
            e.host.raw(where, state(True, FAR), retain=True, qos=1)
            wait_until(lambda: e.host.acks > acks, 20, "the forged STATE sent")
            reports_go_on(e)
            e.host.state(False)  # the real host says offline: the node must leave
            at = len(e.host.rows)
            with contextlib.suppress(AssertionError):  # said below
                e.host.wait(lambda _r: bool(e.host.of("NDEATH")), 20, "the NDEATH")
            after = len([r for r in e.host.rows[at:] if r.get("kind") == "DDATA"])
            assert len(e.host.of("NDEATH")) == 1, (
                f"the node went on publishing after the host said offline: {after} DDATA "
                f"in 20 s")
            # a forged offline one from the far future, then the host comes back online
            wait_until(lambda: e.log().count("waiting for the primary host SCADA") == 2, 30)
            acks = e.host.acks
            e.host.raw(where, state(False, FAR), retain=True, qos=1)
            wait_until(lambda: e.host.acks > acks, 20, "the forged STATE sent")
            e.host.state(True)
            births_seen(e, 2)
            reports_go_on(e)
        assert p.scans is not None
        held(p.scans, control, "STATE from the future")
        refused = [line for line in e.log().splitlines() if "STATE of SCADA ignored" in line]
        assert len(refused) == 2 and all("ahead of this machine's clock" in line
                                         for line in refused), refused
        assert e.problems() == []
        e.alive()


def test_the_newest_state_is_not_carried_to_the_next_session(tmp_path: Path) -> None:
    """Two brokers, the primary host on both: its STATE on the second broker is older than
    the one on the first (it connected there first). The node fails over from the first
    to the second: before, the newest STATE seen on the first made the second's look old,
    and the node never birthed there; now each session reads its broker's STATE afresh."""
    b2 = Broker(tmp_path, name="b2").start()
    host2 = Host(b2, host_id="SCADA", primary=True)
    try:
        host2.wait(lambda _r: bool(host2.of("STATE")), 20, "the host online on b2")
        time.sleep(0.01)  # the first broker's STATE is newer by a few ms at least
        b1 = Broker(tmp_path, name="b1")
        with edge(tmp_path, broker=b1, brokers=[b1.url, b2.url], primary=True,
                  host_id="SCADA", mqtt=PRIMARY) as e:
            births_seen(e)
            assert "connected to " + b1.url in e.log()
            b1.kill()
            host2.wait(lambda _r: bool(host2.of("DBIRTH")), 30, "the births on b2")
            assert "connected to " + b2.url in e.log()
            assert [p for v in check(host2.rows).values() for p in v.problems] == []
            e.alive()
    finally:
        host2.close()
        b2.kill()


# -- retained commands ----------------------------------------------------------------------


def test_a_retained_command_is_refused_at_every_session(tmp_path: Path) -> None:
    """A DCMD published once with retain: before, the broker handed it to every new session
    of the node and it was applied each time (1, 2, 3 writes over 3 starts); now it is
    refused with one warning line each time, and a command without retain still works.
    A retained NCMD Rebirth likewise (before: a rebirth at every start)."""
    with edge(tmp_path, trace=True, plc=REALTIME) as e:
        births_seen(e)
        watch = TraceWatch(tmp_path / "trace.jsonl")
        control = quiet(e, watch)
        ctl_log = tmp_path / "ctl.log"
        logs = []
        with attacked(watch) as p:
            e.mqtt.send_signal(signal.SIGTERM)
            e.mqtt.wait(timeout=20)
            acks = e.host.acks
            e.host.raw(topic("DCMD", "t1"), command_payload(
                int(time.time() * 1000), [Command("Memory/sRate", None, DataType.DOUBLE,
                                                  2.5)]), retain=True, qos=1)
            wait_until(lambda: e.host.acks > acks, 20, "the retained DCMD sent")
            acks = e.host.acks
            e.host.raw(topic("NCMD"), command_payload(
                int(time.time() * 1000), [Command("Node Control/Rebirth", None,
                                                  DataType.BOOLEAN, True)]),
                retain=True, qos=1)
            wait_until(lambda: e.host.acks > acks, 20, "the retained NCMD sent")
            for k in range(3):
                log = tmp_path / f"mqtt-{k}.log"
                logs.append(log)
                e.mqtt = softplc("mqtt", str(e.plant), cwd=tmp_path, log=log)
                with processes(e.mqtt):
                    births_seen(e, k + 2)

                    def seen(log: Path = log, k: int = k) -> bool:
                        return ("DCMD to t1 refused" in log.read_text()
                                or ctl_log.read_text().count("mqtt: set t1.sRate") > k)
                    wait_until(seen, 20, "the retained DCMD applied or refused")
                    reports_go_on(e)
            writes = ctl_log.read_text().count("mqtt: set t1.sRate")
            refusals = [line for log in logs for line in log.read_text().splitlines()
                        if "refused" in line]
            rebirths = [line for log in logs for line in log.read_text().splitlines()
                        if "mqtt: rebirth" in line]
            assert writes == 0, f"{writes} writes of the retained DCMD over 3 starts"
            assert len([r for r in refusals if "DCMD to t1 refused: a retained" in r]) == 3, (
                refusals)
            # the retained NCMD: refused too (it was a rebirth at every start)
            assert len([r for r in refusals if "NCMD refused: a retained" in r]) == 3, (
                refusals, rebirths)
            assert len(refusals) == 6 and rebirths == [], (refusals, rebirths)
            # the edge node serves on: a command without retain is applied
            e.mqtt = softplc("mqtt", str(e.plant), cwd=tmp_path, log=tmp_path / "mqtt.log")
            with processes(e.mqtt):
                births_seen(e, 5)
                e.host.command(topic("DCMD", "t1"), [("Memory/sStop", "BOOLEAN", True)])
                e.host.wait(lambda _r: e.host.latest("t1", "Memory/sStop") is True, 20)
                # (the retained ones come with this session too: refused once more)
                wait_until(lambda: "DCMD to t1 refused" in e.log(), 20)
                assert ctl_log.read_text().count("mqtt: set t1.sRate") == 0
        assert p.scans is not None
        held(p.scans, control, "retained DCMD")
        assert e.problems() == []


# -- rebirth flood -------------------------------------------------------------------------


def test_a_flood_of_rebirth_requests_is_folded(tmp_path: Path) -> None:
    """300 NCMD Rebirth in about a twentieth of a second: before, 300 NBIRTH and 600
    DBIRTH; now at most about one rebirth a second (the requests folded into the next
    one), one log line each, and the reports go on."""
    with edge(tmp_path, trace=True, plc=REALTIME) as e:
        births_seen(e)
        watch = TraceWatch(tmp_path / "trace.jsonl")
        control = quiet(e, watch)
        quiet_rows = len(e.host.rows)
        with attacked(watch) as p:
            t0, rows0 = time.monotonic(), len(e.host.rows)
            births0 = len(e.host.of("NBIRTH"))
            acks = e.host.acks
            e.host.send({"flood": topic("NCMD"), "metrics": [["Node Control/Rebirth",
                                                              "BOOLEAN", True]],
                         "rate": 6000, "seconds": 2, "count": 300})
            wait_until(lambda: e.host.acks > acks, 30, "the flood sent")
            # the first request served at once, the others folded into one rebirth later
            e.host.wait(lambda _r: len(e.host.of("NBIRTH")) >= births0 + 2, 20,
                        "the folded rebirth")
            reports_go_on(e, 20)  # a second or two of reports after it
            span = time.monotonic() - t0
        births = len(e.host.of("NBIRTH")) - births0
        dbirths = len([r for r in e.host.rows[rows0:] if r.get("kind") == "DBIRTH"])
        sys.stderr.write(f"rebirth flood: {births} NBIRTH, {dbirths} DBIRTH in {span:.1f} s "
                         f"({len(e.host.rows) - rows0} messages; {quiet_rows} before)\n")
        assert 2 <= births <= span + 1, f"{births} NBIRTH in {span:.1f} s"
        lines = [line for line in e.log().splitlines() if "mqtt: rebirth" in line]
        assert len(lines) <= births + 1, lines
        assert p.scans is not None
        held(p.scans, control, "rebirth flood")
        assert e.problems() == []
        e.alive()


# -- the stalled broker --------------------------------------------------------------------


def sn_seen(host: Host) -> dict[int, bool]:
    """Every value of t1's Memory/sN the host got, live or as history: value -> live."""
    out: dict[int, bool] = {}
    for r in list(host.rows):
        if r.get("device") == "t1" and r.get("kind") in ("DBIRTH", "DDATA"):
            for m in r["metrics"]:
                if m["name"] == "Memory/sN":
                    v = int(str(m["value"]))
                    out[v] = out.get(v, False) or not m["historical"]
    return out


def test_a_stalled_broker_loses_no_change(tmp_path: Path) -> None:
    """The broker accepts and then stalls (SIGSTOP, 10 s, then SIGCONT): before, some 4 s
    of changes were lost (neither live nor as history: 43 consecutive values of a counter);
    now the stall is seen (the broker does not answer), the session ends, and what was
    published since the broker last answered is sent again as history after the next
    births: every value of t1's counter that the controller's feed gave (a second client
    of the feed, in this test, sees the same frames as the edge node) reaches the host,
    live or as history, with every sequence number right. (A value the feed itself never
    gave, its frames overwritten while the feed thread waited for a processor on this
    loaded machine, is no fault of the edge node: counted apart.)"""
    with edge(tmp_path, primary=True, host_id="SCADA", mqtt=PRIMARY, host_keepalive=60,
              trace=True, plc=REALTIME) as e:
        births_seen(e)
        fed = FeedReader(str(tmp_path / "feed.sock"))
        watch = TraceWatch(tmp_path / "trace.jsonl")
        control = quiet(e, watch)
        first = max(sn_seen(e.host))
        assert e.broker.proc is not None
        with attacked(watch) as p:
            stall(e)
            births_seen(e, 2)
            # live values again, then every value between
            e.host.wait(lambda _r: e.host.latest("t1", "Memory/sN") is not None and int(
                str(e.host.latest("t1", "Memory/sN"))) > first + 100, 30, "live again")
            last = int(str(e.host.latest("t1", "Memory/sN")))
            index = fed.state.index["t1.sN"]

            def given() -> set[int]:
                return {int(vals[index]) for _s, _w, vals in list(fed.frames)
                        if first <= int(vals[index]) <= last}

            def lost() -> list[int]:
                seen = sn_seen(e.host)
                return sorted(v for v in given() if v not in seen)
            with contextlib.suppress(AssertionError):  # what is missing is said below
                wait_until(lambda: not lost(), 20, "every value")
        fed.close()
        seen = sn_seen(e.host)
        with open(tmp_path / "host.jsonl", "w") as f:  # what the host saw, for a post-mortem
            f.writelines(json.dumps(r) + "\n" for r in e.host.rows)
        history = [v for v in range(first, last + 1) if v in seen and not seen[v]]
        never = sorted(set(range(first, last + 1)) - given())
        sys.stderr.write(f"stalled broker: values {first}..{last}, lost {len(lost())} "
                         f"{_runs(lost())}, {len(history)} only as history; never given by "
                         f"the feed {_runs(never)}\n")
        assert lost() == [], f"lost {_runs(lost())}"
        assert len(given()) >= 0.9 * (last - first + 1), f"the feed gave {_runs(never)}"
        assert history, "nothing came as history"
        assert e.problems() == []
        assert re.search(r"did not answer", e.log()), e.log()[-2000:]
        assert p.scans is not None
        stalls = [2]  # rounds of births seen so far

        def stall_again() -> tuple[Scans, Scans]:
            """One more quiet phase and one more stall (births again after it)."""
            control = quiet(e, watch)
            with attacked(watch) as p:
                stall(e)
                stalls[0] += 1
                births_seen(e, stalls[0])
            assert p.scans is not None
            return p.scans, control
        held(p.scans, control, "stalled broker", again=stall_again)
        e.alive()


def stall(e: Edge, seconds: float = 10.0) -> None:
    """The broker stopped (SIGSTOP) for ``seconds``, the attack's length, then let go."""
    assert e.broker.proc is not None
    e.broker.proc.send_signal(signal.SIGSTOP)
    try:
        time.sleep(seconds)  # the attack's length
    finally:
        e.broker.proc.send_signal(signal.SIGCONT)


def _runs(values: list[int]) -> list[tuple[int, int]]:
    """Consecutive runs of ``values``: (first, last) each."""
    out: list[tuple[int, int]] = []
    for v in values:
        if out and out[-1][1] == v - 1:
            out[-1] = (out[-1][0], v)
        else:
            out.append((v, v))
    return out

