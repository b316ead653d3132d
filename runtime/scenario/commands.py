"""``softplc test [PATHS]``: run the scenarios, print each failure as one line, the coverage
(``--coverage``), write JUnit XML (``--junit``) and the coverage file (``--coverage-file``);
exit 0 all passed, 1 a failure (or coverage under ``--fail-under``), 2 a file in error, 5
no scenario found (docs/testing-charts.md)."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time

from runtime.errors import Loc, SourceError
from runtime.language import coverage as C
from runtime.scenario.junit import junit_xml
from runtime.scenario.suite import NONE_FOUND, SUFFIX, Summary, discover, run_all, summarize


def _write(path: str, text: str, option: str) -> None:
    """Write an output file of the run (replaced if it exists: it is ours); SourceError
    naming ``option`` if it cannot be written."""
    try:
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as exc:
        raise SourceError(Loc(option, 1, 1), f"cannot write {path}: "
                                             f"{exc.strerror or exc}") from None


def _lines(s: Summary, seconds: float, args: argparse.Namespace) -> list[str]:
    out = []
    for o in s.outcomes:
        if o.error is not None:
            out.append(o.error)
            continue
        failed = len(o.failed)
        out.append(f"{o.path}: {len(o.cases) - failed} passed"
                   + (f", {failed} failed" if failed else "")
                   + f" ({o.scans} scans, {o.seconds:.2f} s)")
        out += [c.failure for c in o.failed if c.failure is not None]
    out += s.errors
    if args.coverage and s.coverage:
        out.append("coverage (steps active, transitions fired, actions run, divergence "
                   "branches taken):")
        out += ["  " + line for line in C.report(s.coverage)]
    if args.fail_under is not None and s.outcomes and C.total(s.coverage) < args.fail_under:
        out.append(f"softplc test: coverage {C.total(s.coverage):.1f}% is under "
                   f"--fail-under {args.fail_under:g}%")
    n = len(s.outcomes)
    out.append(f"softplc test: {n} scenario{'s' if n != 1 else ''}: {s.passed} passed, "
               f"{s.failed} failed, {s.in_error} in error ({seconds:.2f} s)")
    return out


def cmd_test(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    logging.getLogger("drivers").setLevel(logging.WARNING)  # "driver sim: open" is noise
    files, errors = discover(args.paths or ["."])
    if not files and not errors:
        sys.stdout.write(f"softplc test: no scenario found in {' '.join(args.paths or ['.'])}"
                         f" (files named *{SUFFIX})\n")
        return NONE_FOUND
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    summary = summarize(run_all(files, jobs), errors)
    seconds = time.perf_counter() - t0
    if args.junit:
        _write(args.junit, junit_xml(summary.outcomes, summary.errors, seconds), "--junit")
    if args.coverage_file:
        _write(args.coverage_file, C.dumps(summary.coverage), "--coverage-file")
    sys.stdout.write("".join(f"{line}\n" for line in _lines(summary, seconds, args)))
    return summary.status(args.fail_under)


def _percent(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a percentage, found '{text}'") from None
    if not 0 <= value <= 100:
        raise argparse.ArgumentTypeError(f"expected 0 to 100, found {text}")
    return value


def _jobs(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of processes, found '{text}'"
                                         ) from None
    if value < 1:
        raise argparse.ArgumentTypeError("expected 1 or more processes")
    return value


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    t = sub.add_parser("test", help="run the scenarios (*.test.yaml): expectations, SFC "
                                    "coverage, JUnit XML",
                       description="Run every scenario found in PATHS (files named "
                                   f"*{SUFFIX}; default: the current directory) on the "
                                   "virtual clock, in parallel processes; each failure is "
                                   "one line FILE:LINE:COL: error: ... Exit 0 all passed, 1 "
                                   "a failure, 2 a file in error, 5 no scenario found "
                                   "(docs/testing-charts.md).")
    t.add_argument("paths", nargs="*", metavar="PATH",
                   help="scenario files, or directories searched for *.test.yaml")
    t.add_argument("-j", "--jobs", type=_jobs, metavar="N",
                   help="worker processes (default: one per processor)")
    t.add_argument("--junit", metavar="FILE", help="write a JUnit XML report (for CI)")
    t.add_argument("--coverage", action="store_true",
                   help="print the SFC coverage of each chart: steps never active, "
                        "transitions never fired, actions never run, branches never taken")
    t.add_argument("--fail-under", type=_percent, metavar="N",
                   help="fail (exit 1) if the coverage of all the charts is under N %%")
    t.add_argument("--coverage-file", metavar="FILE",
                   help="write the coverage as JSON, for softplc draw --coverage and "
                        "softplc web --coverage")
    t.set_defaults(func=cmd_test)
