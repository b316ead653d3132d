"""The ``mqtt:`` section of a plant file: defaults, every key checked at its position
(FILE:LINE:COL), writable and published names checked against the plant, one feed per
plant, and ``softplc mqtt`` without the section."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from runtime.errors import SourceError
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import plant_key
from tests.mqtt.kit import write_plant

BASE = "mqtt:\n  brokers: [mqtt://127.0.0.1:1883]\n  group_id: Bench\n"


def plant_with(tmp_path: Path, mqtt: str, cycle: str = "10ms", extra: str = "") -> Path:
    path = write_plant(tmp_path, ["mqtt://127.0.0.1:1883"], cycle=cycle)
    text = path.read_text(encoding="utf-8")
    path.write_text(text[:text.index("mqtt:")] + extra + mqtt, encoding="utf-8")
    return path


def error_of(tmp_path: Path, mqtt: str, extra: str = "") -> SourceError:
    with pytest.raises(SourceError) as e:
        load_plant(str(plant_with(tmp_path, mqtt, extra=extra)))
    return e.value


def test_defaults(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    pdef = load_plant(str(plant_with(tmp_path, BASE)))
    q = pdef.mqtt
    assert q is not None
    assert [(b.host, b.port, b.tls) for b in q.brokers] == [("127.0.0.1", 1883, False)]
    assert q.edge_node_id == socket.gethostname()
    assert q.client_id == f"softplc-Bench-{socket.gethostname()}"
    assert q.publish == ["outputs", "inputs", "steps", "memory", "flags", "controller",
                         "drivers"]
    assert q.writable == [] and q.username is None and q.tls is None
    assert (q.sample_ns, q.statistics_ns, q.keepalive_ns, q.buffer) == (
        100_000_000, 10_000_000_000, 30_000_000_000, 100_000)
    # the plant's own runtime directory (docs/daemon.md): never another plant's feed
    assert q.feed == str(tmp_path / "softplc" / plant_key(pdef.path) / "feed.sock")
    feed = pdef.feed()
    assert feed is not None and feed.path == q.feed and feed.writable == {"mqtt": []}


def test_brokers_in_order_with_default_ports(tmp_path: Path) -> None:
    pdef = load_plant(str(plant_with(tmp_path, "mqtt:\n  brokers: [mqtts://b1.plant, "
                                                "'mqtt://[::1]:1884', mqtt://b3:2000]\n"
                                                "  group_id: G\n  edge_node_id: e1\n")))
    assert pdef.mqtt is not None
    assert [(b.host, b.port, b.tls) for b in pdef.mqtt.brokers] == [
        ("b1.plant", 8883, True), ("::1", 1884, False), ("b3", 2000, False)]


@pytest.mark.parametrize(("mqtt", "line", "col", "words"), [
    ("mqtt:\n  group_id: G\n", 14, 3, "expected brokers"),
    ("mqtt:\n  brokers: [http://x]\n  group_id: G\n", 14, 13,
     "expected mqtt://HOST:PORT or mqtts://HOST:PORT (TLS), found 'http://x'"),
    ("mqtt:\n  brokers: mqtt://x:70000\n  group_id: G\n", 14, 12, "found 'mqtt://x:70000'"),
    ("mqtt:\n  brokers: []\n  group_id: G\n", 14, 12, "at least one broker"),
    ("mqtt:\n  brokers: [mqtt://x]\n", 14, 3, "expected group_id"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: a/b\n", 15, 13,
     "may not hold '+', '#', '/' or spaces"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  edge_node_id: 'pi #7'\n", 16, 18,
     "holds ' '"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  password: secret\n", 16, 3,
     "a password is never written in the plant file"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  password_file: /p\n", 16, 3,
     "password_file without username"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  tls: {ca: /ca.pem}\n", 16, 3,
     "no broker is mqtts://"),
    ("mqtt:\n  brokers: [mqtts://x]\n  group_id: G\n  tls: {certificate: /c.pem}\n", 16, 8,
     "certificate and private_key go together"),
    ("mqtt:\n  brokers: [mqtts://x]\n  group_id: G\n  tls: {cert: /c.pem}\n", 16, 9,
     "unknown key 'cert' in mqtt tls"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  publish: [outputz]\n", 16, 13,
     "unknown group 'outputz'"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  publish: [t1.sNN]\n", 16, 13,
     "t1 has no variable or step 'sNN'"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  writable: [t1.oLamp]\n", 16, 14,
     "mqtt writable: 't1.oLamp' is an output"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  writable: [io.Q0]\n", 16, 14,
     "physical points are never written over MQTT"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  sample: 5ms\n", 16, 11,
     "mqtt sample must be at least the cycle (10 ms)"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  keepalive: 1500ms\n", 16, 14,
     "whole seconds"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  statistics: 100ms\n", 16, 15,
     "at least 1s"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  buffer: -1\n", 16, 11,
     "expected 0 (no store and forward)"),
    ("mqtt:\n  brokers: [mqtt://x]\n  group_id: G\n  brokres: []\n", 16, 3,
     "unknown key 'brokres' in mqtt"),
])
def test_errors_at_their_place(tmp_path: Path, mqtt: str, line: int, col: int,
                               words: str) -> None:
    e = error_of(tmp_path, mqtt)
    assert e.loc.file.endswith("plant.yaml")
    assert (e.loc.line, e.loc.col) == (line, col), e
    assert words in e.message, e.message


def test_one_feed_per_plant(tmp_path: Path) -> None:
    opcua = "opcua:\n  feed: /run/a.sock\n  security: {policies: [None]}\n"
    e = error_of(tmp_path, BASE + "  feed: /run/b.sock\n", extra=opcua)
    assert (e.loc.line, e.loc.col) == (19, 9)
    assert "a plant has one feed, and opcua feed names /run/a.sock" in e.message
    # named once: both sections use it; the feed serves both sides' writable names
    pdef = load_plant(str(plant_with(tmp_path, BASE + "  writable: [t1.sStop]\n",
                                     extra=opcua)))
    assert pdef.mqtt is not None and pdef.opcua is not None
    assert pdef.mqtt.feed == pdef.opcua.feed == "/run/a.sock"
    feed = pdef.feed()
    assert feed is not None
    assert feed.writable == {"opcua": [], "mqtt": ["t1.sStop"]}
    assert feed.sample_ns == 50_000_000  # the faster of the two (opcua's 50 ms)


def test_softplc_mqtt_needs_the_section(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    from runtime.cli import main

    path = plant_with(tmp_path, "")
    assert main(["mqtt", str(path)]) == 2
    assert capsys.readouterr().err == (f"{path}:1:1: error: no 'mqtt:' section: add one to "
                                       "publish this plant over MQTT (docs/mqtt.md)\n")


def test_softplc_mqtt_names_a_missing_file(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    from runtime.cli import main

    path = plant_with(tmp_path, "mqtt:\n  brokers: [mqtts://127.0.0.1:1]\n  group_id: G\n"
                                f"  tls: {{ca: {tmp_path}/nope.pem}}\n")
    assert main(["mqtt", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("softplc mqtt: error: ") and "No such file" in err, err
    assert err.count("\n") == 1
