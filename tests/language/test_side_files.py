"""The files the side processes read at their start besides the plant: the certificates and
keys of ``web: tls:``, ``modbus: tls:`` and ``mqtt: tls:``, and ``mqtt: password_file``
(the OPC UA server's: tests/opcua/test_cert_paths.py). A relative path is read from the
plant file's directory; a file that is not there or cannot be read is an error G308 of
``softplc check`` at its value (FILE:LINE:COL), never a refusal of the plant (the
controller must start whatever happened to a certificate), and the side process refuses
to start on it with its one line."""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.checker.check import check_files
from runtime.cli import main
from tests.web.kit import write_plant

ROOT = Path(__file__).resolve().parents[2]
#: each side's section naming its files (relative to the plant file), and those files in
#: the order its process reads them
SECTIONS = {
    "web": ("  tls:\n    certificate: pki/cert.pem\n    private_key: pki/key.pem\n",
            ("certificate", "private_key")),
    "modbus": ("modbus:\n  listen: off\n  tls:\n    listen: 127.0.0.1:0\n"
               "    certificate: pki/cert.pem\n    private_key: pki/key.pem\n"
               "    clients_ca: pki/ca.pem\n    roles: {operator: write}\n",
               ("certificate", "private_key", "clients_ca")),
    "mqtt": ("mqtt:\n  brokers: [mqtts://127.0.0.1:1]\n  group_id: G\n  username: u\n"
             "  password_file: pki/password\n  tls:\n    ca: pki/ca.pem\n"
             "    certificate: pki/cert.pem\n    private_key: pki/key.pem\n",
             ("ca", "certificate", "private_key", "password_file")),
}
FILES = {"certificate": "cert.pem", "private_key": "key.pem", "clients_ca": "ca.pem",
         "ca": "ca.pem", "password_file": "password"}


def side_plant(tmp: Path, side: str, make: bool = True) -> Path:
    """A plant with the section of ``side`` naming its files in ``pki/`` beside it, made
    (holding a line of text each: the check looks for files, not into them) if ``make``."""
    section, _ = SECTIONS[side]
    plant = write_plant(tmp, section if side == "web" else "", users=False)
    if side != "web":
        plant.write_text(plant.read_text(encoding="utf-8") + section, encoding="utf-8")
    if make:
        (plant.parent / "pki").mkdir()
        for name in set(FILES.values()):
            (plant.parent / "pki" / name).write_text("a line\n", encoding="utf-8")
    return plant


def value_at(plant: Path, key: str) -> tuple[int, int]:
    """The line and column of the value of ``key:`` (its only occurrence) in ``plant``."""
    (found,) = [(n, line.index(f"{key}: ") + len(key) + 3)
                for n, line in enumerate(plant.read_text(encoding="utf-8").splitlines(), 1)
                if line.strip().startswith(f"{key}: ")]
    return found


def what(side: str, key: str) -> str:
    return f"{side} {key}" if key == "password_file" else f"{side} tls {key}"


def g308(plant: Path) -> list[str]:
    (result,) = [r for r in check_files([str(plant)]) if r.path == str(plant)]
    assert result.failure is None, result.failure
    return [str(d) for d in result.diags if d.code == "G308"]


@pytest.mark.parametrize("side", SECTIONS)
def test_files_that_are_there_are_no_error_from_any_directory(
        tmp_path: Path, side: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """(where a relative path is read: tests/language/test_relative_paths.py)"""
    plant = side_plant(tmp_path, side)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert g308(plant) == []


@pytest.mark.parametrize("side", SECTIONS)
def test_a_missing_file_is_g308_at_its_value_and_the_controller_loads(
        tmp_path: Path, side: str) -> None:
    plant = side_plant(tmp_path, side)
    pki = plant.parent / "pki"
    for key in SECTIONS[side][1]:
        (pki / FILES[key]).rename(pki / "away")
        line, col = value_at(plant, key)
        assert g308(plant) == [
            f"{plant}:{line}:{col}: error G308: {what(side, key)}: no file {pki / FILES[key]}: "
            f"'softplc {side}' would refuse to start (docs/{side}.md)"]
        (pki / "away").rename(pki / FILES[key])
    (pki / "key.pem").unlink()
    (pki / "key.pem").mkdir()  # not of its kind
    line, col = value_at(plant, "private_key")
    assert g308(plant) == [
        f"{plant}:{line}:{col}: error G308: {what(side, 'private_key')}: {pki}/key.pem is a "
        f"directory, expected a file: 'softplc {side}' would refuse to start (docs/{side}.md)"]
    # the controller is not kept from running the machine: the plant compiles
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        assert main(["compile", str(plant)]) == 0, out.getvalue()
        assert main(["check", str(plant)]) == 2
    assert f"{plant}:{line}:{col}: error G308: " in out.getvalue()


@pytest.mark.parametrize("side", SECTIONS)
def test_a_file_that_cannot_be_read_is_g308(tmp_path: Path, side: str) -> None:
    """``softplc check`` run by a user who may not read the key (root reads everything:
    the check then runs without the capabilities that let it, CAP_DAC_OVERRIDE and
    CAP_DAC_READ_SEARCH)."""
    plant = side_plant(tmp_path, side)
    key = plant.parent / "pki" / "key.pem"
    key.chmod(0)
    drop: list[str] = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("root reads every file, and setpriv (util-linux) is not here")
        caps = "-dac_override,-dac_read_search"
        drop = ["setpriv", f"--bounding-set={caps}", f"--inh-caps={caps}"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(tmp_path)}
    r = subprocess.run([*drop, sys.executable, "-m", "runtime.cli", "check", "--quiet",
                        str(plant)], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=120, check=False)
    line, col = value_at(plant, "private_key")
    assert r.returncode == 2, r.stdout + r.stderr
    assert (f"{plant.relative_to(tmp_path)}:{line}:{col}: error G308: "
            f"{what(side, 'private_key')}: {key} cannot be "
            f"read (permission denied): 'softplc {side}' would refuse to start "
            f"(docs/{side}.md)") in r.stdout.splitlines(), r.stdout + r.stderr


#: the line each side process refuses to start with when its first file is not there
START_LINES = {
    "web": "softplc web: error: 127.0.0.1:0: No such file or directory",
    "modbus": "softplc modbus: error: :0: No such file or directory",
    "mqtt": "softplc mqtt: error: No such file or directory",
}


@pytest.mark.parametrize("side", SECTIONS)
def test_the_side_process_refuses_to_start_with_one_line(tmp_path: Path, side: str) -> None:
    plant = side_plant(tmp_path, side, make=False)
    assert len(g308(plant)) == len(SECTIONS[side][1])  # every file, each at its value
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(tmp_path)}
    env.pop("JOURNAL_STREAM", None)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", side, str(plant)],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
                       check=False)
    # (the web view warns first that it cannot read the certificate's names)
    assert (r.returncode, r.stderr.splitlines()[-1]) == (2, START_LINES[side]), r.stderr
