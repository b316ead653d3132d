"""The scan loop on a virtual clock: absolute deadlines, lateness, the overrun policy, the
watchdog callback, idle work bounded by the guard band, cycle statistics."""

from __future__ import annotations

import gc
import random
import threading
import time
from array import array
from typing import Any

import pytest

from runtime.controller import stats as stats_module
from runtime.controller.scheduler import Scheduler, Watchdog
from runtime.controller.stats import ScanStats, Summary, percentiles
from tests.daemon.daemonkit import wait_until

MS = 1_000_000


class VirtualTime:
    """A monotonic clock that only moves when the loop sleeps or a scan 'takes' time."""

    def __init__(self, start: int = 5 * MS) -> None:
        self.now = start
        self.sleeps: list[int] = []

    def clock(self) -> int:
        return self.now

    def sleep_until(self, deadline: int) -> None:
        self.sleeps.append(deadline)
        self.now = max(self.now, deadline)


def run(durations: list[int], cycle: int = 10 * MS, watchdog: int = 100 * MS,
        late: list[int] | None = None,
        idle: list[int] | None = None) -> tuple[VirtualTime, list[int], Scheduler, list[int]]:
    """Run len(durations) cycles; scan k takes durations[k] ns and wakes late[k] ns late."""
    vt = VirtualTime()
    wakes: list[int] = []
    slow: list[int] = []
    lateness = iter(late or [0] * len(durations))

    def sleep_until(deadline: int) -> None:
        vt.sleep_until(deadline)
        vt.now += next(lateness)

    def body(now: int) -> None:
        wakes.append(now)
        vt.now += durations[len(wakes) - 1]

    def idle_fn(until: int) -> None:
        if idle is not None:
            idle.append(until)

    s = Scheduler(body, cycle, watchdog, idle=idle_fn, on_watchdog=slow.append,
                  clock=vt.clock, sleep_until=sleep_until, manage_gc=False)
    s.run(cycles=len(durations))
    return vt, wakes, s, slow


def test_cycles_start_on_absolute_deadlines_whatever_the_scan_time() -> None:
    vt, wakes, s, _ = run([1 * MS, 3 * MS, 7 * MS, 2 * MS, 9 * MS])
    t0 = wakes[0]
    assert [w - t0 for w in wakes] == [0, 10 * MS, 20 * MS, 30 * MS, 40 * MS]
    assert s.stats.overruns == 0
    assert s.stats.scan_max == 9 * MS and s.stats.scan_min == 1 * MS


def test_lateness_is_measured_and_does_not_shift_the_schedule() -> None:
    late = [0, 300_000, 0, 1_200_000, 50_000]
    vt, wakes, s, _ = run([1 * MS] * 5, late=late)
    t0 = wakes[0]
    assert [w - t0 for w in wakes] == [0, 10 * MS + 300_000, 20 * MS, 30 * MS + 1_200_000,
                                       40 * MS + 50_000]
    assert s.stats.late_max == 1_200_000 and s.stats.late_last == 50_000
    assert s.stats.lateness().max == 1_200_000


def test_an_overrun_is_counted_and_the_schedule_re_anchored_without_catch_up() -> None:
    # scan 1 takes 25 ms of a 10 ms cycle: it ends 15 ms after the next deadline
    vt, wakes, s, _ = run([1 * MS, 25 * MS, 1 * MS, 1 * MS, 1 * MS])
    t0 = wakes[0]
    rel = [w - t0 for w in wakes]
    assert rel[:2] == [0, 10 * MS]
    end_of_late_scan = 10 * MS + 25 * MS
    # one full period of rest after the late scan, then the normal period again: no burst
    assert rel[2:] == [end_of_late_scan + 10 * MS, end_of_late_scan + 20 * MS,
                       end_of_late_scan + 30 * MS]
    assert s.stats.overruns == 1
    assert s.stats.skipped == 1  # the deadline at 30 ms was passed over
    assert min(b - a for a, b in zip(rel, rel[1:], strict=False)) == 10 * MS


