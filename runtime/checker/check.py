"""``softplc check FILE...``: static checks of seed 000's rules on grafcet and plant files.

Diagnostics are one line each, ``FILE:LINE:COL: error|warning|note GCODE: message``
(docs/check.md lists every code with an example and its fix). Exit status: 2 if a file does
not load (its error line is printed), else 1 if any error was found, else 0.

Errors (seed 000, "Reglas de sintaxis y ejecución (I)"):
G101 no initial step, G102 unreachable step, G103 a transition back to its own source step,
G104 unsafe chart, G105 continuous action on activation/deactivation/event, G106 edge in the
condition of a conditional action. Warnings (rules II and the recommendations): G201 OR
divergence not exclusive, G202 action that never executes, G203 divergence not closed,
G204 same level condition on consecutive transitions, G205 counting statement in a
continuous action, G206 deadlock, G207 bool promoted to a number in a comparison, G208
transition that never fires, G209 analysis cut by its bounds. Plant files: G300 (note)
plant not checked further because a chart of it breaks a rule above, G301 unbound
signal, G302 physical output bound twice, G303 driver point that does not exist (or wrong
direction or type), G304 bad driver configuration, G305 (note) point not checked because the
driver's library is missing, G306 one input point feeding two inputs of an instance, G307 an
output bound to an input point, G308 a file a side process reads at its start
(``opcua: security:``, ``web: tls:``, ``modbus: tls:``, ``mqtt: tls:``, ``mqtt:
password_file``) that is not there or cannot be read.
Chart warnings also G210 (a stored action nothing resets) and G211 (a timer read stale
under ``scan: stable``).

A simulation script (``duration:``/``cycles:``, ``set:``) is checked against its plant
(``--plant``, or the one plant file of its directory), so that ``softplc check
configs/*/*.yaml`` checks everything: an error in it is a loading error (exit status 2),
G400 (note) says when no plant could be found for it, and G401 (note) that it has no length
(``duration:``/``cycles:``): ``softplc simulate --cycles N`` runs it.

This module is the command: it loads each file once, with the loaders collecting their rule
errors as diagnostics (a chart's G101, G105 and G106, a plant's G301 and G302: the loaders
go on after them, so every other check still runs), finds each script's plant, and prints.
The chart rules are runtime/checker/rules.py's, the driver point checks
runtime/checker/plant_rules.py's.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from runtime.checker.diag import Diag, diag, from_loader, show_path
from runtime.checker.plant_rules import check_plant_model
from runtime.checker.reach import LIMIT
from runtime.checker.rules import check_grafcet
from runtime.errors import Diagnostic, Loc, SourceError
from runtime.language.filekind import doc_kind
from runtime.language.grafcetfile import GrafcetLoader, load_grafcet
from runtime.language.model import Grafcet, PlantDef
from runtime.language.plantfile import PlantLoad, load_plant
from runtime.language.yamlsrc import YMap, load_yaml

SEVERITY_ORDER = {"error": 0, "warning": 1, "note": 2}


# -- loading, with the loader's rule errors as diagnostics --------------------------------
CHART_RULES = frozenset({"G101", "G105", "G106"})  # found by the grafcet loader
BINDING_RULES = frozenset({"G301", "G302", "G303"})  # found by the plant loader


@dataclass
class Loaded:
    g: Grafcet | None
    diags: list[Diag]
    failure: SourceError | None = None

    @property
    def repaired(self) -> set[str]:
        """Codes of the rule errors the loader went on after (G101: no reachability)."""
        return {d.code for d in self.diags}


def load_grafcet_checked(path: str, doc: Any = None) -> Loaded:
    """Load a grafcet, its rule errors of seed 000 (G101, G105, G106) as diagnostics: the
    loader leaves out what breaks a rule and goes on, so that every such error is reported
    and the rest of the checks still run. Any other error is the failure. ``doc``: the
    file's YAML document if already read (not read again)."""
    found: list[Diagnostic] = []
    try:
        g: Grafcet | None = (GrafcetLoader(path, doc, found).load() if isinstance(doc, YMap)
                             else load_grafcet(path, found))
    except SourceError as exc:
        if not exc.code:
            return Loaded(None, [from_loader(d) for d in found], exc)
        found.append(exc.diagnostic)  # a rule error the loader could not go on after
        g = None
    return Loaded(g, [from_loader(d) for d in found])


@dataclass
class FileResult:
    path: str
    diags: list[Diag]
    failure: str | None = None  # the loading error line (exit status 2)
    ms: float = 0.0


