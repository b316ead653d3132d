"""What a stream costs the controller's process (issue 40): one copy of the image per scan
whatever the number of streams, and a poll that reads the names whose raw values changed,
not every name. Counts, not timings."""

from __future__ import annotations

import dataclasses
import gc
import math
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import pytest

from runtime.console.protocol import STREAM_LINES_PER_POLL
from runtime.console.streams import Stream, StreamKind
from runtime.engine.names import Catalogue, Image, Signal
from runtime.engine.plant import Plant
from runtime.language import ast as A
from runtime.language.plantfile import load_plant
from tests.console.consolekit import Rig, wait_for

#: drawer testers of the plant whose names are counted
TESTERS = 12


def drawers_plant(write: Callable[[str, str], str]) -> Plant:
    """TESTERS drawer testers on one simulated driver, 8 points each, run two cycles."""
    lines = ["plc: {cycle: 10ms}", "drivers: {sim: {type: sim}}", "instances:"]
    for i in range(TESTERS):
        b = 8 * i
        lines += [f"  t{i}:", "    grafcet: drawer.yaml",
                  f"    inputs: {{iParo: {{from: sim.I{b}, invert: true}}, iMarcha: "
                  f"sim.I{b + 1}, iAbierto: sim.I{b + 2}, iCerrado: sim.I{b + 3}}}",
                  f"    outputs: {{oAbrir: sim.Q{b}, oCerrar: sim.Q{b + 1}, oParado: "
                  f"sim.Q{b + 2}, oTest: sim.Q{b + 3}}}"]
    plant = Plant(load_plant(write("plant.yaml", "\n".join(lines) + "\n")), sim=True,
                  virtual=True)
    plant.open()
    for i in range(TESTERS):
        plant.set(f"sim.I{8 * i}", 1)  # the NC stop buttons released
    plant.cycle(0)
    plant.cycle(10_000_000)
    return plant


def counted(names: list[Signal], reads: list[str]) -> list[Signal]:
    """``names`` whose reads are recorded in ``reads`` (their texts)."""
    def reader(s: Signal) -> Callable[[Image], Any]:
        def read(img: Image) -> Any:
            reads.append(s.text)
            return s.read(img)
        return read
    return [dataclasses.replace(s, read=reader(s)) for s in names]


@pytest.mark.parametrize("kind", ["trace", "watch"])
def test_a_poll_reads_only_the_names_whose_raw_values_changed(
        write: Callable[[str, str], str], drawer: str, kind: str) -> None:
    """A stream of every name of TESTERS testers: when one input point changes, the poll
    reads that point's name; when one tester then scans, only its names (and its
    points). Before, every poll read every name of every queued image: 12 * 35 names
    for one point changed."""
    plant = drawers_plant(write)
    cat = Catalogue(plant)
    reads: list[str] = []
    base = cat.traced if kind == "trace" else cat.expand([*plant.instances, "sim"])
    stream = Stream(kind, counted(base, reads), cat)  # type: ignore[arg-type]
    stream.images.append(cat.capture(-1))
    stream.last_scan = 2
    first = stream.poll(lambda: 0.0, False)
    assert len(reads) == len(base) > 15 * TESTERS  # the first snapshot: every name once
    assert len(first) == (1 if kind == "watch" else 0)

    reads.clear()
    stream.images.append(cat.capture(3))  # nothing changed
    assert stream.poll(lambda: 0.0, False) == []
    assert reads == []

    plant.set("sim.I9", 1)  # t1.iMarcha's point, before t1 scans it
    stream.images.append(cat.capture(4))
    lines = stream.poll(lambda: 0.0, False)
    assert reads == ["sim.I9"]
    if kind == "trace":
        assert lines == ["trace 4: sim.I9=1"]
    else:
        assert len(lines) == 1 and "sim.I9=1 (t1.iMarcha=1)" in lines[0]

    reads.clear()
    plant.cycle(20_000_000)  # t1 leaves gsParado for gsAbrir; the others stay as they were
    stream.images.append(cat.capture(5))
    lines = stream.poll(lambda: 0.0, False)
    assert {r.split(".")[0] for r in reads} <= {"t1", "sim"}, reads
    t1 = [n for n in base if n.text.startswith("t1.")]
    assert 0 < len(reads) <= len(t1) + 8, reads
    assert len(lines) == 1 and "t1.oAbrir=1" in lines[0], lines


def test_one_copy_of_the_image_per_scan_for_every_stream(
        rigs: Callable[..., Rig], monkeypatch: pytest.MonkeyPatch) -> None:
    """Four sessions tracing: the scan thread copies the image once per scan, and the
    four streams get that one copy. Before, each stream copied it: four copies per
    scan."""
    rig = rigs(serial_port=False, unix_socket=False, blink=True)
    cat = rig.service.catalogue
    copied: list[int] = []
    capture = cat.capture

    def counting(scan: int) -> Image:
        copied.append(scan)
        return capture(scan)
    monkeypatch.setattr(cat, "capture", counting)
    sessions = [rig.service.session(f"tracer {k}") for k in range(4)]
    try:
        for s in sessions:
            assert s.feed(b"trace on\r\n")[-1] == "ok"
        streams = [s.stream for s in sessions]
        assert all(streams)
        wait_for(lambda: len([n for n in copied if n >= 0]) > 3 * STREAM_LINES_PER_POLL,
                 "60 scans copied")
        # read between two scans: the queues as the scan thread left them
        queued = rig.daemon.call(lambda: [list(st.images)  # type: ignore[union-attr]
                                          for st in streams])
        for s in sessions:
            s.feed(b"\r")  # the streams end (their images let go)
        scans = [n for n in copied if n >= 0]
        assert len(scans) == len(set(scans)), "an image copied more than once in a scan"
        # the scans all four streams got are the same objects
        newest = min(q[-1].scan for q in queued)
        shared = [next(img for img in q if img.scan == newest) for q in queued]
        assert all(img is shared[0] for img in shared)
        # and the lines they make are the same
        assert rig.service.tap.streams == ()
    finally:
        for s in sessions:
            s.close()


