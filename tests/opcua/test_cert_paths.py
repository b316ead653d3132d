"""The OPC UA certificate, key and trusted directories of a plant file: a relative path is
read from the plant file's directory, as every other path of it (it was read from the
working directory: ``softplc check`` passed and ``softplc opcua``, started elsewhere,
failed 15 s later advising to make a new certificate); a file that is not there is
refused by ``softplc check`` (G308) and by the server, at its value (FILE:LINE:COL), and
never keeps the controller from loading the plant; a file
that is there but cannot be read or holds no certificate or key is said at the server's
start, at once, without advising to make one."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from asyncua import Client, ua

from runtime.checker.check import check_files
from runtime.cli import main
from runtime.errors import SourceError
from runtime.language.opcuaconf import check_security
from runtime.language.plantfile import load_plant
from runtime.opcua import security
from tests.opcua.kit import free_port, write_plant

ROOT = Path(__file__).resolve().parents[2]
SECTION = ("  security:\n    policies: [None, Basic256Sha256_SignAndEncrypt]\n"
           "    certificate: {cert}\n    private_key: {key}\n"
           "    trusted_clients: {trusted}\n")
#: the line and column of the certificate's value (plant_head's 13 lines, then opcua:
#: endpoint, sample, feed, writable, security, policies), and of the key's
CERT_AT, KEY_AT, TRUSTED_AT = (20, 18), (21, 18), (22, 22)


def site(tmp: Path, cert: str = "pki/server-cert.der", key: str = "pki/server-key.pem",
         trusted: str = "pki/trusted", make: bool = True) -> Path:
    """A plant in ``tmp/site`` naming its certificate, key and trusted directory as given
    (relative by default), with a certificate pair made in ``site/pki``."""
    d = tmp / "site"
    d.mkdir()
    if make:
        security.make_certificate(str(d / "pki"), days=30, hosts=["127.0.0.1"])
        (d / "pki" / "trusted").mkdir()
    plant = write_plant(d, port=free_port())
    text = plant.read_text(encoding="utf-8")
    head, _, rest = text.partition("  security:")
    rest = rest.split("\n", 1)[1]
    plant.write_text(head + SECTION.format(cert=cert, key=key, trusted=trusted) + rest,
                     encoding="utf-8")
    return plant


def error_at(plant: Path) -> SourceError:
    """The first missing file of the plant's ``opcua: security:`` as the OPC UA server
    refuses it (``check_security``), once the controller has loaded the plant without
    it: ``softplc check`` says the same as an error G308."""
    sec = load_plant(str(plant)).opcua.security  # type: ignore[union-attr]
    with pytest.raises(SourceError) as err:
        check_security(sec)
    (result,) = [r for r in check_files([str(plant)]) if r.path == str(plant)]
    assert result.failure is None
    e = err.value
    g308 = [d for d in result.diags if d.code == "G308"]
    assert g308 and (g308[0].file, g308[0].line, g308[0].col, g308[0].severity,
                     g308[0].message) == (e.loc.file, e.loc.line, e.loc.col, "error",
                                          e.message), [str(d) for d in result.diags]
    return e


def test_relative_paths_are_read_from_the_plant_files_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plant = site(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    sec = load_plant(str(plant)).opcua.security  # type: ignore[union-attr]
    pki = tmp_path / "site" / "pki"
    assert (sec.certificate, sec.private_key, sec.trusted_clients) == (
        str(pki / "server-cert.der"), str(pki / "server-key.pem"), str(pki / "trusted"))
    # and the server reads them from there
    creds = security.read_credentials(sec)
    assert creds is not None and creds.certificate == (pki / "server-cert.der").read_bytes()


def test_softplc_opcua_started_elsewhere_serves_with_relative_paths(tmp_path: Path) -> None:
    """The issue's case end to end: the real ``softplc check`` and ``softplc opcua``, run
    from another directory than the plant's."""
    plant = site(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(elsewhere)}
    env.pop("JOURNAL_STREAM", None)
    check = subprocess.run([sys.executable, "-m", "runtime.cli", "check", "--quiet",
                            str(plant)], cwd=elsewhere, env=env, capture_output=True,
                           text=True, timeout=120)
    assert check.returncode in (0, 1) and "opcua security" not in check.stdout, check.stdout
    log = elsewhere / "opcua.log"
    with open(log, "wb") as out:
        server = subprocess.Popen([sys.executable, "-m", "runtime.cli", "opcua", str(plant)],
                                  cwd=elsewhere, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        url = load_plant(str(plant)).opcua.endpoint  # type: ignore[union-attr]

        async def endpoints() -> list[str]:
            deadline = time.monotonic() + 120
            while True:
                assert server.poll() is None, log.read_text(encoding="utf-8")
                try:
                    async with Client(url, timeout=5) as c:
                        found = await c.get_endpoints()
                        return [e.SecurityPolicyUri.rsplit("#", 1)[1] for e in found
                                if e.ServerCertificate]
                except (OSError, TimeoutError, ua.UaError):
                    assert time.monotonic() < deadline, log.read_text(encoding="utf-8")
                    await asyncio.sleep(0.3)
        offered = asyncio.run(endpoints())
    finally:
        server.terminate()
        server.wait(30)
    assert "Basic256Sha256" in offered
    assert "opcua-cert" not in log.read_text(encoding="utf-8")


def test_a_missing_certificate_is_refused_by_check_and_the_server_not_the_controller(
        tmp_path: Path) -> None:
    plant = site(tmp_path, cert="pki/nope.der")
    e = error_at(plant)
    want = (f"opcua security certificate: no file {tmp_path}/site/pki/nope.der (its private "
            f"key {tmp_path}/site/pki/server-key.pem is there: put this file of the pair "
            "back beside it, or move that one away and make a new pair with 'softplc "
            "opcua-cert', docs/opcua.md)")
    assert (e.loc.file, e.loc.line, e.loc.col, e.message) == (str(plant), *CERT_AT, want)
    # the controller is not kept from running the machine: the plant compiles
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        assert main(["compile", str(plant)]) == 0, out.getvalue()
    # softplc check exits 2 on it
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        assert main(["check", str(plant)]) == 2
    assert f"{plant}:{CERT_AT[0]}:{CERT_AT[1]}: error G308: {want}" in out.getvalue()


def test_a_missing_pair_advises_making_one(tmp_path: Path) -> None:
    plant = site(tmp_path, make=False, trusted="/")
    e = error_at(plant)
    assert (e.loc.line, e.loc.col) == CERT_AT
    assert e.message == (f"opcua security certificate: no file {tmp_path}/site/pki/"
                         "server-cert.der (make one with 'softplc opcua-cert', "
                         "docs/opcua.md)")


def test_a_missing_key_beside_its_certificate(tmp_path: Path) -> None:
    plant = site(tmp_path, key="pki/other-key.pem")
    e = error_at(plant)
    assert (e.loc.line, e.loc.col) == KEY_AT
    assert e.message.startswith(f"opcua security private_key: no file {tmp_path}/site/pki/"
                                f"other-key.pem (its certificate {tmp_path}/site/pki/"
                                "server-cert.der is there: put this file")


def test_a_directory_where_a_file_is_expected_and_the_reverse(tmp_path: Path) -> None:
    plant = site(tmp_path, cert="pki")
    e = error_at(plant)
    assert (e.loc.line, e.loc.col) == CERT_AT
    assert e.message == (f"opcua security certificate: {tmp_path}/site/pki is a directory, "
                         "expected a file")
    plant.write_text(plant.read_text(encoding="utf-8").replace(
        "certificate: pki\n", "certificate: pki/server-cert.der\n").replace(
        "trusted_clients: pki/trusted", "trusted_clients: pki/server-cert.der"),
        encoding="utf-8")
    e = error_at(plant)
    assert (e.loc.line, e.loc.col, e.message) == (
        *TRUSTED_AT, f"opcua security trusted_clients: {tmp_path}/site/pki/server-cert.der "
                     "is not a directory")
    plant.write_text(plant.read_text(encoding="utf-8").replace(
        "trusted_clients: pki/server-cert.der", "trusted_clients: pki/trustd"),
        encoding="utf-8")
    assert error_at(plant).message == (
        f"opcua security trusted_clients: no directory {tmp_path}/site/pki/trustd (the "
        "directory of the client certificates to trust: make it, docs/opcua.md, 'Step by "
        "step')")


def test_a_file_that_is_there_but_holds_no_certificate_is_one_line_at_once(
        tmp_path: Path) -> None:
    """``softplc opcua`` refuses before asyncua's set-up, at the certificate's value, and
    does not advise making a file that is there."""
    plant = site(tmp_path)
    cert = tmp_path / "site" / "pki" / "server-cert.der"
    cert.write_bytes(b"not a certificate\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("JOURNAL_STREAM", None)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "opcua", str(plant)], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.splitlines()
    assert line.startswith(f"{plant}:{CERT_AT[0]}:{CERT_AT[1]}: error: opcua security "
                           f"certificate: {cert} holds no certificate (DER or PEM): "), line
    assert "opcua-cert" not in line and "make" not in line
    assert cert.read_bytes() == b"not a certificate\n"  # nothing overwritten


@pytest.mark.parametrize("case", ["fifo", "huge", "garbage key", "another key"])
def test_a_key_that_is_there_but_cannot_be_read_or_used(tmp_path: Path, case: str) -> None:
    plant = site(tmp_path)
    pki = tmp_path / "site" / "pki"
    key = pki / "server-key.pem"
    key.unlink()
    if case == "fifo":
        os.mkfifo(key)
        why = f"{key}: a FIFO (named pipe), expected a file of at most 65536 bytes"
    elif case == "huge":
        key.write_bytes(b"x" * 100_000)
        why = f"{key}: a file of 100000 bytes, expected a file of at most 65536 bytes"
    elif case == "garbage key":
        key.write_bytes(b"-----BEGIN PRIVATE KEY-----\nnope\n-----END PRIVATE KEY-----\n")
        why = f"{key} holds no private key without a password (PEM or DER): "
    else:
        security.make_certificate(str(tmp_path / "other"), days=30)
        key.write_bytes((tmp_path / "other" / "server-key.pem").read_bytes())
        why = f"{key} is not the key of the certificate {pki / 'server-cert.der'}"
    sec = load_plant(str(plant)).opcua.security  # type: ignore[union-attr]
    t0 = time.monotonic()
    with pytest.raises(SourceError) as err:
        security.read_credentials(sec)
    assert time.monotonic() - t0 < 5.0  # never waits on the FIFO
    e = err.value
    assert (e.loc.file, e.loc.line, e.loc.col) == (str(plant), *KEY_AT)
    assert e.message.startswith(f"opcua security private_key: {why}"), e.message
    assert "opcua-cert" not in e.message and "make" not in e.message
