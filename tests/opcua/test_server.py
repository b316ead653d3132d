"""The OPC UA server (runtime/opcua) in this process, in a thread of its own, fed by a real
Daemon on sim I/O through the real feed socket, and the asyncua client over TCP: browse,
read, subscribe (every notification equals the trace at its scan), writes, the controller
stopped and started again, events."""

from __future__ import annotations

import asyncio
import json
import socket
import threading
from pathlib import Path
from typing import Any

from asyncua import Client, ua
from asyncua.common.subscription import Subscription

from drivers.base import DriverError
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from runtime.opcua.server import _event_text
from tests.daemon.daemonkit import RecordingDriver
from tests.opcua.feedkit import (
    HeldStatusFeed,
    ServerThread,
    controller,
    driver_health,
    lines_until,
    read_trace,
    serving,
    wait_shown,
    wait_until,
)
from tests.opcua.feedkit import until as _until
from tests.opcua.kit import free_port, write_plant, writer


def started(tmp: Path, **kw: Any) -> tuple[Any, int]:
    port = free_port()
    return controller(tmp, port=port, **kw), port


def test_browse_the_tree_names_types_and_node_ids(tmp_path: Path) -> None:
    ctl, port = started(tmp_path, trace=False)
    with ctl as (d, feed, _), ServerThread(d.pdef) as srv:
        assert srv.ps is not None
        wait_shown(srv)

        async def main() -> None:
            async with Client(srv.url) as c:
                top = {(await n.read_browse_name()).to_string(): n.nodeid.to_string()
                       for n in await c.nodes.objects.get_children()}
                assert {k: v for k, v in top.items() if k.startswith("2:")} == {
                    "2:t1": "ns=2;s=t1", "2:t2": "ns=2;s=t2", "2:io": "ns=2;s=driver.io",
                    "2:Controller": "ns=2;s=controller"}
                t1 = c.get_node("ns=2;s=t1")
                folders = {(await n.read_browse_name()).Name: [
                    (await x.read_browse_name()).Name for x in await n.get_children()]
                    for n in await t1.get_children()}
                assert folders == {
                    "Inputs": ["iGo"], "Outputs": ["oLamp"],
                    "Memory": ["sN", "sStop", "sJam", "sRate", "sDiv", "sQ"],
                    "Flags": ["SFCInit", "SFCReset", "SFCPause", "SFCError", "SFCEnableLimit",
                              "SFCQuitError", "SFCTipMode", "SFCTip", "SFCErrorStep",
                              "SFCCurrentStep"],
                    "Steps": ["gsA", "gsB", "gsJam"],
                    # its methods and its alarms (tests/opcua/test_alarms.py)
                    "Acknowledge": [], "Reset": [], "Pause": [], "Resume": [],
                    "Alarms": ["SFCError", "gsJam.maxtime"]}
                step = [x.nodeid.to_string() for x in
                        await c.get_node("ns=2;s=t1.gsB").get_children()]
                assert step == ["ns=2;s=t1.gsB.X", "ns=2;s=t1.gsB.T"]
                types = {}
                for name in ("t1.iGo", "t1.sN", "t1.sRate", "t1.gsB.T", "t1.SFCCurrentStep",
                             "controller.scans", "driver.io.health", "io.I0", "io.ok"):
                    dt = await c.get_node(f"ns=2;s={name}").read_data_type()
                    types[name] = (await c.get_node(dt).read_browse_name()).Name
                assert types == {"t1.iGo": "Boolean", "t1.sN": "Int64", "t1.sRate": "Double",
                                 "t1.gsB.T": "Duration", "t1.SFCCurrentStep": "String",
                                 "controller.scans": "Int64", "driver.io.health": "String",
                                 "io.I0": "Boolean", "io.ok": "Boolean"}
                access = {n: await c.get_node(f"ns=2;s={n}").get_access_level() for n in (
                    "t1.sStop", "t1.SFCQuitError", "t1.sN", "t2.sStop")}
                writable = {n for n, a in access.items() if ua.AccessLevel.CurrentWrite in a}
                assert writable == {"t1.sStop", "t1.SFCQuitError"}
                assert await c.get_node("ns=2;s=driver.io.health").read_value() == "ok"
                assert await c.get_node("ns=2;s=controller.state").read_value() == "running"
                assert await c.get_node("ns=2;s=t1.sRate").read_value() == 1.5
        asyncio.run(main())


