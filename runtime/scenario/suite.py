"""The scenarios of ``softplc test``: found by their name (``*.test.yaml``), run in
parallel worker processes, their outcomes and coverage summed, the exit status
(docs/testing-charts.md, "Running them")."""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

from runtime.errors import Loc, SourceError
from runtime.language.coverage import ChartCoverage, Item, total
from runtime.scenario.run import Outcome, run_scenario

#: how a scenario file is named, beside its plant
SUFFIX = ".test.yaml"
#: directories a search never enters (besides hidden ones)
SKIPPED = frozenset({"__pycache__", "node_modules"})

#: the exit statuses, as pytest's: all passed, some failed, a file in error, none found
PASSED, FAILED, ERROR, NONE_FOUND = 0, 1, 2, 5


def discover(paths: list[str]) -> tuple[list[str], list[str]]:
    """(scenario files, error lines): each directory searched for ``*.test.yaml`` (hidden
    directories left out), each file taken whatever its name, in order, each once."""
    found: list[str] = []
    errors: list[str] = []
    for p in paths:
        if os.path.isdir(p):
            for root, dirs, files in os.walk(p):
                dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d not in SKIPPED)
                found += [os.path.join(root, f) for f in sorted(files) if f.endswith(SUFFIX)]
        elif os.path.exists(p):
            found.append(p)
        else:
            errors.append(str(SourceError(Loc(p, 1, 1), "no such file or directory")))
    seen: set[str] = set()
    out = []
    for f in found:
        real = os.path.realpath(f)
        if real not in seen:
            seen.add(real)
            out.append(os.path.normpath(f))
    return out, errors


def run_all(files: list[str], jobs: int) -> list[Outcome]:
    """Every scenario's outcome, in the order of ``files``: in ``jobs`` worker processes
    (forked, so they start with this process's modules), or here for one job or file."""
    if jobs <= 1 or len(files) <= 1:
        return [run_scenario(f) for f in files]
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with ProcessPoolExecutor(max_workers=min(jobs, len(files)),
                             mp_context=multiprocessing.get_context(method)) as pool:
        futures = [pool.submit(run_scenario, f) for f in files]
        out = []
        for f, fut in zip(files, futures, strict=True):
            try:
                out.append(fut.result())
            except BrokenProcessPool as exc:  # a worker killed (out of memory ...)
                out.append(Outcome(f, error=str(SourceError(
                    Loc(f, 1, 1), f"the worker process running it ended: {exc}"))))
        return out


@dataclass
class Summary:
    """What the scenarios gave, together."""

    outcomes: list[Outcome]
    errors: list[str] = field(default_factory=list)  # paths that named nothing
    coverage: list[ChartCoverage] = field(default_factory=list)

    @property
    def passed(self) -> int:
        return sum(len(o.cases) - len(o.failed) for o in self.outcomes)

    @property
    def failed(self) -> int:
        return sum(len(o.failed) for o in self.outcomes)

    @property
    def in_error(self) -> int:
        return len(self.errors) + sum(1 for o in self.outcomes if o.error is not None)

    def status(self, fail_under: float | None = None) -> int:
        """The exit status: ERROR if a file is at fault, FAILED if an expectation failed
        or the coverage is under ``fail_under`` (%), NONE_FOUND if there was nothing to
        run, else PASSED."""
        if self.in_error:
            return ERROR
        if not self.outcomes:
            return NONE_FOUND
        if self.failed or (fail_under is not None and total(self.coverage) < fail_under):
            return FAILED
        return PASSED


def summarize(outcomes: list[Outcome], errors: list[str]) -> Summary:
    """The outcomes together, the coverage of each chart summed over the scenarios."""
    charts: dict[str, ChartCoverage] = {}
    for o in outcomes:
        for cov in o.coverage:
            key = os.path.realpath(cov.path)
            if key in charts:
                charts[key].add(cov)
            else:
                charts[key] = ChartCoverage(cov.path, cov.grafcet,
                                            [Item(i.kind, i.key, i.line, i.col, i.count, i.ref)
                                             for i in cov.items], cov.scenarios)
    return Summary(outcomes, errors, list(charts.values()))
