"""Test parts for the OPC UA tests: a chart that changes by itself, its plant with an
``opcua:`` section, free ports, and a polling helper."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from asyncua import Client, ua

from runtime.controller.pin import hash_pin

#: the user the writing tests log in as (runtime/opcua/security.py: anonymous sessions
#: read only); a cheap hash, the cost is tested in tests/console/test_console_pin.py
WRITER, WRITER_PASSWORD = "tester", "tester-pass"
WRITER_HASH = hash_pin(WRITER_PASSWORD, n=16, r=1, p=1)
ROOT = Path(__file__).resolve().parents[2]


def writer(url: str) -> Client:
    """An asyncua client that logs in as :data:`WRITER` (may write the writable names)."""
    client = Client(url)
    client.set_user(WRITER)
    client.set_password(WRITER_PASSWORD)
    return client

CHART = """\
grafcet: Blink
description: A blinker that jams on request (OPC UA tests)
inputs: [iGo]
outputs: [oLamp]
memory:
  sN: 0
  sStop: false
  sJam: false
  sRate: 1.5
  sDiv: 1
  sQ: 0
steps:
  gsA: {initial: true}
  gsB: {actions: [oLamp, "P1 sN := sN + 1"]}
  gsJam: {max: 50ms}
transitions:
  - {from: gsA, to: gsJam, when: sJam}
  - {from: gsA, to: gsB, when: "(gsA.T >= 40ms) · sStop'"}
  - {from: gsB, to: gsA, when: "gsB.T >= 40ms"}
  - {from: gsJam, to: gsA, when: "sJam'"}
post:
  - sQ := 100 / sDiv
"""


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def plant_head(tmp: Path, cycle: str = "10ms", plc: str = "", watchdog: str = "5s") -> str:
    """The chart written in ``tmp``, and the plant file's text before its side process
    section: two instances of it on a sim driver."""
    (tmp / "blink.yaml").write_text(CHART, encoding="utf-8")
    return (f"plc: {{cycle: {cycle}, watchdog: {watchdog}{plc}}}\n"
            "drivers:\n  io: {type: sim}\n"
            "instances:\n"
            "  t1:\n    grafcet: blink.yaml\n    inputs: {iGo: io.I0}\n"
            "    outputs: {oLamp: io.Q0}\n"
            "  t2:\n    grafcet: blink.yaml\n    inputs: {iGo: io.I1}\n"
            "    outputs: {oLamp: io.Q1}\n")


def write_plant(tmp: Path, *, port: int, cycle: str = "10ms", sample: str = "50ms",
                writable: str = "[t1.sStop, t1.sJam, t1.sRate, t1.sDiv, t1.SFCQuitError]",
                extra: str = "", plc: str = "", watchdog: str = "5s") -> Path:
    """chart + plant (two instances, a sim driver) in ``tmp``; the plant's path."""
    plant = tmp / "plant.yaml"
    plant.write_text(
        plant_head(tmp, cycle, plc, watchdog) +
        "opcua:\n"
        f"  endpoint: opc.tcp://127.0.0.1:{port}\n"
        f"  sample: {sample}\n"
        f"  feed: {tmp}/feed.sock\n"
        f"  writable: {writable}\n"
        f"  security: {{policies: [None], users: {{{WRITER}: '{WRITER_HASH}'}}}}\n" + extra,
        encoding="utf-8")
    return plant


def softplc(*args: str, cwd: Path, log: Path | None = None) -> subprocess.Popen[bytes]:
    """``softplc ARGS`` as a process of its own (this tree's code), its runtime directory
    ``cwd``; its output into ``log`` (else discarded)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(cwd)}
    env.pop("JOURNAL_STREAM", None)
    out = open(log, "wb") if log is not None else subprocess.DEVNULL  # noqa: SIM115
    try:
        return subprocess.Popen([sys.executable, "-m", "runtime.cli", *args], cwd=str(cwd),
                                env=env, stdout=out, stderr=subprocess.STDOUT)
    finally:
        if log is not None:
            out.close()  # type: ignore[union-attr]


def end(*procs: subprocess.Popen[bytes] | None, timeout: float = 30.0) -> None:
    """SIGTERM each process still running (SIGCONT first: it may be stopped), wait, and
    SIGKILL one that does not end in ``timeout`` s."""
    for p in procs:
        if p is not None and p.poll() is None:
            p.send_signal(signal.SIGCONT)
            p.send_signal(signal.SIGTERM)
    for p in procs:
        if p is None:
            continue
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


async def variables(client: Client) -> list[str]:
    """Every Variable NodeId of namespace 2 (the plant's), browsed from Objects, sorted."""
    found: list[str] = []
    todo = [client.nodes.objects]
    while todo:
        node = todo.pop()
        for child in await node.get_children():
            if child.nodeid.NamespaceIndex != 2:
                continue
            if await child.read_node_class() == ua.NodeClass.Variable:
                found.append(child.nodeid.to_string())
            else:
                todo.append(child)
    return sorted(set(found))


async def wait_serving(url: str, deadline: float) -> None:
    """Until the server answers with a good controller.scan (the first frame arrived);
    TimeoutError at ``deadline`` (monotonic seconds)."""
    while True:
        try:
            async with Client(url, timeout=5) as c:
                dv = await c.get_node("ns=2;s=controller.scan").read_data_value(
                    raise_on_bad_status=False)
                if dv.StatusCode.is_good():
                    return
        except (OSError, TimeoutError):
            pass
        if time.monotonic() > deadline:
            raise TimeoutError(f"{url}: no good value before the deadline")
        await asyncio.sleep(0.2)


DRAWER = ROOT / "configs" / "drawer_tester"


def drawer_plant(tmp: Path, extra: str = "") -> Path:
    """configs/drawer_tester/plant_sim.yaml as shipped (its I/O list in Spanish), with an
    ``opcua:`` section (policy None, the writer :data:`WRITER`; tester1.sParo writable)
    and ``extra`` at the end; its chart named by its path, its retain file in ``tmp``, no
    console."""
    text = (DRAWER / "plant_sim.yaml").read_text(encoding="utf-8")
    text = text.replace("grafcet: drawer_tester.yaml",
                        f"grafcet: {DRAWER / 'drawer_tester.yaml'}")
    text = text.replace("${RUNTIME_DIR}/drawer_tester_sim.retain.json",
                        str(tmp / "retain.json"))
    text = text[:text.index("monitor:")]
    path = tmp / "plant.yaml"
    path.write_text(text + (
        f"opcua:\n  endpoint: opc.tcp://127.0.0.1:{free_port()}\n  feed: {tmp}/feed.sock\n"
        "  writable: [tester1.sParo]\n"
        f"  security: {{policies: [None], users: {{{WRITER}: '{WRITER_HASH}'}}}}\n") + extra,
        encoding="utf-8")
    return path