class Collect:
    def __init__(self) -> None:
        self.items: list[tuple[str, ua.DataValue]] = []
        self.events: list[Any] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.items.append((node.nodeid.Identifier, data.monitored_item.Value))

    def event_notification(self, event: Any) -> None:
        self.events.append(event)


class BatchSubscription(Subscription):
    """Keeps each publish's data changes together: what a client has seen after each."""

    batches: list[list[tuple[str, ua.DataValue]]]

    async def publish_callback(self, publish_result: ua.PublishResult) -> None:
        for notif in publish_result.NotificationMessage.NotificationData or ():
            if isinstance(notif, ua.DataChangeNotification):
                self.batches.append([
                    (self._monitored_items[i.ClientHandle].node.nodeid.Identifier, i.Value)
                    for i in notif.MonitoredItems])
        await super().publish_callback(publish_result)


def test_every_notification_is_the_trace_at_its_scan(tmp_path: Path) -> None:
    ctl, port = started(tmp_path)
    with ctl as (d, feed, trace), ServerThread(d.pdef) as srv:
        wait_shown(srv)
        handler = Collect()
        batches: list[list[tuple[str, ua.DataValue]]] = []

        async def main() -> float:
            async with Client(srv.url) as c:
                params = ua.CreateSubscriptionParameters(
                    RequestedPublishingInterval=100, RequestedLifetimeCount=1000,
                    RequestedMaxKeepAliveCount=10, MaxNotificationsPerPublish=0,
                    PublishingEnabled=True)
                sub = BatchSubscription(c.uaclient.session, params, handler)
                sub.batches = batches
                res = await sub.init()
                names = [f"t{i}.{n}" for i in (1, 2) for n in (
                    "iGo", "oLamp", "sN", "sStop", "sRate", "SFCError", "SFCCurrentStep",
                    "gsA.X", "gsA.T", "gsB.X", "gsB.T", "gsJam.X")] + ["io.Q0", "io.Q1"]
                nodes = [c.get_node(f"ns=2;s={n}") for n in [*names, "controller.scan"]]
                await sub.subscribe_data_change(nodes, queuesize=100)
                await _until(lambda: _scans(handler) >= 40, what="40 scans notified")
                await sub.delete()
                return float(res.RevisedPublishingInterval)
        revised = asyncio.run(main())
        d.stop()
    assert revised == 100.0
    rows = read_trace(trace)
    # a frame's values all carry its source timestamp, and controller.scan names its scan
    scan_at = {dv.SourceTimestamp: dv.Value.Value for n, dv in handler.items
               if n == "controller.scan"}
    assert len(set(scan_at.values())) == len(scan_at)  # one timestamp per scan
    checked = 0
    first = min(scan_at)
    for name, dv in handler.items:
        if name == "controller.scan" or not dv.StatusCode.is_good():
            continue
        if dv.SourceTimestamp not in scan_at:
            # a value unchanged since before the subscription: its first notification
            # carries the scan at which it last changed (only changed values are written)
            assert dv.SourceTimestamp < first, (name, dv.SourceTimestamp, first)
            continue
        scan = scan_at[dv.SourceTimestamp]
        row = rows[scan]
        value = dv.Value.Value
        if name.endswith(".T"):
            assert row[name[:-2] + ".T_ms"] == int(value), (name, scan)
        elif isinstance(value, bool):
            assert row[name] == int(value), (name, scan)
        else:
            assert row[name] == value, (name, scan)
        checked += 1
    assert checked > 100
    # one scan per update: after each publish, what the client holds is one scan's image
    seen: dict[str, Any] = {}
    for batch in batches:
        seen.update({n: dv.Value.Value for n, dv in batch})
        row = rows[seen["controller.scan"]]
        for name, value in seen.items():
            if name.endswith(".T"):
                assert row[name[:-2] + ".T_ms"] == int(value), (name, seen["controller.scan"])
            elif name != "controller.scan":
                assert row[name] == (int(value) if isinstance(value, bool) else value), (
                    name, seen["controller.scan"])
    assert len(batches) > 10