class CheckRun:
    """One ``softplc check`` run: checks files, each chart once (a plant's charts are
    checked with it).

    ``plant``: the plant that simulation scripts are checked against (``--plant``); without
    it, a script is checked against the one plant file of its directory (the layout of
    ``configs/``: ``plant_sim.yaml`` beside ``story.yaml``)."""

    def __init__(self, limit: int = LIMIT, plant: str | None = None,
                 paths: Iterable[str] = ()) -> None:
        self.limit = limit
        self.plant = plant
        self.paths = list(paths)  # every file of the command line (plants for scripts)
        self.charts_done: set[str] = set()
        self._kinds: dict[str, str] = {}
        #: a chart's or a plant's document, read to tell its kind, kept for its check
        self._docs: dict[str, Any] = {}

    def kind(self, path: str) -> str:
        """The file's kind (read once per run; a chart's or a plant's document is kept for
        its check, so that each file is parsed once)."""
        real = os.path.realpath(path)
        if real not in self._kinds:
            doc = load_yaml(path)
            self._kinds[real] = doc_kind(doc)
            if self._kinds[real] in ("grafcet", "plant") and real not in self.charts_done:
                self._docs[real] = doc
        return self._kinds[real]

    def check_path(self, path: str) -> list[FileResult]:
        t0 = time.perf_counter()
        try:
            kind = self.kind(path)
        except SourceError as exc:
            return [FileResult(path, [], str(exc))]
        if kind == "grafcet":
            if os.path.realpath(path) in self.charts_done:
                return []  # already checked with a plant of this command line
            res = [self._grafcet(path)]
        elif kind == "plant":
            res = self._plant(path)
        elif kind == "script":
            res = [self._script(path)]
        elif kind == "scenario":
            res = [self._scenario(path)]
        else:
            res = [FileResult(path, [], f"{path}:1:1: error: expected a grafcet file "
                                        "('grafcet:' and 'steps:'), a plant file "
                                        "('instances:') or a simulation script "
                                        "('duration:' or 'cycles:', 'set:')")]
        res[0].ms = (time.perf_counter() - t0) * 1000
        return res

    # -- simulation scripts -----------------------------------------------------------------
    def _plant_of_script(self, path: str) -> tuple[str | None, str]:
        """(plant file, how it was found) or (None, why none)."""
        if self.plant is not None:
            return self.plant, "--plant"
        folder = os.path.dirname(os.path.abspath(path))

        def plants(paths: Iterable[str]) -> list[str]:
            out = []
            for p in paths:
                try:
                    if self.kind(p) == "plant" and p not in out:
                        out.append(p)
                except (SourceError, OSError):
                    continue
            return out

        here = [p for p in self.paths if os.path.dirname(os.path.abspath(p)) == folder]
        found = plants(here)
        if not found:
            disk = sorted(os.path.join(folder, n) for n in os.listdir(folder)
                          if n.endswith((".yaml", ".yml")))
            found = plants(disk)
        if len(found) == 1:
            return found[0], "the plant file of its directory"
        if not found:
            return None, "no plant file in its directory"
        names = ", ".join(os.path.basename(p) for p in found)
        return None, f"several plant files in its directory ({names})"

    def _script(self, path: str) -> FileResult:
        """A simulation script is checked against its plant: every name it sets must be an
        input (or chart flag) of an instance, or an input point of a driver, with a value
        of the right type; the times must be times."""
        from runtime.engine.names import PlantNames
        from runtime.engine.script import read_script
        from runtime.language.plantfile import load_plant

        plant, how = self._plant_of_script(path)
        if plant is None:
            return FileResult(path, [diag(Loc(path, 1, 1), "note", "G400", "simulation "
                                          f"script not checked: {how}; name its plant with "
                                          "--plant PLANT.yaml")])
        try:
            names = PlantNames(load_plant(plant))
        except SourceError:
            return FileResult(path, [diag(Loc(path, 1, 1), "note", "G400", "simulation "
                                          f"script not checked: its plant "
                                          f"{show_path(plant)} ({how}) does not load")])
        try:
            script = read_script(path, names, need_length=False)
        except SourceError as exc:
            return FileResult(path, [], f"{exc} (checked against {show_path(plant)})")
        if script.duration_ns is None and script.cycles is None:
            return FileResult(path, [diag(Loc(path, 1, 1), "note", "G401", "the script has "
                                          "neither 'duration:' nor 'cycles:': run it with "
                                          "softplc simulate PLANT --script S --cycles N")])
        return FileResult(path, [])

    def _scenario(self, path: str) -> FileResult:
        """A scenario (``softplc test``) is read as softplc test reads it, against the plant
        it names: its inputs, names, values and times (docs/testing-charts.md)."""
        from runtime.scenario.spec import read_scenario

        try:
            read_scenario(path)
        except SourceError as exc:
            return FileResult(path, [], str(exc))
        return FileResult(path, [])

    def _grafcet(self, path: str, g: Grafcet | None = None) -> FileResult:
        """Check one chart; ``g``: the chart already loaded without error (by its plant)."""
        real = os.path.realpath(path)
        self.charts_done.add(real)
        doc = self._docs.pop(real, None)
        loaded = Loaded(g, []) if g is not None else load_grafcet_checked(path, doc)
        diags = list(loaded.diags)
        if loaded.g is not None:
            diags += check_grafcet(loaded.g, self.limit, loaded.repaired)
        failure = str(loaded.failure) if loaded.failure is not None else None
        return FileResult(path, _sorted(diags), failure)

    def _plant(self, path: str) -> list[FileResult]:
        """Check a plant and then its charts. What the plant loader met first decides, as
        if it had stopped there: nothing (the driver points are checked), a binding error
        (every binding error is reported), a chart breaking a rule of seed 000 (G300: the
        plant is not checked further, the chart is), or another error (the failure)."""
        found: list[Diagnostic] = []
        load = PlantLoad(found)
        fatal: SourceError | None = None
        p: PlantDef | None = None
        try:
            p = load_plant(path, load, doc=self._docs.pop(os.path.realpath(path), None))
        except SourceError as exc:
            fatal = exc
        first = found[0] if found else fatal.diagnostic if fatal is not None else None
        charts: list[tuple[str, Grafcet | None]] = []
        if first is None:
            assert p is not None
            diags = check_plant_model(p)
            for inst in p.instances.values():
                if inst.grafcet.path not in [c for c, _ in charts]:
                    charts.append((inst.grafcet.path, inst.grafcet))
        elif first.code in BINDING_RULES:
            diags = [from_loader(d) for d in found if d.code in BINDING_RULES]
            charts = [(c, None) for c in load.chart_files]
        elif first.code in CHART_RULES:
            chart = first.loc.file
            res = [] if os.path.realpath(chart) in self.charts_done else [self._grafcet(chart)]
            if any(r.failure for r in res):
                return [FileResult(path, [], str(first))]
            note = diag(Loc(path, 1, 1), "note", "G300", f"plant not checked further: its "
                        f"chart {show_path(chart)} does not load")
            return [FileResult(path, [note]), *res]
        else:
            return [FileResult(path, [], str(first))]
        results = [FileResult(path, _sorted(diags))]
        for c, g in charts:
            if os.path.realpath(c) not in self.charts_done:
                results.append(self._grafcet(c, g))
        return results


