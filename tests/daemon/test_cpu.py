"""``plc: realtime: cpu: N`` (docs/daemon.md, "The controller's processor"): every thread
of the controller's process on processor N, the plant's side processes on the others;
in real processes (``softplc run`` and ``softplc web``), their threads' affinity read
from the kernel. A processor the controller may not use is said in one warning line and
the controller runs where it was; a side process with no other processor stays where it
was and says so. The reload's child, started on the controller's processor, leaves it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.controller.reloadchild import child_command
from tests.opcua.feedkit import wait_until
from tests.web.kit import ROOT, rundir_of, start, stop, write_plant

ALLOWED = os.sched_getaffinity(0)
needs_two = pytest.mark.skipif(len(ALLOWED) < 2, reason="needs two processors this process "
                                                        "may use (CI's machine has two)")


def plant_on(tmp: Path, cpu: int) -> Path:
    plant = write_plant(tmp, users=False)
    text = plant.read_text(encoding="utf-8")
    assert "\n  watchdog: 5s\n" in text
    plant.write_text(text.replace("\n  watchdog: 5s\n",
                                  f"\n  watchdog: 5s\n  realtime: {{cpu: {cpu}}}\n", 1),
                     encoding="utf-8")
    return plant


def threads_affinity(pid: int) -> dict[int, set[int]]:
    """Each thread of process ``pid``: the processors it may run on."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            out[int(tid)] = os.sched_getaffinity(int(tid))
        except ProcessLookupError:
            pass
    return out


@needs_two
def test_the_controller_runs_on_its_processor_and_the_side_process_on_the_others(
        tmp_path: Path) -> None:
    cpu = max(ALLOWED)
    plant = plant_on(tmp_path, cpu)
    ctl = start(tmp_path, "run", str(plant), "--sim")
    web = None
    try:
        feed = rundir_of(tmp_path, plant) / "feed.sock"
        wait_until(lambda: feed.exists() or ctl.popen.poll() is not None, 30.0,
                   "the feed socket")
        assert ctl.popen.poll() is None, ctl.log()
        assert f"the controller's threads on processor {cpu} (plc: realtime: cpu)" in ctl.log()
        threads = threads_affinity(ctl.popen.pid)
        assert len(threads) >= 3, threads  # the scan, the watchdog, the feed at least
        assert all(a == {cpu} for a in threads.values()), threads

        web = w = start(tmp_path, "web", str(plant))
        wait_until(lambda: any("is at http" in ln for ln in w.lines)
                   or w.popen.poll() is not None, 30.0, "the web view")
        assert w.popen.poll() is None, w.log()
        side = threads_affinity(w.popen.pid)
        assert all(a == ALLOWED - {cpu} for a in side.values()), side
        assert "not kept off" not in w.log()
        # the controller's threads started since (its feed's client) are there too
        assert all(a == {cpu} for a in threads_affinity(ctl.popen.pid).values())
    finally:
        stop(web, ctl)


def test_a_processor_it_may_not_use_is_said_and_the_controller_runs(tmp_path: Path) -> None:
    cpu = 1023  # within the file's bounds, on no machine this runs on
    assert cpu not in ALLOWED
    plant = plant_on(tmp_path, cpu)
    ctl = start(tmp_path, "run", str(plant), "--sim")
    try:
        feed = rundir_of(tmp_path, plant) / "feed.sock"
        wait_until(lambda: feed.exists() or ctl.popen.poll() is not None, 30.0,
                   "the feed socket")
        assert ctl.popen.poll() is None, ctl.log()
        said = [ln for ln in ctl.lines if "processor 1023" in ln]
        assert len(said) == 1 and re.search(
            r"the controller not kept to processor 1023: processor 1023 is not one this "
            r"process may use \(\d", said[0]), said
        assert all(a == ALLOWED for a in threads_affinity(ctl.popen.pid).values())
    finally:
        stop(ctl)


def in_child(pinned_to: int | None, call: str) -> str:
    """What a Python process kept to processor ``pinned_to`` (None: left as this one)
    prints for ``call`` (a function of runtime.controller.realtime), then its
    processors."""
    pin = "" if pinned_to is None else f"os.sched_setaffinity(0, {{{pinned_to}}}); "
    code = (f"import os; {pin}from runtime.controller.realtime import *; "
            f"print({call}, sorted(os.sched_getaffinity(0)))")
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout.strip()


@needs_two
def test_the_reloads_child_leaves_the_processor_of_a_controller_kept_to_one() -> None:
    """The reload's child inherits the controller's processor; it compiles for seconds,
    and leaves it. The real child, started on one processor (util-linux's taskset, as a
    pinned controller starts it), waiting for the plant on its standard input."""
    cpu = max(ALLOWED)
    assert in_child(cpu, "leave_a_lone_processor()") == f"True {sorted(ALLOWED - {cpu})}"
    child = subprocess.Popen(["taskset", "-c", str(cpu), *child_command(["compile"])],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, cwd="/")
    try:
        wait_until(lambda: os.sched_getaffinity(child.pid) == ALLOWED - {cpu}, 30.0,
                   "the child on the other processors")
    finally:
        child.communicate(b"", timeout=60)  # no plant: it answers with an error and ends
    # a process that may run anywhere stays so
    assert in_child(None, "leave_a_lone_processor()") == f"False {sorted(ALLOWED)}"


def test_a_side_process_with_no_other_processor_stays_and_says_why() -> None:
    cpu = min(ALLOWED)
    assert in_child(cpu, f"keep_off({cpu})") == (
        f"(False, 'no processor but {cpu} for this process') [{cpu}]")
