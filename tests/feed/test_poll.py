"""A side process decodes the shared image at its own sample, not at the feed's (the
shortest of the plant's side processes): the web page's 100 ms beside OPC UA's 10 ms."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from pathlib import Path

import pytest

from bench.jitter import plant_file
from runtime.controller import feed as feed_module
from runtime.controller.feed import FeedServer
from runtime.controller.feedclient import POLLS_PER_SAMPLE, FeedClient, poll_period
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import serving, wait_until
from tests.opcua.kit import free_port, plant_head, write_plant


def test_the_poll_period_is_the_own_sample_when_longer() -> None:
    assert poll_period(0.01, 0.1) == 0.1
    assert poll_period(0.01, 0.01) == 0.01 / POLLS_PER_SAMPLE
    assert poll_period(0.05, 0.01) == 0.05 / POLLS_PER_SAMPLE
    assert poll_period(0.01, None) == 0.01 / POLLS_PER_SAMPLE


def test_a_side_process_decodes_at_its_own_sample(tmp_path: Path) -> None:
    path = tmp_path / "plant.yaml"
    path.write_text(plant_head(tmp_path) + "opcua:\n  endpoint: opc.tcp://127.0.0.1:4840\n"
                    f"  sample: 10ms\n  feed: {tmp_path}/feed.sock\n"
                    f"web:\n  listen: 127.0.0.1:0\n  sample: 100ms\n"
                    f"  feed: {tmp_path}/feed.sock\n", encoding="utf-8")
    pdef = load_plant(str(path))
    with serving(pdef) as (_d, feed):
        assert feed.every == 1  # the controller writes the image every 10 ms scan
        scans: list[int] = []

        async def nothing(*_a: object) -> None:
            return None

        async def main() -> None:
            client: FeedClient

            async def frame() -> None:
                scans.append(client.state.scan)
            client = FeedClient(feed.path, "web", nothing, frame, nothing, plant=pdef)
            task = asyncio.ensure_future(client.run())
            try:
                deadline = time.monotonic() + 60.0
                while len(scans) < 12 and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
            finally:
                client.stop()
                await asyncio.gather(task, return_exceptions=True)
        asyncio.run(main())
    assert len(scans) >= 12, scans
    # decoded about every 10 scans (100 ms of a 10 ms cycle), never every scan: counted
    # in scans, so a loaded machine changes how long the test takes, not what it checks
    steps = [b - a for a, b in zip(scans[1:], scans[2:], strict=False)]
    assert sum(steps) / len(steps) >= 7, steps


def test_a_side_process_busy_building_its_names_is_not_dropped(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A side process building its names for long (an OPC UA server's thousands of nodes:
    tens of seconds at 100 testers) reads nothing from the socket meanwhile: it asks for
    the image before building (no frames), and the controller sends it the latest status
    once it reads again, not every one meanwhile (a 100-tester plant's status, with its
    alarm board, is tens of kB a second): it keeps the side process (it dropped it for not
    reading, 1 MiB waiting, before). The buffers are made small, as a large plant's
    lines fill the real ones as fast. Both halves fail alone (4 and 10 drops)."""
    monkeypatch.setattr(feed_module, "OUT_MAX", 8192)
    # 20 drawer testers: their active steps' times change every scan (frames of changes)
    path = Path(plant_file(str(tmp_path), 20, 10, False))
    path.write_text(path.read_text(encoding="utf-8").replace("watchdog: 100ms", "watchdog: 5s")
                    + "opcua:\n  endpoint: opc.tcp://127.0.0.1:4840\n"
                    f"  sample: 10ms\n  feed: {tmp_path}/feed.sock\n", encoding="utf-8")
    pdef = load_plant(str(path))
    with serving(pdef) as (_d, feed):
        frames: list[int] = []
        built = threading.Event()

        async def main() -> None:
            client: FeedClient

            async def schema(_s: object) -> None:
                # the controller's side of this connection: a small send buffer
                wait_until(lambda: len(feed._clients) == 1, 10.0, "the connection")
                feed._clients[0].sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
                start = _scan(feed)
                # 3 s of 10 ms samples with this event loop busy (building thousands of
                # nodes is CPU work on the loop): nothing of the socket is read meanwhile
                while _scan(feed) < start + 300:
                    time.sleep(0.05)
                built.set()

            async def frame() -> None:
                frames.append(client.state.scan)

            async def nothing() -> None:
                return None
            client = FeedClient(feed.path, "opcua", schema, frame, nothing, plant=pdef)
            task = asyncio.ensure_future(client.run())
            try:
                deadline = time.monotonic() + 60.0
                while len(frames) < 20 and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
            finally:
                client.stop()
                await asyncio.gather(task, return_exceptions=True)
        asyncio.run(main())
        assert built.is_set()
        assert feed.dropped == 0
        assert len(frames) >= 20


def _scan(feed: FeedServer) -> int:
    slot = feed._slot
    return slot[0] if slot is not None else -1


def test_a_value_read_after_an_applied_write_is_the_written_one(tmp_path: Path) -> None:
    """A write answered ok, then the value read: the written one, not the image of the
    sample before (a Modbus client reading back the register it has just written got the
    old value: the image is written every sample, the answer comes within a scan)."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port(), sample="500ms")))
    with serving(pdef) as (_d, feed):
        seen: list[float] = []

        async def nothing(*_a: object) -> None:
            return None

        async def main() -> None:
            client = FeedClient(feed.path, "opcua", nothing, nothing, nothing, plant=pdef)
            task = asyncio.ensure_future(client.run())
            try:
                deadline = time.monotonic() + 30.0
                while (client.image is None or client.state.scan < 0) \
                        and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
                k = client.state.index["t1.sRate"]
                for value in (2.5, 3.5, 4.5):
                    ok, text, _code = await client.ask("set", "t1.sRate", value, "opcua",
                                                       timeout=10.0)
                    assert ok, text
                    seen.append(client.state.values[k])
            finally:
                client.stop()
                await asyncio.gather(task, return_exceptions=True)
        asyncio.run(main())
    assert seen == [2.5, 3.5, 4.5]
