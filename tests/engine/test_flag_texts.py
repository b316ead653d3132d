"""Each chart flag's text (runtime/language/flagtexts.py, the one home every display
reads) held to what the engine does: SFCCurrentStep's said "the first, in file order"
while the value was the last active step in file order. Each text is checked for the
words that make its claim, and the claim against a plant run on the virtual clock, read
as the feed reads it for OPC UA and MQTT (the Catalogue's readers of an Image) and as the
trace reads it (the instance); then the OPC UA Description and the MQTT metric's
description are checked to be that text."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from runtime.engine.names import Catalogue
from runtime.engine.plant import Plant
from runtime.language.flagtexts import FLAG_TEXT
from runtime.language.iolist import IOList
from runtime.language.model import MqttBroker, MqttDef, PlantDef
from runtime.language.plantfile import load_plant
from runtime.language.typecheck import FLAGS_BOOL, FLAGS_STRING

CYCLE_NS = 10_000_000
CHART = """\
grafcet: Flags
description: chart flags against their texts
memory:
  sFork: false
  sJam: false
  sBack: false
steps:
  a: {initial: true}
  b: {}
  c: {}
  d: {max: 50ms}
transitions:
  - {from: a, to: [c, b], when: sFork}
  - {from: a, to: d, when: sJam}
  - {from: [b, c], to: a, when: sBack}
  - {from: d, to: a, when: "sJam'"}
"""
#: a sequence whose every condition is true: tip mode's steps are counted on it
SEQUENCE = """\
grafcet: Sequence
steps:
  s1: {initial: true}
  s2: {}
  s3: {}
  s4: {}
transitions:
  - {from: s1, to: s2, when: "1"}
  - {from: s2, to: s3, when: "1"}
  - {from: s3, to: s4, when: "1"}
"""


class Run:
    """A plant of one instance ``f`` of CHART and one ``q`` of SEQUENCE on sim I/O and a
    virtual clock; values read as the feed reads them (Catalogue, Image)."""

    def __init__(self, tmp: Path) -> None:
        (tmp / "flags.yaml").write_text(CHART, encoding="utf-8")
        (tmp / "sequence.yaml").write_text(SEQUENCE, encoding="utf-8")
        path = tmp / "plant.yaml"
        path.write_text("plc: {cycle: 10ms}\ndrivers:\n  io: {type: sim}\n"
                        "instances:\n  f: {grafcet: flags.yaml}\n"
                        "  q: {grafcet: sequence.yaml}\n", encoding="utf-8")
        self.pdef: PlantDef = load_plant(str(path))
        self.plant = Plant(self.pdef, sim=True, virtual=True)
        self.plant.open()
        self.cat = Catalogue(self.plant)
        self.k = 0

    def scan(self, n: int = 1, **values: Any) -> Run:
        """Set ``values`` (``f_sFork=True`` sets ``f.sFork``), then run ``n`` scans."""
        for key, v in values.items():
            self.plant.set(key.replace("_", ".", 1), v)
        for _ in range(n):
            self.plant.cycle(self.k * CYCLE_NS)
            self.k += 1
        return self

    def __getitem__(self, name: str) -> Any:
        """``name``'s value as the feed sends it (OPC UA, MQTT)."""
        return self.cat.names[name].read(self.cat.capture(self.k))

    def active(self, inst: str) -> list[str]:
        """The active steps of ``inst`` in file order."""
        steps = self.pdef.instances[inst].grafcet.steps
        return [s for s in steps if self[f"{inst}.{s}.X"]]


def current_step(r: Run) -> None:
    r.scan(2, f_sFork=True)
    assert r.active("f") == ["b", "c"]  # two active steps
    assert r["f.SFCCurrentStep"] == "c" != r.active("f")[0]
    assert r.plant.instances["f"].current_step() == "c"  # as the trace has it
    r.scan(2, f_sFork=False, f_sBack=True)
    assert r.active("f") == ["a"] and r["f.SFCCurrentStep"] == "a"


def init(r: Run, flag: str = "SFCInit") -> None:
    r.scan(2, f_sFork=True)
    assert r.active("f") == ["b", "c"]
    r.scan(3, **{f"f_{flag}": True})
    assert r.active("f") == ["a"]  # back in its initial situation, and held there:
    r.scan(3, f_sFork=True)  # sFork is true, and nothing fires
    assert r.active("f") == ["a"]


def pause(r: Run) -> None:
    r.scan(1, f_SFCPause=True)
    r.scan(3, f_sFork=True)
    assert r.active("f") == ["a"]
    r.scan(2, f_SFCPause=False)
    assert r.active("f") == ["b", "c"]


def error(r: Run) -> None:
    r.scan(2, f_sJam=True)  # cycle 0 activates the initial steps, cycle 1 enters d
    assert r.active("f") == ["d"] and r["f.SFCError"] is False
    r.scan(7)  # 70 ms in d: over its max of 50 ms
    assert r["f.SFCError"] is True and r["f.SFCErrorStep"] == "d"
    r.scan(3, f_sJam=False)  # d left: the error stays until acknowledged
    assert r.active("f") == ["a"] and r["f.SFCError"] is True
    r.plant.pulse("f", "SFCQuitError")
    r.scan(2)
    assert r["f.SFCError"] is False


