"""``softplc run`` (no ``--sim``) whose drivers cannot open on this machine: a port that
does not exist, a permission denied, no such CAN interface, no such I2C bus or GPIO chip.
Each is one line naming the driver's plant line and the cause, exit 2, no traceback; the
controller was stopped in order (outputs written off) before it said so."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from tests.drivers.test_driver_config_cli import CHART, ROOT, plant_text

#: (type, config, words of the cause)
CASES = [
    ("modbus_rtu", {"port": f"/dev/ttyNOPE{uuid.uuid4().hex[:6]}"}, "No such file"),
    ("canopen", {"channel": "nocan9"}, "cannot open the bus"),
    ("mcp23017", {"bus": "99"}, "/dev/i2c-99"),
    ("pcf8574", {"bus": "99"}, "/dev/i2c-99"),
    ("gpio", {"chip": "/dev/gpiochip99"}, "/dev/gpiochip99"),
]


def run(plant: Path, *, user: int | None = None) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "runtime.cli", "run", str(plant), "--for", "30s"]
    env = None
    if user is not None:  # as that user: its permissions, not root's
        argv = ["setpriv", f"--reuid={user}", f"--regid={user}", "--clear-groups", *argv]
        # its runtime directory (${TMPDIR}/softplc-UID) where that user may create it: the
        # test's own TMPDIR may be a directory of root's
        shared = plant.parent / "tmp"
        shared.mkdir(exist_ok=True)
        shared.chmod(0o1777)
        env = {**os.environ, "TMPDIR": str(shared)}
    # a bound only a controller that hangs reaches (its start took tens of seconds at a load
    # of 10-18 on 2 cores)
    return subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=600, env=env)


def write_plant(tmp_path: Path, type_name: str, cfg: dict[str, str | None]) -> Path:
    shutil.copy(CHART, tmp_path / "drawer_tester.yaml")
    path = tmp_path / "plant.yaml"
    path.write_text(plant_text(type_name, cfg), "utf-8")
    return path


def assert_one_line(p: subprocess.CompletedProcess[str], path: Path, words: str) -> None:
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    errors = [ln for ln in p.stderr.splitlines() if ": error:" in ln]
    assert len(errors) == 1, p.stderr
    # the driver's name is on line 4 of plant_text, column 3
    assert errors[0].startswith(f"{path}:4:3: error: driver d ("), errors
    assert "cannot start: " in errors[0] and words in errors[0], errors
    assert p.stderr.splitlines()[-1] == errors[0]  # said last, after the orderly stop
    assert "stopping" in p.stderr  # serve stopped the controller: every output off


@pytest.mark.parametrize("type_name, cfg, words", CASES)
def test_a_driver_that_cannot_open_at_start_is_one_line(tmp_path: Path, type_name: str,
                                                        cfg: dict[str, str | None],
                                                        words: str) -> None:
    path = write_plant(tmp_path, type_name, cfg)
    assert_one_line(run(path), path, words)


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None,
                    reason="needs root to run as another user")
def test_permission_denied_on_the_port_is_one_line(tmp_path: Path) -> None:
    port = tmp_path / "ttyS9"
    port.touch(mode=0o000)
    tmp_path.chmod(0o755)
    path = write_plant(tmp_path, "modbus_rtu", {"port": str(port)})
    for f in tmp_path.iterdir():
        if f != port:
            f.chmod(0o644)
    for parent in tmp_path.parents:  # nobody must reach the plant file
        if not os.access(parent, os.X_OK, effective_ids=False) or parent == Path("/"):
            break
        parent.chmod(parent.stat().st_mode | 0o005)
    assert_one_line(run(path, user=65534), path, "Permission denied")


def test_an_exception_in_a_driver_at_start_names_its_plant_line(tmp_path: Path) -> None:
    """Not an OSError: an exception the driver does not expect (here pyserial's ValueError
    on a setting, made to happen by a shim), still one line at the driver's line."""
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "sitecustomize.py").write_text(
        "import serial\n"
        "class _Broken(serial.Serial):\n"
        "    def __init__(self, *a, **k):\n"
        "        raise ValueError('Invalid parity: X')\n"
        "serial.Serial = _Broken\n", "utf-8")
    path = write_plant(tmp_path, "modbus_rtu", {"port": "/dev/ttyS0"})
    env = {**os.environ, "PYTHONPATH": f"{shim}{os.pathsep}{ROOT}"}
    p = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(path), "--for", "30s"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120, env=env)
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    errors = [ln for ln in p.stderr.splitlines() if ": error:" in ln]
    assert errors == [f"{path}:4:3: error: driver d (modbus_rtu): cannot start: ValueError: "
                      "Invalid parity: X"], p.stderr
