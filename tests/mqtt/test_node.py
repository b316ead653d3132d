"""The edge node's logic without a network (runtime/mqtt/node.py), on a virtual clock and
hand-made feed frames: sequence numbers, bdSeq, report by exception, statistics, store and
forward with its bound, devices dying and coming back with the feed, online changes, and
what a command may ask. (The payloads are read back with the node's own schema here; the
tests with a broker read them with pysparkplug, an implementation not ours.)"""

from __future__ import annotations

import json
import re
from typing import Any

import pytest

from runtime.controller.feed import FeedState
from runtime.language.model import MqttBroker, MqttDef
from runtime.mqtt.forward import Buffer, Journal, Report
from runtime.mqtt.metrics import OFFLINE
from runtime.mqtt.node import REBIRTH_HOLD_S, CommandRefused, EdgeNode, Message
from runtime.mqtt.payload import (
    COMMAND_MAX_BYTES,
    Command,
    CommandError,
    DataType,
    Payload,
    command_payload,
    decode_command,
)

NAMES = [["t1.iGo", "bool", "input"], ["t1.oLamp", "bool", "output"],
         ["t1.sN", "int", "memory"], ["t1.sStop", "bool", "memory"],
         ["t1.sRate", "real", "memory"], ["t1.sT", "time", "memory"],
         ["t1.SFCCurrentStep", "string", "chart flag"], ["t1.gsA.X", "bool", "step"],
         ["t1.gsA.T", "time", "step time"], ["io.I0", "bool", "point in"],
         ["io.ok", "bool", "driver health"]]
VALUES = [False, True, 0, False, 1.5, 2_000_000, "gsA", True, 0, False, True]


class Clock:
    def __init__(self) -> None:
        self.t = 1_800_000_000.0

    def __call__(self) -> float:
        return self.t


def mqtt_def(**kw: Any) -> MqttDef:
    q = MqttDef(brokers=[MqttBroker("mqtt://x:1883", "x", 1883, False)], group_id="G",
                edge_node_id="E", client_id="c", sample_ns=50_000_000,
                writable=["t1.sStop", "t1.sRate", "t1.sT", "t1.sN"])
    for k, v in kw.items():
        setattr(q, k, v)
    return q


class Feed:
    """A FeedState driven by hand, as the feed's lines would."""

    def __init__(self, names: list[list[str]] | None = None,
                 instances: dict[str, str] | None = None) -> None:
        self.state = FeedState()
        self.scan = 0
        self.wall = 1_800_000_000.0
        self.values = list(VALUES)
        self.names = names or NAMES
        self.instances = instances or {"t1": "Blink"}
        self.status: dict[str, Any] = {"state": "running", "fault": None, "overruns": 0,
                                       "skipped": 0, "freezes": 0, "uptime_s": 1,
                                       "cycle_ms": 10.0, "lateness_us": {"p50": 20.0},
                                       "drivers": {"io": ["ok", "", True]}}

    def schema(self, node: EdgeNode) -> None:
        self.state.apply(json.dumps({"schema": {
            "names": self.names, "instances": self.instances, "drivers": ["io"],
            "cycle_ms": 10.0, "sample_ms": 10.0, "writable": {}}}).encode())
        node.schema()

    def frame(self, node: EdgeNode, scans: int = 5, **changes: Any) -> list[Message]:
        """``scans`` later, with ``changes`` (name -> value) applied."""
        for name, v in changes.items():
            self.values[[n[0] for n in self.names].index(name)] = v
        self.scan += scans
        self.wall += scans * 0.01
        self.state.apply(json.dumps({"c": self.status}).encode())
        self.state.apply(json.dumps({"f": [self.scan, self.wall, self.values]}).encode())
        return node.frame()


def setup(**kw: Any) -> tuple[EdgeNode, Feed, Clock]:
    clock = Clock()
    feed = Feed()
    node = EdgeNode(mqtt_def(**kw), feed.state, clock)
    feed.schema(node)
    feed.frame(node)
    return node, feed, clock


def decode(m: Message) -> Any:
    p = Payload()
    p.ParseFromString(m.payload)
    return p


def kinds(msgs: list[Message]) -> list[str]:
    return [m.topic.split("/")[2] + ("/" + m.topic.split("/")[4]
                                     if m.topic.count("/") == 4 else "") for m in msgs]


