"""``softplc run`` and ``softplc mqtt`` as processes against Debian's mosquitto, seen by an
independent host application (pysparkplug, tests/mqtt/host): births, report by exception
with the scans' timestamps, every sequence number, commands (applied, refused, hostile),
rebirth, the controller stopping and coming back, TLS with a test CA and a password file,
broker fail-over, and the primary host's STATE."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from subprocess import Popen
from typing import Any

from runtime.mqtt.payload import Command, DataType, command_payload
from tests.mqtt.hostcheck import check
from tests.mqtt.kit import (
    EDGE,
    GROUP,
    Broker,
    Host,
    make_certs,
    processes,
    softplc,
    topic,
    wait_until,
    write_plant,
)
from tests.opcua.feedkit import FeedReader
from tests.opcua.kit import free_port


@dataclass
class Edge:
    tmp: Path
    broker: Broker
    host: Host
    ctl: Popen[str]
    mqtt: Popen[str]
    plant: Path

    def log(self) -> str:
        return (self.tmp / "mqtt.log").read_text()

    def alive(self) -> None:
        assert self.mqtt.poll() is None, self.log()
        assert self.ctl.poll() is None, (self.tmp / "ctl.log").read_text()

    def problems(self) -> list[str]:
        return [p for v in check(self.host.rows).values() for p in v.problems]


@contextmanager
def edge(tmp: Path, *, broker: Broker | None = None, host_user: tuple[str, str] | None = None,
         host_id: str = "softplc-test-host", brokers: list[str] | None = None,
         primary: bool = False, host_keepalive: int = 5, trace: bool = False,
         **plant: Any) -> Iterator[Edge]:
    """A broker, the host application, the controller on sim I/O (its trace in
    ``trace.jsonl`` with ``trace``) and its edge node."""
    b = broker or Broker(tmp)
    b.start()
    host = Host(b, user=host_user[0] if host_user else None,
                password=host_user[1] if host_user else None, host_id=host_id,
                primary=primary, keepalive=host_keepalive)
    path = write_plant(tmp, brokers or [b.url], **plant)
    ctl = softplc("run", str(path), "--sim", *(["--trace", str(tmp / "trace.jsonl")]
                                                if trace else []),
                  cwd=tmp, log=tmp / "ctl.log")
    mqtt = softplc("mqtt", str(path), cwd=tmp, log=tmp / "mqtt.log")
    try:
        with processes(ctl, mqtt):
            yield Edge(tmp, b, host, ctl, mqtt, path)
    finally:
        host.close()
        b.kill()


def births_seen(e: Edge, n: int = 1) -> None:
    e.host.wait(lambda rows: len([r for r in rows if r.get("kind") == "DBIRTH"]) >= 2 * n,
                30, f"{n} round(s) of births")


def test_births_reports_and_timestamps_seen_by_an_independent_host(tmp_path: Path) -> None:
    with edge(tmp_path) as e:
        births_seen(e)
        nb = e.host.of("NBIRTH")[0]
        assert nb["seq"] == 0 and nb["topic"] == f"spBv1.0/{GROUP}/NBIRTH/{EDGE}"
        node = {m["name"]: (m["datatype"], m["value"]) for m in nb["metrics"]}
        assert node["bdSeq"] == ("INT64", 0)
        assert node["Node Control/Rebirth"] == ("BOOLEAN", False)
        assert node["Controller/state"] == ("STRING", "running")
        assert node["Drivers/io/health"] == ("STRING", "ok")
        assert node["Controller/lateness_p99"][0] == "DOUBLE"
        dev = {m["name"]: m["datatype"] for m in e.host.of("DBIRTH", "t1")[0]["metrics"]}
        assert dev == {"Inputs/iGo": "BOOLEAN", "Outputs/oLamp": "BOOLEAN",
                       "Memory/sN": "INT64", "Memory/sStop": "BOOLEAN",
                       "Memory/sJam": "BOOLEAN", "Memory/sRate": "DOUBLE",
                       "Memory/sDiv": "INT64", "Memory/sQ": "INT64",
                       **{f"Flags/{f}": "BOOLEAN" for f in (
                           "SFCInit", "SFCReset", "SFCPause", "SFCError", "SFCEnableLimit",
                           "SFCQuitError", "SFCTipMode", "SFCTip")},
                       "Flags/SFCErrorStep": "STRING", "Flags/SFCCurrentStep": "STRING",
                       "Steps/gsA/X": "BOOLEAN", "Steps/gsB/X": "BOOLEAN",
                       "Steps/gsJam/X": "BOOLEAN", "Command/Result": "STRING"}
        # every report is stamped with the time of the scan that produced it: the feed's
        # frames (scan, wall) seen by a second client of the same feed
        frames = FeedReader(str(tmp_path / "feed.sock"))
        e.host.wait(lambda rows: len([r for r in rows if r["kind"] == "DDATA"]) >= 60, 30,
                    "60 reports")
        walls = {round(w * 1000): (s, vals) for s, w, vals in frames.frames}
        index = frames.state.index
        frames.close()
        checked = 0
        for r in e.host.of("DDATA", "t1"):
            if r["timestamp"] not in walls:
                continue  # before the second client connected
            _scan, vals = walls[r["timestamp"]]
            for m in r["metrics"]:
                assert m["timestamp"] == r["timestamp"]
                if m["name"] == "Memory/sN":
                    assert m["value"] == vals[index["t1.sN"]]
                    checked += 1
        assert checked >= 5, "no report matched a frame of the feed"
        assert e.problems() == []
        e.alive()


def test_commands_applied_refused_and_hostile(tmp_path: Path) -> None:
    with edge(tmp_path) as e:
        births_seen(e)
        t1 = topic("DCMD", "t1")
        e.host.command(t1, [("Memory/sStop", "BOOLEAN", True)])
        e.host.wait(lambda _r: e.host.latest("t1", "Memory/sStop") is True, 20, "sStop set")
        e.host.wait(lambda _r: "ok: t1.sStop set to 1" in str(
            e.host.latest("t1", "Command/Result")), 20, "the result published")
        assert "mqtt: set t1.sStop = 1" in (tmp_path / "ctl.log").read_text()
        # not writable: refused, logged and published; the output is the chart's
        e.host.command(t1, [("Outputs/oLamp", "BOOLEAN", True)])
        e.host.wait(lambda _r: "refused: t1: Outputs/oLamp is not writable" in str(
            e.host.latest("t1", "Command/Result")), 20, "the refusal published")
        assert e.log().count("DCMD to t1 refused: t1: Outputs/oLamp is not writable") == 1
        # hostile payloads: one log line each, nothing applied, the process alive
        before = e.log().count("refused")
        hostile = [
            (t1, b"\x00\xff garbage \xff" * 10,
             "DCMD to t1 refused: not a Sparkplug B payload"),
            (t1, command_payload(1, [Command(f"Memory/m{k}", None, DataType.BOOLEAN, False)
                                     for k in range(200_000)]), "bytes (at most 65536)"),
            (t1, command_payload(1, [Command("Memory/sStop", None, DataType.BOOLEAN, False)
                                     for _k in range(1000)]), "1000 metrics (at most 64)"),
            (t1, command_payload(1, [Command("Memory/sStop", None, DataType.STRING, "0")]),
             "Memory/sStop: expected a Boolean value, found str '0'"),
            (t1, command_payload(1, [Command("Memory/sStop", None, DataType.BOOLEAN, False),
                                     Command("Memory/sRate", None, DataType.BOOLEAN, True)]),
             "Memory/sRate: expected a Double value, found bool True"),
            (topic("DCMD", "t9"), command_payload(1, [Command("Memory/sStop", None,
                                                              DataType.BOOLEAN, False)]),
             "no device 't9'"),
            (topic("NCMD"), b"\x0a\x05 nope", "NCMD refused: no metric"),
            (topic("NCMD"), b"\xff" * 9, "NCMD refused: not a Sparkplug B payload"),
        ]
        for k, (where, data, words) in enumerate(hostile):
            acks, lines = e.host.acks, before + k + 1
            e.host.raw(where, data)  # one after the other: each one's line, in turn
            wait_until(lambda: e.host.acks > acks, 20, f"sent: {words}")  # noqa: B023
            wait_until(lambda: e.log().count("refused") >= lines, 20,  # noqa: B023
                       f"{words} in {e.log()[-600:]}")
        time.sleep(0.5)
        log = e.log()
        assert log.count("refused") == before + len(hostile), log
        for _where, _data, words in hostile:
            assert log.count(words) == 1, (words, log)
        n = len(e.host.rows)
        e.host.wait(lambda rows: len(rows) > n + 10, 20, "reports go on")
        assert e.host.latest("t1", "Memory/sStop") is True  # nothing applied
        assert e.problems() == []
        e.alive()


def test_rebirth_and_the_controller_stopping_and_coming_back(tmp_path: Path) -> None:
    with edge(tmp_path) as e:
        births_seen(e)
        e.host.command(topic("NCMD"), [("Node Control/Rebirth", "BOOLEAN", True)])
        e.host.wait(lambda _r: len(e.host.of("NBIRTH")) == 2, 20, "the rebirth")
        nb = e.host.of("NBIRTH")
        assert [r["seq"] for r in nb] == [0, 0]
        assert [m["value"] for r in nb for m in r["metrics"] if m["name"] == "bdSeq"] == [0, 0]
        births_seen(e, 2)
        # the controller stops: its devices die, the node says so, the node lives on
        e.ctl.send_signal(signal.SIGTERM)
        e.ctl.wait(timeout=20)
        e.host.wait(lambda _r: len(e.host.of("DDEATH")) == 2, 20, "the devices' deaths")
        e.host.wait(lambda _r: e.host.latest(None, "Controller/state") == "offline", 20)
        assert e.host.of("NDEATH") == []
        # it comes back: the devices are born again
        e.ctl = softplc("run", str(e.plant), "--sim", cwd=tmp_path, log=tmp_path / "ctl2.log")
        with processes(e.ctl):
            births_seen(e, 3)
            e.host.wait(lambda _r: e.host.latest(None, "Controller/state") == "running", 20)
            assert e.problems() == []
            assert e.mqtt.poll() is None


def test_tls_with_a_test_ca_a_client_certificate_and_a_password_file(tmp_path: Path) -> None:
    certs = make_certs(tmp_path / "pki")
    (tmp_path / "password").write_text("s3cret-pw\n")
    (tmp_path / "password").chmod(0o600)
    broker = Broker(tmp_path, certs=certs, users={"pi-07": "s3cret-pw", "scada": "scada-pw"},
                    require_certificate=True)
    tls = (f"  tls: {{ca: {certs.ca}, certificate: {certs.client_cert}, "
           f"private_key: {certs.client_key}}}\n")
    auth = f"  username: pi-07\n  password_file: {tmp_path}/password\n"
    # the host application shows no client certificate: only ours is asked for one
    broker.conf.write_text(broker.conf.read_text().replace("require_certificate true\n", ""))
    with edge(tmp_path, broker=broker, host_user=("scada", "scada-pw"),
              mqtt=tls + auth) as e:
        births_seen(e)
        assert "connected to mqtts://127.0.0.1" in e.log()
        assert e.problems() == []
    # a wrong password: refused by the broker, said in the log, no birth
    (tmp_path / "password").write_text("wrong\n")
    broker2 = Broker(tmp_path, certs=certs, users={"pi-07": "s3cret-pw"}, name="b2")
    with edge(tmp_path, broker=broker2, host_user=None, mqtt=tls + auth) as e:
        wait_until(lambda: "not authori" in e.log().lower(), 30, "the refusal in the log")
        assert e.host.of("NBIRTH") == []


def test_an_unknown_certificate_authority_is_refused(tmp_path: Path) -> None:
    certs = make_certs(tmp_path / "pki")
    other = make_certs(tmp_path / "other")
    broker = Broker(tmp_path, certs=certs)
    with edge(tmp_path, broker=broker, mqtt=f"  tls: {{ca: {other.ca}}}\n") as e:
        wait_until(lambda: "certificate verify failed" in e.log(), 30, "the refusal")
        assert e.host.of("NBIRTH") == []
        e.alive()


def test_fail_over_to_the_next_broker(tmp_path: Path) -> None:
    dead = f"mqtt://127.0.0.1:{free_port()}"
    broker = Broker(tmp_path)
    with edge(tmp_path, broker=broker, brokers=[dead, broker.url]) as e:
        births_seen(e)
        assert f"broker {dead}:" in e.log()
        assert f"connected to {broker.url}" in e.log()


def test_waiting_for_the_primary_host(tmp_path: Path) -> None:
    with edge(tmp_path, host_id="SCADA", mqtt="  primary_host: SCADA\n") as e:
        wait_until(lambda: "waiting for the primary host SCADA" in e.log(), 30)
        time.sleep(1.0)
        assert e.host.of("NBIRTH") == []  # connected, silent: the host is not online
        e.host.state(True)
        births_seen(e)
        assert [m["value"] for m in e.host.of("NBIRTH")[0]["metrics"]
                if m["name"] == "bdSeq"] == [0]
        e.host.state(False)  # the host goes offline: NDEATH, a new session, waiting again
        e.host.wait(lambda _r: len(e.host.of("NDEATH")) == 1, 20, "the NDEATH")
        wait_until(lambda: e.log().count("waiting for the primary host SCADA") == 2, 30)
        e.host.state(True)
        births_seen(e, 2)
        bd = [m["value"] for r in e.host.of("NBIRTH") for m in r["metrics"]
              if m["name"] == "bdSeq"]
        assert bd == [0, 1]
        assert [m["value"] for m in e.host.of("NDEATH")[0]["metrics"]] == [0]
        views = check(e.host.rows)
        assert views[(GROUP, EDGE)].deaths == 1 and e.problems() == []


TANK = """\
grafcet: Tank
description: Filling a tank
inputs:
  - iLevel: {type: int, description: 'level of the chart'}
