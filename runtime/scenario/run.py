"""One scenario run: its plant on the virtual clock (``engine.simulate``), the trace's
columns its expectations read, each expectation's verdict, and the coverage of its charts.

What a run gives back (:class:`Outcome`) is plain data: the scenarios of ``softplc test``
run in worker processes and hand it back to the parent."""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from typing import Any

from runtime.engine.simulate import ScanFault, Simulation
from runtime.errors import Loc, SourceError
from runtime.language.coverage import ChartCoverage, counted
from runtime.scenario.expect import Trace, failure
from runtime.scenario.spec import Expectation, read_scenario

log = logging.getLogger(__name__)


@dataclass
class Case:
    """One expectation's verdict (a JUnit test case): ``failure`` is its line, or None."""

    name: str  # "line 12: at 1s500ms"
    failure: str | None = None


@dataclass
class Outcome:
    """A scenario's result. ``error``: the scenario could not run (its file, or its plant's,
    is at fault: one line), and ``cases`` is empty."""

    path: str
    cases: list[Case] = field(default_factory=list)
    error: str | None = None
    seconds: float = 0.0
    scans: int = 0
    coverage: list[ChartCoverage] = field(default_factory=list)

    @property
    def failed(self) -> list[Case]:
        return [c for c in self.cases if c.failure is not None]


@dataclass
class Scenario:
    """A scenario ready to run: its simulation (plant built, its charts counting what they
    do) and its expectations."""

    path: str
    sim: Simulation
    expectations: list[Expectation]
    columns: list[str]  # the trace's columns the expectations read


def load_scenario(path: str) -> Scenario:
    """The scenario at ``path`` read and its plant built; SourceError at the first fault."""
    spec = read_scenario(path)
    sim = Simulation(spec.plant_path, cycles=spec.cycles, pdef=spec.pdef,
                     changes=spec.changes, coverage=True)
    return Scenario(path, sim, spec.expectations, spec.columns)


def run_scenario(path: str) -> Outcome:
    """Load and run the scenario at ``path``; never raises (a fault is in the Outcome)."""
    t0 = time.perf_counter()
    try:
        scenario = load_scenario(path)
        out = play(scenario)
    except SourceError as exc:
        out = Outcome(path, error=str(exc))
    except Exception as exc:  # noqa: BLE001 - a worker's fault: one line, the run goes on
        log.debug("scenario %s", path, exc_info=True)
        out = Outcome(path, error=str(SourceError(Loc(path, 1, 1), f"cannot run the scenario: "
                                                                   f"{type(exc).__name__}: "
                                                                   f"{exc}")))
    out.seconds = time.perf_counter() - t0
    return out


def play(scenario: Scenario) -> Outcome:
    """Run ``scenario``'s simulation, keeping only the columns its expectations read."""
    sim = scenario.sim
    wanted = scenario.columns
    sim.columns = [(key, get) for key, get in sim.columns if key in set(wanted)]
    missing = set(wanted) - {key for key, _ in sim.columns}
    if missing:  # the names read from the definition are the trace's: never here
        raise SourceError(Loc(scenario.path, 1, 1), f"not in the trace: {sorted(missing)}")
    cols: dict[str, list[Any]] = {key: [] for key in wanted}
    adds = [(key, cols[key].append) for key in wanted]
    fault = None
    scans = 0
    try:
        for row in sim.run(trace=True):
            if "fault" in row:  # the last record: the generator raises ScanFault next
                continue
            for key, add in adds:
                add(row[key])
            scans += 1
    except ScanFault as exc:
        fault = str(exc)
    trace = Trace(cols, sim.plant.cycle_ns, scans, fault)
    cases = [Case("run", fault)] if fault is not None else []
    cases += [Case(f"line {e.loc.line}: {e.title}", failure(e, trace))
              for e in scenario.expectations]
    return Outcome(scenario.path, cases, scans=scans, coverage=coverage_of(scenario))


def coverage_of(scenario: Scenario) -> list[ChartCoverage]:
    """The coverage of each chart of the scenario's plant, its instances summed."""
    charts: dict[str, ChartCoverage] = {}
    for inst in scenario.sim.plant.instances.values():
        cov = counted(inst.grafcet, inst.program.coverage(inst.m))
        key = os.path.realpath(cov.path)
        if key in charts:
            charts[key].add(cov)
            charts[key].scenarios = 1  # one scenario, however many instances
        else:
            charts[key] = cov
    return list(charts.values())
