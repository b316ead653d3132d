"""A console pause freezes the program's clock (issue 13 §1), on a virtual clock.

The plant is driven directly with chosen monotonic times (never sleeping). Each timer kind
is started by the activation of ``s1`` and measured from it: the step's ``.T``, the action
qualifiers L, D, SD, DS, SL, the IEC blocks TON, TOF, TP and a seed timer
(``timeX.Ini/End/Val``). Paused for 2 s of clock, ``cycle 1`` moves every one of them by
exactly one cycle of the plant (10 ms), whatever wall time the stepped cycle took, and
``resume`` goes on from the frozen time with no jump.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from runtime.controller.replay import ScriptPlayer
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant

MS = 1_000_000
S = 1_000 * MS
#: the monotonic clock at the controller's start: deliberately not 0
BOOT = 987_654_321_000
CYCLE = 10 * MS
#: every timer of the chart is 50 ms long, from the activation of s1
DUE_MS = 50

CHART = """\
grafcet: Clocks
inputs: [go]
outputs: [oL, oD, oSD, oDS, oSL]
blocks: {ton: TON, tof: TOF, tp: TP}
timers: [timeX]
memory:
  mTonQ: false
  mTonEt: 0s
  mTofQ: false
  mTofEt: 0s
  mTpQ: false
  mTpEt: 0s
  mEnd: false
  mVal: 0s
  mC10: false
  mC2: false
  mC1: false
steps:
  s0: {initial: true}
  s1:
    actions: ["L 50ms oL", "D 50ms oD", "SD 50ms oSD", "DS 50ms oDS", "SL 50ms oSL",
              "P1 timeX.Ini(50ms)"]
transitions:
  - {from: s0, to: s1, when: go}
post:
  - ton(IN := s1.X, PT := 50ms)
  - tof(IN := s0.X, PT := 50ms)
  - tp(IN := s1.X, PT := 50ms)
  - mTonQ := ton.Q
  - mTonEt := ton.ET
  - mTofQ := tof.Q
  - mTofEt := tof.ET
  - mTpQ := tp.Q
  - mTpEt := tp.ET
  - mEnd := timeX.End()
  - mVal := timeX.Val()
  - mC10 := Clock_10Hz
  - mC2 := Clock_2Hz
  - mC1 := Clock_1Hz
"""

PLANT = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  clk:
    grafcet: clocks.yaml
    inputs: {go: sim.I0}
    outputs: {oL: sim.Q0, oD: sim.Q1, oSD: sim.Q2, oDS: sim.Q3, oSL: sim.Q4}
"""


def _ms(ns: int) -> int:
    return ns // MS


#: each timer kind: how the test reads it, and what it must read at ``p`` ms of program
#: time after the activation of s1 (the timers are all 50 ms long)
KINDS: dict[str, tuple[Callable[[Plant], Any], Callable[[int], Any]]] = {
    "step .T": (lambda p: _ms(p.get("clk.s1.T")), lambda ms: ms),
    "L": (lambda p: p.get("clk.oL"), lambda ms: ms < DUE_MS),
    "D": (lambda p: p.get("clk.oD"), lambda ms: ms >= DUE_MS),
    "SD": (lambda p: p.get("clk.oSD"), lambda ms: ms >= DUE_MS),
    "DS": (lambda p: p.get("clk.oDS"), lambda ms: ms >= DUE_MS),
    "SL": (lambda p: p.get("clk.oSL"), lambda ms: ms < DUE_MS),
    "TON": (lambda p: (p.get("clk.mTonQ"), _ms(p.get("clk.mTonEt"))),
            lambda ms: (ms >= DUE_MS, min(ms, DUE_MS))),
    "TOF": (lambda p: (p.get("clk.mTofQ"), _ms(p.get("clk.mTofEt"))),
            lambda ms: (ms < DUE_MS, min(ms, DUE_MS))),
    "TP": (lambda p: (p.get("clk.mTpQ"), _ms(p.get("clk.mTpEt"))),
           lambda ms: (ms < DUE_MS, min(ms, DUE_MS))),
    "timeX.Ini/End": (lambda p: (p.get("clk.mEnd"), _ms(p.get("clk.mVal"))),
                      lambda ms: (ms >= DUE_MS, min(ms, DUE_MS))),
}


class Bench:
    """The plant and its monotonic clock (ns), moved by the test."""

    def __init__(self, write: Callable[[str, str], str]) -> None:
        write("clocks.yaml", CHART)
        self.plant = Plant(load_plant(write("plant.yaml", PLANT)), sim=True)
        self.plant.open()
        self.sim = self.plant.drivers["sim"]
        self.now = BOOT

    def cycle(self, after: int = CYCLE) -> None:
        """One controller cycle ``after`` ns after the last one."""
        self.now += after
        assert self.plant.cycle(self.now) is None

    def held_for(self, duration: int, period: int = CYCLE) -> None:
        """Paused cycles for ``duration`` ns of clock, one every ``period``."""
        end = self.now + duration
        while self.now + period <= end:
            self.cycle(period)

    def step(self, after: int = CYCLE) -> None:
        """``cycle 1`` of the console: one full cycle, ``after`` ns of wall time later."""
        self.plant.step(1)
        self.cycle(after)
        assert not self.plant.stepping

    def activate_s1(self) -> None:
        """s1 active from a scan: every timer starts there (program time 0)."""
        self.plant.cycle(self.now)  # first scan: s0
        self.sim.inputs["I0"] = 1
        self.cycle()
        assert self.plant.get("clk.s1.X") is True and self.plant.get("clk.s1.T") == 0


