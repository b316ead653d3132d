"""Safe state and faults of the daemon, by fault injection: every output off before the
first scan, on a driver fault beyond its policy, an exception in a scan, a watchdog
overrun; held off until ``ack`` once the cause is gone."""

from __future__ import annotations

import pytest

from drivers.base import DriverError, Health
from runtime.controller.daemon import CommandRefused, State
from tests.daemon.daemonkit import MakeDaemon, wait_until

ALL_OFF = {"Q0": 0, "Q1": 0}
RUN_ON = {"Q0": 1, "Q1": 1}


def test_outputs_are_written_off_before_the_first_scan(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon(start=False)
    drv.outputs.update({"Q0": 1, "Q1": 1})  # whatever the image held before
    daemon.start()
    wait_until(lambda: daemon.scan_stats.count >= 3)
    assert drv.sent[0] == ("safe", ALL_OFF)
    assert daemon.state is State.RUNNING


def test_orderly_stop_writes_every_output_off(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon()
    drv.inputs["I0"] = 1
    wait_until(lambda: drv.last() == ("write", RUN_ON), what="outputs on")
    daemon.stop("test")
    assert drv.last() == ("safe", ALL_OFF)
    assert drv.health is Health.CLOSED
    assert daemon.state is State.STOPPED


def test_driver_fault_with_stop_policy_faults_and_holds_outputs_off(
        make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon()
    drv.inputs["I0"] = 1
    wait_until(lambda: drv.last() == ("write", RUN_ON), what="outputs on")
    drv.fail_with = DriverError("node 5 lost: no heartbeat for 600 ms")
    wait_until(lambda: daemon.state is State.FAULT, what="fault")
    assert daemon.fault == "driver io: node 5 lost: no heartbeat for 600 ms"
    mark = len(drv.sent)
    assert drv.sent[mark - 1] == ("safe", ALL_OFF)
    # the cause is still there: ack refused, outputs stay off
    with pytest.raises(CommandRefused, match="still there: driver io: node 5 lost"):
        daemon.ack()
    assert daemon.status()["fault"].startswith("driver io")
    # the node comes back: the driver recovers by itself, the plant waits for ack
    drv.fail_with = None
    wait_until(lambda: drv.health is Health.OK, what="driver recovery")
    n = daemon.scan_stats.count
    wait_until(lambda: daemon.scan_stats.count > n + 5)
    assert daemon.state is State.FAULT
    assert not drv.energised_after(mark), "an output came on before the acknowledge"
    assert daemon.plant.instances["m"].active_steps() == ["gsRun"]  # frozen, not scanned
    reply = daemon.ack()
    assert "charts restarted from their initial situation" in reply
    assert daemon.state is State.RUNNING
    wait_until(lambda: drv.last() == ("write", RUN_ON), what="running again")
    assert [r for _, r in daemon.faults] == ["driver io: node 5 lost: no heartbeat for 600 ms"]


def test_driver_fault_with_hold_policy_keeps_running(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon(on_fault="hold")
    drv.inputs["I0"] = 1
    wait_until(lambda: drv.last() == ("write", RUN_ON))
    drv.fail_with = DriverError("timeout")
    wait_until(lambda: drv.health is Health.FAULT)
    n = daemon.scan_stats.count
    wait_until(lambda: daemon.scan_stats.count > n + 5)
    assert daemon.state is State.RUNNING
    assert daemon.plant.get("m.gsRun.X") == 1  # last good input value held
    assert daemon.plant.get("io.ok") is False
    assert daemon.stats()["drivers"]["io"] == {"health": "fault", "on_fault": "hold",
                                                "reason": "timeout"}


def test_exception_in_a_scan_is_a_fault(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon()
    drv.inputs["I0"] = 1
    wait_until(lambda: drv.last() == ("write", RUN_ON))
    daemon.call(lambda: daemon.plant.set("m.sDiv", 0))  # the chart divides by zero
    wait_until(lambda: daemon.state is State.FAULT)
    assert daemon.fault is not None and "exception in scan: ZeroDivisionError" in daemon.fault
    assert drv.last() == ("safe", ALL_OFF)
    mark = len(drv.sent)
    # ack restarts the chart from its initial situation and initial memory (sDiv = 1)
    assert daemon.ack() == "fault acknowledged: charts restarted from their initial situation"
    wait_until(lambda: daemon.plant.get("m.sQ") == 100)
    assert daemon.state is State.RUNNING
    wait_until(lambda: drv.last() == ("write", RUN_ON))
    assert drv.energised_after(mark)
    assert len(daemon.faults) == 1


def test_a_driver_raising_a_bug_is_a_fault(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon(on_fault="zero")
    drv.fail_with = RuntimeError("bug in a driver")  # not an I/O fault: not tolerated
    wait_until(lambda: daemon.state is State.FAULT)
    assert daemon.fault == "exception in scan: RuntimeError: bug in a driver"


def test_watchdog_puts_outputs_off_while_the_scan_hangs(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon(watchdog="60ms")
    drv.inputs["I0"] = 1
    wait_until(lambda: drv.last() == ("write", RUN_ON))
    drv.wrote_safe.clear()
    drv.block_s = 1.0  # the next read hangs for a second
    assert drv.blocked.wait(5.0)
    # the watchdog thread acts while the scan thread is still stuck in the read
    assert drv.wrote_safe.wait(5.0), "no safe state written during the hung scan"
    assert drv.blocked.is_set()
    mark = len(drv.sent)
    assert drv.sent[mark - 1] == ("safe", ALL_OFF)
    wait_until(lambda: daemon.state is State.FAULT)
    wait_until(lambda: not drv.blocked.is_set())
    n = daemon.scan_stats.count
    wait_until(lambda: daemon.scan_stats.count > n + 3)
    assert daemon.fault is not None and daemon.fault.startswith("watchdog: a scan has been "
                                                                "running for")
    assert not drv.energised_after(mark), "the stuck scan energised an output after the trip"
    daemon.ack()
    wait_until(lambda: drv.last() == ("write", RUN_ON), what="running after ack")


def test_a_slow_scan_beyond_the_watchdog_is_a_fault(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon(watchdog="50ms", cycle="10ms")
    wait_until(lambda: daemon.scan_stats.count > 2)
    daemon.scheduler.on_watchdog = None  # only the watchdog thread is left to see it
    drv.block_s = 0.3
    wait_until(lambda: daemon.state is State.FAULT)
    assert daemon.fault is not None and "watchdog" in daemon.fault


def test_sfc_error_is_acknowledged(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon()
    drv.inputs["I0"] = 1  # gsRun has max: 200ms
    wait_until(lambda: daemon.plant.get("m.SFCError") is True, what="SFCError")
    assert daemon.plant.get("m.SFCErrorStep") == "gsRun"
    drv.inputs["I0"] = 0  # back to gsIdle; SFCError stays until acknowledged
    wait_until(lambda: daemon.plant.get("m.gsIdle.X") == 1)
    assert daemon.plant.get("m.SFCError") is True
    assert daemon.ack() == "SFCError of m (set by step gsRun) acknowledged"
    wait_until(lambda: daemon.plant.get("m.SFCError") is False)
    assert daemon.state is State.RUNNING
    with pytest.raises(CommandRefused, match="nothing to acknowledge"):
        daemon.ack()


def test_halt_after_iocheck_waits_for_ack(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon()
    drv.inputs["I0"] = 1
    wait_until(lambda: drv.last() == ("write", RUN_ON))
    daemon.call(lambda: daemon.plant.set_iocheck(True))
    wait_until(lambda: daemon.state is State.IOCHECK)
    assert drv.last()[1] == ALL_OFF
    daemon.call(lambda: daemon.plant.set("io.Q1", 1))  # the technician drives one output
    wait_until(lambda: drv.last() == ("write", {"Q0": 0, "Q1": 1}))
    daemon.call(lambda: daemon.plant.set_iocheck(False))
    daemon.require_ack("iocheck ended")
    assert daemon.state is State.HALTED
    mark = len(drv.sent)
    n = daemon.scan_stats.count
    wait_until(lambda: daemon.scan_stats.count > n + 3)
    assert not drv.energised_after(mark)
    assert daemon.ack() == "charts restarted from their initial situation"
    wait_until(lambda: drv.last() == ("write", RUN_ON))


def test_fault_record_survives_a_restart(make_daemon: MakeDaemon, tmp_path: object) -> None:
    import pathlib

    retain = str(pathlib.Path(str(tmp_path)) / "state" / "retain.json")
    daemon, drv = make_daemon(retain=retain, watchdog="60ms")
    drv.block_s = 0.4
    wait_until(lambda: daemon.state is State.FAULT)
    daemon.stop("the process is killed and restarted (systemd)")
    again, drv2 = make_daemon(retain=retain)
    assert again.state is State.FAULT
    assert again.fault is not None and again.fault.startswith("before the restart: watchdog")
    drv2.inputs["I0"] = 1
    n = again.scan_stats.count
    wait_until(lambda: again.scan_stats.count > n + 3)
    assert not drv2.energised_after(0)
    again.ack()
    wait_until(lambda: drv2.last() == ("write", RUN_ON))
    third, _ = make_daemon(retain=retain)
    assert third.state is not State.FAULT
