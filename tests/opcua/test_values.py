"""Values OPC UA cannot carry (issue 31), with asyncua's client over TCP against the server
fed by a running controller: a chart integer beyond Int64 (``sBig := sBig * 2 + 1``)
made every read BadInternalError and crashed the subscription's Publish; +Inf written to a
TIME gave BadInternalError and a traceback, and 1e300 ms was accepted as a TIME.

The mapping (docs/opcua.md, "Values out of range"): an INT beyond Int64, or a TIME
beyond 64-bit nanoseconds, reads BadOutOfRange (without a value: a Bad value carries
none, Part 4 7.7.1), the other values good; a
write of a non-finite REAL or TIME, or of a TIME beyond 64-bit nanoseconds, is refused
with BadOutOfRange and never reaches the controller."""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.language.model import PlantDef
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import FeedReader, ServerThread, serving, until, wait_until
from tests.opcua.kit import WRITER, WRITER_HASH, free_port, writer

CHART = """\
grafcet: Big
memory:
  sBig: 1
  sGrow: false
  sWait: 1s
  sRate: 1.5
steps:
  gsA: {initial: true}
  gsB: {}
transitions:
  - {from: gsA, to: gsB, when: sGrow}
post:
  - "IF sGrow THEN sBig := sBig * 2 + 1; END_IF"
"""


def plant(tmp: Path, port: int) -> Path:
    (tmp / "big.yaml").write_text(CHART, encoding="utf-8")
    path = tmp / "plant.yaml"
    path.write_text(
        "plc: {cycle: 10ms, watchdog: 5s}\ndrivers:\n  io: {type: sim}\n"
        "instances:\n  b:\n    grafcet: big.yaml\n"
        f"opcua:\n  endpoint: opc.tcp://127.0.0.1:{port}\n  sample: 50ms\n"
        f"  feed: {tmp}/feed.sock\n  writable: [b.sGrow, b.sWait, b.sRate]\n"
        f"  security: {{policies: [None], users: {{{WRITER}: '{WRITER_HASH}'}}}}\n",
        encoding="utf-8")
    return path


class Changes:
    def __init__(self) -> None:
        self.values: list[ua.DataValue] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.values.append(data.monitored_item.Value)


@contextmanager
def running(tmp: Path) -> Iterator[tuple[Daemon, FeedServer, PlantDef]]:
    """The chart's plant, running on sim I/O with its feed."""
    pdef = load_plant(str(plant(tmp, free_port())))
    with serving(pdef) as (d, feed):
        yield d, feed, pdef


def test_an_integer_beyond_int64_reads_and_publishes_as_bad_out_of_range(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.ERROR)
    with running(tmp_path) as (d, feed, pdef):
        with ServerThread(pdef) as srv:
            wait_until(lambda: srv.ps is not None and srv.ps.frames > 0, what="a frame")

            async def main() -> tuple[list[ua.DataValue], ua.DataValue, ua.DataValue]:
                changes = Changes()
                async with writer(srv.url) as c:
                    big = c.get_node("ns=2;s=b.sBig")
                    sub = await c.create_subscription(100, changes)
                    await sub.subscribe_data_change(
                        [big, c.get_node("ns=2;s=controller.scan")], queuesize=100)
                    await c.get_node("ns=2;s=b.sGrow").write_value(True)
                    await until(lambda: d.plant.instances["b"].get("sBig") > 2**70, 20,
                                 "sBig beyond 2**70")
                    n = len(changes.values)
                    # the subscription keeps publishing: controller.scan goes on
                    await until(lambda: len(changes.values) >= n + 6, 20,
                                 "publishes after sBig left Int64")
                    dv = await big.read_data_value(raise_on_bad_status=False)
                    # the other values still read good
                    scan = await c.get_node("ns=2;s=controller.scan").read_data_value()
                    await sub.delete()
                    return changes.values, dv, scan
            values, dv, scan = asyncio.run(main())
    assert dv.StatusCode.name == "BadOutOfRange" and dv.Value.Value is None
    assert scan.StatusCode.is_good()
    published = [v for v in values if v.StatusCode.name == "BadOutOfRange"]
    assert published and all(v.Value.Value is None for v in published)
    assert not [r for r in caplog.records if "Traceback" in r.getMessage()
                or r.exc_info], [r.getMessage() for r in caplog.records]


@pytest.mark.parametrize(("name", "variant"), [
    ("b.sWait", ua.Variant(math.inf, ua.VariantType.Double)),
    ("b.sWait", ua.Variant(-math.inf, ua.VariantType.Double)),
    ("b.sWait", ua.Variant(math.nan, ua.VariantType.Double)),
    ("b.sWait", ua.Variant(1e300, ua.VariantType.Double)),
    ("b.sWait", ua.Variant(9.3e12, ua.VariantType.Double)),  # past 2**63 - 1 ns
    ("b.sRate", ua.Variant(math.inf, ua.VariantType.Double)),
    ("b.sRate", ua.Variant(math.nan, ua.VariantType.Double)),
])
def test_a_write_out_of_range_is_refused(tmp_path: Path, name: str,
                                         variant: ua.Variant) -> None:
    with running(tmp_path) as (d, feed, pdef):
        with ServerThread(pdef) as srv:
            wait_until(lambda: srv.ps is not None and srv.ps.frames > 0, what="a frame")

            async def main() -> tuple[str, str]:
                async with writer(srv.url) as c:
                    params = ua.WriteParameters()
                    params.NodesToWrite = [ua.WriteValue(
                        NodeId=ua.NodeId.from_string(f"ns=2;s={name}"),
                        AttributeId=ua.AttributeIds.Value, Value=ua.DataValue(variant))]
                    bad = (await c.uaclient.write(params))[0].name
                    # a value in range is still written (a TIME of 1e12 ms: 31 years)
                    ok = ua.Variant(1e12 if name == "b.sWait" else 2.5,
                                    ua.VariantType.Double)
                    params.NodesToWrite[0].Value = ua.DataValue(ok)
                    good = (await c.uaclient.write(params))[0].name
                    return bad, good
            bad, good = asyncio.run(main())
            assert (bad, good) == ("BadOutOfRange", "Good")
            inst = d.plant.instances["b"]
            assert inst.get(name[2:]) == (10**18 if name == "b.sWait" else 2.5)


@pytest.mark.parametrize(("name", "value", "words"), [
    ("b.sWait", 1e306, "out of range"),
    ("b.sWait", 2**63, "out of range"),
    ("b.sRate", math.inf, "not a finite number"),
    ("b.sRate", math.nan, "not a finite number"),
])
def test_the_feed_refuses_values_out_of_range_too(tmp_path: Path, name: str, value: Any,
                                                  words: str) -> None:
    """A local process on the feed socket (the controller's uid) is held to the same."""
    with running(tmp_path) as (d, feed, pdef):
        r = FeedReader(feed.path)
        wait_until(lambda: len(r.frames) >= 1)
        ok, text = r.set(name, value)
        r.close()
    assert not ok and words in text, text