def test_a_nan_that_stays_a_nan_is_no_change() -> None:
    """A REAL name that is NaN scan after scan makes one trace line, when it becomes NaN.
    Before, NaN != NaN made a line at every scan, with nothing changed."""
    x = Signal("p.rX", A.Type.REAL, lambda img: img.m[0][0], "memory", spec=("slot", 0, 0))
    y = Signal("p.rY", A.Type.REAL, lambda img: img.m[0][0], "memory")  # read every image
    cat = SimpleNamespace(names={"p.rX": x, "p.rY": y})
    for name in (x, y):
        stream = Stream("trace", [name], cat)  # type: ignore[arg-type]
        stream.images.append(Image(-1, [[0.0]], [], [], []))  # type: ignore[list-item]
        stream.last_scan = 0
        for scan in range(1, 6):  # a new NaN object each scan, as a division makes it
            stream.images.append(Image(scan, [[float("nan")]], [], [], []))  # type: ignore[list-item]
        assert stream.poll(lambda: 0.0, False) == [f"trace 1: {name.text}=nan"]
        same_nan = math.nan
        stream.images.extend(Image(scan, [[same_nan]], [], [], [])  # type: ignore[list-item]
                             for scan in range(6, 9))
        assert stream.poll(lambda: 0.0, False) == []


def test_a_value_is_shown_as_itself_whatever_was_shown_before() -> None:
    """A stream keeps the text of each (name, value) it has shown; a float equal to an
    int shown before (1.0 == 1) is shown as the float, a bool and an int as the name
    shows them."""
    x = Signal("p.rX", A.Type.REAL, lambda img: img.m[0][0], "memory", spec=("slot", 0, 0))
    b = Signal("p.b", A.Type.BOOL, lambda img: img.m[0][1], "memory", spec=("slot", 0, 1))
    cat = SimpleNamespace(names={"p.rX": x, "p.b": b})
    stream = Stream("trace", [x, b], cat)  # type: ignore[arg-type]
    stream.images.append(Image(-1, [[0, False]], [], [], []))  # type: ignore[list-item]
    stream.last_scan = 0
    for scan, m in enumerate([[1, True], [2.5, 0], [1.0, 1], [2, False], [1.0, True]], 1):
        stream.images.append(Image(scan, [m], [], [], []))  # type: ignore[list-item]
    assert stream.poll(lambda: 0.0, False) == [
        "trace 1: p.rX=1  p.b=1", "trace 2: p.rX=2.5  p.b=0", "trace 3: p.rX=1.0  p.b=1",
        "trace 4: p.rX=2  p.b=0", "trace 5: p.rX=1.0  p.b=1"]


def slot_reader(i: int) -> Callable[[Image], Any]:
    """Reads memory slot ``i`` of an image."""
    return lambda img: img.m[0][i]


def collector_visits(root: object) -> int:
    """The references a garbage collection follows from the containers it tracks that
    ``root`` reaches (``root`` included): what those cost each collection."""
    seen: set[int] = set()
    todo = [root]
    visits = 0
    while todo:
        o = todo.pop()
        if id(o) in seen or not gc.is_tracked(o):
            continue
        seen.add(id(o))
        refs = gc.get_referents(o)
        visits += len(refs)
        todo.extend(refs)
    return visits


@pytest.mark.parametrize("kind", ["trace", "watch"])
def test_the_texts_a_stream_keeps_cost_the_garbage_collector_one_entry_a_name(
        kind: StreamKind) -> None:
    """Every collection of the controller's process runs in the scan thread's idle time,
    and a full one follows every reference of every object it tracks. In bench.observers
    at 1 ms, 4 console traces' texts (up to 20 000 each, keyed by (name, value) tuples)
    were 54 000 of the 69 000 references the first full collection followed, which took
    1.8 to 3.5 ms against about 0.5 ms of idle time. A name's texts are now a dict of
    scalars and strings, which the collector does not track: the stream's texts cost it
    one entry per name, however many values were shown."""
    n = 30
    names = [Signal(f"p.i{i}", A.Type.INT, slot_reader(i), "memory", spec=("slot", 0, i))
             for i in range(n)]
    cat = SimpleNamespace(names={s.text: s for s in names})
    stream = Stream(kind, names, cat)  # type: ignore[arg-type]
    stream.images.append(Image(-1, [[-1] * n], [], [], []))
    stream.last_scan = 0
    lines = 0
    for first in range(1, 400, 10):  # counters counting, and booleans toggling
        stream.images.extend(Image(s, [[s if i % 2 else s % 2 == 0 for i in range(n)]],
                                   [], [], []) for s in range(first, first + 10))
        lines += len(stream.poll(lambda: 0.0, False))
    assert lines >= 399  # a line each scan (and the start's)
    assert collector_visits(stream._shown) <= 2 * n  # before: 12 216 (trace)
    shown = stream.line(kind, {"p.i1": 399, "p.i0": False}, 400, 0, False)
    assert shown.endswith("p.i1=399  p.i0=0")
