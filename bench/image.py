"""Benchmark: what the feed costs per sample, on the scan thread and in the side process,
against the number of names (runtime/controller/image.py). Not a test: prints a table.

The plant is bench/jitter.py's (``n`` drawer testers, 39 names each), built as ``softplc
run --sim`` builds it, not running (the costs are measured by calling the functions
directly, the best of ``--repeat`` runs of ``--number`` calls: the least disturbed by
the other processes of this machine). Columns, microseconds per sample:

- ``rest`` and ``worst``: ``ImageWriter.write`` (the feed thread between two scans, the
  scan thread when first built; this design: a seqlock, a CRC32, the slots read by one
  generated function, and a ``pack_into`` per region whose values changed since the last
  write), with between two writes (not timed) a plant at
  rest: every instance's chart clock advanced, nothing else changed (a drawer waiting in
  its step); the worst case: besides, one BOOL slot of every instance and the first input
  and output point of every driver flipped, so that every numeric region is packed (the
  strings, which change rarely, stay);
- ``capture``: ``Catalogue.capture`` (the scan thread before this design, at every
  sample; now only while a client takes frames or follows transitions);
- ``frame``: what the controller's feed thread did per sample before, in the controller's
  process: every name read from the capture, compared, a delta frame JSON-encoded;
- ``decode``: ``ImageReader.read`` (the side process: copy, check, every name computed).

``--gap-ms`` sleeps between two timed writes (not timed), as the scan thread idles
between two samples in a running controller: back to back (the default) the write finds
its data in the caches, spaced by a 10 ms sleep it cost about 3.5 times as much on this
VM (96 µs against 362 µs at rest, 100 testers), which is what the running controller
pays (``bench.observers``' image write column: 310-370 µs).

``--breakdown`` prints instead, for each plant, where a write's time goes (the generated
reader, the compares, the packs, the clocks, the strings, the CRC, the stamps).

    python -m bench.image [--testers 10,25,50,100] [--number 200] [--repeat 5] [--breakdown]
                          [--gap-ms 0]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import timeit
import zlib
from collections.abc import Callable
from typing import Any

from bench.jitter import plant_file
from runtime.controller.daemon import Daemon
from runtime.controller.image import STAMP_AT, ImageReader, ImageWriter
from runtime.engine.names import Catalogue
from runtime.language.plantfile import load_plant


def best_us(fn: Callable[[], Any], number: int, repeat: int) -> float:
    """The best of ``repeat`` runs of ``number`` calls, microseconds per call."""
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


#: seconds slept between two timed writes (``--gap-ms``; 0: back to back)
GAP_S = [0.0]


def per_write_us(writer: ImageWriter, change: Callable[[], None], number: int,
                 repeat: int) -> float:
    """The best of ``repeat`` means of ``number`` writes, microseconds per write, each
    after ``change()`` and, with ``--gap-ms``, a sleep (neither timed)."""
    best = float("inf")
    for _ in range(repeat):
        total = 0
        for scan in range(number):
            change()
            if GAP_S[0]:
                time.sleep(GAP_S[0])
            t0 = time.perf_counter_ns()
            writer.write(scan, 0)
            total += time.perf_counter_ns() - t0
        best = min(best, total / number / 1e3)
    return best


def changes(cat: Catalogue, writer: ImageWriter) -> tuple[Callable[[], None],
                                                          Callable[[], None]]:
    """(at rest: every chart clock advanced by 10 ms; the worst case: besides, in every
    instance its first BOOL slot of the image flipped, every driver's first input and
    output point flipped)."""
    insts = list(cat.plant.instances.values())
    clocks = {(insts[s.spec[1]].m, s.spec[3]) for s in cat.names.values()
              if s.spec and s.spec[0] == "steptime"}
    flips = []
    for (_at, fmt, nums, *_strs), inst in zip(writer.describe()["instances"], insts,
                                              strict=True):
        if "?" in fmt[1:]:
            flips.append((inst.m, nums[fmt[1:].index("?")]))
    lists = [vals for d in cat.plant.drivers.values()
             for vals in (d.inputs.vals, d.outputs.vals) if vals]

    def rest() -> None:
        for m, k in clocks:
            m[k] = m[k] + 10_000_000

    def worst() -> None:
        rest()
        for m, k in flips:
            m[k] = not m[k]
        for vals in lists:
            vals[0] = 0 if vals[0] else 1
    return rest, worst


def breakdown(writer: ImageWriter, worst: Callable[[], None], number: int,
              repeat: int) -> list[tuple[str, float]]:
    """Where a write's time goes, microseconds (the writer's parts called one by one)."""
    w = writer
    mm = w._mm
    w.write(0, 0)
    got = w._read()
    numeric = list(zip(w._packs, got, strict=False))

    def compare() -> None:
        for j, (a, b, _real) in enumerate(w._blocks):
            if got[a:b] != w._kept_blocks[j]:
                pass

    def packs() -> None:
        for pack, vals in numeric:
            pack(*vals)

    def clocks() -> None:
        for at, v in zip(w._clock_ats, got[len(w._numeric)], strict=True):
            w._regions[len(w._numeric)][1](mm, at, v)

    def strings() -> None:
        if got[-1] != w._last[-1]:
            pass

    def crc() -> None:
        with memoryview(mm) as view:
            zlib.crc32(view[STAMP_AT:])
    w.write(0, 0)
    parts = [("read (the generated reader)", w._read),
             ("compare (the numeric regions by blocks, none changed)", compare),
             ("pack (every numeric region)", packs),
             ("clocks (packed every write)", clocks),
             ("strings (compared at once)", strings),
             ("crc32", crc)]
    out = [(name, best_us(fn, number, repeat)) for name, fn in parts]
    rest, _worst = changes_of[id(w)]
    out.append(("write at rest", per_write_us(w, rest, number, repeat)))
    out.append(("write, worst case", per_write_us(w, worst, number, repeat)))
    return out


changes_of: dict[int, tuple[Callable[[], None], Callable[[], None]]] = {}


def row(directory: str, testers: int, number: int, repeat: int, parts: bool) -> str:
    pdef = load_plant(plant_file(directory, testers, 10, False))
    daemon = Daemon(pdef, sim=True, manage_gc=False)
    cat = Catalogue(daemon.plant)
    writer = ImageWriter(cat, f"{directory}/image-{testers}", 1)
    try:
        rest, worst = changes(cat, writer)
        if parts:
            changes_of[id(writer)] = (rest, worst)
            return "\n".join(f"{testers:>7} {name:<46} {us:>7.1f}"
                             for name, us in breakdown(writer, worst, number, repeat))
        schema = json.loads(json.dumps({"image": writer.describe(),
                                        "specs": [list(s.spec)
                                                  for s in cat.names.values()]}))
        reader = ImageReader(schema)
        writer.write(1, 0)
        names = list(cat.names.values())
        img = cat.capture(0)
        prev = [s.read(img) for s in names]

        def frame() -> bytes:
            values = [s.read(img) for s in names]
            changes: list[Any] = []
            for i, v in enumerate(values):
                if v != prev[i] or type(v) is not type(prev[i]):
                    changes += (i, v)
            return json.dumps({"d": [1, 0.0, changes]}).encode()
        at_rest = per_write_us(writer, rest, number, repeat)
        at_worst = per_write_us(writer, worst, number, repeat)
        capture = best_us(lambda: cat.capture(0), number, repeat)
        old = best_us(frame, max(1, number // 10), repeat)
        decode = best_us(reader.read, max(1, number // 10), repeat)
        reader.close()
    finally:
        writer.retire()
    return (f"{testers:>7} {len(names):>6} {writer.size:>7} {at_rest:>8.0f} {at_worst:>8.0f} "
            f"{capture:>8.0f} {old:>8.0f} {decode:>8.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--testers", default="10,25,50,100")
    ap.add_argument("--number", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--breakdown", action="store_true")
    ap.add_argument("--gap-ms", type=float, default=0.0,
                    help="sleep this long between two timed writes, as a controller's "
                         "scan thread idles between samples (0: back to back, the caches "
                         "warm: about a third of what a running controller pays)")
    args = ap.parse_args()
    GAP_S[0] = args.gap_ms / 1e3
    sys.stdout.write("testers  part                                           us\n"
                     if args.breakdown else
                     "testers  names   bytes     rest    worst  capture    frame   decode  (us)\n")
    with tempfile.TemporaryDirectory() as directory:
        for n in (int(x) for x in args.testers.split(",")):
            sys.stdout.write(row(directory, n, args.number, args.repeat,
                                 args.breakdown) + "\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
