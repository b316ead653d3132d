"""Test parts for the OPC UA tests: a chart that changes by itself, its plant with an
``opcua:`` section, free ports, and a polling helper."""

from __future__ import annotations

import socket
from pathlib import Path

from asyncua import Client

from runtime.controller.pin import hash_pin

#: the user the writing tests log in as (runtime/opcua/security.py: anonymous sessions
#: read only); a cheap hash, the cost is tested in tests/console/test_console_pin.py
WRITER, WRITER_PASSWORD = "tester", "tester-pass"
WRITER_HASH = hash_pin(WRITER_PASSWORD, n=16, r=1, p=1)


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


def plant_head(tmp: Path, cycle: str = "10ms", plc: str = "") -> str:
    """The chart written in ``tmp``, and the plant file's text before its side process
    section: two instances of it on a sim driver."""
    (tmp / "blink.yaml").write_text(CHART, encoding="utf-8")
    return (f"plc: {{cycle: {cycle}, watchdog: 5s{plc}}}\n"
            "drivers:\n  io: {type: sim}\n"
            "instances:\n"
            "  t1:\n    grafcet: blink.yaml\n    inputs: {iGo: io.I0}\n"
            "    outputs: {oLamp: io.Q0}\n"
            "  t2:\n    grafcet: blink.yaml\n    inputs: {iGo: io.I1}\n"
            "    outputs: {oLamp: io.Q1}\n")


def write_plant(tmp: Path, *, port: int, cycle: str = "10ms", sample: str = "50ms",
                writable: str = "[t1.sStop, t1.sJam, t1.sRate, t1.sDiv, t1.SFCQuitError]",
                extra: str = "", plc: str = "") -> Path:
    """chart + plant (two instances, a sim driver) in ``tmp``; the plant's path."""
    plant = tmp / "plant.yaml"
    plant.write_text(
        plant_head(tmp, cycle, plc) +
        "opcua:\n"
        f"  endpoint: opc.tcp://127.0.0.1:{port}\n"
        f"  sample: {sample}\n"
        f"  feed: {tmp}/feed.sock\n"
        f"  writable: {writable}\n"
        f"  security: {{policies: [None], users: {{{WRITER}: '{WRITER_HASH}'}}}}\n" + extra,
        encoding="utf-8")
    return plant