def metrics(m: Message) -> dict[str, Any]:
    p = decode(m)
    return {x.name or x.alias: getattr(x, x.WhichOneof("value")) if x.WhichOneof("value")
            else None for x in p.metrics}


def test_births_name_every_metric_with_its_type_and_an_alias() -> None:
    node, _feed, _ = setup()
    node.will()
    msgs = node.start_publishing()
    assert kinds(msgs) == ["NBIRTH", "DBIRTH/t1"]
    nb, db = decode(msgs[0]), decode(msgs[1])
    assert nb.seq == 0 and db.seq == 1
    node_metrics = {m.name: m for m in nb.metrics}
    assert node_metrics["bdSeq"].long_value == 0
    assert node_metrics["Node Control/Rebirth"].boolean_value is False
    assert node_metrics["Controller/state"].string_value == "running"
    assert node_metrics["Drivers/io/health"].string_value == "ok"
    assert node_metrics["Drivers/io/ok"].boolean_value is True
    assert "Drivers/io/Inputs/I0" not in node_metrics  # points: not a default group
    dev = {m.name: m for m in db.metrics}
    assert {k: DataType(v.datatype).name for k, v in dev.items()} == {
        "Inputs/iGo": "BOOLEAN", "Outputs/oLamp": "BOOLEAN", "Memory/sN": "INT64",
        "Memory/sStop": "BOOLEAN", "Memory/sRate": "DOUBLE", "Memory/sT": "DOUBLE",
        "Flags/SFCCurrentStep": "STRING", "Steps/gsA/X": "BOOLEAN",
        "Command/Result": "STRING"}
    assert dev["Memory/sT"].double_value == 2.0  # TIME: milliseconds
    assert dev["Memory/sT"].properties.keys == ["engUnit"]
    aliases = [m.alias for m in (*nb.metrics, *db.metrics)]
    assert len(set(aliases)) == len(aliases)
    assert all(m.timestamp == nb.timestamp for m in nb.metrics)


def test_seq_counts_every_message_and_wraps_nbirth_restarts_it() -> None:
    node, feed, clock = setup(statistics_ns=3600_000_000_000)
    node.will()
    seqs = [decode(m).seq for m in node.start_publishing()]
    for n in range(300):
        seqs += [decode(m).seq for m in feed.frame(node, **{"t1.sN": n + 1})]
    assert seqs == [k % 256 for k in range(len(seqs))]
    assert len(seqs) == 302
    clock.t += 5.0  # the births' hold is over
    rebirth = node.node_command([Command("Node Control/Rebirth", None, DataType.BOOLEAN,
                                         True)])
    assert [decode(m).seq for m in rebirth] == [0, 1]
    assert metrics(rebirth[0])["bdSeq"] == 0  # the same session, the same bdSeq


def test_bdseq_counts_sessions_in_the_will_and_the_birth() -> None:
    node, _feed, _ = setup()
    for session in range(258):
        will = node.will()
        assert will.qos == 1 and not will.retain and will.topic == "spBv1.0/G/NDEATH/E"
        assert decode(will).HasField("seq") is False
        assert metrics(will) == {"bdSeq": session % 256}
        births = node.start_publishing()
        assert metrics(births[0])["bdSeq"] == session % 256
        node.session_lost()


def test_report_by_exception_at_most_every_sample() -> None:
    node, feed, _ = setup()
    node.will()
    node.start_publishing()
    assert feed.frame(node, scans=5) == []  # nothing changed
    assert feed.frame(node, scans=2, **{"t1.sN": 1}) == []  # sooner than sample (50 ms)
    out = feed.frame(node, scans=3)
    assert kinds(out) == ["DDATA/t1"]
    p = decode(out[0])
    assert p.timestamp == round(feed.wall * 1000)  # the time of the scan that produced it
    assert [(m.alias, m.long_value, m.timestamp) for m in p.metrics] == [
        (p.metrics[0].alias, 1, p.timestamp)]
    assert not p.metrics[0].HasField("name")  # data: the alias only


def test_statistics_go_out_every_period_only() -> None:
    node, feed, clock = setup(statistics_ns=10_000_000_000)
    node.will()
    node.start_publishing()
    feed.status["overruns"] = 3
    assert feed.frame(node) == []  # a statistic: not before its period
    clock.t += 11
    feed.wall = clock.t
    out = feed.frame(node)
    assert kinds(out) == ["NDATA"]
    assert metrics(out[0]) != {}


