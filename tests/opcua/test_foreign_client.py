"""A client not built on asyncua against a running plant: node-opcua (a separate
implementation, TypeScript on Node.js) browses, reads and subscribes to `softplc opcua`
fed by `softplc run --sim`, and every published value is compared with the controller's
trace of the same run; then its writes, as an anonymous reader and as a trusted
SignAndEncrypt client. scripts/test.sh installs it (`npm ci` in tests/opcua/node)."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from runtime.controller.pin import hash_pin
from runtime.opcua import security
from tests.opcua.kit import CHART, free_port, wait_serving, write_plant
from tests.opcua.nodekit import NEEDS_NODE, NODE_DIR
from tests.opcua.seckit import Certs, make_certs

ROOT = Path(__file__).resolve().parents[2]
#: how long a start or a client run may take on a loaded machine, s
DEADLINE_S = 90.0
#: how long the foreign client stays subscribed, s
SUBSCRIBED_S = 3.0
#: the variables subscribed to and compared with the trace (the controller's scan first)
WATCHED = ["controller.scan", "t1.sN", "t1.gsB.X", "t1.oLamp", "t1.sStop", "t2.sN",
           "t2.gsA.X"]

pytestmark = NEEDS_NODE


@dataclass
class Running:
    """A plant run by `softplc run --sim --trace` and served by `softplc opcua`."""

    tmp: Path
    url: str
    run: subprocess.Popen[bytes]
    opcua: subprocess.Popen[bytes]

    def trace(self) -> dict[int, dict[str, Any]]:
        """The trace's lines by scan number (the controller stopped first: all flushed)."""
        out: dict[int, dict[str, Any]] = {}
        for line in (self.tmp / "trace.jsonl").read_text(encoding="utf-8").splitlines():
            row = json.loads(line)
            out[int(row["cycle"])] = row
        return out

    def stop_controller(self) -> None:
        if self.run.poll() is None:
            self.run.send_signal(signal.SIGTERM)
            self.run.wait(DEADLINE_S)


def softplc(*args: str, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as f:
        return subprocess.Popen([sys.executable, "-m", "runtime.cli", *args], cwd=ROOT,
                                stdout=f, stderr=subprocess.STDOUT)


def start(tmp: Path, security_yaml: str) -> Running:
    port = free_port()
    plant = write_plant(tmp, port=port, cycle="10ms", sample="50ms")
    text = re.sub(r"^  security:.*\n", lambda m: security_yaml,
                  plant.read_text(encoding="utf-8"), count=1, flags=re.M)
    assert security_yaml in text
    plant.write_text(text, encoding="utf-8")
    run = softplc("run", "--sim", str(plant), "--trace", str(tmp / "trace.jsonl"),
                  "--for", "120s", log=tmp / "run.log")
    opcua = softplc("opcua", str(plant), log=tmp / "opcua.log")
    return Running(tmp, f"opc.tcp://127.0.0.1:{port}", run, opcua)


def stop(r: Running) -> None:
    for p in (r.opcua, r.run):
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in (r.opcua, r.run):
        try:
            p.wait(DEADLINE_S)
        except subprocess.TimeoutExpired:
            p.kill()


@pytest.fixture(scope="module")
def open_plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Running]:
    """Policy None listed, anonymous read, one user."""
    tmp = tmp_path_factory.mktemp("foreign-none")
    users = {"operator": hash_pin("right-pass", n=16, r=1, p=1)}
    r = start(tmp, "  security:\n    policies: [None]\n"
                   f"    users: {{operator: '{users['operator']}'}}\n")
    try:
        asyncio.run(wait_serving(r.url, time.monotonic() + DEADLINE_S))
        yield r
    finally:
        stop(r)


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Certs:
    return make_certs(tmp_path_factory.mktemp("pki"))


@pytest.fixture(scope="module")
def secure_plant(tmp_path_factory: pytest.TempPathFactory, certs: Certs) -> Iterator[Running]:
    """The default policy (Basic256Sha256 SignAndEncrypt only), a trusted client."""
    tmp = tmp_path_factory.mktemp("foreign-secure")
    r = start(tmp, "  security:\n    policies: [Basic256Sha256_SignAndEncrypt]\n"
                   f"    certificate: {certs.server_cert}\n"
                   f"    private_key: {certs.server_key}\n"
                   f"    trusted_clients: {certs.trusted_dir}\n")
    try:
        # the probe has no certificate: wait on the feed's first frame through the log
        deadline = time.monotonic() + DEADLINE_S
        while b"address space:" not in (tmp / "opcua.log").read_bytes():
            assert time.monotonic() < deadline, (tmp / "opcua.log").read_text()
            assert r.opcua.poll() is None, (tmp / "opcua.log").read_text()
            time.sleep(0.1)
        yield r
    finally:
        stop(r)


def foreign(cfg: dict[str, Any], pki: Path) -> list[dict[str, Any]]:
    """Run the node-opcua client with ``cfg``; its JSON lines (the last one is
    ``{"done": true}`` or ``{"error": ...}``)."""
    cfg = {"pki": str(pki), **cfg}
    proc = subprocess.run(["node", str(NODE_DIR / "client.js"), json.dumps(cfg)],
                          cwd=NODE_DIR, capture_output=True, timeout=DEADLINE_S,
                          env={**os.environ, "NODE_NO_WARNINGS": "1"})
    lines = [json.loads(x) for x in proc.stdout.decode().splitlines() if x.startswith("{")]
    assert lines, proc.stderr.decode()[-2000:]
    return lines


def nid(name: str) -> str:
    return f"ns=2;s={name}"


