"""The JSON Schemas of configs/schema/ (editor completion and validation of the four YAML
file kinds) are valid, accept every file in configs/ and the examples of the language
contract, and reject what they are meant to catch.

The schemas check the *shape* of a file (keys, enums, time literals, required keys); the
expressions inside the strings are the loader's business (``softplc check``).
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path
from typing import Any

import pytest

from runtime.language.yamlsrc import load_yaml

jsonschema = pytest.importorskip("jsonschema")
from jsonschema import Draft202012Validator  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
SCHEMA_DIR = CONFIGS / "schema"
KINDS = ("grafcet", "plant", "script", "scenario")
#: the kinds whose schema is generated from the declarations (runtime/language/schemas.py)
GENERATED = ("grafcet", "plant", "script", "scenario")
YAML_FILES = sorted(p for p in CONFIGS.rglob("*") if p.suffix in (".yaml", ".yml")
                    and "schema" not in p.relative_to(CONFIGS).parts)


def load_schema(kind: str) -> dict[str, Any]:
    with open(SCHEMA_DIR / f"{kind}.schema.json", encoding="utf-8") as f:
        return json.load(f)


VALIDATORS = {k: Draft202012Validator(load_schema(k)) for k in KINDS}


def kind_of(doc: Any) -> str:
    """The file kind from its top-level keys (language.md: grafcet, plant, script;
    testing-charts.md: scenario)."""
    if isinstance(doc, dict):
        if "grafcet" in doc:
            return "grafcet"
        if "instances" in doc:
            return "plant"
        if "expect" in doc:
            return "scenario"
        if {"set", "duration", "cycles"} & set(doc):
            return "script"
    return "unknown"


def errors(kind: str, doc: Any) -> list[str]:
    return [f"{e.json_path}: {e.message}" for e in VALIDATORS[kind].iter_errors(doc)]


def read(text: str, path: str = "<text>") -> Any:
    """YAML as softplc reads it (YAML 1.2 booleans: yes/no/on/off are text)."""
    return load_yaml(path, text)


def y(text: str) -> Any:
    return read(textwrap.dedent(text))


# --------------------------------------------------------------------------- the schemas


@pytest.mark.parametrize("kind", KINDS)
def test_schema_is_valid_draft_2020_12(kind: str) -> None:
    schema = load_schema(kind)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    Draft202012Validator.check_schema(schema)
    assert schema["$id"] and schema["title"] and schema["description"]


def _resolve(schema: dict[str, Any], node: dict[str, Any]) -> dict[str, Any]:
    ref = node.get("$ref")
    if isinstance(ref, str) and ref.startswith("#/"):
        target: Any = schema
        for part in ref[2:].split("/"):
            target = target[part]
        return target
    return node


def _walk(node: Any, path: str = "#"):
    if isinstance(node, dict):
        yield path, node
        for k, v in node.items():
            yield from _walk(v, f"{path}/{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _walk(v, f"{path}/{i}")


@pytest.mark.parametrize("kind", KINDS)
def test_every_key_has_a_description(kind: str) -> None:
    """Editors show the descriptions on hover and in completion lists."""
    schema = load_schema(kind)
    missing = []
    for path, node in _walk(schema):
        props = node.get("properties")
        if not isinstance(props, dict) or path.endswith("/properties") or "/if" in path:
            continue  # (an 'if' only selects a branch; editors show the 'then' side)
        for key, sub in props.items():
            if isinstance(sub, dict) and "description" not in sub and (
                    "description" not in _resolve(schema, sub)):
                missing.append(f"{path}/properties/{key}")
    assert not missing, missing


# ---------------------------------------------------------------- every file in configs/


def test_configs_are_found() -> None:
    names = {p.relative_to(CONFIGS).as_posix() for p in YAML_FILES}
    assert "drawer_tester/drawer_tester.yaml" in names
    assert "drawer_tester/plant_sim.yaml" in names
    assert "drawer_tester/story.yaml" in names


@pytest.mark.parametrize("path", YAML_FILES, ids=[p.relative_to(CONFIGS).as_posix()
                                                  for p in YAML_FILES])
def test_config_file_matches_its_schema(path: Path) -> None:
    doc = read(path.read_text(encoding="utf-8"), str(path))
    kind = kind_of(doc)
    assert kind != "unknown", f"{path}: not a grafcet, plant or script file (top-level keys)"
    errs = errors(kind, doc)
    assert not errs, f"{path} ({kind}):\n" + "\n".join(errs)


def _keys(node: Any, path: str = ""):
    if isinstance(node, dict):
        for k, v in node.items():
            yield path, k
            yield from _keys(v, f"{path}/{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _keys(v, f"{path}/{i}")


@pytest.mark.parametrize("path", YAML_FILES, ids=[p.relative_to(CONFIGS).as_posix()
                                                  for p in YAML_FILES])
def test_config_keys_are_strings(path: Path) -> None:
    """softplc reads YAML 1.2 booleans (a step or an input named 'on' or 'No' stays a name,
    where YAML 1.1 would make it True/False), but a bare number is still an int key."""
    doc = read(path.read_text(encoding="utf-8"), str(path))
    bad = [(p, k) for p, k in _keys(doc) if not isinstance(k, str)]
    assert not bad, f"{path}: non-string keys {bad}"


# ------------------------------------------------ the examples of docs/language.md validate

SPEC_GRAFCET = """\
grafcet: DrawerTester
description: Drawer-slide endurance tester
scan: immediate
inputs:  [iParo, iMarcha, iAbierto, iCerrado]
outputs: [oAbrir, oCerrar, oParado, oTest]
memory:
  sParo: false
  sCierres: {init: 0, retain: true}