def _scans(h: Collect) -> int:
    return sum(1 for n, _ in h.items if n == "controller.scan")


def test_a_subscription_asking_for_zero_ms_publishes_at_the_sample(tmp_path: Path) -> None:
    """A 0 ms subscription would publish in the middle of a frame's batch: revised."""
    ctl, port = started(tmp_path, trace=False)
    with ctl as (d, feed, _), ServerThread(d.pdef) as srv:
        async def main() -> float:
            async with Client(srv.url) as c:
                params = ua.CreateSubscriptionParameters(
                    RequestedPublishingInterval=0, RequestedLifetimeCount=1000,
                    RequestedMaxKeepAliveCount=10, PublishingEnabled=True)
                res = await Subscription(c.uaclient.session, params, Collect()).init()
                return float(res.RevisedPublishingInterval)
        assert asyncio.run(main()) == 50.0


def test_writes_allowed_refused_and_applied_between_scans(tmp_path: Path) -> None:
    ctl, port = started(tmp_path)
    with ctl as (d, feed, trace), ServerThread(d.pdef) as srv:
        wait_shown(srv)

        async def write(c: Client, name: str, variant: ua.Variant) -> ua.StatusCode:
            params = ua.WriteParameters()
            params.NodesToWrite = [ua.WriteValue(
                NodeId=ua.NodeId.from_string(f"ns=2;s={name}"),
                AttributeId=ua.AttributeIds.Value, Value=ua.DataValue(variant))]
            return (await c.uaclient.write(params))[0]

        async def main() -> tuple[int, int]:
            async with writer(srv.url) as c:
                b = ua.VariantType.Boolean
                before = d.scan_stats.count
                good = await write(c, "t1.sStop", ua.Variant(True, b))
                after = d.scan_stats.count
                assert good.is_good(), good
                codes = {n: (await write(c, n, v)).name for n, v in (
                    ("t1.sN", ua.Variant(5, ua.VariantType.Int64)),
                    ("t1.oLamp", ua.Variant(True, b)),
                    ("t2.sStop", ua.Variant(True, b)),
                    ("controller.scans", ua.Variant(0, ua.VariantType.Int64)),
                    ("io.Q0", ua.Variant(True, b)),
                    ("t1.sStop", ua.Variant(1, ua.VariantType.Int64)))}
                assert codes == {"t1.sN": "BadNotWritable", "t1.oLamp": "BadNotWritable",
                                 "t2.sStop": "BadNotWritable",
                                 "controller.scans": "BadNotWritable",
                                 "io.Q0": "BadNotWritable", "t1.sStop": "BadTypeMismatch"}
                node = c.get_node("ns=2;s=t1.sStop")
                await _until(lambda: _value_is(node, True), what="t1.sStop read back as 1")
                # the asyncua client's own helper says the same
                try:
                    await c.get_node("ns=2;s=t1.sN").write_value(
                        ua.Variant(5, ua.VariantType.Int64))
                    raise AssertionError("t1.sN was written")
                except ua.UaStatusCodeError as exc:
                    assert exc.code == ua.StatusCodes.BadNotWritable
                return before, after
        before, after = asyncio.run(main())
        # the read-back can come a scan or two after the write, while t1 is still in gsB
        # (40 ms): let it get back to gsA, where sStop holds it, before the stop (asked in
        # the scan thread: that scan's trace row is queued before the answer comes back)
        t1 = d.plant.instances["t1"]
        wait_until(lambda: d.call(lambda: t1.get("gsA.X")) is True, what="t1 back in gsA")
        d.stop()
    rows = read_trace(trace)
    first = min(cy for cy, row in rows.items() if row["t1.sStop"] == 1)
    assert before - 1 <= first <= after
    assert all(row["t1.sStop"] == (1 if cy >= first else 0) for cy, row in rows.items())
    # and it acted: from the first gsA after it, t1 stays in gsA (sStop holds it)
    held = min(cy for cy, row in rows.items() if cy >= first and row["t1.gsA.X"] == 1)
    assert all(row["t1.gsA.X"] == 1 for cy, row in rows.items() if cy >= held)


