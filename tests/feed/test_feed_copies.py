"""What the feed costs the scan thread: the state is copied (Catalogue.capture) only for
what needs a copy in the controller's process: frames for a client that does not read the
shared image, and the transitions a client follows, explained every WHY_EVERY_NS."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from runtime.controller import feed as feed_module
from runtime.controller.feed import (
    POLL_S,
    STATS_EVERY_NS,
    WHY_EVERY_NS,
    FeedServer,
    why_request,
)
from runtime.controller.image import STAMP, STAMP_AT, ImageWriter
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import FeedReader, controller, serving, wait_until
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


def _counting_followed(feed: FeedServer, monkeypatch: pytest.MonkeyPatch
                       ) -> list[tuple[str, ...]]:
    """The instances of each copy the scan thread takes for the explanations."""
    copies: list[tuple[str, ...]] = []
    real = getattr(feed, "_copy_followed", None)

    def copy(cat: Any, names: tuple[str, ...]) -> Any:
        assert real is not None
        got = real(cat, names)
        copies.append(tuple(got))
        return got
    monkeypatch.setattr(feed, "_copy_followed", copy, raising=False)
    return copies


def test_the_explanations_are_copied_for_every_100_ms_not_every_sample(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A client of the image following one instance of two: the scan thread copies that
    instance's state once per WHY_EVERY_NS, nothing of the other, and never the whole
    image (the copy for the frames) while no client takes frames. Following both: one
    instance a copy, in turn, each once per WHY_EVERY_NS."""
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        assert feed.every == 1 and feed.why_every == WHY_EVERY_NS // 10_000_000
        assert len(d.plant.instances) == 2
        copies = _counting(feed, monkeypatch)
        followed = _counting_followed(feed, monkeypatch)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            r.sock.sendall(b'{"image": true}\n')
            # an image reader alone: the scan copies nothing
            wait_until(lambda: bool(feed._clients) and all(c.image for c in feed._clients),
                       10.0, "the client reads the image")
            start, before, before_f = _scan(feed), len(copies), len(followed)
            wait_until(lambda: _scan(feed) >= start + 30, 30.0, "30 samples")
            assert len(copies) == before and len(followed) == before_f
            # following transitions: t1's state copied once per WHY_EVERY_NS, t2's never
            r.sock.sendall(why_request(["t1"]))
            wait_until(lambda: "t1" in r.state.whys, 10.0, "t1's transitions")
            start, before, before_f = _scan(feed), len(copies), len(followed)
            wait_until(lambda: _scan(feed) >= start + 10 * feed.why_every, 60.0,
                       "ten explanation periods")
            samples = _scan(feed) - start
            assert len(copies) == before, (
                f"the whole image copied {len(copies) - before} times in {samples} samples "
                "for the explanations")
            made = followed[before_f:]
            assert 1 <= len(made) <= samples // feed.why_every + 2, (len(made), samples)
            assert all(names == ("t1",) for names in made), made
            # two followed: one instance a copy, in turn, each once per WHY_EVERY_NS (one
            # explanation a sample at most, never both in the same sample)
            r.sock.sendall(why_request(["t1", "t2"]))
            wait_until(lambda: "t2" in r.state.whys, 10.0, "t2's transitions")
            start, before_f = _scan(feed), len(followed)
            wait_until(lambda: _scan(feed) >= start + 10 * feed.why_every, 60.0,
                       "ten explanation periods")
            samples = _scan(feed) - start
            made = followed[before_f:]
            assert all(len(names) == 1 for names in made), made
            for name in ("t1", "t2"):
                got = sum(names == (name,) for names in made)
                assert 5 <= got <= samples // feed.why_every + 2, (name, got, samples)
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
            # the status: at least three changes, each seen by every client, and at least
            # 100 samples (the two changes are not in step: three can come within a second)
            wait_until(lambda: _scan(feed) - start >= 100
                       and all(len(r.statuses) >= g + 3
                               for r, g in zip(readers, got0, strict=True)),
                       30.0, "100 samples and three changes of the status")
            samples = _scan(feed) - start
            changes = max(len(r.statuses) - g for r, g in zip(readers, got0, strict=True))
            # one build per change (and the one in progress), not one per sample
            assert len(builds) <= changes + 2, (len(builds), changes, samples)
            # one encode per change, shared: not one per client
            assert len(encodes) <= changes + 2, (len(encodes), changes)
        finally:
            for r in readers:
                r.close()