timers: [timeTest]
blocks:
  tonDoor: TON
pre:
  - sParo.Set(1, iParo)
  - tAveriaAbrir := gsAbrir.T >= 10s
  - tParo := iCerrado·sParo + (sCierres >= 1000)
steps:
  gsParado: {initial: true, actions: [oParado]}
  gsAbrir:  {actions: [oAbrir, oTest]}
  gsCerrar:
    actions:
      - oCerrar
      - oTest
      - P1 sCierres := sCierres + 1
  gsAveria: {actions: ["N oParado if Clock_1Hz"]}
  gsEspera: {max: 30s, min: 1s}
  gsLlenado:
    macro:
      steps:
        eLlenarA: {entry: true, actions: [oValvA]}
        eLlenarB: {actions: [oValvB]}
        sLleno:   {exit: true}
      transitions:
        - {from: eLlenarA, to: eLlenarB, when: iNivelA}
        - {from: eLlenarB, to: sLleno, when: iNivelB}
transitions:
  - {from: gsParado, to: gsAbrir, when: "↑iMarcha·iParo'"}
  - {from: gsAbrir, to: gsCerrar, when: iAbierto}
  - {from: [gsA1, gsB1], to: gsFin, when: "1"}
  - {from: gsFin, to: [gsA2, gsB2], when: iGo}
  - {from: gsLlenado, to: gsAgitar, when: "1"}
  - {from: [], to: gsAlarma, when: ↑iEmergencia}
  - {from: gsAlarma, to: [], when: iAck}
  - {from: gsX, to: gsY, when: 1}
  - {from: gsY, to: gsX, when: true}
post:
  - oParado := gsParado.X + sParo·Clock_1Hz
"""

SPEC_PLANT = """\
plc:
  cycle: 10ms
  watchdog: 100ms
  retain: /var/lib/softplc/retain.json
  retain_interval: 1s
  realtime: {priority: 50, lock_memory: true}
drivers:
  sim:  {type: sim}
  gpio: {type: gpio, chip: /dev/gpiochip0, bias: pull_up, debounce: 5ms}
  exp1: {type: mcp23017, bus: 1, address: 0x20}
  exp2: {type: pcf8574, bus: 1, address: "0x38", on_fault: hold}
  rio:  {type: canopen, channel: can0, interface: socketcan, node: 5, heartbeat: 500ms,
         pdo: {tpdo1: ["6000:1"], rpdo1: ["6200:1"]}}
  mb:   {type: modbus_rtu, port: /dev/ttyUSB0, baudrate: 115200, unit: 1, parity: E,
         timeout: 0.1, on_fault: zero}
instances:
  tester1:
    grafcet: drawer_tester.yaml
    inputs:
      iParo:    {from: gpio.17, invert: true}
      iMarcha:  gpio.27
      iAbierto: exp1.A0
      iCerrado: exp1.A1
      SFCPause: {from: supervisor.oPausaTodo}
    outputs:
      oAbrir:  exp1.B0
      oCerrar: exp1.B1
      oParado: exp1.B2
      oTest:   exp1.B3