def test_store_and_forward_keeps_the_newest_and_counts_the_dropped() -> None:
    node, feed, _ = setup(buffer=100, statistics_ns=3600_000_000_000)
    node.will()
    feed.frame(node)  # the statistics of the first report
    start = node.buffer.dropped + node.buffer.values
    walls = []
    for n in range(1000):  # no session: every report kept, the oldest dropped beyond 100
        assert feed.frame(node, **{"t1.sN": n + 1}) == []
        walls.append(round(feed.wall * 1000))
    assert node.buffer.values == 100 and node.buffer.dropped == start + 900
    out = node.start_publishing()
    assert kinds(out)[:2] == ["NBIRTH", "DBIRTH/t1"]
    assert metrics(out[0])["Edge/buffer_dropped"] == start + 900
    assert metrics(out[1])["Memory/sN"] == 1000  # the birth: the value now, not history
    assert kinds(out[2:]) == ["DDATA/t1"]  # a device's history in one message (<= 500)
    (history,) = [decode(m) for m in out[2:]]
    assert [m.long_value for m in history.metrics] == list(range(901, 1001))
    assert [m.timestamp for m in history.metrics] == walls[900:]  # each its scan's time
    assert all(m.is_historical for m in history.metrics)
    assert history.seq == 2 and history.timestamp == walls[-1]
    assert node.buffer.values == 0


def test_history_goes_out_in_messages_of_at_most_500_values() -> None:
    node, feed, _ = setup(buffer=2000, statistics_ns=3600_000_000_000)
    node.will()
    feed.frame(node)
    for n in range(1200):
        feed.frame(node, **{"t1.sN": n + 1})
    out = node.start_publishing()
    sizes = [len(decode(m).metrics) for m in out[2:] if "/DDATA/" in m.topic]
    assert sizes == [500, 500, 200]
    assert [decode(m).seq for m in out] == list(range(len(out)))


def test_after_the_feed_comes_back_the_state_waits_for_the_new_status() -> None:
    """Frames can come before the controller's first status on a new connection (from the
    shared image): Controller/state stays offline until that status, not the last
    controller's state again (the feed's client marks each connection's status:
    ``FeedState.status_current``)."""
    node, feed, _ = setup()
    node.will()
    node.start_publishing()
    node.lost()
    feed.state.status_current = False  # as FeedClient does on its new connection
    feed.schema(node)
    feed.scan += 5
    feed.state.apply(json.dumps({"f": [feed.scan, feed.wall, feed.values]}).encode())
    out = node.frame()
    assert kinds(out)[:1] == ["DBIRTH/t1"]
    assert "running" not in [v for m in out for v in metrics(m).values()], [
        metrics(m) for m in out]
    out = feed.frame(node)  # with the new connection's first status
    assert "running" in [v for m in out for v in metrics(m).values()], [
        metrics(m) for m in out]


def test_the_feed_lost_kills_the_devices_and_its_return_births_them() -> None:
    node, feed, _ = setup()
    node.will()
    node.start_publishing()
    out = node.lost()
    assert kinds(out) == ["DDEATH/t1", "NDATA"]
    assert list(metrics(out[1]).values()) == [OFFLINE]  # Controller/state, by its alias
    feed.schema(node)
    out = feed.frame(node, **{"t1.sN": 7})
    assert kinds(out)[:1] == ["DBIRTH/t1"]
    assert metrics(out[0])["Memory/sN"] == 7
    assert metrics(out[1])  # Controller/state running again (an NDATA)
    seqs = [decode(m).seq for m in out]
    assert seqs == sorted(seqs)


def test_an_online_change_births_what_changed() -> None:
    node, feed, _ = setup()
    node.will()
    node.start_publishing()
    # a new instance: its DBIRTH, nothing else reborn
    feed.names = [*NAMES, ["t2.sN", "int", "memory"]]
    feed.values = [*VALUES, 5]
    feed.instances = {"t1": "Blink", "t2": "Blink"}
    feed.schema(node)
    assert kinds(feed.frame(node)) == ["DBIRTH/t2"]
    # an instance gone, another whose metrics changed: DDEATH, DDEATH, DBIRTH
    feed.names = [n for n in NAMES if n[0] != "t1.sRate"]
    feed.values = [v for n, v in zip(NAMES, VALUES, strict=True) if n[0] != "t1.sRate"]
    feed.instances = {"t1": "Blink"}
    feed.schema(node)
    assert kinds(feed.frame(node)) == ["DDEATH/t1", "DDEATH/t2", "DBIRTH/t1"]