@pytest.fixture
def bench(write: Callable[[str, str], str]) -> Bench:
    return Bench(write)


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_paused_timer_moves_one_cycle_per_console_cycle_and_resumes_without_a_jump(
        bench: Bench, kind: str) -> None:
    read, at = KINDS[kind]
    bench.activate_s1()
    bench.cycle()
    bench.cycle()
    assert read(bench.plant) == at(20)
    bench.plant.pause()
    bench.held_for(2 * S)
    assert read(bench.plant) == at(20), "a paused chart is not scanned"
    bench.step()
    assert read(bench.plant) == at(30), "cycle 1 after 2 s paused: exactly one cycle"
    bench.held_for(700 * MS)
    bench.step(after=137 * MS)  # a stepped cycle counts one cycle, whatever it took
    assert read(bench.plant) == at(40)
    bench.held_for(1 * S)
    bench.plant.resume()
    bench.cycle(after=3 * MS)  # the first cycle after resume: one cycle on, no jump
    assert read(bench.plant) == at(50)
    bench.cycle()
    assert read(bench.plant) == at(60)
    bench.cycle(after=25 * MS)  # running again: the program's time is the clock's
    assert read(bench.plant) == at(85)


def test_the_due_scan_is_the_one_a_running_chart_would_have(bench: Bench) -> None:
    """Stepped one cycle at a time, every 50 ms timer switches in the scan 50 ms after
    the activation, as it does when the chart runs, and not before."""
    bench.activate_s1()
    bench.plant.pause()
    for ms in range(10, 70, 10):
        bench.held_for(2 * S)
        bench.step()
        for kind, (read, at) in KINDS.items():
            assert read(bench.plant) == at(ms), f"{kind} at {ms} ms"


def test_cycle_n_moves_the_program_time_by_n_cycles(bench: Bench) -> None:
    bench.activate_s1()
    bench.plant.pause()
    bench.held_for(2 * S)
    bench.plant.step(4)
    for _ in range(4):
        bench.cycle(after=50 * MS)  # the cycles of a `cycle 4` on a loaded machine
    assert not bench.plant.stepping
    assert bench.plant.get("clk.s1.T") == 40 * MS
    bench.held_for(2 * S)
    assert bench.plant.get("clk.s1.T") == 40 * MS


def clock_bits(p: Plant) -> tuple[bool, bool, bool]:
    return p.get("clk.mC10"), p.get("clk.mC2"), p.get("clk.mC1")


def expected_bits(up_ms: int) -> tuple[bool, bool, bool]:
    """Clock_10Hz, Clock_2Hz, Clock_1Hz at ``up_ms`` of program time since the start."""
    return (up_ms % 100 < 50, up_ms % 500 < 250, up_ms % 1000 < 500)


def test_clock_bits_follow_the_program_time_so_they_freeze_while_paused(bench: Bench) -> None:
    bench.plant.cycle(bench.now)  # program time 0
    for _ in range(3):
        bench.cycle()
    assert clock_bits(bench.plant) == expected_bits(30)
    bench.plant.pause()
    bench.held_for(1_270 * MS)  # the wall clock's bits would read (270 + 10) ms on
    bench.step()
    assert clock_bits(bench.plant) == expected_bits(40)
    assert bench.plant.last_up == 40 * MS
    bench.plant.resume()
    bench.cycle()
    assert clock_bits(bench.plant) == expected_bits(50)
    assert bench.plant.last_up == 50 * MS


def test_the_program_time_stands_still_in_iocheck(bench: Bench) -> None:
    """iocheck stops the charts too; if they go on afterwards without a restart (the
    daemon restarts them through ack), no timer fires for the time spent there."""
    bench.activate_s1()
    bench.cycle()
    bench.plant.set_iocheck(True)
    bench.held_for(2 * S)
    bench.plant.set_iocheck(False)
    bench.cycle()
    assert bench.plant.get("clk.s1.T") == 20 * MS
    assert bench.plant.get("clk.oL") is True and bench.plant.get("clk.oD") is False


def test_never_paused_the_chart_sees_the_monotonic_clock(bench: Bench) -> None:
    """Without a pause the program's time is the clock's, overruns included."""
    bench.activate_s1()
    bench.cycle(after=37 * MS)
    bench.cycle(after=3 * MS)
    assert bench.plant.get("clk.s1.T") == 40 * MS
    assert bench.plant.instances["clk"].program.scan_time(
        bench.plant.instances["clk"].m) == bench.now


def test_a_run_script_waits_with_the_paused_chart(bench: Bench,
                                                  write: Callable[[str, str], str]) -> None:
    """``run --script`` plays its events on the program's time (``Plant.last_up``): while
    paused the simulated machine stands still with the chart, and a stepped chart sees an
    event in the scan at its time, as a running one does."""
    player = ScriptPlayer(bench.plant, write("story.yaml", """\
        duration: 1s
        set:
          - {at: 30ms, clk.go: 1}
        """))
    bench.plant.cycle(bench.now)  # program time 0
    player(0)
    bench.cycle()  # 10 ms
    player(1)
    bench.plant.pause()
    for n in range(2, 200):  # 2 s of paused cycles, the player called after each
        bench.cycle()
        player(n)
    assert bench.sim.inputs["I0"] == 0, "a scripted event played while paused"
    bench.step()  # 20 ms
    player(200)
    assert bench.plant.get("clk.s0.X") is True and bench.sim.inputs["I0"] == 1
    bench.step()  # 30 ms: the scan at the event's time sees it
    assert bench.plant.get("clk.s1.X") is True and bench.plant.last_up == 30 * MS