monitor:
  serial: {port: /dev/ttyGS0, baudrate: 115200}
  socket: /run/softplc/console.sock
  tcp: {port: 7070, trusted: true}
  pin_hash: "abc"
  release_forces_on_disconnect: true
"""

SPEC_SCRIPT = """\
duration: 2s
set:
  - at: 0ms
    tester1.iMarcha: 1
  - at: 50ms
    tester1.iMarcha: 0
  - at: 1s
    tester1.SFCPause: 1
  - {at: T#1s500ms, sim.I0: 0, tester1.iParo: true}
"""


def test_an_output_bound_with_to_validates() -> None:
    doc = {**MINIMAL_PLANT, **y("""\
        instances: {t1: {grafcet: g.yaml, outputs: {oA: {to: sim.Q0, invert: true}}}}""")}
    assert not errors("plant", doc), errors("plant", doc)


@pytest.mark.parametrize("kind, text", [("grafcet", SPEC_GRAFCET), ("plant", SPEC_PLANT),
                                        ("script", SPEC_SCRIPT)])
def test_contract_examples_validate(kind: str, text: str) -> None:
    doc = read(text)
    assert kind_of(doc) == kind
    assert not errors(kind, doc), errors(kind, doc)


@pytest.mark.parametrize("value", ["10s", "250ms", "1m30s", "1d23h30m20s700ms", "1.5s",
                                   "T#10s", "TIME#1h30m", "t#5ms", "1_000ms", "30m", 0])
def test_time_literals_accepted(value: Any) -> None:
    doc = {"grafcet": "G", "steps": {"gsA": {"initial": True, "max": value}}}
    assert not errors("grafcet", doc)


@pytest.mark.parametrize("value", ["10", "10 s", "1s10m", "10sec", "s", "T#", "1ms1s",
                                   "-5s", 10, 1.5, True, "10s!"])
def test_bad_time_literals_rejected(value: Any) -> None:
    doc = {"grafcet": "G", "steps": {"gsA": {"initial": True, "max": value}}}
    assert errors("grafcet", doc)


# ------------------------------------------------------------------------ negative cases

MINIMAL_GRAFCET = {"grafcet": "G", "steps": {"gsA": {"initial": True}}}

GRAFCET_BAD = {
    "unknown top-level key": "trasitions: []",
    "bad scan model": "scan: fast",
    "YAML 1.1 'on' read as a bool, not a scan model": "scan: on",
    "grafcet name not a string": "grafcet: [a, b]",
    "unknown step key": "steps: {gsA: {intial: true}}",
    "max not a time": "steps: {gsA: {initial: true, max: 10}}",
    "min with a bad unit order": "steps: {gsA: {initial: true, min: 1s10m}}",
    "actions not strings": "steps: {gsA: {initial: true, actions: [{N: oX}]}}",
    "macro-step with actions": """\
        steps:
          gsA: {initial: true}
          gsM:
            actions: [oX]
            macro: {steps: {e: {entry: true}, s: {exit: true}}}
        """,
    "macro without steps": "steps: {gsA: {initial: true}, gsM: {macro: {transitions: []}}}",
    "unknown key in a macro": "steps: {gsM: {macro: {steps: {e: {entry: true}}, trans: []}}}",
    "entry on a top-level step": "steps: {gsA: {initial: true, entry: true}}",
    "step is a list": "steps: {gsA: [initial]}",
    "no steps at all": "steps: {}",
    "bad block type": "blocks: {tonDoor: TONN}",
    "typed signal with a bad type": "inputs: [{tT: float}]",
    "typed signal with two keys": "inputs: [{tA: int, tB: int}]",
    "memory with a misspelt key": "memory: {sN: {init: 0, retian: true}}",
    "memory initial value a list": "memory: {sN: [0]}",
    "memory bad time": "memory: {sT: 10 s}",
    "timers not a list": "timers: timeTest",
    "pre not statements": "pre: {a: 1}",
    "transition without when": "transitions: [{from: gsA, to: gsB}]",
    "transition with an unknown key": "transitions: [{from: gsA, to: gsB, when: iX, if: iY}]",
    "transition condition 2": "transitions: [{from: gsA, to: gsB, when: 2}]",
    "transition from a number": "transitions: [{from: 3, to: gsB, when: iX}]",
    "transitions not a list": "transitions: {from: gsA, to: gsB, when: iX}",
}


@pytest.mark.parametrize("case", GRAFCET_BAD, ids=list(GRAFCET_BAD))
def test_grafcet_schema_rejects(case: str) -> None:
    doc = dict(MINIMAL_GRAFCET)
    doc.update(y(GRAFCET_BAD[case]))
    assert errors("grafcet", doc), f"accepted: {case}"


def test_grafcet_needs_name_and_steps() -> None:
    assert errors("grafcet", {"grafcet": "G"})
    assert errors("grafcet", {"steps": {"gsA": {"initial": True}}})
    assert not errors("grafcet", MINIMAL_GRAFCET)


MINIMAL_PLANT = {"instances": {"t1": {"grafcet": "g.yaml"}}}

PLANT_BAD = {
    "unknown top-level key": "instance: {}",
    "unknown plc key": "plc: {cycle_time: 10ms}",
    "cycle as a bare number": "plc: {cycle: 10}",
    "realtime priority out of range": "plc: {realtime: {priority: 0}}",
    "realtime true (the default needs no key)": "plc: {realtime: true}",
    "unknown driver type": "drivers: {g: {type: gpoi}}",
    "driver without type": "drivers: {g: {chip: /dev/gpiochip0}}",
    "bad on_fault": "drivers: {s: {type: sim, on_fault: ignore}}",
    "config key on a sim driver": "drivers: {s: {type: sim, chip: /dev/gpiochip0}}",
    "gpio bad bias": "drivers: {g: {type: gpio, bias: up}}",
    "key of another driver type": "drivers: {g: {type: gpio, bus: 1}}",
    "mcp23017 without address": "drivers: {e: {type: mcp23017, bus: 1}}",
    "mcp23017 misspelt key": "drivers: {e: {type: mcp23017, bus: 1, adress: 0x20}}",
    "mcp23017 address out of range": "drivers: {e: {type: mcp23017, bus: 1, address: 0x80}}",
    "canopen node out of range": "drivers: {r: {type: canopen, node: 200}}",
    "canopen bad pdo key": "drivers: {r: {type: canopen, node: 5, pdo: {tpdo9: ['6000:1']}}}",
    "modbus bad parity": "drivers: {m: {type: modbus_rtu, port: /dev/ttyUSB0, parity: X}}",
    "modbus stop bits": "drivers: {m: {type: modbus_rtu, port: /dev/ttyUSB0, stopbits: 3}}",
    "modbus without port": "drivers: {m: {type: modbus_rtu, unit: 1}}",
    "no instances": "instances: {}",
    "instance without grafcet": "instances: {t1: {inputs: {iA: sim.I0}}}",
    "instance unknown key": "instances: {t1: {grafcet: g.yaml, input: {iA: sim.I0}}}",
    "binding without a point": "instances: {t1: {grafcet: g.yaml, inputs: {iA: gpio17}}}",
    "binding invert a string": """\
        instances: {t1: {grafcet: g.yaml, inputs: {iA: {from: sim.I0, invert: "true"}}}}""",
    "binding without from": "instances: {t1: {grafcet: g.yaml, inputs: {iA: {invert: true}}}}",
    "binding unknown key": """\
        instances: {t1: {grafcet: g.yaml, outputs: {oA: {from: sim.Q0, negate: true}}}}""",
    "input bound with to": "instances: {t1: {grafcet: g.yaml, inputs: {iA: {to: sim.I0}}}}",
    "output bound with from and to": """\
        instances: {t1: {grafcet: g.yaml, outputs: {oA: {from: sim.Q0, to: sim.Q1}}}}""",
    "monitor unknown key": "monitor: {telnet: 23}",
    "monitor serial without port": "monitor: {serial: {baudrate: 115200}}",
    "monitor trusted not a bool": "monitor: {socket: {path: /tmp/s.sock, trusted: 1}}",
    "monitor tcp port out of range": "monitor: {tcp: 70000}",
    "monitor tcp port 0": "monitor: {tcp: 0}",
    "monitor serial baud rate 0": "monitor: {serial: {port: /dev/ttyGS0, baudrate: 0}}",
    "monitor serial baud rate not a rate": "monitor: {serial: {port: /dev/ttyGS0, "
                                           "baudrate: 12345}}",
    "monitor socket with a NUL": 'monitor: {socket: "/run/c\\0.sock"}',
    "monitor socket path empty": 'monitor: {socket: {path: ""}}',
    "retain with a NUL": 'plc: {retain: "r\\0.json"}',
    "grafcet with a NUL": 'instances: {t1: {grafcet: "g\\0.yaml"}}',
    "opcua feed with a NUL": 'opcua: {feed: "f\\0.sock"}',
    "opcua certificate with a NUL": 'opcua: {security: {certificate: "c\\0.der"}}',
}


@pytest.mark.parametrize("case", PLANT_BAD, ids=list(PLANT_BAD))
def test_plant_schema_rejects(case: str) -> None:
    doc = dict(MINIMAL_PLANT)
    doc.update(y(PLANT_BAD[case]))
    assert errors("plant", doc), f"accepted: {case}"


def test_the_scan_at_normal_priority_is_realtime_false() -> None:
    """SCHED_FIFO 50 is the default where permitted; ``realtime: false`` says no, and the
    loader reads it as priority 0 (none)."""
    assert not errors("plant", {**MINIMAL_PLANT, **y("plc: {realtime: false}")})


def test_yaml_reads_hex_addresses_as_ints() -> None:
    """0x20 is the integer 32 to softplc's YAML reader: the schema takes it, and "0x20"."""
    doc = y("drivers: {e: {type: mcp23017, bus: 1, address: 0x20}}")
    assert doc["drivers"]["e"]["address"] == 32
    plant = {**MINIMAL_PLANT, **doc}
    assert not errors("plant", plant)
    plant["drivers"]["e"]["address"] = "0x20"
    assert not errors("plant", plant)


SCRIPT_BAD = {
    "nothing to do": "description: no length, no changes",
    "unknown top-level key": "duration: 1s\nevents: []",
    "bad duration": "duration: 2 s",
    "negative cycles": "cycles: -1",
    "entry without at": "duration: 1s\nset: [{t1.iA: 1}]",
    "entry with only at": "duration: 1s\nset: [{at: 0ms}]",
    "key without instance or driver": "duration: 1s\nset: [{at: 0ms, iMarcha: 1}]",
    "value not a number": "duration: 1s\nset: [{at: 0ms, t1.iA: high}]",
    "bad at": "duration: 1s\nset: [{at: soon, t1.iA: 1}]",
    "set not a list": "duration: 1s\nset: {at: 0ms, t1.iA: 1}",
}


@pytest.mark.parametrize("case", SCRIPT_BAD, ids=list(SCRIPT_BAD))
def test_script_schema_rejects(case: str) -> None:
    assert errors("script", y(SCRIPT_BAD[case])), f"accepted: {case}"


def test_script_cycles_or_duration() -> None:
    assert not errors("script", {"cycles": 10})
    # a script meant for `softplc simulate --cycles N` has no length of its own
    assert not errors("script", {"set": [{"at": "0ms", "t1.iA": 1}]})
    assert not errors("script", {"duration": "1s", "set": [{"at": "0ms", "sim.I0": 1}]})
    assert not errors("script", {"cycles": 5, "set": [{"at": 0, "t1.iA": True,
                                                       "t1.tTemp": 21.5}]})


def _props(kind: str, *path: str | int) -> set[str]:
    node: Any = load_schema(kind)
    for step in path:
        node = node[step]
    return set(node["properties"])


def test_the_schemas_know_every_key_the_loader_reads() -> None:
    """Each section's keys in the schema are the loader's (an editor flags a key the
    controller reads as unknown otherwise: ``alarms:`` was missing once), at the place
    editors look for them."""
    from runtime.language import alarmconf, filekind, grafcetfile, mqttconf, opcuaconf, webconf
    from runtime.language import plantfile as pf
    from runtime.language.shape import Section

    plant = ("plant", "properties")
    sections: dict[str, tuple[Section, tuple[str | int, ...]]] = {
        "plant": (pf.PLANT, ("plant",)),
        "plc": (pf.PLC, (*plant, "plc")),
        "plc realtime": (pf.REALTIME, (*plant, "plc", "properties", "realtime", "oneOf", 1)),
        "monitor": (pf.MONITOR, (*plant, "monitor")),
        "monitor serial": (pf.SERIAL, (*plant, "monitor", "properties", "serial")),
        "monitor socket": (pf.SOCKET, (*plant, "monitor", "properties", "socket", "oneOf", 1)),
        "monitor tcp": (pf.TCP, (*plant, "monitor", "properties", "tcp", "oneOf", 1)),
        "monitor limits": (pf.CONSOLE_LIMITS, (*plant, "monitor", "properties", "limits")),
        "opcua": (opcuaconf.OPCUA, (*plant, "opcua")),
        "opcua security": (opcuaconf.SECURITY, (*plant, "opcua", "properties", "security")),
        "opcua limits": (opcuaconf.LIMITS, (*plant, "opcua", "properties", "limits")),
        "mqtt": (mqttconf.MQTT, (*plant, "mqtt")),
        "mqtt tls": (mqttconf.TLS, (*plant, "mqtt", "properties", "tls")),
        "web": (webconf.WEB, (*plant, "web")),
        "web tls": (webconf.TLS, (*plant, "web", "properties", "tls")),
        "alarms": (alarmconf.ALARMS, (*plant, "alarms")),
        "alarms severity": (alarmconf.SEVERITY, (*plant, "alarms", "properties", "severity")),
        "alarms overruns": (alarmconf.OVERRUNS, (*plant, "alarms", "properties",
                                                 "overruns")),
        "instance": (pf.INSTANCE, ("plant", "$defs", "instance")),
        "binding": (pf.BINDING_SPEC, ("plant", "$defs", "binding", "oneOf", 1)),
        "output binding": (pf.OUTPUT_BINDING_SPEC, ("plant", "$defs", "outputBinding", "oneOf",
                                                    1)),
        "grafcet": (grafcetfile.GRAFCET, ("grafcet",)),
        "step": (grafcetfile.STEP, ("grafcet", "$defs", "innerStep")),
        "macro": (grafcetfile.MACRO, ("grafcet", "$defs", "macro")),
        "transition": (grafcetfile.TRANSITION, ("grafcet", "$defs", "transition")),
        "memory": (grafcetfile.MEMORY_SPEC, ("grafcet", "properties", "memory",
                                             "additionalProperties", "anyOf", 1)),
        "script": (filekind.SCRIPT, ("script",)),
    }
    differ = {}
    for name, (section, path) in sections.items():
        try:
            schema = _props(path[0], *path[1:])  # type: ignore[arg-type]
        except KeyError:
            schema = set()
        keys = set(section.names)
        if schema != keys:
            differ[name] = (sorted(keys - schema), sorted(schema - keys))
    assert differ == {}, f"section: (the loader's only, the schema's only): {differ}"
    step = _props("grafcet", "$defs", "step")
    assert step == set(grafcetfile.STEP.names) - {"entry", "exit"}  # only inside a macro-step
    assert _props("scenario") == set(filekind.SCENARIO.names)


@pytest.mark.parametrize("kind", GENERATED)
def test_the_committed_schemas_are_what_the_declarations_generate(kind: str) -> None:
    """configs/schema/ is generated (scripts/make-schemas.sh): a key declared for the
    loader and missing from an editor's schema, or the reverse, fails here."""
    from runtime.language import schemas

    committed = (SCHEMA_DIR / f"{kind}.schema.json").read_text(encoding="utf-8")
    assert committed == schemas.render(kind), (
        f"configs/schema/{kind}.schema.json differs from the declarations: run "
        "scripts/make-schemas.sh")


def test_make_schemas_writes_every_file(tmp_path: Path) -> None:
    import subprocess

    subprocess.run(["bash", str(ROOT / "scripts" / "make-schemas.sh"), str(tmp_path)],
                   check=True, cwd=ROOT, timeout=120)
    for kind in GENERATED:
        written = (tmp_path / f"{kind}.schema.json").read_text(encoding="utf-8")
        assert written == (SCHEMA_DIR / f"{kind}.schema.json").read_text(encoding="utf-8")


def test_the_alarm_severities_of_the_schema_are_the_kinds() -> None:
    from runtime.language.model import ALARM_SEVERITY

    assert _props("plant", "properties", "alarms", "properties", "severity") == set(
        ALARM_SEVERITY)
    doc = y("alarms: {severity: {fault: 1000, driver: 1}, overruns: {count: 0, window: 1h}}")
    assert not errors("plant", {**MINIMAL_PLANT, **doc})
    for bad in ("alarms: {severity: {falut: 900}}", "alarms: {severity: {fault: 1001}}",
                "alarms: {overruns: {count: -1}}", "alarms: {overruns: {window: soon}}",
                "alarms: {levels: {}}"):
        assert errors("plant", {**MINIMAL_PLANT, **y(bad)}), f"accepted: {bad}"
