"""Test parts for the MQTT tests: Debian's mosquitto on a loopback port with a config of the
test's own (plain, TLS with a test CA, a password file), the independent host application
(host/host.py, pysparkplug in its own environment), the plant with an ``mqtt:`` section, and
``softplc run`` / ``softplc mqtt`` as processes."""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.mqtt.hostenv import HOST_DIR, host_python
from tests.opcua.feedkit import wait_until
from tests.opcua.kit import free_port, plant_head

ROOT = Path(__file__).resolve().parents[2]
MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
GROUP, EDGE = "Bench", "pi-07"


def need_mosquitto() -> None:
    if not os.access(MOSQUITTO, os.X_OK):
        if os.environ.get("CI"):
            raise AssertionError("mosquitto missing: scripts/test.sh installs it")
        pytest.skip("mosquitto is not installed (apt-get install mosquitto; scripts/test.sh "
                    "does it)")


# -- TLS ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Certs:
    """A test CA, a broker certificate it signed (127.0.0.1, localhost) and a client's."""

    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path


def make_certs(directory: Path) -> Certs:
    """A CA and two certificates signed by it, made here (cryptography)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    directory.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def pem_key(key: Any, path: Path) -> None:
        path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
        path.chmod(0o600)

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (x509.CertificateBuilder().subject_name(name("softplc test CA"))
          .issuer_name(name("softplc test CA")).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(minutes=5))
          .not_valid_after(now + datetime.timedelta(days=2))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False,
                                       False), critical=True)
          .sign(ca_key, hashes.SHA256()))

    def leaf(cn: str, server: bool) -> tuple[Any, Any]:
        key = ec.generate_private_key(ec.SECP256R1())
        b = (x509.CertificateBuilder().subject_name(name(cn)).issuer_name(ca.subject)
             .public_key(key.public_key()).serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(minutes=5))
             .not_valid_after(now + datetime.timedelta(days=2))
             .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
             .add_extension(x509.ExtendedKeyUsage(
                 [ExtendedKeyUsageOID.SERVER_AUTH if server
                  else ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False))
        if server:
            b = b.add_extension(x509.SubjectAlternativeName(
                [x509.DNSName("localhost"),
                 x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
        return key, b.sign(ca_key, hashes.SHA256())

    paths = Certs(directory / "ca.pem", directory / "server.pem", directory / "server-key.pem",
                  directory / "client.pem", directory / "client-key.pem")
    paths.ca.write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    for (key, cert), cpath, kpath in ((leaf("broker", True), paths.server_cert,
                                       paths.server_key),
                                      (leaf("pi-07", False), paths.client_cert,
                                       paths.client_key)):
        cpath.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        pem_key(key, kpath)
    return paths


# -- the broker ----------------------------------------------------------------------


class Broker:
    """mosquitto on 127.0.0.1 (or ``bind``) with a config of this test's: anonymous, or
    with ``users`` (a password file made by mosquitto_passwd); TLS with ``certs`` (and the
    client's certificate required with ``require_certificate``)."""

    def __init__(self, tmp: Path, *, port: int | None = None, bind: str = "127.0.0.1",
                 certs: Certs | None = None, users: dict[str, str] | None = None,
                 require_certificate: bool = False, name: str = "broker") -> None:
        need_mosquitto()
        self.tmp, self.bind, self.certs, self.name = tmp, bind, certs, name
        self.port = port or free_port()
        self.log = tmp / f"{name}.log"
        self.conf = tmp / f"{name}.conf"
        lines = [f"listener {self.port} {bind}", "persistence false",
                 f"log_dest file {self.log}", "log_type error", "log_type warning",
                 "log_type notice", "log_type information", "connection_messages true",
                 "max_queued_messages 100000"]
        if os.geteuid() == 0:
            lines.insert(0, "user root")  # it would drop to 'mosquitto', locked out of tmp
        if users:
            pw = tmp / f"{name}.passwd"
            pw.write_text("")
            for user, password in users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(pw), user, password],
                               check=True, capture_output=True)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        else:
            lines.append("allow_anonymous true")
        if certs is not None:
            lines += [f"cafile {certs.ca}", f"certfile {certs.server_cert}",
                      f"keyfile {certs.server_key}"]
            if require_certificate:
                lines.append("require_certificate true")
        self.conf.write_text("\n".join(lines) + "\n")
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"{'mqtts' if self.certs else 'mqtt'}://{self.bind}:{self.port}"

    def start(self, netns: str | None = None) -> Broker:
        cmd = [MOSQUITTO, "-c", str(self.conf)]
        if netns is not None:
            cmd = ["ip", "netns", "exec", netns, *cmd]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        wait_until(lambda: self._listening() or self.proc is None or
                   self.proc.poll() is not None, 20, f"{self.name} listening")
        assert self.proc.poll() is None, self.proc.communicate()[1].decode()
        return self

    def _listening(self) -> bool:
        return "running" in (self.log.read_text() if self.log.exists() else "")

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            self.proc.wait(timeout=20)
        self.proc = None

    def restart(self) -> None:
        self.log.unlink(missing_ok=True)
        self.start()