def test_a_feed_without_clients_does_not_wake_every_sample(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Nobody connected: the feed thread waits for a connection (or POLL_S), not for the
    window of every scan; a client that connects then is served as before."""
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (_d, feed):
        assert feed.every == 1
        turns: list[int] = []
        until = feed.window.until

        def counted() -> float:
            turns.append(_scan(feed))
            return until()
        monkeypatch.setattr(feed.window, "until", counted)
        wait_until(lambda: _scan(feed) >= 0, 10.0, "a first sample")
        start, before, t0 = _scan(feed), len(turns), time.monotonic()
        wait_until(lambda: _scan(feed) >= start + 100, 60.0, "100 samples")
        samples, woke = _scan(feed) - start, len(turns) - before
        elapsed = time.monotonic() - t0
        # each turn waits POLL_S for a connection first (50 ms: five samples of a 10 ms
        # cycle): at most one turn per POLL_S, where it was one per sample
        assert woke <= elapsed / POLL_S + 2, (woke, samples, elapsed)
        assert woke < samples / 2, (woke, samples)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1 and bool(r.statuses), 10.0,
                       "the schema and a status")
        finally:
            r.close()


def test_the_lateness_percentiles_are_computed_once_a_second_in_slices(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The status's lateness percentiles (a sort of the window's 8192 cycles): computed
    once per STATS_EVERY_NS, not per sample, in slices with the feed's ScanWindow.pause
    between them (never one stretch holding the GIL)."""
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        stats = d.scan_stats
        real = stats.lateness_quantiles
        pauses: list[Any] = []

        def counted(pause: Any = None) -> list[int]:
            pauses.append(pause)
            return real(pause)
        monkeypatch.setattr(stats, "lateness_quantiles", counted)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            r.sock.sendall(b'{"image": true}\n')
            start, t0 = _scan(feed), time.monotonic()
            wait_until(lambda: len(pauses) >= 2 and _scan(feed) >= start + 100, 30.0,
                       "two computations and 100 samples")
            elapsed = time.monotonic() - t0
            assert len(pauses) <= elapsed * 1e9 / STATS_EVERY_NS + 2, (len(pauses), elapsed)
            assert all(p == feed.window.pause for p in pauses), pauses
            assert r.statuses[-1]["lateness_us"]["p99"] >= 0
        finally:
            r.close()


def _image_reads(feed: FeedServer) -> list[tuple[str, int]]:
    """Each read of the image's values: (the thread's name, the scheduler's seq then)."""
    reads: list[tuple[str, int]] = []
    image = feed.image
    assert image is not None
    real = image._read

    def read() -> Any:
        seq = getattr(feed.daemon.scheduler, "seq", -1)
        reads.append((threading.current_thread().name, seq))
        return real()
    image._read = read  # type: ignore[method-assign]
    return reads


def _written(image: ImageWriter) -> list[int]:
    """The scan of each image ``image`` writes from now on."""
    written: list[int] = []
    publish = image.publish

    def published(got: Any, scan: int, wall_ns: int) -> None:
        written.append(scan)
        publish(got, scan, wall_ns)
    image.publish = published  # type: ignore[method-assign]
    return written


def _image_scan(feed: FeedServer) -> int:
    """The scan the image file holds now (its stamp)."""
    image = feed.image
    assert image is not None
    return int(STAMP.unpack_from(image._mm, STAMP_AT)[0])


def test_the_scan_thread_never_reads_the_image(tmp_path: Path) -> None:
    """Issue 40: the scan thread read every value of the image at every sample (a
    generated function, one cell read per name: 62 µs at 4000 names with its data in
    the caches, 210 µs after a 10 ms idle, bench.image) and packed it. The feed thread
    reads it, between the sample's scan and the next, with the scan thread asleep (the
    scheduler's seq even), and writes it: the image still follows the scans."""
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        reads = _image_reads(feed)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            r.sock.sendall(b'{"image": true}\n')
            start = _image_scan(feed)
            wait_until(lambda: len(reads) >= 30, 30.0, "30 images read")
            assert {name for name, _ in reads} == {"softplc-feed"}, reads
            assert all(seq % 2 == 0 for _, seq in reads), reads
            assert _image_scan(feed) > start
            assert d.scan_stats.count - 1 - _image_scan(feed) <= 30
        finally:
            r.close()


def test_an_image_read_while_a_scan_ran_is_not_written(tmp_path: Path) -> None:
    """A read the scan thread interrupted (its seq moved during the read: a scan ran) is
    not one moment's state: it is not written, and the state is read again in a later
    gap, stamped with the scan it then follows (``images_late``), never with the
    sample's."""
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        image = feed.image
        assert image is not None
        real = image._read
        torn: list[int] = []

        def read() -> Any:
            got = real()
            if not torn:  # the next scan runs before the read is checked
                due = feed._image_due
                torn.append(due[1] if due is not None else -1)
                count = d.scan_stats.count
                wait_until(lambda: d.scan_stats.count > count, 10.0, "the next scan")
            return got
        image._read = read  # type: ignore[method-assign]
        written = _written(image)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            r.sock.sendall(b'{"image": true}\n')
            wait_until(lambda: bool(torn) and _image_scan(feed) > torn[0] + 2, 30.0,
                       "images after the torn one")
            assert torn[0] not in written and written[-1] > torn[0], (torn, written)
            assert feed.images_late + feed.images_missed >= 1
        finally:
            r.close()


def test_a_request_served_between_two_scans_does_not_keep_the_image_from_being_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A long cycle (50 ms) serves requests as they come, between two scans: one served
    after each sampled scan and before the feed thread reads the image changes the state
    there, but no scan has begun, so the image is still read (the scan thread waiting
    again) and written; an image that required no request served since its scan was
    missed at every such sample."""
    with controller(tmp_path, trace=False, cycle="50ms", sample="50ms") as (d, feed, _):
        image = feed.image
        assert image is not None
        written = _written(image)
        real = feed._write_image
        served: list[int] = []

        def write_image(closes: float) -> None:
            due = feed._image_due
            if due is not None and due is not feed._image_taken:
                # a request (a client's write) served by the scan thread in its wait
                d.call(lambda: served.append(d.scan_stats.count))
            real(closes)
        monkeypatch.setattr(feed, "_write_image", write_image)
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            r.sock.sendall(b'{"image": true}\n')
            first = d.scan_stats.count
            wait_until(lambda: d.scan_stats.count >= first + 20, 30.0, "20 scans")
            last = d.scan_stats.count
            got = [s for s in written if first <= s < last - 2]
            assert len(served) >= 15, served
            assert len(got) >= last - 2 - first - 2, (got, first, last, feed.images_missed)
        finally:
            r.close()
