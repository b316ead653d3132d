"""A side process decodes the shared image at its own sample, not at the feed's (the
shortest of the plant's side processes): the web page's 100 ms beside OPC UA's 10 ms."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

from runtime.controller.feedclient import POLLS_PER_SAMPLE, FeedClient, poll_period
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import serving
from tests.opcua.kit import plant_head


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