def test_node_opcua_anonymous_write_is_denied_user_write_applied(open_plant: Running,
                                                                 tmp_path: Path) -> None:
    """sRate: a memory variable the chart does not use (the trace test runs after)."""
    out = foreign({"endpoint": open_plant.url, "mode": "None",
                   "write": {"nodeId": nid("t1.sRate"), "value": 2.5, "type": "Double"}},
                  tmp_path / "a")
    assert [o["status"] for o in out if "write" in o] == ["BadUserAccessDenied"]
    out = foreign({"endpoint": open_plant.url, "mode": "None", "user": "operator",
                   "password": "right-pass",
                   "write": {"nodeId": nid("t1.sRate"), "value": 2.5, "type": "Double"}},
                  tmp_path / "b")
    assert [o["status"] for o in out if "write" in o] == ["Good"], out
    out = foreign({"endpoint": open_plant.url, "mode": "None", "user": "operator",
                   "password": "wrong-pass", "read": [nid("t1.sRate")]}, tmp_path / "c")
    assert "error" in out[-1] and not any("read" in o for o in out), out


def test_node_opcua_browses_reads_and_sees_the_trace(open_plant: Running,
                                                     tmp_path: Path) -> None:
    out = foreign({"endpoint": open_plant.url, "mode": "None",
                   "browse": ["ns=0;i=85", nid("t1"), nid("t1/Memory"), nid("t1/Steps")],
                   "read": [nid("t1.sRate"), nid("t1.sStop"), nid("t1.gsB.T"),
                            nid("controller.cycle")],
                   "subscribe": [nid(n) for n in WATCHED], "seconds": SUBSCRIBED_S},
                  tmp_path / "pki")
    assert out[-1] == {"done": True}, out[-1]
    open_plant.stop_controller()
    trace = open_plant.trace()

    browse = {b["browse"]: dict(b["children"]) for b in out if "browse" in b}
    objects = browse["ns=0;i=85"]
    assert {k: objects[k] for k in ("t1", "t2", "io", "Controller")} == {
        "t1": nid("t1"), "t2": nid("t2"), "io": nid("driver.io"),
        "Controller": nid("controller")}
    assert set(browse[nid("t1")]) == {"Inputs", "Outputs", "Memory", "Steps", "Flags", "Alarms",
                                      "Acknowledge", "Reset", "Pause", "Resume"}
    chart = yaml.safe_load(CHART)
    assert browse[nid("t1/Memory")] == {n: nid(f"t1.{n}") for n in chart["memory"]}
    assert set(browse[nid("t1/Steps")]) == set(chart["steps"])

    reads = {r["read"]: r for r in out if "read" in r}
    # 2.5: written by the user in the test before
    assert (reads[nid("t1.sRate")]["value"], reads[nid("t1.sRate")]["type"]) == (2.5, "Double")
    assert (reads[nid("t1.sStop")]["value"], reads[nid("t1.sStop")]["type"]) == (False,
                                                                                 "Boolean")
    assert reads[nid("t1.gsB.T")]["type"] == "Double"  # Duration, ms
    assert reads[nid("controller.cycle")]["value"] == 10.0

    handles = next(o["handles"] for o in out if "handles" in o)
    state: dict[str, Any] = {}
    compared: list[int] = []
    for pub in (o for o in out if "publish" in o):
        for handle, value, _source_ms, status in pub["items"]:
            state[handles[str(handle)].removeprefix("ns=2;s=")] = (value, status)
        if any(status != "Good" for _, status in state.values()):
            continue
        if len(state) < len(WATCHED):
            continue
        scan = int(state["controller.scan"][0])
        row = trace[scan]
        seen = {n: state[n][0] for n in WATCHED[1:]}
        expected = {n: (bool(row[n]) if isinstance(seen[n], bool) else row[n])
                    for n in WATCHED[1:]}
        assert seen == expected, f"publish {pub['publish']} (scan {scan})"
        compared.append(scan)
    # a comparison that could not fail would prove nothing: many publishes, scans moving,
    # and values that changed during them
    assert len(compared) >= 10, compared
    assert compared == sorted(compared) and compared[-1] > compared[0]
    assert len({trace[s]["t1.sN"] for s in compared}) >= 3


def test_node_opcua_trusted_signandencrypt_client_writes(secure_plant: Running,
                                                         certs: Certs,
                                                         tmp_path: Path) -> None:
    cfg = {"endpoint": secure_plant.url, "mode": "SignAndEncrypt",
           "cert": certs.client_cert, "key": certs.client_key,
           "applicationUri": security.CLIENT_URI, "serverCert": certs.server_cert}
    out = foreign({**cfg, "write": {"nodeId": nid("t1.sStop"), "value": True},
                   "read": [nid("t1.sRate")]}, tmp_path / "pki")
    assert out[-1] == {"done": True}, out
    assert [o["status"] for o in out if "write" in o] == ["Good"]
    secure_plant.stop_controller()
    # the write was applied between two scans: the trace shows it
    assert any(row["t1.sStop"] == 1 for row in secure_plant.trace().values())


def test_node_opcua_untrusted_client_is_refused(secure_plant: Running, certs: Certs,
                                                tmp_path: Path) -> None:
    out = foreign({"endpoint": secure_plant.url, "mode": "SignAndEncrypt",
                   "cert": certs.stranger_cert, "key": certs.stranger_key,
                   "applicationUri": security.CLIENT_URI, "serverCert": certs.server_cert,
                   "read": [nid("t1.sRate")]}, tmp_path / "pki")
    assert "error" in out[-1] and not any("read" in o for o in out), out