def test_a_scan_ending_exactly_on_the_next_deadline_is_an_overrun() -> None:
    vt, wakes, s, _ = run([10 * MS, 1 * MS])
    assert s.stats.overruns == 1 and s.stats.skipped == 0
    assert wakes[1] - wakes[0] == 20 * MS


def test_a_scan_longer_than_the_watchdog_is_reported() -> None:
    vt, wakes, s, slow = run([1 * MS, 30 * MS, 1 * MS], watchdog=20 * MS)
    assert slow == [30 * MS]


def test_idle_work_ends_a_guard_band_before_the_next_deadline() -> None:
    idle: list[int] = []
    vt, wakes, s, _ = run([1 * MS, 1 * MS], idle=idle)
    assert s.guard_ns == 2 * MS  # a fifth of a 10 ms cycle (and never below 300 µs)
    assert idle == [wakes[0] + 8 * MS, wakes[0] + 18 * MS]


def test_stop_event_ends_the_loop() -> None:
    vt = VirtualTime()
    s: Scheduler

    def body(now: int) -> None:
        if now - vt.sleeps[0] >= 30 * MS:
            s.stop_event.set()

    s = Scheduler(body, 10 * MS, 100 * MS, clock=vt.clock, sleep_until=vt.sleep_until,
                  manage_gc=False)
    s.run()
    assert s.stats.count == 4
    assert s.scanning_since == 0 and s.last_wake == 0


def test_watchdog_thread_trips_on_a_hung_scan() -> None:
    release = threading.Event()
    tripped: list[int] = []
    trip_seen = threading.Event()

    def body(now: int) -> None:
        release.wait(10)  # hangs until the test releases it

    s = Scheduler(body, 5 * MS, 40 * MS, manage_gc=False)

    def trip(running_ns: int) -> None:
        tripped.append(running_ns)
        trip_seen.set()

    wd = Watchdog(s, 40 * MS, trip)
    wd.start()
    t = threading.Thread(target=s.run, kwargs={"cycles": 1}, name="softplc-test-scan")
    t.start()
    try:
        assert trip_seen.wait(10), "the watchdog did not trip"
        assert tripped[0] > 40 * MS
    finally:
        release.set()
        t.join()
        wd.stop()
    assert len(tripped) == 1  # once per stuck scan


def test_watchdog_thread_trips_when_the_loop_is_stuck_between_scans() -> None:
    release = threading.Event()
    trip_seen = threading.Event()

    def idle(until: int) -> None:
        release.wait(10)  # e.g. a console request that never returns

    s = Scheduler(lambda now: None, 5 * MS, 40 * MS, idle=idle, manage_gc=False)
    wd = Watchdog(s, 40 * MS, lambda ns: trip_seen.set())
    wd.start()
    t = threading.Thread(target=s.run, kwargs={"cycles": 1}, name="softplc-test-scan")
    t.start()
    try:
        assert trip_seen.wait(10)
    finally:
        release.set()
        t.join()
        wd.stop()


def test_stats_percentiles_over_the_window_and_totals_over_the_run() -> None:
    st = ScanStats(window=100)
    for i in range(1, 201):  # 1..200 µs; the window keeps 101..200
        st.record(i * 1000, 0)
    scan = st.scan()
    assert isinstance(scan, Summary)
    assert scan.min == 1000 and scan.max == 200_000  # whole run
    assert scan.mean == pytest.approx(100_500)
    assert scan.p50 in (150_000, 151_000)
    assert scan.p99 == 199_000
    assert scan.p999 == 200_000
    d = st.as_dict()
    assert d["cycles"] == 200 and d["scan_us"]["max"] == 200.0
    st.reset()
    assert st.scan().max == 0 and st.count == 0


def test_stats_storage_does_not_grow() -> None:
    st = ScanStats(window=64)
    before = (len(st._scan), len(st._late))
    for i in range(10_000):
        st.record(i, i)
    assert (len(st._scan), len(st._late)) == before