async def _value_is(node: Any, value: Any) -> bool:
    return bool(await node.read_value() == value)


def test_controller_stopped_then_started_again(tmp_path: Path) -> None:
    port = free_port()
    with controller(tmp_path, trace=False, port=port) as (d, feed, _):
        pdef = load_plant(str(tmp_path / "plant.yaml"))
    with ServerThread(pdef) as srv:
        async def status(c: Client) -> tuple[str, str]:
            dv = await c.get_node("ns=2;s=controller.scans").read_data_value(
                raise_on_bad_status=False)
            dv2 = await c.get_node("ns=2;s=t1.sN").read_data_value(raise_on_bad_status=False)
            return dv.StatusCode.name, dv2.StatusCode.name

        async def main() -> None:
            async with Client(srv.url) as c:
                # before the first schema the plant's names are not there yet
                assert await status(c) == ("BadWaitingForInitialData", "BadNodeIdUnknown")
                with controller(tmp_path, trace=False, port=port) as (d, feed, _):
                    await _until(lambda: _status_is(c, "Good"), what="good values")
                    scans = await c.get_node("ns=2;s=controller.scans").read_value()
                    assert scans > 0
                await _until(lambda: _status_is(c, "BadNoCommunication"),
                             what="BadNoCommunication once the controller is gone")
                assert await status(c) == ("BadNoCommunication", "BadNoCommunication")
                with controller(tmp_path, trace=False, port=port) as (d, feed, _):
                    await _until(lambda: _status_is(c, "Good"), what="good values again")
        asyncio.run(main())


async def _status_is(c: Client, name: str) -> bool:
    dv = await c.get_node("ns=2;s=t1.sN").read_data_value(raise_on_bad_status=False)
    return bool(dv.StatusCode.name == name)


def test_sfcerror_set_and_cleared_are_events_of_the_instance(tmp_path: Path) -> None:
    ctl, port = started(tmp_path, trace=False)
    with ctl as (d, feed, _), ServerThread(d.pdef) as srv:
        wait_shown(srv)
        handler = Collect()

        async def main() -> None:
            async with writer(srv.url) as c:
                sub = await c.create_subscription(100, handler)
                await sub.subscribe_events(c.get_node("ns=2;s=t1"))
                await c.get_node("ns=2;s=t1.sJam").write_value(True)
                await _until(lambda: _has(handler, "t1: SFCError set by step gsJam"),
                             what="the SFCError event")
                await c.get_node("ns=2;s=t1.sJam").write_value(False)
                await c.get_node("ns=2;s=t1.SFCQuitError").write_value(True)
                await _until(lambda: _has(handler, "t1: SFCError cleared"),
                             what="the cleared event")
                await sub.delete()
        asyncio.run(main())
    texts = [(e.Message.Text, e.Severity, e.SourceName) for e in handler.events]
    assert texts == [("t1: SFCError set by step gsJam", 700, "t1"),
                     ("t1: SFCError cleared", 300, "t1")]


def test_an_sfcerror_the_chart_set_is_said_so_in_its_event() -> None:
    """No step's max time set it (SFCErrorStep empty): the event says who did, as the log,
    the alarms and the console do (it said 't1: SFCError set')."""
    assert _event_text("i:t1", (False, ""), (True, "")) == ("t1: SFCError set by the chart",
                                                            700)
    assert _event_text("i:t1", (False, ""), (True, "gsJam"))[0] == "t1: SFCError set by step gsJam"


async def _has(h: Collect, text: str) -> bool:
    return any(e.Message.Text == text for e in h.events)


def test_a_frame_is_written_without_a_suspension_point(tmp_path: Path) -> None:
    """The mechanism behind "one scan per update": applying a frame never yields to the
    event loop, so no publish task can run between two of its values. Checked by stepping
    the coroutine once, with a client subscribed to every value (the notifications are
    queued during the batch)."""
    ctl, port = started(tmp_path, trace=False)
    with ctl as (d, feed, _), ServerThread(d.pdef) as srv:
        wait_shown(srv)
        ps = srv.ps
        assert ps is not None

        async def one_step() -> bool:
            coro = ps._frame()
            try:
                coro.send(None)
            except StopIteration:
                return True
            coro.close()
            return False

        async def main() -> list[bool]:
            async with Client(srv.url) as c:
                sub = await c.create_subscription(100, Collect())
                await sub.subscribe_data_change(
                    [c.get_node(n) for n in ps.space.nodes], queuesize=10)
                results = []
                for _ in range(20):
                    results.append(srv.call(one_step()))
                    await asyncio.sleep(0.01)
                await sub.delete()
                return results
        assert asyncio.run(main()) == [True] * 20