outputs: [oPump]
memory:
  sMax: {init: 80, description: 'fill up to this level'}
steps:
  gsFill: {initial: true, actions: [oPump], description: 'Filling'}
transitions: []
"""


def test_the_births_carry_the_plants_io_list(tmp_path: Path) -> None:
    """A plant name's unit (engUnit), engineering range (engLow, engHigh) and description,
    from the plant's I/O list (issue 29: one home, every reader), read by the host with
    pysparkplug's own generated module; a TIME value's unit is ms."""
    (tmp_path / "tank.yaml").write_text(TANK, encoding="utf-8")
    b = Broker(tmp_path)
    b.start()
    host = Host(b)
    plant = tmp_path / "plant.yaml"
    plant.write_text(
        "plc: {cycle: 10ms, watchdog: 5s}\n"
        "drivers:\n  io: {type: sim}\n"
        "instances:\n"
        "  t1:\n    grafcet: tank.yaml\n    description: Depósito 1\n"
        "    inputs:\n      iLevel: {from: io.IR0, unit: cm, range: [0, 250], "
        "description: 'Sonda de nivel LT1'}\n"
        "    outputs:\n      oPump: {from: io.Q0, description: 'Bomba de llenado QM1'}\n"
        "mqtt:\n"
        f"  brokers: [{b.url}]\n  group_id: {GROUP}\n  edge_node_id: {EDGE}\n"
        f"  feed: {tmp_path}/feed.sock\n  keepalive: 2s\n"
        "  publish: [inputs, outputs, memory, steps, step_times, points]\n",
        encoding="utf-8")
    ctl = softplc("run", str(plant), "--sim", cwd=tmp_path, log=tmp_path / "ctl.log")
    mqtt = softplc("mqtt", str(plant), cwd=tmp_path, log=tmp_path / "mqtt.log")
    try:
        with processes(ctl, mqtt):
            host.wait(lambda _r: bool(host.of("DBIRTH", "t1")), 30, "the DBIRTH of t1")
            dev = {m["name"]: m.get("properties") for m in host.of("DBIRTH", "t1")[0]["metrics"]}
            node = {m["name"]: m.get("properties") for m in host.of("NBIRTH")[0]["metrics"]}
    finally:
        host.close()
        b.kill()
    assert dev["Inputs/iLevel"] == {"engUnit": "cm", "engLow": 0.0, "engHigh": 250.0,
                                    "description": "Sonda de nivel LT1"}, dev
    assert dev["Outputs/oPump"] == {"description": "Bomba de llenado QM1"}, dev
    assert dev["Memory/sMax"] == {"description": "fill up to this level"}, dev
    assert dev["Steps/gsFill/T"]["engUnit"] == "ms", dev
    assert dev["Steps/gsFill/X"]["description"].startswith("Filling"), dev
    # the module's point, with the signal it carries
    assert node["Drivers/io/Inputs/IR0"]["engUnit"] == "cm", node
    assert "Sonda de nivel LT1" in node["Drivers/io/Inputs/IR0"]["description"], node
