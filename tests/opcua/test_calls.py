"""Method calls held to OPC UA Part 4 (runtime/opcua/calls.py): a writer's ``t1.Pause``
with an argument too many, or called on the object ``t2``, ran (Good) before; every
method the server exposes now answers BadTooManyArguments, BadArgumentsMissing,
BadInvalidArgument (BadTypeMismatch per argument), BadMethodInvalid, BadNodeIdUnknown,
BadNodeIdInvalid, BadNotImplemented or BadSubscriptionIdInvalid as Part 4 says, runs
nothing, says it in one log line, and the server keeps serving the other clients while
such calls arrive. With the asyncua client (Python) and node-opcua (a client not built on
the server's library)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from runtime.controller.daemon import Daemon
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import ServerThread, serving, wait_shown, wait_until
from tests.opcua.kit import WRITER, WRITER_PASSWORD, free_port, write_plant, writer
from tests.opcua.nodekit import NEEDS_NODE, AlarmClient

V = ua.VariantType
#: the condition of t1's SFCError (there from the first status on: a quiet condition)
CONDITION = "ns=2;s=alarm.t1.SFCError"


@contextmanager
def running(tmp: Path) -> Iterator[tuple[Daemon, ServerThread]]:
    path = write_plant(tmp, port=free_port())
    text = path.read_text(encoding="utf-8")
    # a loaded test machine overruns now and then: that alarm kept quiet here
    path.write_text(text + "alarms:\n  overruns: {count: 1000000}\n", encoding="utf-8")
    pdef = load_plant(str(path))
    with serving(pdef) as (d, _feed), ServerThread(pdef) as srv:
        wait_shown(srv)
        assert srv.ps is not None
        conditions = srv.ps.conditions
        wait_until(lambda: "t1.SFCError" in conditions._by_key, what="the conditions")
        yield d, srv


def request(obj: str, method: str, *args: ua.Variant) -> ua.CallMethodRequest:
    req = ua.CallMethodRequest()
    req.ObjectId = ua.NodeId.from_string(obj)
    req.MethodId = ua.NodeId.from_string(method)
    req.InputArguments = list(args)
    return req


async def call(c: Client, obj: str, method: str, *args: ua.Variant
               ) -> tuple[str, list[str]]:
    """(the status's name, the names of InputArgumentResults)."""
    res = (await c.uaclient.call([request(obj, method, *args)]))[0]
    return res.StatusCode.name, [s.name for s in res.InputArgumentResults]


#: (ObjectId, MethodId, arguments, the answer): none of them may run anything
REFUSED: list[tuple[str, str, tuple[ua.Variant, ...], tuple[str, list[str]]]] = [
    # the attacks of the issue: one argument too many, another instance's object
    ("ns=2;s=t1", "ns=2;s=t1.Pause", (ua.Variant(True, V.Boolean),),
     ("BadTooManyArguments", [])),
    ("ns=2;s=t2", "ns=2;s=t1.Pause", (), ("BadMethodInvalid", [])),
    ("ns=2;s=t2", "ns=2;s=t1.Acknowledge", (), ("BadMethodInvalid", [])),
    ("ns=2;s=controller", "ns=2;s=t1.Pause", (), ("BadMethodInvalid", [])),
    ("ns=2;s=t1", "ns=2;s=controller.Ack", (), ("BadMethodInvalid", [])),
    ("ns=2;s=controller", "ns=2;s=controller.Ack", (ua.Variant("x", V.String),),
     ("BadTooManyArguments", [])),
    # not a method, no such object, not an object
    ("ns=2;s=t1", "ns=2;s=t1.sN", (), ("BadMethodInvalid", [])),
    ("ns=2;s=t1", "ns=2;s=t1.Nope", (), ("BadMethodInvalid", [])),
    ("ns=2;s=t9", "ns=2;s=t1.Pause", (), ("BadNodeIdUnknown", [])),
    ("ns=2;s=t1.sN", "ns=2;s=t1.Pause", (), ("BadNodeIdInvalid", [])),
    # a condition's Acknowledge and Confirm: (EventId ByteString, Comment LocalizedText)
    (CONDITION, "i=9111", (), ("BadArgumentsMissing", [])),
    (CONDITION, "i=9111", (ua.Variant(b"x", V.ByteString),), ("BadArgumentsMissing", [])),
    (CONDITION, "i=9113", (ua.Variant(b"x", V.ByteString),
                           ua.Variant(ua.LocalizedText("c"), V.LocalizedText),
                           ua.Variant(3, V.Int32)), ("BadTooManyArguments", [])),
    (CONDITION, "i=9111", (ua.Variant("x", V.String),
                           ua.Variant(ua.LocalizedText("c"), V.LocalizedText)),
     ("BadInvalidArgument", ["BadTypeMismatch", "Good"])),
    (CONDITION, "i=9113", (ua.Variant([b"x"], V.ByteString),
                           ua.Variant("c", V.String)),
     ("BadInvalidArgument", ["BadTypeMismatch", "BadTypeMismatch"])),
    # Acknowledge of the conditions called on an object that is not a condition
    ("ns=2;s=t1", "i=9111", (ua.Variant(b"x", V.ByteString),
                             ua.Variant(ua.LocalizedText("c"), V.LocalizedText)),
     ("BadMethodInvalid", [])),
    # ConditionRefresh (SubscriptionId: IntegerId, a UInt32), on ConditionType
    ("i=2782", "i=3875", (), ("BadArgumentsMissing", [])),
    ("i=2782", "i=3875", (ua.Variant("1", V.String),),
     ("BadInvalidArgument", ["BadTypeMismatch"])),
    # a standard method of the Server object that asyncua does not implement
    ("i=2253", "i=11492", (ua.Variant(1, V.UInt32),), ("BadNotImplemented", [])),
]


def test_calls_part_4_refuses_run_nothing_and_are_logged_once(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, "runtime")
    with running(tmp_path) as (d, srv):
        t1, t2 = d.plant.instances["t1"], d.plant.instances["t2"]

        async def main() -> list[tuple[str, list[str]]]:
            async with writer(srv.url) as c:
                return [await call(c, obj, m, *args) for obj, m, args, _ in REFUSED]
        got = asyncio.run(main())
        assert got == [answer for *_, answer in REFUSED]
        # nothing ran: no chart paused, no alarm acknowledged
        assert d.call(lambda: (t1.get("SFCPause"), t2.get("SFCPause"))) == (False, False)
        assert all(a.by == "" for a in d.alarms.alarms())

        async def good() -> tuple[str, list[str]]:
            async with writer(srv.url) as c:
                return await call(c, "ns=2;s=t1", "ns=2;s=t1.Pause")
        assert asyncio.run(good()) == ("Good", [])
        assert d.call(lambda: (t1.get("SFCPause"), t2.get("SFCPause"))) == (True, False)
    said = [r.getMessage() for r in caplog.records if "refused: Bad" in r.getMessage()]
    assert len(said) == len(REFUSED), said
    assert said[0].startswith(f"opcua: {WRITER} (127.0.0.1:")
    assert said[0].endswith(": call of ns=2;s=t1.Pause on ns=2;s=t1 with 1 argument(s) "
                            "refused: BadTooManyArguments")
    assert said[1].endswith(": call of ns=2;s=t1.Pause on ns=2;s=t2 with 0 argument(s) "
                            "refused: BadMethodInvalid")


def test_a_batch_answers_each_call_in_its_place(tmp_path: Path) -> None:
    """One Call request holding good and bad calls: each answered in its place, the good
    ones run, the bad ones not."""
    with running(tmp_path) as (d, srv):
        t1, t2 = d.plant.instances["t1"], d.plant.instances["t2"]

        async def main() -> list[str]:
            async with writer(srv.url) as c:
                res = await c.uaclient.call([
                    request("ns=2;s=t2", "ns=2;s=t1.Pause"),
                    request("ns=2;s=t2", "ns=2;s=t2.Pause"),
                    request("ns=2;s=t1", "ns=2;s=t1.Pause", ua.Variant(1, V.Int32)),
                    request("ns=2;s=controller", "ns=2;s=controller.Ack")])
                return [r.StatusCode.name for r in res]
        assert asyncio.run(main()) == ["BadMethodInvalid", "Good", "BadTooManyArguments",
                                       "BadInvalidState"]  # nothing to acknowledge
        assert d.call(lambda: (t1.get("SFCPause"), t2.get("SFCPause"))) == (False, True)


def test_condition_refresh_of_another_sessions_subscription_is_refused(
        tmp_path: Path) -> None:
    """ConditionRefresh names a subscription: only the caller's own (a subscription
    belongs to its session), else BadSubscriptionIdInvalid and no event is sent."""
    with running(tmp_path) as (_d, srv):
        async def main() -> tuple[str, str, str]:
            async with Client(srv.url) as mine, Client(srv.url) as other:
                sub = await other.create_subscription(100, _Quiet())
                own = await mine.create_subscription(100, _Quiet())
                refresh = "i=3875"
                theirs = await call(mine, "i=2782", refresh,
                                    ua.Variant(sub.subscription_id, V.UInt32))
                unknown = await call(mine, "i=2782", refresh, ua.Variant(999_999, V.UInt32))
                ok = await call(mine, "i=2782", refresh,
                                ua.Variant(own.subscription_id, V.UInt32))
                return theirs[0], unknown[0], ok[0]
        assert asyncio.run(main()) == ("BadSubscriptionIdInvalid",
                                       "BadSubscriptionIdInvalid", "Good")


class _Quiet:
    def __init__(self) -> None:
        self.changes = 0

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.changes += 1

    def event_notification(self, event: Any) -> None:
        pass

    def status_change_notification(self, status: Any) -> None:
        pass


def test_the_server_keeps_serving_while_bad_calls_arrive(tmp_path: Path) -> None:
    """A reader subscribed to the scan counter: its notifications a second while a writer
    sends bad calls as fast as it can, against a quiet phase of the same length just
    before (a ratio in the same run); every bad call answered, none run."""
    with running(tmp_path) as (d, srv):
        t1 = d.plant.instances["t1"]

        async def main() -> tuple[int, int, int, set[str]]:
            async with Client(srv.url) as reader, writer(srv.url) as attacker:
                seen = _Quiet()
                sub = await reader.create_subscription(50, seen)
                await sub.subscribe_data_change(reader.get_node("ns=2;s=controller.scan"))
                loop = asyncio.get_running_loop()
                while seen.changes < 3:  # the subscription publishes
                    await asyncio.sleep(0.05)
                start, before = loop.time(), seen.changes
                answers: set[str] = set()
                calls = 0
                bad = [request("ns=2;s=t2", "ns=2;s=t1.Pause"),
                       request("ns=2;s=t1", "ns=2;s=t1.Pause", ua.Variant(True, V.Boolean)),
                       request(CONDITION, "i=9111")] * 10
                # the attack first, for as long as 200 calls take (at least 3 s: a pause of
                # this process, the server's, is then a small part of either phase)
                while calls < 200 or loop.time() - start < 3.0:
                    res = await attacker.uaclient.call(bad)
                    answers.update(r.StatusCode.name for r in res)
                    calls += len(bad)
                attacked_s = loop.time() - start
                during = seen.changes - before
                # then a quiet phase of the same length
                quiet_start, before = loop.time(), seen.changes
                while loop.time() - quiet_start < attacked_s:
                    await asyncio.sleep(0.02)
                quiet = seen.changes - before
                return during, quiet, calls, answers
        during, quiet, calls, answers = asyncio.run(main())
        assert answers == {"BadMethodInvalid", "BadTooManyArguments", "BadArgumentsMissing"}
        assert calls >= 200
        assert quiet > 0
        # the reader's notifications went on at least half as often as in the quiet phase
        assert during >= quiet / 2, (during, quiet, calls)
        assert d.call(lambda: t1.get("SFCPause")) is False


@NEEDS_NODE
def test_node_opcua_pause_with_an_argument_too_many_or_on_t2_is_refused(
        tmp_path: Path) -> None:
    """The issue's attack from a client not built on asyncua."""
    with running(tmp_path) as (d, srv):
        t1, t2 = d.plant.instances["t1"], d.plant.instances["t2"]
        op = AlarmClient(srv.url, WRITER, WRITER_PASSWORD)
        try:
            assert op.ask(call="ns=2;s=t1", method="ns=2;s=t1.Pause",
                          args=[["Boolean", True]]) == {
                "call": "BadTooManyArguments"}
            assert op.ask(call="ns=2;s=t2", method="ns=2;s=t1.Pause") == {
                "call": "BadMethodInvalid"}
            assert op.ask(call=CONDITION, method="i=9111",
                          args=[["String", "x"], ["LocalizedText", {"text": "c"}]]) == {
                "call": "BadInvalidArgument", "inputs": ["BadTypeMismatch", "Good"]}
            assert d.call(lambda: (t1.get("SFCPause"), t2.get("SFCPause"))) == (False, False)
            assert op.ask(call="ns=2;s=t1", method="ns=2;s=t1.Pause") == {
                "call": "Good"}
            deadline = time.monotonic() + 10
            while d.call(lambda: t1.get("SFCPause")) is not True:
                assert time.monotonic() < deadline, "t1 not paused"
                time.sleep(0.02)
        finally:
            op.close()