def test_a_controller_fault_and_its_ack_are_events_of_the_controller(tmp_path: Path) -> None:
    ctl, port = started(tmp_path, trace=False)
    with ctl as (d, feed, _), ServerThread(d.pdef) as srv:
        wait_shown(srv)
        handler = Collect()

        async def main() -> None:
            async with writer(srv.url) as c:
                sub = await c.create_subscription(100, handler)
                await sub.subscribe_events(c.get_node("ns=2;s=controller"))
                await c.get_node("ns=2;s=t1.sDiv").write_value(0)  # 100 / 0 in a scan
                await _until(lambda: bool(handler.events), what="the fault event")
                state = c.get_node("ns=2;s=controller.state")
                await _until(lambda: _value_is(state, "fault"), what="state fault")
                # memory is written between scans whatever the state; then the ack
                await c.get_node("ns=2;s=t1.sDiv").write_value(1)
                await asyncio.to_thread(d.ack)
                await _until(lambda: len(handler.events) >= 2, what="the ack event")
                await _until(lambda: _value_is(state, "running"), what="running again")
                await sub.delete()
        asyncio.run(main())
    texts = [(e.Message.Text, e.Severity, e.SourceName) for e in handler.events]
    assert texts == [
        ("controller fault: exception in scan: ZeroDivisionError: integer division or "
         "modulo by zero", 900, "Controller"),
        ("controller: fault acknowledged, now running", 300, "Controller")]