@pytest.mark.parametrize("window,count", [(8192, 8192), (8192, 20_000), (8192, 700),
                                          (100, 250), (8192, 1), (8192, 0), (8192, 513)])
def test_stats_percentiles_equal_those_of_the_sorted_window(window: int, count: int) -> None:
    """The percentiles come from sorted chunks and bisection (no call sorts a whole
    window): the same figures as sorting the window, ties and equal values included."""
    st = ScanStats(window=window)
    rng = random.Random(count)
    for _ in range(count):
        st.record(rng.randrange(10_000_000), rng.choice((0, rng.randrange(3_000_000))))
    n = min(count, window)

    def at(ranked: list[int], q: float) -> int:
        return ranked[min(n - 1, max(0, int(round(q * (n - 1)))))] if n else 0
    for ring, summary in ((st._scan, st.scan()), (st._late, st.lateness())):
        ranked = sorted(ring[:n])
        assert (summary.p50, summary.p99, summary.p999) == tuple(
            at(ranked, q) for q in (0.5, 0.99, 0.999))
    assert st.p99() == (st.scan().p99, st.lateness().p99)
    if count:
        assert st.scan_last == st._scan[(count - 1) % window]


@pytest.mark.parametrize("window", [8192, 1024, 100])
def test_stats_percentiles_stay_those_of_the_sorted_window_as_cycles_go_on(
        window: int) -> None:
    """Asked again and again while cycles are recorded (the window wrapping over the
    sorted chunks a ScanStats keeps, a reset in between): each time the figures of
    sorting the window then."""
    st = ScanStats(window=window)
    rng = random.Random(window)
    for step in [1, 510, 1, 2, 700, 3000, 512, 9000, 5, 0, 16_384, 8191, 77] * 2:
        if step == 0:
            st.reset()
        for _ in range(step):
            st.record(rng.randrange(1000, 90_000), rng.choice((0, 7, rng.randrange(9000))))
        n = min(st.count, window)
        for ring, summary in ((st._scan, st.scan()), (st._late, st.lateness())):
            ranked = sorted(ring[:n])
            assert (summary.p50, summary.p99, summary.p999) == tuple(
                ranked[min(n - 1, max(0, round(q * (n - 1))))] if n else 0
                for q in (0.5, 0.99, 0.999)), (step, st.count)


