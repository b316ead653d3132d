"""The ``opcua:`` section of a plant file: defaults, every key checked at its position
(FILE:LINE:COL), writable names checked against the plant, and the JSON Schema agreeing."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from runtime.errors import SourceError
from runtime.language.plantfile import load_plant
from runtime.language.yamlsrc import load_yaml
from tests.opcua.kit import write_plant

ROOT = Path(__file__).resolve().parents[2]


def plant_with(tmp_path: Path, opcua: str, cycle: str = "10ms") -> Path:
    path = write_plant(tmp_path, port=4840, cycle=cycle)
    text = path.read_text(encoding="utf-8")
    path.write_text(text[:text.index("opcua:")] + opcua, encoding="utf-8")
    return path


def error_of(tmp_path: Path, opcua: str, cycle: str = "10ms") -> SourceError:
    path = plant_with(tmp_path, opcua, cycle)
    with pytest.raises(SourceError) as e:
        load_plant(str(path))
    return e.value


def test_defaults(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    pdef = load_plant(str(plant_with(tmp_path, "opcua: {}\n")))
    o = pdef.opcua
    assert o is not None
    assert o.endpoint == "opc.tcp://127.0.0.1:4840"
    assert o.sample_ns == 50_000_000
    assert o.feed.endswith("/feed.sock") and "${" not in o.feed
    assert o.writable == []
    assert o.security.policies == ["Basic256Sha256_SignAndEncrypt"]
    assert o.security.anonymous == "read"


def test_no_section_no_server(tmp_path: Path) -> None:
    path = write_plant(tmp_path, port=4840)
    text = path.read_text(encoding="utf-8")
    path.write_text(text[:text.index("opcua:")], encoding="utf-8")
    assert load_plant(str(path)).opcua is None


def test_sample_never_below_the_cycle(tmp_path: Path) -> None:
    pdef = load_plant(str(plant_with(tmp_path, "opcua: {}\n", cycle="100ms")))
    assert pdef.opcua is not None and pdef.opcua.sample_ns == 100_000_000
    e = error_of(tmp_path, "opcua:\n  sample: 5ms\n")
    assert (e.loc.line, e.loc.col) == (14, 11)
    assert "opcua sample must be at least the cycle (10 ms)" in e.message


def test_the_full_section(tmp_path: Path) -> None:
    etc = tmp_path / "etc"  # what the section names is there (a missing file is refused)
    (etc / "t").mkdir(parents=True)
    (etc / "r").mkdir()
    (etc / "c.der").write_bytes(b"x")
    (etc / "k.pem").write_bytes(b"x")
    pdef = load_plant(str(plant_with(tmp_path, (
        "opcua:\n  endpoint: opc.tcp://0.0.0.0:4841\n  sample: 100ms\n"
        "  feed: /tmp/x/feed.sock\n  writable: [t1.sStop, t2.SFCQuitError, t1.sStop]\n"
        "  security:\n    policies: [None, Basic256Sha256_SignAndEncrypt]\n"
        f"    certificate: {etc}/c.der\n    private_key: {etc}/k.pem\n"
        f"    trusted_clients: {etc}/t\n    trusted_readers: etc/r\n    anonymous: none\n"
        "    users: {operator: 'scrypt$16384$8$1$c2FsdA$aGFzaA'}\n"))))
    o = pdef.opcua
    assert o is not None
    assert (o.endpoint, o.sample_ns, o.feed) == ("opc.tcp://0.0.0.0:4841", 100_000_000,
                                                 "/tmp/x/feed.sock")
    assert o.writable == ["t1.sStop", "t2.SFCQuitError"]
    s = o.security
    assert s.policies == ["None", "Basic256Sha256_SignAndEncrypt"]
    assert (s.certificate, s.private_key, s.trusted_clients, s.trusted_readers,
            s.anonymous) == (f"{etc}/c.der", f"{etc}/k.pem", f"{etc}/t",
                             f"{etc}/r", "none")  # relative: from the plant file's directory
    assert list(s.users) == ["operator"]
    assert o.limits.sessions == 10  # the defaults


def test_the_limits(tmp_path: Path) -> None:
    pdef = load_plant(str(plant_with(tmp_path, (
        "opcua:\n  limits: {sessions: 3, subscriptions: 2, items: 100, items_total: 250,\n"
        "           session_timeout: 30s, abandoned: 5s, publish_rate: 10,\n"
        "           publish_rate_total: 25.5}\n"))))
    assert pdef.opcua is not None
    lim = pdef.opcua.limits
    assert (lim.sessions, lim.subscriptions, lim.items, lim.items_total,
            lim.session_timeout_ns, lim.abandoned_ns) == (3, 2, 100, 250, 30 * 10**9,
                                                          5 * 10**9)
    assert (lim.publish_rate, lim.publish_rate_total) == (10.0, 25.5)


@pytest.mark.parametrize(("writable", "col", "words"), [
    ("[t1.sStop, t1.oLamp]", 24, "'t1.oLamp' is an output, written by the chart every scan"),
    ("[t1.iGo]", 14, "'t1.iGo' is an input, copied from its binding before every scan"),
    ("[io.Q0]", 14, "'io.Q0' is a driver point: physical points are never written"),
    ("[t1.sStp]", 14, "'t1.sStp': t1 has no variable 'sStp' (did you mean 'sStop'?)"),
    ("[t3.sStop]", 14, "unknown instance in 't3.sStop'"),
    ("[t1.SFCErrorStep]", 14, "'t1.SFCErrorStep' is a string chart flag, read-only"),
    ("[t1]", 14, "unknown instance in 't1': expected instance.variable"),
])
def test_writable_names_are_checked(tmp_path: Path, writable: str, col: int,
                                    words: str) -> None:
    e = error_of(tmp_path, f"opcua:\n  writable: {writable}\n")
    assert (e.loc.line, e.loc.col) == (14, col), e
    assert f"opcua writable: {words}" in e.message


def test_a_chart_flag_bound_to_a_point_is_not_writable(tmp_path: Path) -> None:
    path = plant_with(tmp_path, "opcua:\n  writable: [t1.SFCReset]\n")
    text = path.read_text(encoding="utf-8").replace("inputs: {iGo: io.I0}",
                                                    "inputs: {iGo: io.I0, SFCReset: io.I5}")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SourceError, match="'t1.SFCReset' is bound to io.I5, which sets it"):
        load_plant(str(path))


@pytest.mark.parametrize(("opcua", "line", "col", "words"), [
    ("opcua:\n  endpoint: http://x:80\n", 14, 13, "expected opc.tcp://HOST:PORT"),
    ("opcua:\n  endpoint: opc.tcp://h:70000\n", 14, 13, "expected opc.tcp://HOST:PORT"),
    ("opcua:\n  port: 4840\n", 14, 3, "unknown key 'port' in opcua"),
    ("opcua:\n  security: {policies: [Basic128]}\n", 14, 25, "unknown policy 'Basic128'"),
    ("opcua:\n  security: {policies: []}\n", 14, 24, "expected at least one"),
    ("opcua:\n  security: {anonymous: write}\n", 14, 25, "expected read or none"),
    ("opcua:\n  security: {users: {op: secret}}\n", 14, 26, "made by 'softplc hash-pin'"),
    ("opcua:\n  security: {pin: 1}\n", 14, 14, "unknown key 'pin' in opcua security"),
    ("opcua:\n  limits: {sessions: 0}\n", 14, 22, "sessions: expected 1 to 1000, found 0"),
    ("opcua:\n  limits: {items: 50, items_total: 20}\n", 14, 19,
     "items (50) per session is more than items_total (20)"),
    ("opcua:\n  limits: {session_timeout: 2h}\n", 14, 29,
     "session_timeout: expected 10 s to 3600 s, found 7200 s"),
    ("opcua:\n  limits: {abandoned: 2m, session_timeout: 1m}\n", 14, 23,
     "abandoned (120 s) is longer than session_timeout (60 s)"),
    ("opcua:\n  limits: {clients: 3}\n", 14, 12, "unknown key 'clients' in opcua limits"),
    ("opcua:\n  limits: {publish_rate: 0}\n", 14, 26,
     "publish_rate: expected 0.1 to 10000 publishes a second, found 0"),
    ("opcua:\n  limits: {publish_rate: 300}\n", 14, 26,
     "publish_rate (300) per session is more than publish_rate_total (200)"),
])
def test_bad_values_are_placed(tmp_path: Path, opcua: str, line: int, col: int,
                               words: str) -> None:
    e = error_of(tmp_path, opcua)
    assert (e.loc.line, e.loc.col) == (line, col), e
    assert words in e.message


def test_the_schema_accepts_the_section_and_rejects_a_typo(tmp_path: Path) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((ROOT / "configs/schema/plant.schema.json").read_text())
    v = jsonschema.Draft202012Validator(schema)
    path = write_plant(tmp_path, port=4840)
    doc = json.loads(json.dumps(load_yaml(str(path))))
    assert list(v.iter_errors(doc)) == []
    doc["opcua"]["security"]["policies"] = ["Basic128"]
    doc["opcua"]["sampel"] = "1s"
    assert len(list(v.iter_errors(doc))) == 2


def test_softplc_opcua_needs_the_section(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    from runtime.cli import main

    path = write_plant(tmp_path, port=4840)
    text = path.read_text(encoding="utf-8")
    path.write_text(text[:text.index("opcua:")], encoding="utf-8")
    assert main(["opcua", str(path)]) == 2
    assert capsys.readouterr().err == (f"{path}:1:1: error: no 'opcua:' section: add one to "
                                       "serve this plant over OPC UA (docs/opcua.md)\n")
