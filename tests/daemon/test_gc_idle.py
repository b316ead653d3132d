"""Garbage collection in the scan's idle time never makes the scan late: a full collection
that would not end before the next cycle waits, and the process image's copies (the
console's and the feed's captures) give the collector nothing to examine.

Measured before: with four consoles tracing 100 drawer testers, a full collection once a
minute examined 160 000 objects (132 000 of them the captures' lists) and took 56 ms in
an idle time of 8 ms: three overruns (``bench.observers``)."""

from __future__ import annotations

import gc
import logging
import re
import sys
from dataclasses import dataclass, field

import pytest

from runtime.controller import scheduler as scheduler_mod
from runtime.controller.daemon import Daemon
from runtime.controller.scheduler import Scheduler
from runtime.engine.names import Catalogue
from runtime.language.plantfile import load_plant
from tests.daemon.test_daemon_scheduler import MS, VirtualTime

S = 1_000_000_000


@dataclass
class FakeCollector:
    """The ``gc`` module as the scheduler sees it, on virtual time: each collection takes
    ``cost[generation]`` ns of the clock; ``pending`` objects wait for a young one."""

    vt: VirtualTime
    cost: dict[int, int]
    pending: int = 0
    collections: list[tuple[int, int]] = field(default_factory=list)

    def get_count(self) -> tuple[int, int, int]:
        return (self.pending, 0, 0)

    def collect(self, generation: int = 2) -> int:
        self.collections.append((generation, self.vt.now))
        self.vt.now += self.cost[generation]
        self.pending = 0
        return 0

    def isenabled(self) -> bool:
        return False

    def freeze(self) -> None: ...

    def unfreeze(self) -> None: ...

    def enable(self) -> None: ...

    def disable(self) -> None: ...


