"""The install of docs/daemon.md, done as written: a clean virtual environment, ``pip
install`` of the source tree, ``softplc install-service --root`` of every example plant of
configs/, then ``softplc compile`` and ``softplc check`` of each staged plant with that
environment's softplc; every driver type the plants name imports there (the field's
libraries are core dependencies: the documented Pi install must not start in fault)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from runtime.language.filekind import file_kind

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
PLANTS = sorted(p for p in ROOT.glob("configs/*/*.yaml") if file_kind(str(p)) == "plant")
#: what sudo leaves of PATH (secure_path): the venv's softplc is called by its full path
SUDO_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
#: not part of the source tree a user copies (caches, build outputs, the dev venv)
NOT_SOURCE = shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info",
                                    "__pycache__", ".*_cache", "*.pyc")


def run(cmd: list[str | Path], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    env["PATH"] = SUDO_PATH
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout, check=False)


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """/opt/softplc/venv of the docs, made below a temporary directory."""
    base = tmp_path_factory.mktemp("install")
    src = base / "softplc-src"
    shutil.copytree(ROOT, src, ignore=NOT_SOURCE)  # pip builds in the tree: not in ours
    v = base / "venv"
    r = run([sys.executable, "-m", "venv", v], cwd=base)
    assert r.returncode == 0, r.stderr
    r = run([v / "bin" / "pip", "install", "--disable-pip-version-check", src], cwd=base,
            timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return v


def test_the_package_is_installed_not_read_from_the_source_tree(venv: Path,
                                                                 tmp_path: Path) -> None:
    r = run([venv / "bin" / "python", "-c", "import runtime, drivers; "
             "print(runtime.__file__); print(drivers.__file__)"], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for line in r.stdout.splitlines():
        assert line.startswith(str(venv)) and "site-packages" in line, line
    want = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    r = run([venv / "bin" / "softplc", "--version"], cwd=tmp_path)
    assert (r.returncode, r.stdout) == (0, f"softplc {want}\n"), r.stderr


def test_every_driver_type_imports_but_gpio_which_names_its_extra(venv: Path,
                                                                  tmp_path: Path) -> None:
    """smbus2, python-can, canopen and pyserial come with softplc; gpiod (no wheel for
    32-bit ARM on PyPI) is the extra ``gpio``, and the error without it says so."""
    probe = """
from drivers.registry import DRIVERS, DriverImportError, driver_class
for t in DRIVERS:
    try:
        print(t, driver_class(t).__name__)
    except DriverImportError as exc:
        print(t, "missing:", exc)
"""
    r = run([venv / "bin" / "python", "-c", probe], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    got = dict(line.split(" ", 1) for line in r.stdout.splitlines())
    for t in ("sim", "mcp23017", "pcf8574", "canopen", "modbus_rtu"):
        assert "missing" not in got[t], (t, got[t])
    assert run([venv / "bin" / "python", "-c", "import gpiod"], cwd=tmp_path).returncode, \
        "gpiod is the extra 'gpio': a plain install must not bring it"
    # the install's own pip and the tree it was installed from (no 'softplc[gpio]' of an
    # index: this project publishes none)
    src = venv.parent / "softplc-src"
    hint = re.compile(rf"{re.escape(str(venv))}/bin/python[0-9.]* -m pip install "
                      rf"{re.escape(repr(f'{src}[gpio]'))}")
    assert got["gpio"].startswith("missing:") and hint.search(got["gpio"]), got
    # the controller of a gpio plant says so in one line and stops (exit 2), no traceback
    (tmp_path / "chart.yaml").write_text("grafcet: G\ninputs: [go]\nsteps:\n"
                                         "  s: {initial: true}\n")
    (tmp_path / "plant.yaml").write_text("drivers: {io: {type: gpio}}\n"
                                         "instances: {g: {grafcet: chart.yaml, "
                                         "inputs: {go: io.17}}}\n")
    r = run([venv / "bin" / "softplc", "run", "plant.yaml", "--for", "1s"], cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "driver type 'gpio' needs the Python package 'gpiod': " in r.stderr, r.stderr
    assert hint.search(r.stderr), r.stderr


@pytest.mark.parametrize("plant", PLANTS, ids=[f"{p.parent.name}/{p.name}" for p in PLANTS])
def test_each_example_plant_stages_compiles_and_checks(venv: Path, tmp_path: Path,
                                                       plant: Path) -> None:
    softplc = venv / "bin" / "softplc"
    root = tmp_path / "root"
    r = run([softplc, "install-service", "--root", root, plant], cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    etc = root / "etc" / "softplc" / plant.parent.name  # the plant's name: its directory's
    staged = etc / "plant.yaml"  # whatever its name in configs/
    unit = (root / "etc" / "systemd" / "system" / "softplc@.service").read_text()
    assert f"ExecStart={softplc} run /etc/softplc/%i/plant.yaml" in unit.splitlines()
    # compile and check the staged copy, from /etc/softplc's stand-in, with the venv's softplc
    r = run([softplc, "compile", staged], cwd=etc)
    assert r.returncode == 0 and f"{staged}: ok: " in r.stderr, r.stderr
    r = run([softplc, "check", staged], cwd=etc)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout + r.stderr
    assert "Traceback" not in out and "needs the Python package" not in out, out
    # the drivers the plant names load in the venv (the controller would start, not fault)
    probe = ("import sys\nfrom runtime.language.plantfile import load_plant\n"
             "from drivers.registry import driver_class\n"
             "for d in load_plant(sys.argv[1]).drivers.values():\n"
             "    print(d.type, driver_class(d.type).__name__)\n")
    r = run([venv / "bin" / "python", "-c", probe, staged], cwd=etc)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip(), "a plant without drivers"