def test_driver_events_follow_every_status_not_the_frames(tmp_path: Path) -> None:
    """Statuses come on the feed's socket, frames at their own pace (from the shared
    image, at the server's own sample): a driver's fault and its recovery, said by two
    statuses between two frames, are two events. The lines are a real controller's
    (its schema without the image, so that the frames come as lines too), played again
    by a feed in this test that sends no frame between the statuses."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port())))
    drv = RecordingDriver("io", {"on_fault": "hold"})
    with serving(pdef, Plant(pdef, drivers={"io": drv})) as (_d, feed):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.connect(feed.path)
        buf = bytearray()
        schema, *_ = lines_until(sock, buf, lambda ln: ln.startswith(b'{"schema"'))
        healthy = lines_until(sock, buf, lambda ln: driver_health(ln) == "ok")[-1]
        frame = lines_until(sock, buf, lambda ln: ln.startswith(b'{"f"'))[-1]
        drv.fail_with = DriverError("bus gone")
        fault = lines_until(sock, buf, lambda ln: driver_health(ln) == "fault")[-1]
        drv.fail_with = None
        sock.close()
    plain = json.loads(schema)
    plain["schema"]["image"] = None
    scan, wall, values = json.loads(frame)["f"]
    later = json.dumps({"f": [scan + 100, wall + 1.0, values]}).encode() + b"\n"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    assert pdef.opcua is not None
    listener.bind(pdef.opcua.feed)
    listener.listen(1)
    go = threading.Event()

    def play() -> None:
        conn, _ = listener.accept()
        with conn:
            conn.sendall(json.dumps(plain).encode() + b"\n" + healthy + frame)
            go.wait(30.0)
            conn.sendall(fault + healthy + later)
            go.wait(60.0)  # until the test ends (the listener closed)

    player = threading.Thread(target=play, daemon=True)
    player.start()
    handler = Collect()
    try:
        with ServerThread(pdef) as srv:
            wait_until(lambda: srv.ps is not None and srv.ps.frames > 0, what="a first frame")

            async def main() -> None:
                async with Client(srv.url) as c:
                    sub = await c.create_subscription(100, handler)
                    await sub.subscribe_events(c.get_node("ns=2;s=driver.io"))
                    go.set()
                    assert srv.ps is not None
                    await _until(lambda: srv.ps is not None and srv.ps.frames >= 2,
                                 what="the later frame")
                    await _until(lambda: len(handler.events) >= 2, timeout=5.0,
                                 what="the fault and the recovery")
                    await sub.delete()
            asyncio.run(main())
    finally:
        go.set()
        listener.close()
    texts = [(e.Message.Text, e.Severity, e.SourceName) for e in handler.events]
    assert texts == [("driver io: fault: bus gone", 800, "io"),
                     ("driver io: recovered (ok)", 300, "io")], texts


def test_status_nodes_wait_for_this_connections_status(tmp_path: Path) -> None:
    """Frames (from the shared image) can come before the controller's first status on a
    connection. Until that status, the controller's and the drivers' nodes show no value
    as good: before the first status, none was ever written (BadWaitingForInitialData,
    not a good empty state); after a reconnection, the last connection's status is not
    shown again as good (BadNoCommunication stays until the new status). A real
    controller's lines, played again by a feed in this test that holds its statuses."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port())))
    assert pdef.opcua is not None
    played = HeldStatusFeed(pdef, pdef.opcua.feed)
    nodes = ("controller.state", "controller.cycle", "controller.uptime", "driver.io.health")

    def waiting(code: str, k: int) -> dict[str, tuple[str, Any]]:
        """The status nodes all ``code``, the frame of scan ``scan + k`` shown."""
        return {**{n: (code, None) for n in nodes},
                "controller.scans": ("Good", played.scan + k + 1)}

    try:
        with ServerThread(pdef) as srv:
            wait_until(lambda: srv.ps is not None and srv.ps.frames > 0, what="a first frame")

            async def shown(c: Client) -> dict[str, tuple[str, Any]]:
                got = {}
                for n in (*nodes, "controller.scans"):
                    dv = await c.get_node(f"ns=2;s={n}").read_data_value(
                        raise_on_bad_status=False)
                    got[n] = (dv.StatusCode.name, dv.Value.Value if dv.StatusCode.is_good()
                              else None)
                return got

            async def after(c: Client, frames: int, what: str) -> dict[str, tuple[str, Any]]:
                await _until(lambda: srv.ps is not None and srv.ps.frames >= frames,
                             what=what)
                return await shown(c)

            async def main() -> None:
                async with Client(srv.url) as c:
                    got = await shown(c)
                    assert got == waiting("BadWaitingForInitialData", 0), got
                    played.steps[0].set()
                    got = await after(c, 2, "the frame after the status")
                    assert got["controller.state"] == ("Good", "running"), got
                    assert got["driver.io.health"] == ("Good", "ok"), got
                    played.steps[1].set()  # the connection ends; the server connects again
                    got = await after(c, 3, "the new connection's first frame")
                    assert got == waiting("BadNoCommunication", 2), got
                    played.steps[2].set()
                    got = await after(c, 4, "the frame after the new status")
                    assert got["controller.state"] == ("Good", "running"), got
                    assert got["driver.io.health"] == ("Good", "ok"), got
            asyncio.run(main())
    finally:
        played.close()