# -- the host application --------------------------------------------------------------


class Host:
    """host/host.py in its own environment: every message it decoded, in arrival order."""

    def __init__(self, broker: Broker, *, user: str | None = None,
                 password: str | None = None, host_id: str = "softplc-test-host",
                 primary: bool = False, netns: str | None = None, keepalive: int = 5) -> None:
        cmd = [host_python(), str(HOST_DIR / "host.py"), broker.bind, str(broker.port),
               "--id", host_id, "--keepalive", str(keepalive),
               *(["--primary"] if primary else [])]
        if netns is not None:
            cmd = ["ip", "netns", "exec", netns, *cmd]
        if broker.certs is not None:
            cmd += ["--ca", str(broker.certs.ca)]
        if user is not None:
            cmd += ["--user", user, "--password", password or ""]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, bufsize=1)
        self.rows: list[dict[str, Any]] = []
        self.ready = threading.Event()
        #: requests the host application has carried out
        self.acks = 0
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        if not self.ready.wait(60):
            self.close()
            raise AssertionError(f"host application not ready: {self.stderr()}")

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            row = json.loads(line)
            if row.get("ready"):
                self.ready.set()
            elif "topic" in row:
                self.rows.append(row)
            elif "fatal" in row:
                self.ready.set()
            elif "sent" in row:
                self.acks += 1

    def stderr(self) -> str:
        return "" if self.proc.poll() is None else (self.proc.stderr.read()
                                                     if self.proc.stderr else "")

    def send(self, req: dict[str, Any]) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()

    def command(self, topic: str, metrics: list[tuple[str, str, Any]]) -> None:
        """An NCMD or DCMD encoded by pysparkplug: (name, datatype name, value)."""
        self.send({"cmd": topic, "metrics": [list(m) for m in metrics]})

    def raw(self, topic: str, data: bytes, *, retain: bool = False, qos: int = 0) -> None:
        self.send({"raw": topic, "hex": data.hex(), "retain": retain, "qos": qos})

    def state(self, online: bool) -> None:
        self.send({"state": online})

    def of(self, kind: str, device: str | None = None) -> list[dict[str, Any]]:
        return [r for r in list(self.rows) if r.get("kind") == kind and
                (device is None or r.get("device") == device)]

    def wait(self, pred: Callable[[list[dict[str, Any]]], bool], timeout: float = 30.0,
             what: str = "") -> None:
        wait_until(lambda: pred(list(self.rows)), timeout, what)

    def latest(self, device: str | None, name: str) -> Any:
        """The last live value of metric ``name`` (of ``device``, or the node's)."""
        for r in reversed(list(self.rows)):
            if r.get("device") == device and r.get("kind") in ("NBIRTH", "DBIRTH", "NDATA",
                                                               "DDATA"):
                for m in r["metrics"]:
                    if m["name"] == name and not m["historical"]:
                        return m["value"]
        return None

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self._thread.join(timeout=5)


# -- the plant and the processes -------------------------------------------------------


def write_plant(tmp: Path, brokers: list[str], *, cycle: str = "10ms", sample: str = "50ms",
                writable: str = "[t1.sStop, t1.sJam, t1.sRate, t1.sDiv]", mqtt: str = "",
                plc: str = "", opcua: str = "") -> Path:
    """chart + plant (two instances, a sim driver, an ``mqtt:`` section) in ``tmp``."""
    plant = tmp / "plant.yaml"
    plant.write_text(
        plant_head(tmp, cycle, plc) +
        "mqtt:\n"
        f"  brokers: [{', '.join(brokers)}]\n"
        f"  group_id: {GROUP}\n  edge_node_id: {EDGE}\n"
        f"  sample: {sample}\n  feed: {tmp}/feed.sock\n  keepalive: 2s\n"
        f"  writable: {writable}\n" + mqtt + opcua,
        encoding="utf-8")
    return plant


def softplc(*args: str, cwd: Path, netns: str | None = None,
            log: Path | None = None) -> subprocess.Popen[str]:
    """``softplc ARGS`` as a process (in network namespace ``netns``); stderr to ``log``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(cwd)}
    env.pop("JOURNAL_STREAM", None)
    cmd = [sys.executable, "-m", "runtime.cli", *args]
    if netns is not None:
        cmd = ["ip", "netns", "exec", netns, *cmd]
    err = open(log, "w") if log is not None else subprocess.PIPE  # noqa: SIM115
    return subprocess.Popen(cmd, cwd=str(cwd), env=env, text=True, stdout=subprocess.PIPE,
                            stderr=err)


@contextmanager
def processes(*procs: subprocess.Popen[str]) -> Iterator[None]:
    """Ends every process (SIGTERM, then SIGKILL) whatever happens."""
    try:
        yield
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def topic(kind: str, device: str | None = None) -> str:
    return f"spBv1.0/{GROUP}/{kind}/{EDGE}" + (f"/{device}" if device else "")


def connect_ok(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1):
            return True
    except OSError:
        return False