def run_minutes(monkeypatch: pytest.MonkeyPatch, full_ns: int, minutes: float,
                scan_ns: int = 2 * MS, cycle_ns: int = 10 * MS
                ) -> tuple[Scheduler, FakeCollector, int]:
    """The scan loop for ``minutes`` of virtual time, every scan leaving 100 objects for
    the collector, a full collection costing ``full_ns`` (a young one 50 µs); returns
    the scheduler, the collector and the first scan's time."""
    vt = VirtualTime()
    fake = FakeCollector(vt, {0: 50_000, 1: 200_000, 2: full_ns})
    monkeypatch.setattr(scheduler_mod, "gc", fake)

    wakes: list[int] = []

    def body(now: int) -> None:
        wakes.append(now)
        vt.now += scan_ns
        fake.pending += 100

    s = Scheduler(body, cycle_ns, 100 * MS, clock=vt.clock, sleep_until=vt.sleep_until)
    s.run(cycles=int(minutes * 60 * S // cycle_ns))
    return s, fake, wakes[0]


def test_a_full_collection_longer_than_the_idle_time_waits(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "runtime.controller")
    s, fake, _ = run_minutes(monkeypatch, 12 * MS, 3)
    # the idle time is 8 ms less the guard: a 12 ms collection is never started in it
    assert s.stats.overruns == 0, fake.collections
    assert s.stats.late_max == 0, fake.collections[-5:]
    young = [g for g, _ in fake.collections if g < 2]
    assert len(young) > 100  # the young ones go on
    assert s.stats.gc_full_deferred > 0
    said = [r.getMessage() for r in caplog.records if "full garbage collection" in r.message]
    assert len(said) == 1, said  # said once, not every cycle
    assert "12.0 ms" in said[0] and "idle" in said[0]


def test_a_full_collection_that_fits_runs_once_a_minute(
        monkeypatch: pytest.MonkeyPatch) -> None:
    s, fake, first = run_minutes(monkeypatch, 3 * MS, 3.5)
    assert s.stats.late_max == 0
    # before the first scan, at start-up, the one that also measures what a full one
    # costs; then one a minute
    fulls = [t for g, t in fake.collections if g == 2 and t > first]
    assert len(fulls) == 3, fulls
    assert all(60 * S <= b - a < 61 * S for a, b in zip([first, *fulls], fulls, strict=False))
    assert s.stats.gc_full_deferred == 0
    assert s.stats.gc_full_max == s.stats.gc_full_last == 3 * MS
    gens = [g for g, _ in fake.collections]
    assert 0 < 9 * gens.count(1) <= gens.count(0)  # every tenth young one: the middle


def test_a_full_collection_that_grew_is_not_started_again_in_too_short_a_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The heap grew between two full collections (clients connected): the one that took
    longer than its time is the last to; the next ones wait for a time that holds it."""
    vt = VirtualTime()
    fake = FakeCollector(vt, {0: 50_000, 1: 200_000, 2: 1 * MS})
    monkeypatch.setattr(scheduler_mod, "gc", fake)
    cycles = [0]

    def body(now: int) -> None:
        cycles[0] += 1
        vt.now += 2 * MS
        fake.pending += 100
        if cycles[0] == 3000:  # 30 s in: the heap is now ten times what it was
            fake.cost[2] = 10 * MS

    s = Scheduler(body, 10 * MS, 100 * MS, clock=vt.clock, sleep_until=vt.sleep_until)
    s.run(cycles=5 * 60 * 100)
    # the first full collection after the growth took 10 ms: one wake-up late, no more
    assert sum(1 for g, _ in fake.collections if g == 2) <= 3
    assert s.stats.late_max <= 4 * MS
    assert [g for g, _ in fake.collections].count(2) <= 3  # start-up, 60 s (grown): no more
    assert s.stats.gc_full_deferred > 0


@dataclass
class SurvivorsCollector(FakeCollector):
    """A middle collection examines what survived the young ones since the last: it
    costs ``cost[1]`` plus ``per_young`` ns for each young collection since."""

    per_young: int = 0
    young_since: int = 0

    def collect(self, generation: int = 2) -> int:
        self.young_since += 1
        extra = self.per_young * self.young_since if generation >= 1 else 0
        if generation >= 1:
            self.young_since = 0
        self.vt.now += extra
        return super().collect(generation)


def test_middle_collections_that_do_not_fit_come_more_often_until_they_fit(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A 1 ms cycle: 0.5 ms of idle time before the guard, what survived each young
    collection costs 120 µs in the next middle one. Every tenth young one, a middle
    one took 1.25 ms, past the next deadline each time (measured in bench.observers at
    1 ms with observers: 1.5 to 1.7 ms). Now two late ones make them come every second
    young one (0.29 ms); once survivors cost 5 µs each, every tenth again."""
    vt = VirtualTime()
    fake = SurvivorsCollector(vt, {0: 50_000, 1: 50_000, 2: 100_000}, per_young=120_000)
    monkeypatch.setattr(scheduler_mod, "gc", fake)
    cycles = [0]
    late: list[int] = []  # the scans that woke after their deadline

    def body(now: int) -> None:
        cycles[0] += 1
        if s.due and now > s.due:
            late.append(cycles[0])
        vt.now += 200_000
        fake.pending += 100
        if cycles[0] == 30_000:
            fake.per_young = 5_000

    s = Scheduler(body, 1 * MS, 100 * MS, clock=vt.clock, sleep_until=vt.sleep_until)
    s.run(cycles=20_000)
    gens = [g for g, _ in fake.collections]
    # the two that taught it, early; none since
    assert len(late) <= 2 and not [c for c in late if c > 1000], late
    assert s.gc_middle_every == 2, gens[:40]
    assert gens.count(1) * 3 >= gens.count(0), (gens.count(1), gens.count(0))
    s.run(cycles=20_000)  # survivors cheap from the 30 000th scan on
    assert s.gc_middle_every == scheduler_mod.GC_MIDDLE_EVERY
    assert len(late) <= 2, late


def test_the_process_image_copies_are_not_tracked_by_the_collector(tmp_path) -> None:
    """A capture (console streams, the feed) holds values only: after the collections of
    the idle time none of its copies is left for a full one to examine (the capture
    itself, one object, is)."""
    from bench.jitter import plant_file

    daemon = Daemon(load_plant(plant_file(str(tmp_path), 3, 10, False)), sim=True,
                    manage_gc=False)
    cat = Catalogue(daemon.plant)
    images = [cat.capture(n) for n in range(20)]
    gc.collect(0)  # a young collection: every copy of a slot or point list
    for img in images:
        copies = [*img.m, *img.inputs, *img.outputs]
        assert copies and not any(gc.is_tracked(c) for c in copies), \
            [type(c).__name__ for c in copies if gc.is_tracked(c)]
    gc.collect(1)  # the middle generation (every tenth): the tuples holding them too
    for img in images:
        assert not any(gc.is_tracked(c) for c in (img.m, img.inputs, img.outputs, img.ok))
    # and they still read as the state does
    a = next(iter(daemon.plant.instances.values()))
    assert list(images[-1].m[0]) == a.m[:]


def free_tuples(capfd: pytest.CaptureFixture[str]) -> int | None:
    """The tuples CPython keeps freed for reuse now (``sys._debugmallocstats``, which
    writes to the process's stderr), or None if it does not say."""
    capfd.readouterr()
    sys._debugmallocstats()
    said = capfd.readouterr().err
    counts = re.findall(r"^\s*([\d,]+) free \d+-sized PyTupleObjects", said, re.M)
    return sum(int(c.replace(",", "")) for c in counts) if counts else None


def test_the_first_full_collection_is_timed_with_the_free_tuples_it_will_free(
        capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """A full collection frees every tuple the interpreter keeps for reuse (2000 of each
    length 1 to 19 in CPython 3.11): 0.4 to 1 ms here, whatever the heap. The start-up
    collection that gives the first estimate ran right after another had freed them, so
    it said a few µs, and in bench.observers at 1 ms the first full collection, a minute
    in, overran (0.8 to 3.5 ms in about 0.5 ms of idle time). The estimate is now timed
    with the free lists full (before: 4 tuples in them)."""
    if free_tuples(capfd) is None:
        pytest.skip("this interpreter does not report its free tuples")
    at_estimate: list[int | None] = []
    frozen = [False]

    class Spy:
        """The gc module, noting the free tuples when the estimate's collection starts."""

        def __getattr__(self, name: str) -> object:
            return getattr(gc, name)

        def freeze(self) -> None:
            frozen[0] = True
            gc.freeze()

        def collect(self, generation: int = 2) -> int:
            if generation == 2 and frozen[0] and not at_estimate:
                at_estimate.append(free_tuples(capfd))
            return gc.collect(generation)

    monkeypatch.setattr(scheduler_mod, "gc", Spy())
    vt = VirtualTime()

    def body(now: int) -> None:
        vt.now += MS

    Scheduler(body, 10 * MS, 100 * MS, clock=vt.clock, sleep_until=vt.sleep_until).run(1)
    assert at_estimate and at_estimate[0] is not None
    assert at_estimate[0] >= 19 * 2000 * 9 // 10  # CPython 3.11's, 9 in 10 of them
