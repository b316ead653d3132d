"""What the feed costs the scan thread: the state is copied (Catalogue.capture) only for
what needs a copy in the controller's process: frames for a client that does not read the
shared image, and the transitions a client follows, explained every WHY_EVERY_NS."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from runtime.controller.feed import WHY_EVERY_NS, FeedServer, why_request
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import FeedReader, serving, wait_until
from tests.opcua.kit import plant_head


def _plant(tmp: Path) -> Path:
    """A 10 ms cycle sampled every scan (the feed's smallest sample)."""
    path = tmp / "plant.yaml"
    path.write_text(plant_head(tmp) + "opcua:\n  endpoint: opc.tcp://127.0.0.1:4840\n"
                    f"  sample: 10ms\n  feed: {tmp}/feed.sock\n", encoding="utf-8")
    return path


def _counting(feed: FeedServer, monkeypatch: pytest.MonkeyPatch) -> list[int]:
    copies: list[int] = []
    cat = feed._cat
    real = cat.capture

    def capture(scan: int) -> Any:
        copies.append(scan)
        return real(scan)
    monkeypatch.setattr(cat, "capture", capture)
    return copies


def _scan(feed: FeedServer) -> int:
    slot = feed._slot
    return slot[0] if slot is not None else -1


def test_the_explanations_are_copied_for_every_100_ms_not_every_sample(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        assert feed.every == 1 and feed.why_every == WHY_EVERY_NS // 10_000_000
        copies = _counting(feed, monkeypatch)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            r.sock.sendall(b'{"image": true}\n')
            # an image reader alone: the scan copies nothing
            wait_until(lambda: bool(feed._clients) and all(c.image for c in feed._clients),
                       10.0, "the client reads the image")
            start, before = _scan(feed), len(copies)
            wait_until(lambda: _scan(feed) >= start + 30, 30.0, "30 samples")
            assert len(copies) == before
            # following transitions: explained (and copied) once per WHY_EVERY_NS
            r.sock.sendall(why_request(["t1"]))
            wait_until(lambda: "t1" in r.state.whys, 10.0, "t1's transitions")
            start, before = _scan(feed), len(copies)
            wait_until(lambda: _scan(feed) >= start + 10 * feed.why_every, 60.0,
                       "ten explanation periods")
            samples = _scan(feed) - start
            made = len(copies) - before
            assert 1 <= made <= samples // feed.why_every + 2, (made, samples)
        finally:
            r.close()
