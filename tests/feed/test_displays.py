"""A BOOL driver point decodes from the shared image as a Python bool, where the JSON
frames carry what the driver list holds (0/1 ints): every display shows the same for a
point in and out, on and off, whichever way its value came (the side processes' own
conversions: Modbus coils and discrete inputs, MQTT Sparkplug metrics, OPC UA
variables). The web page shows no driver point (its rows are the instances' variables,
read alike both ways); the console reads the plant itself."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.ua.ua_binary import variant_to_binary

from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedState
from runtime.controller.image import ImageReader, ImageWriter
from runtime.engine.names import Catalogue
from runtime.language import ast as A
from runtime.language.plantfile import load_plant
from runtime.modbus.tables import Tables
from runtime.mqtt.metrics import _feed
from runtime.mqtt.payload import PLANT_TYPES, Value, encode
from runtime.opcua.space import TYPES, to_ua
from tests.opcua.kit import plant_head

POINTS = ("io.I0", "io.I1", "io.Q0", "io.Q1")


def _both(tmp: Path, on: int) -> tuple[Any, list[str], list[Any], list[Any]]:
    """(the plant definition, names, values from the image, values as frames carry
    them) with every BOOL point of the sim driver holding the int ``on``."""
    path = tmp / "plant.yaml"
    path.write_text(plant_head(tmp) + f"modbus:\n  listen: 127.0.0.1:0\n"
                    f"  feed: {tmp}/feed.sock\n", encoding="utf-8")
    pdef = load_plant(str(path))
    d = Daemon(pdef, sim=True, manage_gc=False)
    io = d.plant.drivers["io"]
    io.inputs.vals[:] = [on] * len(io.inputs.vals)  # what a driver holds: ints
    io.outputs.vals[:] = [on] * len(io.outputs.vals)
    cat = Catalogue(d.plant)
    writer = ImageWriter(cat, str(tmp / f"img{on}"), 1)
    try:
        reader = ImageReader(json.loads(json.dumps(
            {"image": writer.describe(), "specs": [list(s.spec)
                                                   for s in cat.names.values()]})))
        writer.write(1, 0)
        got = reader.read()
        reader.close()
    finally:
        writer.retire()
    assert got is not None
    img = cat.capture(0)
    framed = json.loads(json.dumps([s.read(img) for s in cat.names.values()]))
    return pdef, list(cat.names), got[2], framed


def test_a_bool_point_shows_alike_from_the_image_and_from_frames(tmp_path: Path) -> None:
    for on in (0, 1):
        pdef, names, imaged, framed = _both(tmp_path, on)
        at = [names.index(p) for p in POINTS]
        # the values differ in Python type only (bool from the image, int from frames)
        assert [imaged[i] for i in at] == [framed[i] for i in at] == [on] * 4
        assert {type(imaged[i]) for i in at} == {bool}
        # Modbus: the coils and discrete inputs of the plant's own map
        assert pdef.modbus is not None
        shown = []
        for values in (imaged, framed):
            t = Tables(pdef.modbus.points, pdef.modbus.words)
            t.refresh(defaultdict(int, zip(names, values, strict=True)).__getitem__)
            shown.append({k: list(v) for k, v in t.values.items()})
        assert shown[0] == shown[1]
        # (a driver point has no Modbus address: docs/modbus.md, its chart signal does)
        assert not any(pt.name in POINTS for pt in pdef.modbus.points)
        for i in at:
            # MQTT: the metric's bytes (its type from the name's type, BOOL: Boolean)
            st_i, st_f = FeedState(values=imaged), FeedState(values=framed)
            get = _feed(i, A.Type.BOOL)
            dt = PLANT_TYPES[A.Type.BOOL]
            assert (encode(0, [Value(1, dt, get(st_i, {}), 0, name=names[i])], 0)
                    == encode(0, [Value(1, dt, get(st_f, {}), 0, name=names[i])], 0))
            # OPC UA: the variable's Boolean value and status, as encoded
            (vi, ci), (vf, cf) = to_ua("bool", imaged[i]), to_ua("bool", framed[i])
            assert ci == cf
            vt = TYPES["bool"][0]
            assert variant_to_binary(ua.Variant(vi, vt)) == variant_to_binary(
                ua.Variant(vf, vt))
