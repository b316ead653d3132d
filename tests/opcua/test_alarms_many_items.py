"""Alarm events reach clients that also hold a thousand monitored items each: the plant
of bench/opcua.py (30 drawer testers, their drawers moving: 1183 variables, about 420 of
them changing every sample), the real ``softplc opcua`` process, two asyncua clients each
subscribed to every variable and to the Server object's alarms and conditions. Ten
testers' SFCError alarms are raised and cleared in turn, each state held until the feed
sent it; every change of the board (raised, cleared) is an event each client receives,
and the data changes go on flowing. (Before the server wrote only the changed values, it
fell behind the feed: the feed dropped it again and again and the second client could not
subscribe: it received none of the events.)"""

from __future__ import annotations

import asyncio
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

from asyncua import Client, ua

from bench.opcua import opcua_plant, start_daemon, stop_daemon
from runtime.controller.daemon import Daemon
from tests.opcua.feedkit import FeedReader, until, wait_until
from tests.opcua.kit import end, free_port, softplc, variables, wait_serving

TESTERS = 30
#: alarms raised (and cleared) one after the other: twice as many board changes
RAISED = 10
#: clients, each subscribed to every variable and to the alarms (as bench/opcua.py's)
CLIENTS = 2
#: generous bounds for a loaded 2-core machine (server at niceness 10), seconds
START_S = 240.0
EVENTS_S = 90.0
SUBSCRIBE_S = 150.0


class Counter:
    """An asyncua subscription handler: data changes counted, alarm events kept as
    (condition, active)."""

    def __init__(self) -> None:
        self.changes = 0
        self.events: list[tuple[str, bool]] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.changes += 1

    def event_notification(self, event: Any) -> None:
        fields = event.get_event_props_as_fields_dict()
        name = fields.get("ConditionName")
        active = fields.get("ActiveState/Id")
        self.events.append((str(getattr(name, "Value", name)),
                            bool(getattr(active, "Value", active))))


def board_changes(d: Daemon, feed: FeedReader, keys: list[str]) -> list[tuple[str, bool]]:
    """Raise and clear the SFCError alarm of each of ``keys``' instances in turn, from this
    thread (between two scans, as the console's ``set``); each state waited for in the
    status the feed sent (``feed``, a client of it beside the server: the server got the
    same line), so that none is shorter than a sample. The (key, active) changes made."""
    made: list[tuple[str, bool]] = []
    plant = d.plant

    def sent(key: str, active: bool) -> bool:
        last = feed.statuses[-1] if feed.statuses else {}
        return any(a["key"] == key and bool(a["active"]) is active
                   for a in (last.get("alarms") or []))
    for key in keys:
        name = key.split(".", 1)[0]
        d.call(partial(plant.set, f"{name}.SFCError", True))
        wait_until(partial(sent, key, True), 30.0, f"{key} raised")
        made.append((key, True))
        d.call(partial(plant.pulse, name, "SFCQuitError"))
        wait_until(partial(sent, key, False), 30.0, f"{key} cleared")
        made.append((key, False))
    return made


async def watch(url: str, counter: Counter, ready: threading.Event, done: threading.Event
                ) -> int:
    """Subscribe to every variable and to the Server's alarms, set ``ready``, and keep the
    session until ``done``: the number of data change items created."""
    client = Client(url, timeout=60, watchdog_intervall=60)
    await client.connect()
    try:
        ids = await variables(client)
        sub = await client.create_subscription(100, counter)
        nodes = [client.get_node(i) for i in ids]
        for k in range(0, len(nodes), 500):
            await sub.subscribe_data_change(nodes[k:k + 500], queuesize=1)
        # AlarmConditionType: its fields selected (ActiveState among them)
        await sub.subscribe_alarms_and_conditions(client.nodes.server,
                                                  ua.ObjectIds.AlarmConditionType)
        ready.set()
        await until(done.is_set, timeout=START_S + 3 * EVENTS_S, what="the test's end")
        return len(ids)
    finally:
        await client.disconnect()


class Watcher:
    """One client (:func:`watch`) in a thread of its own, with its own event loop."""

    def __init__(self, url: str, done: threading.Event) -> None:
        self.counter = Counter()
        self.ready = threading.Event()
        self.result: dict[str, Any] = {}
        self.thread = threading.Thread(target=self._run, args=(url, done), daemon=True)

    def _run(self, url: str, done: threading.Event) -> None:
        try:
            self.result["items"] = asyncio.run(watch(url, self.counter, self.ready, done))
        except BaseException as exc:  # handed to the test
            self.result["error"] = exc
            self.ready.set()

    def events(self, keys: list[str]) -> list[tuple[str, bool]]:
        return [e for e in self.counter.events if e[0] in keys]


def test_every_alarm_event_reaches_clients_of_a_thousand_items(tmp_path: Path) -> None:
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}"
    path = opcua_plant(str(tmp_path), TESTERS, port, False, None, clients=CLIENTS)
    assert f"feed: {tmp_path}/feed.sock" in Path(path).read_text(encoding="utf-8")
    d, fs = start_daemon(path, TESTERS, True)
    server = softplc("opcua", path, cwd=tmp_path, log=tmp_path / "server.log")
    done = threading.Event()
    watchers = [Watcher(url, done) for _ in range(CLIENTS)]
    try:
        asyncio.run(wait_serving(url, time.monotonic() + START_S))
        for w in watchers:  # one after the other, as bench/opcua.py; one that cannot
            w.thread.start()  # subscribe receives nothing: the counts below say so
            w.ready.wait(SUBSCRIBE_S)
        # control: data changes flow to the clients before any alarm
        before = [w.counter.changes for w in watchers]
        try:
            wait_until(lambda: all(w.counter.changes > b + 1000
                                   for w, b in zip(watchers, before, strict=True)),
                       EVENTS_S, "data changes")
        except AssertionError:
            pass
        keys = [f"t{k}.SFCError" for k in range(RAISED)]
        feed = FeedReader(str(tmp_path / "feed.sock"))
        try:
            made = board_changes(d, feed, keys)
        finally:
            feed.close()
        assert len(made) == 2 * RAISED
        flowing = [w.counter.changes for w in watchers]
        try:
            wait_until(lambda: all(len(w.events(keys)) >= len(made) for w in watchers),
                       EVENTS_S, "every alarm event")
        except AssertionError:
            pass  # the counts below say what came
        for k, w in enumerate(watchers):
            got = w.events(keys)
            assert sorted(got) == sorted(made), (
                f"client {k + 1}: {len(got)} of {len(made)} alarm events received; "
                f"{w.counter.changes} data changes received; subscribed: "
                f"{w.ready.is_set()}, {w.result}")
        # and the data changes went on meanwhile
        wait_until(lambda: all(w.counter.changes > f
                               for w, f in zip(watchers, flowing, strict=True)),
                   EVENTS_S, "data changes still")
    finally:
        done.set()
        for w in watchers:
            if w.thread.is_alive() or w.thread.ident is not None:
                w.thread.join(60)
        end(server)
        stop_daemon(d, fs)
    for w in watchers:
        assert w.result.get("items", 0) > 1000, w.result
