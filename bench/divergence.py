"""Benchmark: compile and check of the two chart shapes that grew quadratically (issue 31).

- a selection (OR) divergence of n branches from one step (``fan_text``): every branch on
  the same condition (``iGo``: the first in file order wins), or each on its own value of a
  selector (``--distinct``: ``iGo AND sSel = k``, mutually exclusive);
- a chain of n steps in a loop (``chain_text``).

For each size, in this process: the load (YAML, parse, type-check), ``check_grafcet`` (every
rule of ``softplc check``) and ``compile_grafcet`` (generate, ``compile``, ``exec``), each
the best of ``--repeat`` runs, with the growth exponent between consecutive sizes
(log(t2/t1) / log(n2/n1): 1 is linear, 2 quadratic), the generated source's size and the
peak memory of the compile (tracemalloc, one more run). Not a test: prints a table; the
tests measure the same growth by ratios of memory and of work counted
(tests/engine/test_compile_scale.py, tests/check/test_check_divergence_scale.py).

    python -m bench.divergence [--shape fan|chain] [--distinct] [--sizes 250 500 1000 2000]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import tracemalloc

from bench.compile import best, growth, out
from runtime.checker.rules import check_grafcet
from runtime.compiler.codegen import Compiler, compile_grafcet
from runtime.language import yamlsrc
from runtime.language.grafcetfile import load_grafcet


def fan_text(n: int, scan: str = "immediate", distinct: bool = False) -> str:
    """Step s0 and n branches b0..b(n-1), each entered from s0 (on iGo, or with
    ``distinct`` on iGo and its own value of sSel) and left back to s0 on iStop."""
    lines = ["grafcet: Fan", f"scan: {scan}", "inputs: [iGo, iStop]", "outputs: [oMotor]",
             "memory: {sSel: 0}", "steps:", "  s0: {initial: true}"]
    lines += [f"  b{i}: {{actions: [oMotor]}}" for i in range(n)]
    lines.append("transitions:")
    for i in range(n):
        when = f'"iGo AND sSel = {i}"' if distinct else "iGo"
        lines += [f"  - {{from: s0, to: b{i}, when: {when}}}",
                  f"  - {{from: b{i}, to: s0, when: iStop}}"]
    return "\n".join(lines) + "\n"


def chain_text(n: int) -> str:
    """A loop of n steps s0..s(n-1), each passed on a rise of iGo, oMotor on in all but
    the first."""
    lines = ["grafcet: Chain", "inputs: [iGo]", "outputs: [oMotor]", "steps:",
             "  s0: {initial: true}"]
    lines += [f"  s{i}: {{actions: [oMotor]}}" for i in range(1, n)]
    lines.append("transitions:")
    lines += [f"  - {{from: s{i}, to: s{(i + 1) % n}, when: ↑iGo}}" for i in range(n)]
    return "\n".join(lines) + "\n"


def measure(path: str, repeat: int) -> list[float]:
    """[load s, check s, compile s, generated source MB, compile peak MB] of one chart."""
    tl, g = best(lambda: load_grafcet(path), repeat)
    tc, _ = best(lambda: check_grafcet(g), repeat)
    tk, _ = best(lambda: compile_grafcet(g), repeat)
    tracemalloc.start()
    compile_grafcet(g)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return [tl, tc, tk, len(Compiler(g).generate()) / 1e6, peak / 1e6]


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--shape", choices=["fan", "chain"], default="fan")
    ap.add_argument("--distinct", action="store_true", help="fan: exclusive conditions")
    ap.add_argument("--sizes", type=int, nargs="+", default=[250, 500, 1000, 2000])
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    yamlsrc.NODE_ALLOWANCE = max(yamlsrc.NODE_ALLOWANCE, 20 * max(args.sizes))
    names = ["load s", "check s", "compile s", "source MB", "compile peak MB"]
    out(f"{'n':>6}" + "".join(f"{x:>16}" for x in names) + "   growth: load check compile")
    rows: list[tuple[int, list[float]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            text = fan_text(n, distinct=args.distinct) if args.shape == "fan" else chain_text(n)
            path = os.path.join(tmp, f"{args.shape}{n}.yaml")
            with open(path, "w", encoding="utf-8") as f:
                f.write(text)
            rows.append((n, measure(path, args.repeat)))
            before = rows[-2] if len(rows) > 1 else None
            grows = [growth((before[0], before[1][k]) if before else None, n, rows[-1][1][k])
                     for k in range(3)]
            out(f"{n:>6}" + "".join(f"{v:>16.2f}" for v in rows[-1][1]) + "   " + " ".join(grows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