def test_a_driver_fault_and_its_recovery_are_events_of_the_driver(tmp_path: Path) -> None:
    """A real driver object that fails and comes back (the recording driver of the daemon
    tests, on_fault: hold so the controller runs on): the driver object's events."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port())))
    drv = RecordingDriver("io", {"on_fault": "hold"})
    handler = Collect()
    with serving(pdef, Plant(pdef, drivers={"io": drv})) as (d, feed):
        with ServerThread(d.pdef) as srv:
            wait_shown(srv)
            # the server has been told the driver is healthy: a fault is then a change
            wait_until(lambda: srv.ps is not None and (
                srv.ps.state.status.get("drivers") or {}).get("io", [""])[0] == "ok",
                what="a status of the healthy driver")

            async def main() -> None:
                async with Client(srv.url) as c:
                    sub = await c.create_subscription(100, handler)
                    await sub.subscribe_events(c.get_node("ns=2;s=driver.io"))
                    drv.fail_with = DriverError("bus gone")
                    await _until(lambda: bool(handler.events), what="the fault event")
                    drv.fail_with = None
                    await _until(lambda: len(handler.events) >= 2, what="the recovery")
                    await sub.delete()
            asyncio.run(main())
    texts = [(e.Message.Text, e.Severity, e.SourceName) for e in handler.events]
    assert texts[0][1:] == (800, "io") and texts[0][0].startswith("driver io: fault: ")
    assert "bus gone" in texts[0][0]
    assert texts[1] == ("driver io: recovered (ok)", 300, "io")


def test_an_anonymous_write_is_refused_even_on_a_channel_never_opened(tmp_path: Path
                                                                       ) -> None:
    """asyncua keeps its permission rules with the secure channel: a client that skips
    OpenSecureChannel (HEL, then CreateSession) had none, and its anonymous write reached
    the controller (a review found it). The server checks the writer itself."""
    ctl, port = started(tmp_path)
    with ctl as (d, feed, trace), ServerThread(d.pdef) as srv:
        wait_shown(srv)

        async def attempt(skip_open: bool) -> str:
            c = Client(srv.url, timeout=20)
            if skip_open:
                async def no_open(renew: bool = False) -> None:
                    return None
                c.open_secure_channel = no_open  # type: ignore[method-assign]
            await c.connect()
            try:
                await c.get_node("ns=2;s=t1.sStop").write_value(
                    ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
                return "written"
            except ua.UaStatusCodeError as exc:
                return type(exc).__name__
            finally:
                await c.disconnect()
        assert asyncio.run(attempt(False)) == "BadUserAccessDenied"
        assert asyncio.run(attempt(True)) == "BadUserAccessDenied"
        assert d.plant.instances["t1"].get("sStop") is False


def test_an_online_change_keeps_the_unchanged_nodes_and_their_subscriptions(
        tmp_path: Path) -> None:
    """A reload that adds a variable and changes another's type: the subscription to an
    unchanged variable goes on (before, every node was deleted and made again, and such a
    subscription froze at its last good value); the changed one's subscribers see
    BadNodeIdUnknown, then the node is there again with its new type."""
    ctl, port = started(tmp_path, trace=False)
    with ctl as (d, feed, _), ServerThread(d.pdef) as srv:
        wait_shown(srv)
        handler = Collect()

        async def main() -> tuple[Any, Any]:
            async with Client(srv.url) as c:
                sub = await c.create_subscription(100, handler)
                await sub.subscribe_data_change([c.get_node("ns=2;s=t1.sN"),
                                                 c.get_node("ns=2;s=t1.sRate")])
                await _until(lambda: _count(handler, "t1.sN") >= 2, what="sN before")
                chart = tmp_path / "blink.yaml"
                chart.write_text(chart.read_text(encoding="utf-8").replace(
                    "  sQ: 0\n", "  sQ: 0\n  sExtra: 7\n").replace("sRate: 1.5", "sRate: 2"),
                    encoding="utf-8")
                result = await asyncio.to_thread(d.reload)
                assert result.applied, result.refusals
                n = _count(handler, "t1.sN")
                await _until(lambda: _count(handler, "t1.sN") >= n + 3, what="sN after")
                await _until(lambda: _node_has(c, "t1.sExtra"), what="the new node")
                extra = await c.get_node("ns=2;s=t1.sExtra").read_value()
                rate = await c.get_node("ns=2;s=t1.sRate").read_data_value()
                await sub.delete()
                return extra, rate
        extra, rate = asyncio.run(main())
    assert extra == 7
    assert rate.Value.Value == 2 and rate.Value.VariantType == ua.VariantType.Int64
    assert all(v.StatusCode.is_good() for n, v in handler.items if n == "t1.sN")
    last_rate = [v for n, v in handler.items if n == "t1.sRate"][-1]
    assert last_rate.StatusCode.name == "BadNodeIdUnknown"


def _count(h: Collect, name: str) -> int:
    return sum(1 for n, _ in h.items if n == name)


async def _node_has(c: Client, name: str) -> bool:
    dv = await c.get_node(f"ns=2;s={name}").read_data_value(raise_on_bad_status=False)
    return bool(dv.StatusCode.is_good())
