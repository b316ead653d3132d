"""Benchmark: what the feed costs per sample, on the scan thread and in the side process,
against the number of names (runtime/controller/image.py). Not a test: prints a table.

The plant is bench/jitter.py's (``n`` drawer testers, 39 names each), built as ``softplc
run --sim`` builds it, not running (the costs are measured by calling the functions
directly, the best of ``--repeat`` runs of ``--number`` calls: the least disturbed by
the other processes of this machine). Columns, microseconds per sample:

- ``write``: ``ImageWriter.write`` (the scan thread, this design: a seqlock, a CRC32 and one
  ``pack_into`` per instance and driver region);
- ``capture``: ``Catalogue.capture`` (the scan thread before this design, at every
  sample; now only while a client takes frames or follows transitions);
- ``frame``: what the controller's feed thread did per sample before, in the controller's
  process: every name read from the capture, compared, a delta frame JSON-encoded;
- ``decode``: ``ImageReader.read`` (the side process: copy, check, every name computed).

    python -m bench.image [--testers 10,25,50,100] [--number 200] [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import timeit
from collections.abc import Callable
from typing import Any

from bench.jitter import plant_file
from runtime.controller.daemon import Daemon
from runtime.controller.image import ImageReader, ImageWriter
from runtime.engine.names import Catalogue
from runtime.language.plantfile import load_plant


def best_us(fn: Callable[[], Any], number: int, repeat: int) -> float:
    """The best of ``repeat`` runs of ``number`` calls, microseconds per call."""
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def row(directory: str, testers: int, number: int, repeat: int) -> str:
    pdef = load_plant(plant_file(directory, testers, 10, False))
    daemon = Daemon(pdef, sim=True, manage_gc=False)
    cat = Catalogue(daemon.plant)
    writer = ImageWriter(cat, f"{directory}/image-{testers}", 1)
    try:
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
        write = best_us(lambda: writer.write(1, 0), number, repeat)
        capture = best_us(lambda: cat.capture(0), number, repeat)
        old = best_us(frame, max(1, number // 10), repeat)
        decode = best_us(reader.read, max(1, number // 10), repeat)
        reader.close()
    finally:
        writer.retire()
    return (f"{testers:>7} {len(names):>6} {writer.size:>7} {write:>8.0f} {capture:>8.0f} "
            f"{old:>8.0f} {decode:>8.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--testers", default="10,25,50,100")
    ap.add_argument("--number", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    sys.stdout.write("testers  names   bytes    write  capture    frame   decode  (us)\n")
    with tempfile.TemporaryDirectory() as directory:
        for n in (int(x) for x in args.testers.split(",")):
            sys.stdout.write(row(directory, n, args.number, args.repeat) + "\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
