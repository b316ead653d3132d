"""``softplc import FILE.xml -o DIR`` and ``softplc export CHART|PLANT [-o FILE.xml]``."""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
from collections.abc import Callable

from runtime import package_version
from runtime.errors import Loc, SourceError
from runtime.language.filekind import file_kind
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet
from runtime.language.plantfile import load_plant
from runtime.plcopen.export import export_chart
from runtime.plcopen.importer import ImportedChart, ImportResult, import_file
from runtime.plcopen.plantexport import export_plant
from runtime.plcopen.yamlout import chart_yaml, plant_yaml

#: the plant skeleton's file name in the output directory
PLANT_FILE = "plant.yaml"


def chart_text(path: str, chart: ImportedChart) -> str:
    """The grafcet file of an imported chart (its document, which the language's loader
    has checked: tests/plcopen load every file written back)."""
    return chart_yaml(chart.doc, [f"Imported by softplc import from "
                                  f"{os.path.basename(path)} (POU {chart.pou}); "
                                  "docs/plcopen.md"])


def plant_text(path: str, result: ImportResult, files: dict[str, str]) -> str:
    """The plant skeleton: every instance of the import's plan (``files``: the chart file of
    each POU), its last line the fingerprint that tells an edited plant (``edited``)."""
    charts = {c.pou: c for c in result.charts}
    entries = []
    for inst in result.plan.instances:
        iface = charts[inst.pou].interface
        entries.append((inst, files[inst.pou],
                        [(v.name, v.type, v.address) for v in iface.inputs],
                        [(v.name, v.type, v.address) for v in iface.outputs]))
    text = plant_yaml(entries, result.plan.cycle_ns, [
        f"Plant skeleton written by softplc import from {os.path.basename(path)}: every input",
        "and output of the imported charts bound to simulated I/O (driver sim), so that",
        "softplc simulate and softplc run --sim work at once. Bind them to real points",
        "(docs/language.md, \"The plant file\"; docs/drivers.md). Once edited, softplc",
        "import never overwrites this file (--chart-only updates the charts alone).",
        *(f"Comment of program {c}" for c in result.plan.comments)], result.plan.drivers)
    return text + f"{FINGERPRINT}{_digest(text)}\n"


#: the last line of a plant skeleton: the digest of the lines above it, as written
FINGERPRINT = "# written by softplc import, sha256 "


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def edited(path: str) -> bool:
    """Whether the plant file at ``path`` is no longer what softplc import wrote (its last
    line is the digest of the lines above it); a file that cannot be read counts as
    edited."""
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read(1 << 20)
    except (OSError, UnicodeDecodeError):
        return True
    body, _, last = text.rstrip("\n").rpartition("\n")
    return not (last.startswith(FINGERPRINT)
                and last[len(FINGERPRINT):] == _digest(body + "\n"))


def chart_files(result: ImportResult) -> dict[str, str]:
    """POU -> the name of its chart file: the POU's name, unless that is the plant file's
    (whatever the case: some file systems ignore it), then with ``_chart``."""
    out: dict[str, str] = {}
    taken = {PLANT_FILE.lower()}
    for c in result.charts:
        name = f"{c.pou}.yaml"
        k = 1
        while name.lower() in taken:
            name = f"{c.pou}_chart{'' if k == 1 else k}.yaml"
            k += 1
        taken.add(name.lower())
        out[c.pou] = name
    return out


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
    files = chart_files(result)
    texts = [chart_text(args.file, c) for c in result.charts]
    charts = [os.path.join(args.output, files[c.pou]) for c in result.charts]
    plant = os.path.join(args.output, PLANT_FILE)
    todo = list(zip(charts, texts, strict=True))
    if not args.chart_only:
        if os.path.lexists(plant) and edited(plant):
            sys.stderr.write(f"softplc import: error: {plant} was edited since softplc import "
                             "wrote it: not overwritten, even with --force (--chart-only "
                             "updates the charts alone; remove it for a new skeleton)\n")
            return 2
        todo.append((plant, plant_text(args.file, result, files)))
    force = args.force or args.chart_only
    existing = [t for t, _ in todo if os.path.lexists(t)]
    if existing and not force:
        sys.stderr.write(f"softplc import: error: {', '.join(existing)} exist(s): not "
                         "overwritten (remove, choose another -o, or --force)\n")
        return 2
    try:
        os.makedirs(args.output, exist_ok=True)
        _write_all(todo, force)
    except OSError as exc:
        return _fail("import", exc)
    for c, target in zip(result.charts, charts, strict=True):
        g = c.grafcet
        sys.stderr.write(f"{args.file}: POU {c.pou} -> {target} ({len(g.steps)} steps, "
                         f"{len(g.transitions)} transitions, "
                         f"{sum(len(s.actions) for s in g.steps.values())} actions)\n")
    if args.chart_only:
        sys.stderr.write(f"{plant}: not written (--chart-only)\n")
    else:
        sys.stderr.write(f"{plant}: plant skeleton on simulated I/O "
                         f"({len(result.plan.instances)} instance(s))\n")
    if args.scenario:
        return _scenario(plant, args.file)
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
    if file_kind(args.chart) == "plant":
        plant = load_plant(args.chart)
        what = (f"plant exported ({len(plant.instances)} instances of "
                f"{len({i.grafcet.path for i in plant.instances.values()})} charts)")
        export: Callable[[], str] = lambda: export_plant(  # noqa: E731
            plant, version=package_version(), layout=args.layout)
    else:
        g: Grafcet = load_grafcet(args.chart)
        what = (f"{g.name} exported ({len(g.steps)} steps, {len(g.transitions)} "
                "transitions)")
        export = lambda: export_chart(  # noqa: E731
            g, version=package_version(), layout=args.layout)
    try:
        text = export()
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
    sys.stderr.write(f"{args.output}: {what}\n")
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
    i.add_argument("--force", action="store_true",
                   help="overwrite existing files (never a plant file edited since)")
    i.add_argument("--chart-only", action="store_true",
                   help="write (and replace) the charts only, never the plant file")
    i.add_argument("--scenario", action="store_true",
                   help="also write a scenario skeleton, plant.test.yaml: the inputs to set, "
                        "the outputs to expect (softplc test; never overwritten)")
    i.set_defaults(func=cmd_import)
    e = sub.add_parser("export", help="export a chart or a plant as a PLCopen XML project",
                       description="Write a PLCopen TC6 XML v2.01 project holding the chart as "
                                   "an SFC program, or the plant's charts as SFC function "
                                   "blocks called by an FBD program, laid out as softplc draw "
                                   "lays them out (docs/plcopen.md).")
    e.add_argument("chart", metavar="CHART|PLANT")
    e.add_argument("-o", "--output", metavar="FILE.xml", help="default: standard output")
    e.add_argument("--layout", choices=("auto", "dot", "python"), default="auto",
                   help="as softplc draw: auto uses Graphviz's dot if installed")
    e.add_argument("--force", action="store_true", help="overwrite an existing FILE.xml")
    e.set_defaults(func=cmd_export)
