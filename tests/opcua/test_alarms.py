"""Alarms and Conditions and the plant's methods (issue 29), with a client not built on
asyncua: node-opcua (tests/opcua/node/alarms.js) subscribed to the Server object's
events, against the server fed by a running controller. A step over its max time raises
an AlarmConditionType condition (ConditionRefresh shows it), a writer acknowledges it (it
stays active until its cause clears), the instance's Acknowledge method clears the cause,
Confirm ends it; readers are refused the changing methods; each call is logged with the
caller's identity, and the console's status says the same states."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from runtime.controller.alarms import alarm_lines
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import ServerThread, serving, wait_shown, wait_until
from tests.opcua.kit import WRITER, WRITER_PASSWORD, free_port, write_plant
from tests.opcua.nodekit import NEEDS_NODE, AlarmClient

KEY = "t1.gsJam.maxtime"
CONDITION = f"ns=2;s=alarm.{KEY}"

pytestmark = NEEDS_NODE


@contextmanager
def running(tmp: Path) -> Iterator[tuple[Any, ServerThread]]:
    path = write_plant(tmp, port=free_port(), extra="")
    text = path.read_text(encoding="utf-8").replace("  t1:\n", "  t1:\n    description: Banco 1\n")
    # a loaded test machine overruns now and then: that alarm kept quiet here
    path.write_text(text + "alarms:\n  overruns: {count: 1000000}\n", encoding="utf-8")
    pdef = load_plant(str(path))
    with serving(pdef) as (d, feed), ServerThread(pdef) as srv:
        wait_shown(srv)
        yield d, srv


def test_a_max_time_alarm_refreshed_acknowledged_and_confirmed(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    with running(tmp_path) as (d, srv):
        writer = AlarmClient(srv.url, WRITER, WRITER_PASSWORD)
        reader = AlarmClient(srv.url)
        try:
            assert writer.refresh() == []  # nothing to show
            d.call(lambda: d.plant.set("t1.sJam", True))
            raised = writer.wait_event(lambda e: e["ConditionName"] == KEY and e["Active"],
                                       "the alarm raised")
            assert {k: raised[k] for k in ("ConditionId", "SourceName", "Severity", "Retain",
                                           "Acked", "Confirmed", "Message")} == {
                "ConditionId": CONDITION, "SourceName": "t1", "Severity": 700,
                "Retain": True, "Acked": False, "Confirmed": False,
                "Message": "t1 (Banco 1): step gsJam over its max time 50ms"}
            assert raised["EventType"] == "ns=0;i=2915"  # AlarmConditionType
            shown = reader.refresh()  # a panel starting now sees it too
            assert [(e["ConditionId"], e["Active"], e["Acked"]) for e in shown] == [
                (CONDITION, True, False)]
            # a reader may not acknowledge
            assert reader.ask(ack=CONDITION, eventId=raised["EventId"],
                              comment="no") == {"ack": "BadUserAccessDenied"}
            # an EventId that is not the condition's last
            assert writer.ask(ack=CONDITION, eventId="00", comment="x") == {
                "ack": "BadEventIdUnknown"}
            assert writer.ask(ack=CONDITION, eventId=raised["EventId"],
                              comment="visto") == {"ack": "Good"}
            acked = writer.wait_event(lambda e: e["ConditionName"] == KEY and e["Acked"],
                                      "the acknowledged state")
            assert (acked["Active"], acked["Confirmed"], acked["Retain"],
                    acked["Comment"]) == (True, False, True, "visto")
            assert acked["ClientUserId"].startswith(f"{WRITER} (127.0.0.1:")
            assert writer.ask(ack=CONDITION, eventId=acked["EventId"], comment="") == {
                "ack": "BadConditionBranchAlreadyAcked"}
            time.sleep(0.3)
            assert [a.active for a in d.alarms.alarms() if a.key == KEY] == [True]
            assert alarm_lines(d.status()["alarms"]) == [
                f"alarm {KEY} (700) active, acknowledged, unconfirmed: t1 (Banco 1): step "
                "gsJam over its max time 50ms"]
            # the cause cleared: the jam released and the chart's SFCError acknowledged
            # by the instance's method
            d.call(lambda: d.plant.set("t1.sJam", False))
            assert reader.ask(call="ns=2;s=t1", method="ns=2;s=t1.Acknowledge") == {
                "call": "BadUserAccessDenied"}
            assert writer.ask(call="ns=2;s=t1", method="ns=2;s=t1.Acknowledge") == {
                "call": "Good"}
            cleared = writer.wait_event(lambda e: e["ConditionName"] == KEY and
                                        not e["Active"], "the alarm inactive")
            assert (cleared["Acked"], cleared["Confirmed"], cleared["Retain"]) == (
                True, False, True)
            assert writer.ask(confirm=CONDITION, eventId=cleared["EventId"],
                              comment="cajón liberado") == {"confirm": "Good"}
            done = writer.wait_event(lambda e: e["ConditionName"] == KEY and e["Confirmed"],
                                     "the confirmed state")
            assert done["Retain"] is False
            assert writer.refresh() == []  # nothing left to show
        finally:
            writer.close()
            reader.close()
    said = [r.getMessage() for r in caplog.records]
    assert any(m.startswith(f"alarm {KEY} acknowledged by {WRITER} (127.0.0.1:")
               and m.endswith(": visto (active, acknowledged, unconfirmed)") for m in said)
    assert any(m.startswith(f"opcua: {WRITER} (127.0.0.1:") and
               m.endswith("called t1.Acknowledge: t1: SFCError (set by step gsJam) acknowledged")
               for m in said), said
    assert any(m.startswith("opcua: t1.Acknowledge refused to anonymous (127.0.0.1:")
               for m in said)


def test_methods_are_for_writers_and_applied_between_two_scans(tmp_path: Path) -> None:
    with running(tmp_path) as (d, srv):
        writer = AlarmClient(srv.url, WRITER, WRITER_PASSWORD)
        reader = AlarmClient(srv.url)
        t1 = d.plant.instances["t1"]
        try:
            for who, expected in ((writer, True), (reader, False)):
                for node in ("ns=2;s=t1.Pause", "ns=2;s=controller.Ack"):
                    assert who.ask(executable=node) == {"executable": expected,
                                                        "status": "Good"}
            assert reader.ask(call="ns=2;s=t1", method="ns=2;s=t1.Pause") == {
                "call": "BadUserAccessDenied"}
            assert d.call(lambda: t1.get("SFCPause")) is False
            assert writer.ask(call="ns=2;s=t1", method="ns=2;s=t1.Pause") == {
                "call": "Good"}
            assert d.call(lambda: t1.get("SFCPause")) is True
            assert writer.ask(call="ns=2;s=t1", method="ns=2;s=t1.Resume") == {
                "call": "Good"}
            assert d.call(lambda: t1.get("SFCPause")) is False
            # Reset: the chart back to its initial situation; held in gsA (sStop), gsA is
            # entered again and its time restarts
            d.call(lambda: d.plant.set("t1.sStop", True))
            wait_until(lambda: d.call(lambda: t1.get("gsA.T")) > 300_000_000,
                       what="t1 held in gsA")
            assert writer.ask(call="ns=2;s=t1", method="ns=2;s=t1.Reset") == {
                "call": "Good"}
            assert d.call(lambda: t1.get("gsA.X")) is True
            assert d.call(lambda: t1.get("gsA.T")) < 300_000_000
            d.call(lambda: d.plant.set("t1.sStop", False))
            # nothing to acknowledge: the controller refuses
            assert writer.ask(call="ns=2;s=t1", method="ns=2;s=t1.Acknowledge") == {
                "call": "BadInvalidState"}
            assert writer.ask(call="ns=2;s=controller",
                              method="ns=2;s=controller.Ack") == {"call": "BadInvalidState"}
            # a fault, acknowledged by the controller's Ack
            d.call(lambda: d.plant.set("t1.sDiv", 0))
            wait_until(lambda: d.fault is not None, what="the fault")
            d.call(lambda: d.plant.set("t1.sDiv", 1))
            assert writer.ask(call="ns=2;s=controller",
                              method="ns=2;s=controller.Ack") == {"call": "Good"}
            assert d.fault is None
        finally:
            writer.close()
            reader.close()


def test_in_fault_the_charts_methods_and_confirm_are_refused_saying_why(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """While the controller is in fault no chart runs, and its Ack restarts every chart
    from its initial situation: an instance's Acknowledge (and Reset, Pause, Resume) would
    be lost, and confirming the fault's alarm would say its cause was dealt with. Each is
    refused (BadInvalidState) in one log line that says why; the alarm may still be
    acknowledged (seen); the Controller's Ack clears the fault and the chart's SFCError,
    and the fault's alarm may then be confirmed."""
    caplog.set_level(logging.INFO)
    fault = "ns=2;s=alarm.controller.fault"
    with running(tmp_path) as (d, srv):
        op = AlarmClient(srv.url, WRITER, WRITER_PASSWORD)
        t1 = d.plant.instances["t1"]
        try:
            d.call(lambda: d.plant.set("t1.sJam", True))
            wait_until(lambda: d.call(lambda: t1.get("SFCError")) is True, what="SFCError")
            d.call(lambda: d.plant.set("t1.sDiv", 0))
            wait_until(lambda: d.fault is not None, what="the fault")
            d.call(lambda: d.plant.set("t1.sDiv", 1))
            d.call(lambda: d.plant.set("t1.sJam", False))
            raised = op.wait_event(lambda e: e["ConditionId"] == fault and e["Active"],
                                   "the fault's alarm")
            caplog.clear()
            for method in ("Acknowledge", "Reset", "Pause", "Resume"):
                assert op.ask(call="ns=2;s=t1", method=f"ns=2;s=t1.{method}") == {
                    "call": "BadInvalidState"}, method
            assert d.fault is not None
            assert d.call(lambda: (t1.get("SFCError"), t1.get("SFCPause"))) == (True, False)
            # the alarm: seen, yes; confirmed (its cause dealt with), not yet
            assert op.ask(ack=fault, eventId=raised["EventId"], comment="seen") == {
                "ack": "Good"}
            acked = op.wait_event(lambda e: e["ConditionId"] == fault and e["Acked"],
                                  "the fault's alarm acknowledged")
            assert op.ask(confirm=fault, eventId=acked["EventId"], comment="") == {
                "confirm": "BadInvalidState"}
            said = [r.getMessage() for r in caplog.records]
            assert op.ask(call="ns=2;s=controller", method="ns=2;s=controller.Ack") == {
                "call": "Good"}
            assert d.fault is None
            wait_until(lambda: d.call(lambda: t1.get("SFCError")) is False,
                       what="SFCError cleared by the Ack")
            cleared = op.wait_event(lambda e: e["ConditionId"] == fault and not e["Active"],
                                    "the fault's alarm inactive")
            assert op.ask(confirm=fault, eventId=cleared["EventId"], comment="") == {
                "confirm": "Good"}
        finally:
            op.close()
    refusals = [m for m in said if "Ack it first" in m]
    # one line per refusal, none of them saying it was done
    assert len(refusals) == 5, said
    for method in ("Acknowledge", "Reset", "Pause", "Resume"):
        line = [m for m in refusals if f"t1.{method}:" in m]
        assert len(line) == 1 and "the controller is in fault" in line[0], (method, said)
    assert any(m.startswith(f"opcua: {WRITER} (127.0.0.1:") and "confirm" in m
               and "alarm controller.fault" in m for m in refusals), refusals
    assert not any("acknowledged" in m and "t1" in m for m in said), said
