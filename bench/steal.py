"""Benchmark: how often the machine takes a processor from a thread that is running, and
for how long, unseen by this system's scheduler (not a test: prints a table).

One process per processor, pinned to it, reads the monotonic clock in a loop for
``--seconds``, with the thread's scheduler statistics (/proc/thread-self/schedstat: time
waiting runnable, times put on a processor). A gap between two reads longer than
``--gap-us`` is a time the thread did not run:

- "this system": the kernel put another task on the processor meanwhile (the thread's
  waiting time or its count of slices moved);
- "the host": they did not. On a virtual machine, the host ran something else on that
  virtual processor's core (steal time), or handled an interrupt for that long.

Why it matters to the controller (docs/architecture.md, "The host's share"): a thread of
the controller's process that holds the GIL when the host takes its processor keeps the
scan waiting for as long, however little the thread had left to do. Where the kernel does
not subtract the host's share from the threads' processor times
(``CONFIG_PARAVIRT_TIME_ACCOUNTING``, said in the report), that time counts as the
thread's own, and a probe sees "the GIL's holder ran".

    python -m bench.steal [--seconds 20] [--gap-us 200]
"""

from __future__ import annotations

import argparse
import gzip
import multiprocessing as mp
import os
import time
from typing import Any

from bench.opcua import out


def _spin(cpu: int, seconds: float, gap_ns: int, q: Any) -> None:
    """Pinned to ``cpu``: the gaps longer than ``gap_ns``, each (ns, unseen by the kernel)."""
    os.sched_setaffinity(0, {cpu})
    fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    mono = time.monotonic_ns
    end = mono() + int(seconds * 1e9)
    last, prev = mono(), os.pread(fd, 64, 0).split()
    gaps: list[tuple[int, bool]] = []
    while last < end:
        cur = os.pread(fd, 64, 0).split()
        now = mono()
        if now - last > gap_ns:
            # the waiting time (2nd) and the slices (3rd) still: no task of this kernel ran
            gaps.append((now - last, cur[1] == prev[1] and cur[2] == prev[2]))
        last, prev = now, cur
    os.close(fd)
    q.put((cpu, gaps))


def paravirt_accounting() -> str:
    """Whether this kernel subtracts the host's share from the tasks' processor times:
    "yes", "no" or "unknown" (its configuration not readable)."""
    release = os.uname().release
    for path in ("/proc/config.gz", f"/boot/config-{release}"):
        try:
            opener: Any = gzip.open if path.endswith(".gz") else open
            with opener(path, "rt", encoding="utf-8") as f:
                text = f.read()
        except OSError:
            continue
        return "yes" if "CONFIG_PARAVIRT_TIME_ACCOUNTING=y" in text else "no"
    return "unknown"


def measure(seconds: float, gap_us: float) -> dict[int, list[tuple[int, bool]]]:
    """Per processor, the gaps of its pinned spinning process."""
    q: Any = mp.Queue()
    cpus = sorted(os.sched_getaffinity(0))
    procs = [mp.Process(target=_spin, args=(c, seconds, int(gap_us * 1e3), q))
             for c in cpus]
    for p in procs:
        p.start()
    got = dict(q.get(timeout=seconds + 60) for _ in procs)
    for p in procs:
        p.join()
    return got


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.steal", description=__doc__.split(
        "\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--gap-us", type=float, default=200.0, metavar="US")
    args = ap.parse_args(argv)
    got = measure(args.seconds, args.gap_us)
    out(f"{len(got)} processors, {args.seconds:.0f} s, gaps over {args.gap_us:.0f} us; "
        f"load average {os.getloadavg()[0]:.1f}; the kernel subtracts the host's share "
        f"from the tasks' processor times: {paravirt_accounting()}")
    out("| cpu | taken by | gaps | over 1 ms | max us | the longest five us |")
    out("|---|---|---|---|---|---|")
    for cpu, gaps in sorted(got.items()):
        for unseen, who in ((True, "the host"), (False, "this system")):
            d = sorted(g for g, u in gaps if u is unseen)
            out(f"| {cpu} | {who} | {len(d)} | {sum(1 for g in d if g > 1_000_000)} | "
                f"{(d[-1] if d else 0) / 1e3:.0f} | "
                f"{', '.join(f'{g / 1e3:.0f}' for g in d[-5:]) or '-'} |")


if __name__ == "__main__":
    main()
