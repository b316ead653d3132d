"""``softplc diff OLD NEW`` says "can be applied online" exactly when ``reload`` of NEW into
a controller running OLD applies it, on the same two files: every example plant of
configs/ with its I/O list edited (a description, a unit and a range where the signal is a
number), and generated plants (tests/language/plantgen.py: every key of every section may
be present) with random edits, some online, some not (a plant setting, a driver's bus, a
new point, a side section added...).

Issue: ``softplc diff`` said "can be applied online" for a plant whose I/O list had a
``unit:``, and ``softplc reload`` was refused (the reload's child could not hand the plant
back). The reload here is the real one (``Daemon.reload``: the child process, the prepare,
the swap), on a running daemon of simulated I/O in its initial situation (no state check
applies: no edit removes a step)."""

from __future__ import annotations

import contextlib
import copy
import io
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from runtime.cli import main
from runtime.controller import daemon as daemon_mod
from runtime.controller.daemon import Daemon
from runtime.engine.plant import Plant
from runtime.language import ast as A
from runtime.language.filekind import file_kind
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import wait_until
from tests.language.plantgen import plant_docs

ROOT = Path(__file__).resolve().parents[2]
PLANTS = sorted(p for p in (ROOT / "configs").glob("*/*.yaml") if file_kind(str(p)) == "plant")


@pytest.fixture(autouse=True)
def no_real_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """The daemons here run at normal priority, their memory not locked, whatever the
    plant says (a test never takes the machine's real-time scheduling)."""
    monkeypatch.setattr(daemon_mod, "set_fifo_priority", lambda prio: (False, "a test"))
    monkeypatch.setattr(daemon_mod, "lock_memory", lambda: (False, "a test"))


def diff_says(old: Path, new: Path) -> tuple[bool, list[str]]:
    """(``softplc diff OLD NEW`` says it can be applied online, what it printed)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["diff", str(old), str(new)])
    assert rc in (0, 1), (rc, err.getvalue())
    lines = out.getvalue().splitlines()
    assert ("can be applied online" in lines) == (rc == 0), lines
    return rc == 0, lines


@contextlib.contextmanager
def running(plant: Path) -> Iterator[Daemon]:
    """A started daemon of ``plant`` on simulated I/O, once it has scanned."""
    pdef = load_plant(str(plant))
    daemon = Daemon(pdef, plant=Plant(pdef, sim=True), manage_gc=False)
    daemon.start()
    try:
        wait_until(lambda: daemon.plant.scans > 0, 10.0, "a scan")
        yield daemon
    finally:
        daemon.stop("end of test")


def same_verdict(old: Path, new: Path, generated: bool = False) -> None:
    online, lines = diff_says(old, new)
    with running(old) as daemon:
        result = daemon.reload(str(new))
    if generated:  # how many of the examples were applied (--hypothesis-show-statistics)
        event(f"applied online: {result.applied}")
    assert result.applied == online, (lines, result.refusals)
    if not result.applied:
        assert result.refusals
        for line in result.refusals:  # the operator's terms, never an exception
            assert "Error" not in line and "Traceback" not in line, line


# -- the example plants, their I/O list edited -----------------------------------------
def io_list_edited(plant: dict[str, Any], types: dict[str, dict[str, A.Type]]) -> int:
    """Every binding of ``plant`` given a new description, and a unit and a range when
    its signal is a number; the number of bindings given a unit."""
    units = 0
    for name, inst in plant["instances"].items():
        for key in ("inputs", "outputs"):
            for sig, spec in list((inst.get(key) or {}).items()):
                spec = dict(spec) if isinstance(spec, dict) else {"from": spec}
                spec["description"] = f"edited: {sig}"
                if types[name][sig] in (A.Type.INT, A.Type.REAL):
                    spec["unit"], spec["range"] = "mm", [0, 100]
                    units += 1
                inst[key][sig] = spec
    return units


@pytest.fixture
def short_run() -> Iterator[Path]:
    """A runtime directory of a short path (a plant's sockets below it: at most 107 bytes)."""
    run = Path(tempfile.mkdtemp(prefix="v", dir="/tmp"))
    try:
        yield run
    finally:
        shutil.rmtree(run, ignore_errors=True)


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: str(p.relative_to(ROOT / "configs")))
def test_an_example_plant_with_its_io_list_edited(
        path: Path, tmp_path: Path, short_run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(short_run))
    shutil.copytree(ROOT / "configs", tmp_path / "configs")  # charts of sibling folders
    here = tmp_path / "configs" / path.parent.name
    old = here / path.name
    doc = yaml.safe_load(old.read_text(encoding="utf-8"))
    if (doc.get("plc") or {}).get("retain"):  # never the machine's /var/lib/softplc
        doc["plc"]["retain"] = "${RUNTIME_DIR}/test.retain.json"
        old.write_text(yaml.safe_dump(doc, allow_unicode=True, sort_keys=False),
                       encoding="utf-8")
    pdef = load_plant(str(old))
    types = {n: {v.name: v.type for v in i.grafcet.variables.values()}
             for n, i in pdef.instances.items()}
    io_list_edited(doc, types)
    new = here / f"edited_{path.name}"
    new.write_text(yaml.safe_dump(doc, allow_unicode=True, sort_keys=False),
                   encoding="utf-8")
    same_verdict(old, new)


