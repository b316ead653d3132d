"""Generated plants for property tests: a chart and a plant file using every key of every
section the loader knows (the chart's, the plant's ``plc:``, ``drivers:`` of every type,
``instances:`` with the I/O list, ``monitor:``, ``opcua:``, ``mqtt:``, ``web:``,
``modbus:``, ``alarms:``), each optional key present or not, values drawn from what the
loader accepts.

``plant_files(full=True)`` gives every key at once (``tests/language/test_modeldata.py``
holds that set to the JSON Schemas of configs/schema/, so a key added to a section and its
schema is a key this generator must learn). The documents are Python data written with
PyYAML (``write``), read back by the project's own loader.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import yaml
from hypothesis import strategies as st

from drivers.registry import BAUDRATES, CAN_BITRATES, CAN_INTERFACES

#: a password hash as ``softplc hash-pin`` writes it (the loader checks its shape only)
HASH = "scrypt$16384$8$1$c2FsdHNhbHRzYWx0c2FsdA$aGFzaGhhc2hoYXNoaGFzaGhhc2hoYXNoaGFzaGhhc2g"
#: units of the I/O list, as codes, symbols and ASCII spellings
UNITS = ("CEL", "°C", "bar", "mm", "l/min", "%", "m3/h", "rpm", "kWh", "A", "1", "59")
_serial = itertools.count()


def texts(max_size: int = 30) -> st.SearchStrategy[str]:
    """One line of text as a description may be (no control character, any script)."""
    return st.text(st.characters(blacklist_categories=("Cc", "Cs", "Zl", "Zp")),
                   max_size=max_size).map(str.strip)


def times(low_ms: int, high_ms: int) -> st.SearchStrategy[str]:
    """A time literal from ``low_ms`` to ``high_ms``, in one of the spellings."""
    return st.integers(low_ms, high_ms).flatmap(lambda ms: st.sampled_from(
        [f"{ms}ms", f"T#{ms}ms"] + ([f"{ms // 1000}s"] if ms % 1000 == 0 and ms else [])))


class Draw:
    """The draws of one document: ``has(key)`` is True for every key when ``full``."""

    def __init__(self, draw: st.DrawFn, full: bool) -> None:
        self.draw, self.full = draw, full

    def __call__(self, strategy: st.SearchStrategy[Any]) -> Any:
        return self.draw(strategy)

    def has(self) -> bool:
        return self.full or bool(self.draw(st.booleans()))

    def text(self) -> str:
        return str(self.draw(texts()))


def chart(d: Draw) -> dict[str, Any]:
    """A chart with every key: typed signals, memory of every form, a timer, blocks, pre
    and post, steps with times and actions, a macro-step nested in a macro-step, named
    and described transitions."""
    def step(**more: Any) -> dict[str, Any]:
        out: dict[str, Any] = dict(more)
        if d.has():
            out["description"] = d.text()
        if d.has():
            out["min"] = d(times(0, 50))
        if d.has():
            out["max"] = d(times(100, 90_000))
        if d.has():
            out["renamed_from"] = f"sWas{next(_serial)}"
        return out

    doc: dict[str, Any] = {"grafcet": "Gen"}
    if d.has():
        doc["description"] = d.text()
    if d.has():
        doc["scan"] = d(st.sampled_from(["immediate", "codesys", "stable"]))
    doc["inputs"] = ["iGo", {"iLevel": "int"},
                     {"iTemp": {"type": "real", **({"description": d.text()} if d.has()
                                                   else {}),
                                **({"iec_type": d(st.sampled_from(["REAL", "LREAL"]))}
                                   if d.has() else {})}},
                     {"iWait": "time"}]
    doc["outputs"] = ["oRun", {"oSpeed": "int"},
                      {"oValve": {"type": "real", **({"description": d.text()} if d.has()
                                                     else {}),
                                  **({"iec_type": d(st.sampled_from(["REAL", "LREAL"]))}
                                     if d.has() else {})}},
                      {"oLamp": {"type": "bool"}}]
    memory: dict[str, Any] = {"sFlag": d(st.booleans()), "sReal": d(st.floats(-1e6, 1e6)),
                              "sCount": {"init": d(st.integers(-1000, 1000))}}
    if d.has():
        memory["sCount"]["retain"] = d(st.booleans())
    if d.has():
        memory["sCount"]["description"] = d.text()
    if d.has():
        memory["sCount"]["renamed_from"] = "sCounter"
    if d.has():
        memory["sCount"]["iec_type"] = d(st.sampled_from(["INT", "DINT", "UINT", "LINT"]))
    doc["memory"] = memory
    doc["timers"] = ["timeStir"]
    doc["blocks"] = {"tonGo": "TON", "ctuRuns": d(st.sampled_from(["CTU", "CTD"]))}
    pre = ["tonGo(IN := iGo, PT := 2s)", "tReady := tonGo.Q + iLevel > 3"]
    pre.append("ctuRuns(CU := gsRun.X, R := gsIdle.X, PV := 5)" if doc["blocks"]["ctuRuns"]
               == "CTU" else "ctuRuns(CD := gsRun.X, LD := gsIdle.X, PV := 5)")
    doc["pre"] = pre
    doc["post"] = ["oSpeed := sCount", "oValve := iTemp * 0.5"]
    inner = step(entry=True, actions=["oLamp", "P1 timeStir.Ini(30s)"])
    doc["steps"] = {
        "gsIdle": step(initial=True, actions=["P1 sCount := 0"]),
        "gsRun": step(actions=["oRun", "N sFlag := tReady", "P1 sCount := sCount + 1"]),
        "gsMacro": {"macro": {
            "steps": {"eIn": inner,
                      "eDeep": {"macro": {"steps": {"fIn": {"entry": True},
                                                    "fOut": {"exit": True}},
                                          "transitions": [{"from": "fIn", "to": "fOut",
                                                           "when": "iGo'"}]},
                                **({"description": d.text()} if d.has() else {})},
                      "eOut": {"exit": True, "initial": False}},
            "transitions": [
                {"from": "eIn", "to": "eDeep", "when": "timeStir.End()",
                 **({"name": "tInner"} if d.has() else {}),
                 **({"description": d.text()} if d.has() else {})},
                {"from": "eDeep", "to": "eOut", "when": 1}]},
            **({"description": d.text()} if d.has() else {})},
    }
    first: dict[str, Any] = {"from": "gsIdle", "to": "gsRun", "when": "↑iGo·tReady"}
    if d.has():
        first["name"] = "tStart"
    if d.has():
        first["description"] = d.text()
    doc["transitions"] = [first,
                          {"from": "gsRun", "to": "gsMacro", "when": "iWait >= 1s"},
                          {"from": "gsMacro", "to": "gsIdle", "when": 1}]
    return doc


def binding(d: Draw, point: str, number: bool, invert: bool = False,
            output: bool = False, key: str | None = None, at: str = "") -> Any:
    """A binding to ``point``: its short form, or its mapping with the I/O list (an
    ``output``'s point named by ``from:`` or ``to:``, drawn unless ``key`` says; its IEC
    located address ``at`` if given)."""
    if not d.full and not d(st.booleans()):
        return point
    if key is None:
        key = "to" if output and d(st.booleans()) else "from"
    out: dict[str, Any] = {key: point}
    if invert and d.has():
        out["invert"] = d(st.booleans())
    if d.has():
        out["description"] = d.text()
    if number and d.has():
        out["unit"] = d(st.sampled_from(UNITS))
    if number and d.has():
        low = d(st.integers(-1000, 1000))
        out["range"] = [low, low + d(st.integers(1, 10_000))]
    if at and d.has():
        out["at"] = at
    return out


def drivers(d: Draw) -> dict[str, Any]:
    """The sim driver the instance is bound to, and one driver of every other type with
    its keys (never opened: the tests run the plant on simulated I/O)."""
    fault = st.sampled_from(["stop", "hold", "zero"])

    def maybe(spec: dict[str, Any], key: str, strategy: st.SearchStrategy[Any]) -> None:
        if d.has():
            spec[key] = d(strategy)

    out: dict[str, Any] = {"sim": {"type": "sim"}}
    maybe(out["sim"], "on_fault", fault)
    gpio: dict[str, Any] = {"type": "gpio"}
    maybe(gpio, "chip", st.sampled_from(["/dev/gpiochip0", "/dev/gpiochip4"]))
    maybe(gpio, "bias", st.sampled_from(["pull_up", "pull_down", "none"]))
    maybe(gpio, "debounce", times(0, 100))
    maybe(gpio, "on_fault", fault)
    mcp: dict[str, Any] = {"type": "mcp23017", "bus": d(st.integers(0, 3)),
                           "address": d(st.integers(0x20, 0x27))}
    maybe(mcp, "pull_up", st.booleans())
    maybe(mcp, "debounce", times(0, 100))
    pcf: dict[str, Any] = {"type": "pcf8574", "bus": 1,
                           "address": d(st.sampled_from([0x20, 0x27, 0x38, 0x3F]))}
    maybe(pcf, "debounce", times(0, 100))
    can: dict[str, Any] = {"type": "canopen", "node": d(st.integers(1, 127))}
    if d.has():
        can["interface"] = d(st.sampled_from(CAN_INTERFACES))
        can["channel"] = "can0" if can["interface"] == "socketcan" else d(
            st.sampled_from(["can0", 0, "PCAN_USBBUS1"]))
    maybe(can, "bitrate", st.sampled_from(CAN_BITRATES))
    maybe(can, "heartbeat", times(1, 5000))
    maybe(can, "eds", st.just("node.eds"))
    maybe(can, "sync", times(1, 1000))
    maybe(can, "pdo", st.just({"tpdo1": ["6000:1"], "rpdo1": ["6200:1", "2000:0/16"]}))
    mb: dict[str, Any] = {"type": "modbus_rtu", "port": "/dev/ttyUSB0"}
    maybe(mb, "baudrate", st.sampled_from(BAUDRATES))
    maybe(mb, "parity", st.sampled_from(["N", "E", "O", "even", "none"]))
    maybe(mb, "unit", st.integers(1, 247))
    maybe(mb, "timeout", times(1, 1000))
    maybe(mb, "retries", st.integers(0, 10))
    maybe(mb, "stopbits", st.sampled_from([1, 2]))
    tcp: dict[str, Any] = {"type": "modbus_tcp",
                           "host": d(st.sampled_from(["192.168.10.20", "io-1.plant", "::1"]))}
    maybe(tcp, "port", st.integers(1, 65535))
    maybe(tcp, "unit", st.integers(0, 255))
    maybe(tcp, "timeout", times(1, 1000))
    maybe(tcp, "retries", st.integers(0, 10))
    out.update({"gp": gpio, "exp": mcp, "pcf": pcf, "can": can, "mb": mb, "tcp": tcp})
    return out


@st.composite
def plant_docs(draw: st.DrawFn, full: bool = False) -> tuple[dict[str, Any], dict[str, Any]]:
    """(chart document, plant document naming it ``chart.yaml``)."""
    d = Draw(draw, full)
    plant: dict[str, Any] = {}
    cycle_ms = d(st.sampled_from([5, 10, 20]))
    plc: dict[str, Any] = {"cycle": f"{cycle_ms}ms"}
    if d.has():
        plc["watchdog"] = d(times(10, 6000))
    if d.has():
        plc["retain"] = "${RUNTIME_DIR}/gen.retain.json"
        if d.has():
            plc["retain_required"] = d(st.booleans())
    if d.has():
        plc["retain_interval"] = d(times(1, 5000))
    if d.has():
        # a processor no test machine has: a daemon started in the test's process
        # (tests/change/test_change_verdict.py) would otherwise keep the whole test run
        # on one processor (it says it cannot, and runs where it was)
        plc["realtime"] = ({"priority": d(st.integers(1, 99)), "lock_memory": d(st.booleans()),
                            "cpu": d(st.integers(512, 1023))}
                           if d.full or d(st.booleans()) else False)
    if d.has():
        plc["log"] = d(st.sampled_from(["steps", "none"]))
    plant["plc"] = plc
    plant["drivers"] = drivers(d)
    inst: dict[str, Any] = {"grafcet": "chart.yaml"}
    if d.has():
        inst["description"] = d.text()
    if d.has():
        inst["log"] = d(st.sampled_from(["steps", "none"]))
    inst["inputs"] = {"iGo": binding(d, "sim.I0", False, invert=True, at="%IX0.0"),
                      "iLevel": binding(d, "sim.IR0", True, at="%IW0"),
                      "iTemp": binding(d, "sim.IR1", True),
                      "iWait": "sim.IR2"}
    if d.has():
        inst["inputs"]["SFCPause"] = binding(d, "sim.I1", False, invert=True)
    # a full plant names one output's point with to:, one with from:, the others drawn
    inst["outputs"] = {"oRun": binding(d, "sim.Q0", False, invert=True, output=True,
                                       key="to" if d.full else None, at="%QX0.0"),
                       "oSpeed": binding(d, "sim.HR0", True, output=True,
                                         key="from" if d.full else None, at="%QW0"),
                       "oValve": binding(d, "sim.HR1", True, output=True),
                       "oLamp": binding(d, "sim.Q1", False, invert=True, output=True)}
    instances = {"m1": inst}
    if d.has():  # a second instance of the same chart (the load shares it), linked
        instances["m2"] = {"grafcet": "chart.yaml",
                           "inputs": {"iGo": {"from": "m1.oRun", "description": d.text()}
                                      if d.has() else "m1.gsRun.X",
                                      "iLevel": "m1.sCount", "iTemp": "sim.IR3",
                                      "iWait": "m1.gsRun.T"},
                           "outputs": {"oRun": "sim.Q4", "oSpeed": "sim.HR4",
                                       "oValve": "sim.HR5", "oLamp": "sim.Q5"}}
    plant["instances"] = instances
    monitor: dict[str, Any] = {
        "socket": ({"path": "${RUNTIME_DIR}/gen.sock", "trusted": d(st.booleans())}
                   if d.full or d(st.booleans()) else "${RUNTIME_DIR}/gen.sock")}
    if d.has():
        monitor["tcp"] = ({"port": d(st.integers(1024, 65535)), "trusted": d(st.booleans())}
                          if d.full or d(st.booleans()) else d(st.integers(1024, 65535)))
    if d.has():
        monitor["serial"] = {"port": "/dev/ttyGS0", "baudrate": d(st.sampled_from(
            [9600, 115200])), "trusted": d(st.booleans())}
    if d.has():
        monitor["pin_hash"] = HASH
    if d.has():
        monitor["release_forces_on_disconnect"] = d(st.booleans())
    if d.has():
        limits: dict[str, Any] = {"warn_before": "30s"}
        for key in ("max_pause", "max_force", "relock_after_idle"):
            if d.has():
                limits[key] = d(st.sampled_from(["1m", "15m", "2h"]))
        monitor["limits"] = limits
    plant["monitor"] = monitor
    feed = "${RUNTIME_DIR}/gen-feed.sock"
    sample = f"{cycle_ms * d(st.integers(1, 20))}ms"
    if d.has():
        opcua: dict[str, Any] = {}
        if d.has():
            opcua["endpoint"] = f"opc.tcp://127.0.0.1:{d(st.integers(1024, 65535))}"
        if d.has():
            opcua["sample"] = sample
        if d.has():
            opcua["feed"] = feed
        if d.has():
            opcua["writable"] = ["m1.sFlag", "m1.SFCPause"] if "SFCPause" not in (
                inst["inputs"]) else ["m1.sFlag"]
        if d.has():
            sec: dict[str, Any] = {}
            if d.has():
                sec["policies"] = d(st.lists(st.sampled_from(
                    ["None", "Basic256Sha256_Sign", "Basic256Sha256_SignAndEncrypt"]),
                    min_size=1, max_size=3))
            for key, path in (("certificate", "cert.der"), ("private_key", "key.pem"),
                              ("trusted_clients", "clients"), ("trusted_readers", "readers")):
                if d.has():
                    sec[key] = path
            if d.has():
                sec["anonymous"] = d(st.sampled_from(["read", "none"]))
            if d.has():
                sec["users"] = {"op": HASH}
            opcua["security"] = sec
        if d.has():
            lim: dict[str, Any] = {}
            for key, strategy in (("sessions", st.integers(1, 1000)),
                                  ("subscriptions", st.integers(1, 100)),
                                  ("items", st.integers(1, 5000)),
                                  ("items_total", st.integers(5000, 10_000_000)),
                                  ("publish_rate", st.floats(0.1, 50)),
                                  ("publish_rate_total", st.floats(50, 100_000)),
                                  ("session_timeout", st.sampled_from(["60s", "1h"])),
                                  ("abandoned", st.sampled_from(["1s", "10s", "60s"]))):
                if d.has():
                    lim[key] = d(strategy)
            opcua["limits"] = lim
        plant["opcua"] = opcua
    if d.has():
        mqtt: dict[str, Any] = {"brokers": d(st.sampled_from(
            [["mqtts://127.0.0.1:8883"], ["mqtt://10.0.0.1", "mqtts://[::1]:8883"]])),
            "group_id": "Hall"}
        if d.has():
            mqtt["edge_node_id"] = "press1"
        else:
            mqtt["edge_node_id"] = "press2"  # never the host name (it may be no id)
        if d.has():
            mqtt["client_id"] = "c-1"
        if d.has():
            mqtt["username"] = "node"
            if d.has():
                mqtt["password_file"] = "secret.txt"
        if d.has():
            mqtt["tls"] = {k: v for k, v in (("ca", "ca.pem"), ("certificate", "c.pem"),
                                             ("private_key", "k.pem"))
                           if k == "ca" or d.full or d(st.booleans())}
            if ("certificate" in mqtt["tls"]) != ("private_key" in mqtt["tls"]):
                mqtt["tls"].pop("certificate", None)
                mqtt["tls"].pop("private_key", None)
        if d.has():
            mqtt["primary_host"] = "scada"
        if d.has():
            mqtt["publish"] = d(st.lists(st.sampled_from(
                ["inputs", "outputs", "memory", "flags", "steps", "step_times", "temporaries",
                 "points", "controller", "drivers", "m1.sCount", "sim.Q0"]), min_size=1))
        if d.has():
            mqtt["writable"] = ["m1.sCount"]
        if d.has():
            mqtt["sample"] = sample
        if d.has():
            mqtt["statistics"] = d(st.sampled_from(["1s", "10s"]))
        if d.has():
            mqtt["keepalive"] = d(st.sampled_from(["1s", "30s", "65535s"]))
        if d.has():
            mqtt["buffer"] = d(st.integers(0, 10_000_000))
        if d.has():
            mqtt["feed"] = feed
        if "tls" in mqtt and not any(b.startswith("mqtts") for b in mqtt["brokers"]):
            del mqtt["tls"]
        plant["mqtt"] = mqtt
    if d.has():
        web: dict[str, Any] = {}
        tls = d.has()
        if tls:
            web["tls"] = {"certificate": "web.pem", "private_key": "web.key"}
        if d.has():
            web["listen"] = ("0.0.0.0:8443" if tls and d(st.booleans())
                             else f"127.0.0.1:{d(st.integers(0, 65535))}")
        if d.has():
            web["sample"] = sample
        if d.has():
            web["feed"] = feed
        if d.has():
            web["users"] = {"demo": HASH}
            if d.has():
                web["read"] = d(st.sampled_from(["anyone", "users"]))
        elif d.has():
            web["read"] = "anyone"
        if d.has():
            web["idle_logout"] = d(st.sampled_from(["1m", "10m", "24h"]))
        if d.has():
            web["max_pages"] = d(st.integers(1, 200))
        if d.has():
            web["page_timeout"] = d(st.sampled_from(["3s", "30s", "10m"]))
        if d.has():
            web["hosts"] = d(st.sampled_from([["plc.example"], ["*.plant.example",
                                                                "press1"]]))
        plant["web"] = web
    if d.has():
        modbus: dict[str, Any] = {}
        if d.has():
            modbus["listen"] = d(st.sampled_from(["127.0.0.1:1502", "[::1]:5020", "off"]))
        if d.has():
            modbus["clients"] = d(st.sampled_from([["127.0.0.1"], ["192.168.10.0/24",
                                                                   "10.0.0.7"]]))
            if d.has():
                modbus["listen"] = "0.0.0.0:502"
        if d.has():
            modbus["unit"] = d(st.integers(0, 255))
        if d.has():
            modbus["map"] = {"m1.sFlag": d(st.sampled_from(["Q100", "%QX12.4"])),
                             "m1.sReal": {"at": d(st.sampled_from(["HR200", "%MD3"])),
                                          **({"type": "REAL"} if d.has() else {})},
                             "m1.gsIdle.X": "I300"}
        if d.has():
            modbus["writable"] = ["m1.sCount", "m1.sFlag"]
        if d.has():
            modbus["words"] = d(st.sampled_from(["high_first", "low_first"]))
        if d.has():
            modbus["sample"] = sample
        if d.has():
            modbus["feed"] = feed
        if d.has() or modbus.get("listen") == "off":
            modbus["tls"] = {"certificate": "mb.pem", "private_key": "mb.key",
                             "clients_ca": "ca.pem", "roles": {"operator": "write",
                                                               "viewer": "read"}}
            if d.has():
                modbus["tls"]["listen"] = "127.0.0.1:8020"
        if d.has():
            lims: dict[str, Any] = {}
            for key, strategy in (("connections", st.integers(1, 1000)),
                                  ("rate", st.integers(1, 100_000)),
                                  ("idle", st.sampled_from(["1s", "60s", "24h"]))):
                if d.has():
                    lims[key] = d(strategy)
            modbus["limits"] = lims
        plant["modbus"] = modbus
    if d.has():
        alarms: dict[str, Any] = {}
        if d.has():
            alarms["severity"] = {k: d(st.integers(1, 1000)) for k in
                                  ("fault", "driver", "sfcerror", "maxtime", "overruns")
                                  if d.full or d(st.booleans())}
        if d.has():
            alarms["overruns"] = {k: v for k, v in (("count", d(st.integers(0, 100))),
                                                    ("window", d(st.sampled_from(
                                                        ["1s", "1m", "1h"]))))
                                  if d.full or d(st.booleans())}
        plant["alarms"] = alarms
    if "retain_required" in plc and "retain" not in plc:
        del plc["retain_required"]
    return chart(d), plant


def write(directory: Path, docs: tuple[dict[str, Any], dict[str, Any]]) -> Path:
    """The chart and the plant of ``docs`` written in a new directory below ``directory``
    (a plant of its own: its own name and identity); the plant file's path."""
    where = directory / f"p{next(_serial)}"
    where.mkdir(parents=True)
    chart_doc, plant_doc = docs
    (where / "chart.yaml").write_text(yaml.safe_dump(chart_doc, allow_unicode=True,
                                                     sort_keys=False), encoding="utf-8")
    path = where / "plant.yaml"
    path.write_text(yaml.safe_dump(plant_doc, allow_unicode=True, sort_keys=False),
                    encoding="utf-8")
    return path