def test_a_command_is_checked_whole_before_anything_is_written() -> None:
    node, _feed, _ = setup()
    lay = node.layout
    assert lay is not None
    alias = lay.metrics[lay.by_name[("t1", "Memory/sStop")]].alias
    writes = node.device_command("t1", [Command(None, alias, DataType.BOOLEAN, True),
                                        Command("Memory/sT", None, DataType.DOUBLE, 2.5),
                                        Command("Memory/sRate", None, DataType.INT64, 3)])
    assert [(w.plant, w.value) for w in writes] == [
        ("t1.sStop", True), ("t1.sT", 2_500_000), ("t1.sRate", 3.0)]
    for cmds, words in [
        ([Command("Outputs/oLamp", None, DataType.BOOLEAN, True)], "not writable"),
        ([Command("Memory/sStop", None, DataType.STRING, "yes")], "expected a Boolean"),
        ([Command("Memory/sN", None, DataType.DOUBLE, 1.5)], "expected a Int64"),
        ([Command("Memory/sN", None, DataType.BOOLEAN, True)], "expected a Int64"),
        ([Command("Memory/nope", None, DataType.BOOLEAN, True)], "no metric Memory/nope"),
        ([Command(None, 9999, DataType.BOOLEAN, True)], "no metric alias 9999"),
        ([Command("Memory/sStop", None, DataType.BOOLEAN, True),
          Command("Inputs/iGo", None, DataType.BOOLEAN, True)], "not writable"),
    ]:
        with pytest.raises(CommandRefused, match=words):
            node.device_command("t1", cmds)
    with pytest.raises(CommandRefused, match="no device 't9'"):
        node.device_command("t9", [Command("Memory/sStop", None, DataType.BOOLEAN, True)])
    with pytest.raises(CommandRefused, match="not a node command"):
        node.node_command([Command("Memory/sStop", None, DataType.BOOLEAN, True)])
    with pytest.raises(CommandRefused, match="expected the Boolean true"):
        node.node_command([Command("Node Control/Rebirth", None, DataType.BOOLEAN, False)])


def test_hostile_command_payloads_are_refused_whole() -> None:
    ok = command_payload(1, [Command("Memory/sStop", None, DataType.BOOLEAN, True)])
    assert decode_command(ok) == [Command("Memory/sStop", None, DataType.BOOLEAN, True)]
    neg = command_payload(1, [Command("Memory/sN", None, DataType.INT64, -5)])
    assert decode_command(neg)[0].value == -5  # two's complement, as the spec says
    many = command_payload(1, [Command(f"M/{k}", None, DataType.BOOLEAN, True)
                               for k in range(65)])
    cases = {b"\xff\xff\xff garbage": "not a Sparkplug B payload",
             b"": "no metric",
             b"x" * (COMMAND_MAX_BYTES + 1): "bytes (at most",
             many: "65 metrics (at most 64)",
             command_payload(1, [Command(None, None, DataType.BOOLEAN, True)]):
                 "neither name nor alias",
             command_payload(1, [Command("a", None, DataType.DOUBLE, float("nan"))]):
                 "not a finite number",
             command_payload(1, [Command("a", None, DataType.STRING, "x" * 2000)]):
                 "a text of 2000 characters",
             command_payload(1, [Command("a", None, DataType.BOOLEAN, None)]): "null value"}
    for data, words in cases.items():
        with pytest.raises(CommandError, match=re.escape(words)):
            decode_command(data)
    p = Payload(timestamp=1)
    p.metrics.add(name="a", datatype=17, bytes_value=b"x")
    with pytest.raises(CommandError, match="datatype 17"):
        decode_command(p.SerializeToString())
    p = Payload(timestamp=1)
    p.metrics.add(name="a", datatype=11)
    with pytest.raises(CommandError, match="no value"):
        decode_command(p.SerializeToString())


REBIRTH = [Command("Node Control/Rebirth", None, DataType.BOOLEAN, True)]