def test_a_plant_whose_io_list_has_a_unit(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The issue's case: a unit in the I/O list, a description edited."""
    (tmp_path / "run").mkdir()
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "run"))
    (tmp_path / "c.yaml").write_text(
        "grafcet: C\ninputs: [iGo, {iLevel: int}]\noutputs: [oRun]\nsteps:\n"
        "  s0: {initial: true}\n  s1: {actions: [oRun]}\ntransitions:\n"
        "  - {from: s0, to: s1, when: iGo}\n  - {from: s1, to: s0, when: iLevel > 5}\n",
        encoding="utf-8")
    text = ("drivers:\n  io: {type: sim}\ninstances:\n  m:\n    grafcet: c.yaml\n"
            "    inputs:\n      iGo: io.I0\n      iLevel: {from: io.IR0, unit: cm, "
            "description: LT1}\n    outputs: {oRun: io.Q0}\n")
    (tmp_path / "old.yaml").write_text(text, encoding="utf-8")
    (tmp_path / "new.yaml").write_text(text.replace("LT1", "LT1 tank level"),
                                       encoding="utf-8")
    online, _ = diff_says(tmp_path / "old.yaml", tmp_path / "new.yaml")
    assert online
    same_verdict(tmp_path / "old.yaml", tmp_path / "new.yaml")


# -- generated plants, random edits ----------------------------------------------------
def _bindings(plant: dict[str, Any]) -> list[tuple[dict[str, Any], str]]:
    return [(inst[key], sig) for inst in plant["instances"].values()
            for key in ("inputs", "outputs") for sig in inst.get(key) or {}]


def _as_map(section: dict[str, Any], sig: str) -> dict[str, Any]:
    spec = section[sig]
    section[sig] = spec = dict(spec) if isinstance(spec, dict) else {"from": spec}
    return spec