def _sorted(diags: list[Diag]) -> list[Diag]:
    unique = list(dict.fromkeys(diags))
    return sorted(unique, key=lambda d: (d.file, d.line, d.col, SEVERITY_ORDER[d.severity],
                                         d.code))


def check_files(paths: Iterable[str], limit: int = LIMIT,
                plant: str | None = None) -> list[FileResult]:
    paths = list(paths)
    run = CheckRun(limit, plant, paths)
    out: list[FileResult] = []
    for p in paths:
        out += run.check_path(p)
    return out


def exit_status(results: Iterable[FileResult]) -> int:
    """2 if any file has an error (a loading error or a rule's), as every command exits on
    an error in a file; else 0: warnings and notes never change it."""
    results = list(results)
    if any(r.failure or any(d.severity == "error" for d in r.diags) for r in results):
        return 2
    return 0


# -- command line ---------------------------------------------------------------------------
def cmd_check(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    results = check_files(args.files, args.limit, args.plant)
    errors = warnings = 0
    for r in results:
        for d in r.diags:
            if args.errors_only and d.severity != "error":
                continue
            sys.stdout.write(f"{d}\n")
        if r.failure:
            sys.stdout.write(f"{r.failure}\n")
        errors += sum(d.severity == "error" for d in r.diags) + (1 if r.failure else 0)
        warnings += sum(d.severity == "warning" for d in r.diags)
    ms = (time.perf_counter() - t0) * 1000
    if not args.quiet:
        sys.stderr.write(f"check: {len(results)} file(s), {errors} error(s), {warnings} "
                         f"warning(s) in {ms:.0f} ms\n")
    sys.stdout.flush()
    return exit_status(results)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    c = sub.add_parser("check", help="static checks of seed 000's rules (G1xx errors, G2xx "
                                     "warnings, G3xx plant bindings)",
                       description="Check grafcet files, plant files and simulation "
                                   "scripts: FILE:LINE:COL: error|warning|note GCODE: "
                                   "message. Exit 1 on errors, 2 if a file does not load.")
    c.add_argument("files", nargs="+", metavar="FILE")
    c.add_argument("--limit", type=int, default=LIMIT,
                   help=f"most reachable situations to explore (default {LIMIT})")
    c.add_argument("--plant", metavar="PLANT.yaml",
                   help="plant that simulation scripts among FILE are checked against "
                        "(default: the one plant file in each script's directory)")
    c.add_argument("--errors-only", action="store_true", help="print errors only")
    c.add_argument("-q", "--quiet", action="store_true", help="no summary line on stderr")
    c.set_defaults(func=cmd_check)
