"""``softplc import FILE.xml -o DIR`` and ``softplc export CHART [-o FILE.xml]``."""

from __future__ import annotations

import argparse
import os
import sys

from runtime import package_version
from runtime.errors import Loc, SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet
from runtime.plcopen.export import export_chart
from runtime.plcopen.importer import ImportedChart, ImportResult, import_file
from runtime.plcopen.yamlout import chart_yaml, plant_yaml

#: the plant skeleton's file name in the output directory
PLANT_FILE = "plant.yaml"


def chart_text(path: str, chart: ImportedChart) -> str:
    """The grafcet file of an imported chart (its document, which the language's loader
    has checked: tests/plcopen load every file written back)."""
    return chart_yaml(chart.doc, [f"Imported by softplc import from "
                                  f"{os.path.basename(path)} (POU {chart.pou}); "
                                  "docs/plcopen.md"])


def plant_text(path: str, result: ImportResult, files: list[str]) -> str:
    entries = []
    for chart, file in zip(result.charts, files, strict=True):
        iface = chart.interface
        entries.append((chart.instance or chart.pou, file,
                        [(v.name, v.type, v.address) for v in iface.inputs],
                        [(v.name, v.type, v.address) for v in iface.outputs]))
    cycles = [c.cycle_ns for c in result.charts if c.cycle_ns]
    return plant_yaml(entries, cycles[0] if cycles else None, [
        f"Plant skeleton written by softplc import from {os.path.basename(path)}: every input",
        "and output of the imported charts bound to simulated I/O (driver sim), so that",
        "softplc simulate and softplc run --sim work at once. Bind them to real points",
        "(docs/language.md, \"The plant file\"; docs/drivers.md)."])


def _write(path: str, text: str, force: bool) -> None:
    """Write a whole file or none: written beside it, then put in place; an existing file is
    replaced only with ``force`` (FileExistsError otherwise)."""
    part = f"{path}.{os.getpid()}.part"
    try:
        with open(part, "x", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        if force:
            os.replace(part, path)
        else:
            os.link(part, path)  # fails if the file exists: never overwritten
    except OSError as exc:  # said of the file asked for, not of the one beside it
        raise type(exc)(exc.errno, exc.strerror, path) from None
    finally:
        if os.path.exists(part):
            os.unlink(part)


def _write_all(files: list[tuple[str, str]], force: bool) -> None:
    """Write every file or, on a failure, remove the ones this call created."""
    created: list[str] = []
    try:
        for path, text in files:
            existed = os.path.exists(path)
            _write(path, text, force)
            if not existed:
                created.append(path)
    except OSError:
        for path in created:
            os.unlink(path)
        raise


def _fail(command: str, exc: OSError) -> int:
    where = f"{exc.filename}: " if exc.filename else ""
    sys.stderr.write(f"softplc {command}: error: {where}{exc.strerror or exc}\n")
    return 2


def cmd_import(args: argparse.Namespace) -> int:
    result = import_file(args.file, args.pou)
    for note in result.notes:
        sys.stderr.write(f"{note}\n")
    lost = [n for n in result.notes if n.lost]
    if args.strict and lost:
        sys.stderr.write(f"softplc import: error: {len(lost)} element(s) would be left out "
                         "or changed (--strict): nothing written\n")
        return 2
    files = [f"{c.pou}.yaml" for c in result.charts]
    texts = [chart_text(args.file, c) for c in result.charts]
    plant = plant_text(args.file, result, files)
    targets = [os.path.join(args.output, f) for f in [*files, PLANT_FILE]]
    existing = [t for t in targets if os.path.exists(t)]
    if existing and not args.force:
        sys.stderr.write(f"softplc import: error: {', '.join(existing)} exist(s): not "
                         "overwritten (remove, choose another -o, or --force)\n")
        return 2
    try:
        os.makedirs(args.output, exist_ok=True)
        _write_all(list(zip(targets, [*texts, plant], strict=True)), args.force)
    except OSError as exc:
        return _fail("import", exc)
    for c, target in zip(result.charts, targets, strict=False):
        g = c.grafcet
        sys.stderr.write(f"{args.file}: POU {c.pou} -> {target} ({len(g.steps)} steps, "
                         f"{len(g.transitions)} transitions, "
                         f"{sum(len(s.actions) for s in g.steps.values())} actions)\n")
    sys.stderr.write(f"{targets[-1]}: plant skeleton on simulated I/O\n")
    if args.scenario:
        return _scenario(os.path.join(args.output, PLANT_FILE), args.file)
    return 0


def _scenario(plant: str, source: str) -> int:
    """``--scenario``: the scenario skeleton beside the plant, never over an existing one."""
    from runtime.scenario.skeleton import write_skeleton

    try:
        path = write_skeleton(plant, os.path.basename(source))
    except FileExistsError as exc:
        sys.stderr.write(f"{exc.filename}: exists: kept (a scenario is never overwritten; "
                         "remove it for a new skeleton)\n")
        return 0
    except OSError as exc:
        return _fail("import", exc)
    sys.stderr.write(f"{path}: scenario skeleton (softplc test {os.path.dirname(path)})\n")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    g: Grafcet = load_grafcet(args.chart)
    try:
        text = export_chart(g, version=package_version(), layout=args.layout)
    except RuntimeError as exc:
        sys.stderr.write(f"softplc export: error: {exc}\n")
        return 2
    if args.output is None:
        sys.stdout.write(text)
        return 0
    try:
        _write(args.output, text, args.force)
    except FileExistsError:
        raise SourceError(Loc(args.output, 1, 1), "exists: not overwritten (remove it, or "
                                                  "--force)") from None
    except OSError as exc:
        return _fail("export", exc)
    sys.stderr.write(f"{args.output}: {g.name} exported ({len(g.steps)} steps, "
                     f"{len(g.transitions)} transitions)\n")
    return 0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    i = sub.add_parser("import", help="import the SFC POUs of a PLCopen XML file as charts",
                       description="Write each SFC POU of a PLCopen TC6 XML v2.01 file as a "
                                   "grafcet file in DIR, with a plant skeleton binding their "
                                   "inputs and outputs to simulated I/O (docs/plcopen.md). "
                                   "What a chart cannot carry is left out with one warning "
                                   "each.")
    i.add_argument("file", metavar="FILE.xml")
    i.add_argument("--pou", metavar="NAME", help="import this POU only")
    i.add_argument("-o", "--output", required=True, metavar="DIR")
    i.add_argument("--strict", action="store_true",
                   help="refuse (exit 2, nothing written) if anything would be left out")
    i.add_argument("--force", action="store_true", help="overwrite existing files")
    i.add_argument("--scenario", action="store_true",
                   help="also write a scenario skeleton, plant.test.yaml: the inputs to set, "
                        "the outputs to expect (softplc test; never overwritten)")
    i.set_defaults(func=cmd_import)
    e = sub.add_parser("export", help="export a chart as a PLCopen XML project",
                       description="Write a PLCopen TC6 XML v2.01 project holding the chart as "
                                   "an SFC program, laid out as softplc draw lays it out "
                                   "(docs/plcopen.md).")
    e.add_argument("chart", metavar="CHART")
    e.add_argument("-o", "--output", metavar="FILE.xml", help="default: standard output")
    e.add_argument("--layout", choices=("auto", "dot", "python"), default="auto",
                   help="as softplc draw: auto uses Graphviz's dot if installed")
    e.add_argument("--force", action="store_true", help="overwrite an existing FILE.xml")
    e.set_defaults(func=cmd_export)