def test_stats_percentiles_sort_each_chunk_of_cycles_once(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The feed's status asks for the lateness percentiles every second. A call sorts
    only the chunks of the window completed since the last call and the one being
    written, not the whole window again (8192 values and ~1 ms of processor time a
    call, which at a 1 ms cycle ran into the next scan's deadline); what it keeps is
    one reference a chunk for the garbage collector to follow (not one a value)."""
    sorted_from_the_ring: list[int] = []
    longest = [0]  # the most values one call sorted (the GIL held all along)

    def counting_sorted(values: Any, **kw: Any) -> list[Any]:
        if isinstance(values, array):  # a slice of the ring (not a selection's values)
            sorted_from_the_ring.append(len(values))
        values = list(values)
        longest[0] = max(longest[0], len(values))
        return sorted(values, **kw)
    monkeypatch.setattr(stats_module, "sorted", counting_sorted, raising=False)
    st = ScanStats()
    rng = random.Random(4)
    for _ in range(20_000):
        st.record(rng.randrange(20_000, 40_000), rng.randrange(3000, 90_000))
    st.lateness_quantiles()
    assert sum(sorted_from_the_ring) == st.window  # the first call: the whole window
    for _ in range(10):  # a second at a 1 ms cycle between two calls
        sorted_from_the_ring.clear()
        for _ in range(1000):
            st.record(rng.randrange(20_000, 40_000), rng.randrange(3000, 90_000))
        st.lateness_quantiles()
        # the (at most two) chunks completed since, and the one being written
        assert sum(sorted_from_the_ring) <= 1000 + 2 * stats_module.CHUNK, \
            sorted_from_the_ring
    assert longest[0] <= stats_module.CHUNK
    kept = [c for d in st._sorted for c in d.values()]  # each refers to its type only
    assert kept and len(gc.get_referents(*kept)) <= len(kept)


def test_stats_percentiles_stay_exact_when_the_ring_overtakes_their_sorts() -> None:
    """The scan goes on while another thread computes the percentiles (it pauses between
    chunks): a chunk copied after the ring wrote over it is used for that call, and kept
    only under a number that no later window holds; the next calls give the sorted
    window's figures."""
    st = ScanStats(window=2048)
    rng = random.Random(7)

    def record(k: int) -> None:
        for _ in range(k):
            st.record(rng.randrange(1000, 90_000), rng.randrange(9000))
    record(5000)
    st.p99(pause=lambda: record(1500))  # the next chunk written over at each pause
    for _ in range(3):
        for ring, summary in ((st._scan, st.scan()), (st._late, st.lateness())):
            ranked = sorted(ring)
            assert (summary.p50, summary.p99, summary.p999) == tuple(
                ranked[round(q * 2047)] for q in (0.5, 0.99, 0.999))
        record(600)


def test_stats_percentiles_of_negative_and_equal_values() -> None:
    values = array("q", [-5, -5, 7, 7, 7, 0, 3 * 10**12, -(10**12)] * 300)
    ranked = sorted(values)
    for q in (0.0, 0.1, 0.5, 0.9, 0.99, 0.999, 1.0):
        (got,) = percentiles(values, len(values), (q,))
        assert got == ranked[int(round(q * (len(values) - 1)))], q


def test_watchdog_builds_the_status_in_its_thread_when_asked_and_every_interval() -> None:
    threads: list[str] = []
    s = Scheduler(lambda now: None, 5 * MS, 400 * MS, manage_gc=False)
    wd = Watchdog(s, 400 * MS, lambda ns: None, status_interval_ns=10_000 * MS,
                  status=lambda: threads.append(threading.current_thread().name))
    wd.start()
    try:
        wd.request_status()  # long before the interval (10 s) or the period (100 ms)
        wait_until(lambda: bool(threads), timeout=10.0, what="the status")
        assert threads == ["softplc-watchdog"]
        wd.stop_pinging()
        wd.request_status()
        wd.report(time.monotonic_ns() + 20_000 * MS)  # due by time too: still nothing
        assert threads == ["softplc-watchdog"]
    finally:
        wd.stop()


def test_seq_is_odd_while_the_scan_thread_may_change_the_state_even_while_it_sleeps() -> None:
    """``Scheduler.seq``: what a thread reading the state between two scans (the feed's
    image) checks before and after its read. Odd in the scan, its idle work and a request
    served in a long cycle's wait; even in the sleep and once the loop has ended."""
    vt = VirtualTime()
    seen: list[tuple[str, int]] = []
    s: Scheduler

    def body(now: int) -> None:
        seen.append(("scan", s.seq))
        vt.now += 1 * MS
        s.wake()  # a request queued: served in the wait of this long cycle

    def idle(until: int) -> None:
        seen.append(("idle", s.seq))

    def serve(until: int) -> None:
        seen.append(("serve", s.seq))
        vt.now = until  # the wait ends

    def sleep_until(deadline: int) -> None:
        seen.append(("sleep", s.seq))
        vt.sleep_until(deadline)

    s = Scheduler(body, 50 * MS, 500 * MS, idle=idle, serve=serve, clock=vt.clock,
                  sleep_until=sleep_until, manage_gc=False)
    s.run(cycles=3)
    assert s.seq % 2 == 0
    kinds = [k for k, _ in seen]
    assert kinds == ["sleep", "scan", "idle", "serve"] * 3, kinds
    for kind, seq in seen:
        assert seq % 2 == (kind != "sleep"), seen
    seqs = [q for _, q in seen]
    assert seqs == sorted(seqs) and len(set(q for k, q in seen if k == "sleep")) == 3