def enable_limit(r: Run) -> None:
    assert r["f.SFCEnableLimit"] is True  # the default
    r.scan(10, f_SFCEnableLimit=False, f_sJam=True)
    assert r.active("f") == ["d"] and r["f.SFCError"] is False


def quit_error(r: Run) -> None:
    r.scan(8, f_sJam=True)
    assert r["f.SFCError"] is True
    r.scan(2, f_SFCQuitError=True, f_sJam=False)  # d's condition to leave is true...
    assert r["f.SFCError"] is False and r.active("f") == ["d"]  # ...cleared and paused
    r.scan(2, f_SFCQuitError=False)
    assert r.active("f") == ["a"]


def tip_mode(r: Run) -> None:
    r.scan(1, f_SFCTipMode=True)
    r.scan(3, f_sFork=True)
    assert r.active("f") == ["a"]  # no SFCTip edge: nothing fires
    r.scan(1, f_SFCTip=True)
    assert r.active("f") == ["b", "c"]


def tip(r: Run) -> None:
    r.scan(2, q_SFCTipMode=True)
    assert r.active("q") == ["s1"]
    r.scan(3, q_SFCTip=True)  # one rising edge, held: one step
    assert r.active("q") == ["s2"]
    r.scan(1, q_SFCTip=False)
    r.scan(1, q_SFCTip=True)  # the next edge: the next step
    assert r.active("q") == ["s3"]


#: flag -> (the words its text must say, the run that shows them true)
CLAIMS: dict[str, tuple[tuple[str, ...], Callable[[Run], None]]] = {
    "SFCCurrentStep": (("last active step", "file order"), current_step),
    "SFCInit": (("while true", "held in its initial situation"), init),
    "SFCReset": (("while true", "initial situation"), lambda r: init(r, "SFCReset")),
    "SFCPause": (("while true", "no transition fires"), pause),
    "SFCError": (("step over its max time", "until acknowledged"), error),
    "SFCErrorStep": (("the step that set SFCError",), error),
    "SFCEnableLimit": (("max time supervision", "default true"), enable_limit),
    "SFCQuitError": (("while true", "SFCError cleared", "paused"), quit_error),
    "SFCTipMode": (("while true", "only on SFCTip"), tip_mode),
    "SFCTip": (("tip mode", "one step per rising edge"), tip),
}


def test_every_chart_flag_has_a_text_and_a_claim() -> None:
    assert set(FLAG_TEXT) == set(FLAGS_BOOL) | set(FLAGS_STRING) == set(CLAIMS)


@pytest.mark.parametrize("flag", sorted(CLAIMS))
def test_each_flags_text_says_what_the_engine_does(tmp_path: Path, flag: str) -> None:
    words, shown = CLAIMS[flag]
    text = FLAG_TEXT[flag]
    for w in words:
        assert w in text, (flag, text, w)
    shown(Run(tmp_path))


def test_sfccurrentstep_never_says_first() -> None:
    assert "first" not in FLAG_TEXT["SFCCurrentStep"]


def test_opc_ua_and_mqtt_show_these_texts(tmp_path: Path) -> None:
    """The OPC UA Description (a server's address space built from the feed's schema) and
    the MQTT metric's description property (the edge node's layout) of every chart flag
    are the one text."""
    from asyncua import Server, ua

    from runtime.mqtt.metrics import Layout
    from runtime.opcua.space import Space, build_fixed, build_names

    r = Run(tmp_path)
    schema = {"names": [[s.text, s.type.value, s.role] for s in r.cat.names.values()],
              "instances": {n: i.grafcet.name for n, i in r.pdef.instances.items()},
              "drivers": list(r.plant.drivers)}
    flags = [f"f.{flag}" for flag in FLAG_TEXT]
    q = MqttDef(brokers=[MqttBroker("mqtt://x:1883", "x", 1883, False)], group_id="G",
                edge_node_id="E", client_id="c", sample_ns=50_000_000, publish=flags)
    lay = Layout.build(schema, q, IOList(r.pdef).meaning)
    mqtt = {m.plant: m.description for m in lay.metrics if m.plant in flags}

    async def described() -> dict[str, str]:
        server = Server()
        await server.init()
        await server.register_namespace("urn:softplc:plant")
        space = Space()
        await build_fixed(server, r.pdef, space)
        await build_names(schema, space, lambda _n: False, server)
        out = {}
        for name in flags:
            text = await server.get_node(ua.NodeId(name, 2)).read_description()
            out[name] = str(text.Text)
        return out
    opcua = asyncio.run(described())
    want = {f"f.{flag}": text for flag, text in FLAG_TEXT.items()}
    assert mqtt == want
    assert opcua == want
