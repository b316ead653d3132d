"""Every change of an alarm reaches an OPC UA client as its own event, in order, even when
the server's event loop stalls or the change lasts less than a feed sample: a real
controller and feed, the OPC UA server in this process (``ServerThread``), a real asyncua
client subscribed to every variable and to the Server object's alarms and conditions.

Before the feed sent each change of the alarm board as a line of its own (the board's
journal), the alarms came only with the controller's status: a server whose socket was
full (its event loop stalled) got the latest status once it read again, and the feed
read the board once per sample; an alarm raised and cleared within the stall, or within
one sample, reached the client as its last state only (one event, cleared)."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import ServerThread, serving, wait_shown, wait_until
from tests.opcua.kit import free_port, write_plant
from tests.opcua.test_alarms_many_items import Counter, Watcher

KEY = "t1.SFCError"
#: generous bounds for a loaded 2-core machine, seconds
SUBSCRIBE_S = 120.0
EVENTS_S = 30.0


class States(Counter):
    """Each alarm event kept also as (condition, active, acked, confirmed)."""

    def __init__(self) -> None:
        super().__init__()
        self.states: list[tuple[str, bool, bool, bool]] = []

    def event_notification(self, event: Any) -> None:
        super().event_notification(event)
        fields = event.get_event_props_as_fields_dict()

        def flag(name: str) -> bool:
            v = fields.get(name)
            return bool(getattr(v, "Value", v))
        self.states.append((self.events[-1][0], flag("ActiveState/Id"),
                            flag("AckedState/Id"), flag("ConfirmedState/Id")))

    def of(self, key: str) -> list[tuple[str, bool, bool, bool]]:
        return [s for s in self.states if s[0] == key]


@contextmanager
def running(tmp: Path) -> Iterator[tuple[Daemon, FeedServer, ServerThread, States]]:
    """The controller, its feed, the server and one subscribed client."""
    path = write_plant(tmp, port=free_port())
    # a loaded test machine overruns now and then: that alarm kept quiet here
    path.write_text(path.read_text(encoding="utf-8")
                    + "alarms:\n  overruns: {count: 1000000}\n", encoding="utf-8")
    pdef = load_plant(str(path))
    done = threading.Event()
    with serving(pdef) as (d, feed), ServerThread(pdef) as srv:
        wait_shown(srv)
        watcher = Watcher(srv.url, done)
        states = watcher.counter = States()
        watcher.thread.start()
        try:
            assert watcher.ready.wait(SUBSCRIBE_S), "the client did not subscribe"
            assert "error" not in watcher.result, watcher.result
            yield d, feed, srv, states
        finally:
            done.set()
            watcher.thread.join(60)


def board_has(d: Daemon, active: bool) -> bool:
    return any(a.key == KEY and a.active is active for a in d.alarms.alarms())


def turns_after(feed: FeedServer, n: int = 2) -> None:
    """Wait until the feed published ``n`` more turns (what the board had is sent)."""
    start = feed.frames
    wait_until(lambda: feed.frames >= start + n, 10.0, "feed turns")


def test_an_alarm_raised_and_cleared_while_the_server_stalls(tmp_path: Path) -> None:
    with running(tmp_path) as (d, feed, srv, states):
        plant = d.plant
        server = [c for c in feed._clients if c.image]
        assert len(server) == 1, feed._clients
        # a small socket buffer: the stalled server is behind within a few statuses
        server[0].sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1)
        release = srv.stall()
        try:
            wait_until(lambda: bool(server[0].out), 30.0, "the feed to see the server behind")
            d.call(partial(plant.set, "t1.SFCError", True))
            wait_until(partial(board_has, d, True), 10.0, f"{KEY} raised")
            turns_after(feed)
            d.call(partial(plant.pulse, "t1", "SFCQuitError"))
            wait_until(partial(board_has, d, False), 10.0, f"{KEY} cleared")
            turns_after(feed)
            assert server[0].out, "the server was not behind the whole time"
            assert states.of(KEY) == []
        finally:
            release.set()
        try:
            wait_until(lambda: len(states.of(KEY)) >= 2, EVENTS_S, "both events")
        except AssertionError:
            pass  # what came is said below
        assert states.of(KEY) == [(KEY, True, False, False), (KEY, False, False, False)]


def test_raised_acknowledged_cleared_and_confirmed_within_one_sample(
        tmp_path: Path) -> None:
    with running(tmp_path) as (d, feed, srv, states):
        plant, board = d.plant, d.alarms
        # the feed's samples held (set between two scans, as the scan thread sets it):
        # the four changes are made between two turns of the feed
        d.call(lambda: setattr(feed, "_next", 1 << 62))
        wait_until(lambda: feed._taken is feed._slot, 10.0, "the last sample published")
        frames = feed.frames
        try:
            d.call(partial(plant.set, "t1.SFCError", True))
            wait_until(partial(board_has, d, True), 10.0, f"{KEY} raised")
            board.acknowledge(KEY, "tester", "seen")
            d.call(partial(plant.pulse, "t1", "SFCQuitError"))
            wait_until(partial(board_has, d, False), 10.0, f"{KEY} cleared")
            board.confirm(KEY, "tester", "done")
            assert feed.frames == frames, "a turn of the feed came between the changes"
        finally:
            d.call(lambda: setattr(feed, "_next", 0))
        try:
            wait_until(lambda: len(states.of(KEY)) >= 4, EVENTS_S, "the four events")
        except AssertionError:
            pass  # what came is said below
        assert states.of(KEY) == [(KEY, True, False, False), (KEY, True, True, False),
                                  (KEY, False, True, False), (KEY, False, True, True)]


def test_more_changes_in_a_stall_than_a_data_item_queues(tmp_path: Path) -> None:
    """120 changes of two alarms made while the server's event loop is blocked: once it
    reads again it fires them at once, before its next publish; every one reaches the
    client, in order (an event item queues up to EVENT_QUEUE_MAX notifications between two
    publishes: at QUEUE_MAX, 100, the oldest 20 were discarded)."""
    keys = ["t1.SFCError", "t2.SFCError"]
    with running(tmp_path) as (d, feed, srv, states):
        plant, board = d.plant, d.alarms

        def all_(active: bool) -> bool:
            return all(a.active is active for a in board.alarms() if a.key in keys)

        def both(fn: Any) -> None:
            for key in keys:
                fn(key.split(".")[0])
        made: list[tuple[str, bool, bool, bool]] = []
        release = srv.stall()
        try:
            for _round in range(15):
                d.call(lambda: both(lambda n: plant.set(f"{n}.SFCError", True)))
                wait_until(partial(all_, True), 10.0, "both raised")
                made += [(k, True, False, False) for k in keys]
                for key in keys:
                    board.acknowledge(key, "op", "")
                    made.append((key, True, True, False))
                d.call(lambda: both(lambda n: plant.pulse(n, "SFCQuitError")))
                wait_until(partial(all_, False), 10.0, "both cleared")
                made += [(k, False, True, False) for k in keys]
                for key in keys:
                    board.confirm(key, "op", "")
                    made.append((key, False, True, True))
            turns_after(feed)
        finally:
            release.set()

        def got() -> list[tuple[str, bool, bool, bool]]:
            return [s for s in states.states if s[0] in keys]
        try:
            wait_until(lambda: len(got()) >= len(made), EVENTS_S, "every event")
        except AssertionError:
            pass  # what came is said below
        assert len(got()) == len(made) == 120
        # in order per alarm (the two alarms' changes of one evaluation may interleave)
        for key in keys:
            assert [s for s in got() if s[0] == key] == [m for m in made if m[0] == key]