@st.composite
def edited(draw: st.DrawFn) -> tuple[Any, Any]:
    """(old documents, new documents): one to three edits of a generated plant."""
    docs = draw(plant_docs())
    chart, plant = copy.deepcopy(docs)
    numbers = {"iLevel", "iTemp", "oSpeed", "oValve"}
    for _ in range(draw(st.integers(1, 3))):
        what = draw(st.sampled_from([
            "description", "unit", "range", "chart text", "memory init", "step",
            "watchdog", "cycle", "driver bus", "new point", "section key", "section",
            "monitor socket", "alarms"]))
        if what == "description":
            section, sig = draw(st.sampled_from(_bindings(plant)))
            _as_map(section, sig)["description"] = draw(st.text(
                st.characters(min_codepoint=0x20, max_codepoint=0x2FF), max_size=20)).strip()
        elif what in ("unit", "range"):
            section, sig = draw(st.sampled_from(
                [(s, g) for s, g in _bindings(plant) if g in numbers]))
            spec = _as_map(section, sig)
            if what == "unit":
                spec["unit"] = draw(st.sampled_from(["bar", "°C", "KWH", "%"]))
            else:
                spec["range"] = [-5, draw(st.integers(1, 500))]
        elif what == "chart text":
            chart["description"] = "edited"
            chart["steps"]["gsRun"]["description"] = "running, edited"
        elif what == "memory init":
            chart["memory"]["sFlag"] = not chart["memory"]["sFlag"]
        elif what == "step":  # a new step on a branch not taken
            chart["steps"]["gsExtra"] = {"actions": ["oLamp"]}
            chart["transitions"].append({"from": "gsIdle", "to": "gsExtra",
                                         "when": "iLevel > 1000000"})
            chart["transitions"].append({"from": "gsExtra", "to": "gsIdle", "when": 1})
        elif what == "watchdog":
            plant["plc"]["watchdog"] = "5s" if plant["plc"].get("watchdog") != "5s" else "4s"
        elif what == "cycle":
            plant["plc"]["cycle"] = "5ms" if plant["plc"]["cycle"] != "5ms" else "10ms"
        elif what == "driver bus":
            plant["drivers"]["mb"]["retries"] = 1 + int(
                plant["drivers"]["mb"].get("retries", 2) == 1)
        elif what == "new point":
            plant["instances"]["m1"]["outputs"]["oLamp"] = "sim.Q7"
        elif what == "section key":
            for key, field, value in (("web", "max_pages", 7), ("mqtt", "buffer", 99),
                                      ("opcua", "writable", ["m1.sFlag"])):
                if key in plant:
                    plant[key][field] = value
                    break
        elif what == "section":
            key = draw(st.sampled_from(["opcua", "web"]))
            if key in plant:
                del plant[key]
            else:
                plant[key] = {"listen": "127.0.0.1:0"} if key == "web" else {}
        elif what == "monitor socket":
            plant["monitor"]["socket"] = "${RUNTIME_DIR}/other.sock"
        elif what == "alarms":
            plant["alarms"] = {"severity": {"fault": 999}}
    return docs, (chart, plant)


def write_pair(where: Path, old: Any, new: Any) -> tuple[Path, Path]:
    """Both versions as files of one plant directory (the new plant names its own chart
    file); their paths."""
    where.mkdir(parents=True)
    paths = []
    for tag, (chart, plant) in (("old", old), ("new", new)):
        (where / f"chart_{tag}.yaml").write_text(
            yaml.safe_dump(chart, allow_unicode=True, sort_keys=False), encoding="utf-8")
        plant = copy.deepcopy(plant)
        for inst in plant["instances"].values():
            inst["grafcet"] = f"chart_{tag}.yaml"
        path = where / f"plant_{tag}.yaml"
        path.write_text(yaml.safe_dump(plant, allow_unicode=True, sort_keys=False),
                        encoding="utf-8")
        paths.append(path)
    return paths[0], paths[1]


@pytest.fixture(scope="module")
def gen_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("verdict")


_count = iter(range(1 << 30))


@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
@given(pair=edited())
def test_generated_plants_and_edits(gen_dir: Path, monkeypatch: pytest.MonkeyPatch,
                                    pair: tuple[Any, Any]) -> None:
    where = gen_dir / f"p{next(_count)}"
    old, new = write_pair(where, *pair)
    (where / "run").mkdir()  # ${RUNTIME_DIR}: a directory of this user, the plant's own
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(where / "run"))
    same_verdict(old, new, generated=True)


def test_a_version_kept_in_another_directory(tmp_path: Path, short_run: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """A plant's ``${RUNTIME_DIR}`` is its own (docs/daemon.md): a new version kept
    elsewhere (an edited copy, a checkout) is read as a version of the running plant by
    ``softplc diff`` and ``reload``, its paths there the running plant's, so the change is
    the edit, not "plc: retain changed" and "monitor: consoles changed"."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(short_run))
    shutil.copytree(ROOT / "configs", tmp_path / "configs")
    old = tmp_path / "configs" / "drawer_tester" / "plant_sim.yaml"
    aside = tmp_path / "edits"
    aside.mkdir()
    shutil.copy(old.parent / "drawer_tester.yaml", aside / "drawer_tester.yaml")
    new = aside / "plant_sim.yaml"
    new.write_text(old.read_text(encoding="utf-8").replace(
        "Piloto PFT, ensayo en marcha", "Piloto PFT"), encoding="utf-8")
    online, lines = diff_says(old, new)
    assert online, lines
    assert not any("retain" in x or "consoles" in x or "feed" in x for x in lines), lines
    same_verdict(old, new)