def test_rebirth_requests_are_folded_into_one_a_second() -> None:
    """300 NCMD Rebirth at once: one rebirth now, one for all the others when the hold
    (REBIRTH_HOLD_S after the last births) is over; a request that comes later is served
    at once. (Before: 300 rebirths, each NBIRTH and every DBIRTH.)"""
    node, feed, clock = setup()
    node.will()
    node.start_publishing()
    clock.t += REBIRTH_HOLD_S  # births a second ago: a request is served at once
    first = node.node_command(REBIRTH)
    assert kinds(first) == ["NBIRTH", "DBIRTH/t1"]
    later = [node.node_command(REBIRTH) for _ in range(299)]
    assert all(m == [] for m in later)
    assert node.rebirth_due == clock.t + REBIRTH_HOLD_S
    assert node.owed_rebirth() == []  # not yet
    clock.t += REBIRTH_HOLD_S / 2
    assert kinds(feed.frame(node, **{"t1.sN": 7})) == ["DDATA/t1"]  # reports go on
    assert node.owed_rebirth() == []
    clock.t += REBIRTH_HOLD_S / 2
    owed = node.owed_rebirth()
    assert kinds(owed) == ["NBIRTH", "DBIRTH/t1"] and decode(owed[0]).seq == 0
    assert node.rebirth_due is None and node.owed_rebirth() == []
    # births for another reason answer the requests folded before them
    clock.t += 0.1
    node.node_command(REBIRTH)
    assert node.rebirth_due is not None
    node.session_lost()
    assert node.rebirth_due is None
    node.will()
    assert kinds(node.start_publishing()) == ["NBIRTH", "DBIRTH/t1"]
    assert node.owed_rebirth() == []


def history(msgs: list[Message]) -> list[tuple[str, Any, bool]]:
    """(topic kind, each metric's value, historical) of data messages."""
    return [(kinds([m])[0], v, x.is_historical) for m in msgs
            for x in decode(m).metrics
            for v in [getattr(x, x.WhichOneof("value")) if x.WhichOneof("value") else None]]


def test_reports_the_broker_did_not_take_come_back_as_history() -> None:
    """Every data message carries its report (device, name, type, value, time); what a
    session's broker was not seen to take goes back before what was buffered since, and
    comes after the next births as history, each value with its own time, in order."""
    node, feed, clock = setup(statistics_ns=3600_000_000_000)
    node.will()
    node.start_publishing()
    sent = [m for n in range(1, 4) for m in feed.frame(node, **{"t1.sN": n})]
    assert [m.report is not None for m in sent] == [True, True, True]
    assert [c[1:4] for m in sent for c in m.report.changes] == [  # type: ignore[union-attr]
        ("Memory/sN", DataType.INT64, n) for n in (1, 2, 3)]
    stamps = [m.report.changes[0][4] for m in sent]  # type: ignore[union-attr]
    assert stamps == sorted(stamps) and stamps[0] == decode(sent[0]).timestamp
    # the session ends; the broker was seen to take the first report only
    node.session_lost()
    node.requeue([m.report for m in sent[1:] if m.report is not None])
    assert feed.frame(node, **{"t1.sN": 4}) == []  # kept, after the two that came back
    node.will()
    out = node.start_publishing()
    assert kinds(out)[:2] == ["NBIRTH", "DBIRTH/t1"]
    hist = history(out[2:])
    assert hist == [("DDATA/t1", 2, True), ("DDATA/t1", 3, True), ("DDATA/t1", 4, True)]
    assert [x.timestamp for x in decode(out[2]).metrics][:2] == stamps[1:]
    # the history messages carry their reports too (a second outage sends them again)
    assert [c[3] for m in out[2:] for c in m.report.changes] == [2, 3, 4]  # type: ignore
    # births carry none: they are sent again by the next session anyway
    assert out[0].report is None and out[1].report is None
    assert clock.t  # the virtual clock never moved: nothing here is timed


def test_the_buffer_takes_reports_back_before_its_own_within_its_bound() -> None:
    b = Buffer(5)
    b.add(Report(3, [("t1", "a", DataType.INT64, 3, 3)] * 2))
    b.add_front([Report(1, [("t1", "a", DataType.INT64, 1, 1)] * 2),
                 Report(2, [("t1", "a", DataType.INT64, 2, 2)] * 2)])
    assert [r.timestamp for r in b.reports] == [2, 3] and b.dropped == 2  # oldest first
    j = Journal()
    k1, k2, k3 = (j.add(Report(t, [])) for t in (1, 2, 3))
    j.confirm(k2)
    assert [r.timestamp for r in j.take()] == [3] and j.take() == []
    assert k3 == 3 and Buffer(0).dropped == 0
    zero = Buffer(0)
    zero.add_front([Report(1, [("t1", "a", DataType.INT64, 1, 1)])])
    assert zero.dropped == 1 and not zero.reports
