"""What the feed costs the scan thread: the state is copied (Catalogue.capture) only for
what needs a copy in the controller's process: frames for a client that does not read the
shared image, and the transitions a client follows, explained every WHY_EVERY_NS."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from runtime.controller import feed as feed_module
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


def test_the_status_is_built_and_encoded_once_per_change_not_per_sample_or_client(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Four clients of the image, a sample every scan: the controller's status is built
    (``_status``) and encoded (a ``{"c": ...}`` line) once per change of what it says,
    the same bytes queued to every client; never once per sample, nor once per client."""
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (_d, feed):
        assert feed.every == 1
        readers = [FeedReader(feed.path) for _ in range(4)]
        try:
            wait_until(lambda: all(r.schemas == 1 for r in readers), 10.0, "schemas")
            for r in readers:
                r.sock.sendall(b'{"image": true}\n')
            wait_until(lambda: len(feed._clients) == 4 and all(c.image for c in feed._clients),
                       10.0, "four clients of the image")
            builds: list[int] = []
            encodes: list[int] = []
            build, line = feed._status, feed_module._line

            def counted_status(*args: Any) -> dict[str, Any]:
                builds.append(1)
                return build(*args)

            def counted_line(msg: dict[str, Any]) -> bytes:
                if "c" in msg:
                    encodes.append(1)
                return line(msg)
            monkeypatch.setattr(feed, "_status", counted_status)
            monkeypatch.setattr(feed_module, "_line", counted_line)
            got0 = [len(r.statuses) for r in readers]
            start = _scan(feed)
            # the uptime (whole seconds) and the lateness percentiles (every second) change
            # the status: at least three changes, each seen by every client
            wait_until(lambda: all(len(r.statuses) >= g + 3 for r, g in zip(readers, got0)),
                       30.0, "three changes of the status")
            samples = _scan(feed) - start
            changes = max(len(r.statuses) - g for r, g in zip(readers, got0))
            assert samples >= 100, samples
            # one build per change (and the one in progress), not one per sample
            assert len(builds) <= changes + 2, (len(builds), changes, samples)
            # one encode per change, shared: not one per client
            assert len(encodes) <= changes + 2, (len(encodes), changes)
        finally:
            for r in readers:
                r.close()
