"""The shared image (runtime/controller/image.py): what a side process decodes from it is
what the controller's Catalogue reads; the seqlock never yields a torn copy; the file's
mode, life and identity."""

from __future__ import annotations

import json
import multiprocessing
import os
import stat
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from bench.jitter import plant_file
from runtime.compiler.guard import GeneratedCodeRefused
from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.controller.image import (
    CRC,
    CRC_AT,
    DATA_AT,
    MAGIC,
    SEQ,
    SEQ_AT,
    STAMP_AT,
    ImageError,
    ImageReader,
    ImageWriter,
    _reader_code,
    image_path,
)
from runtime.engine.names import Catalogue
from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import FeedReader, serving, wait_until
from tests.opcua.kit import plant_head

#: an output of t2 bound inverted, a string slot (SFCErrorStep), step times
INVERTED = "    outputs: {oLamp: {to: io.Q1, invert: true}}\n"


def _plant(tmp: Path, sample: str = "20ms") -> Path:
    head = plant_head(tmp).replace("    outputs: {oLamp: io.Q1}\n", INVERTED)
    path = tmp / "plant.yaml"
    path.write_text(head + f"opcua:\n  endpoint: opc.tcp://127.0.0.1:4840\n"
                    f"  sample: {sample}\n  feed: {tmp}/feed.sock\n", encoding="utf-8")
    return path


def _schema(feed: FeedServer) -> dict[str, Any]:
    schema: dict[str, Any] = json.loads(feed._schema_line)["schema"]
    return schema


def _both_ways(d: Daemon, feed: FeedServer) -> tuple[list[Any], list[Any], list[str]]:
    """At one scan boundary: the image written and captured (the feed's own writes
    unhooked meanwhile: ``_compare``); (decoded, the Catalogue's reading, names)."""
    cat = Catalogue(d.plant)
    image = feed.image
    assert image is not None
    reader = ImageReader(_schema(feed))

    def at_boundary() -> Any:
        image.write(10**9, time.time_ns())
        return cat.capture(0)
    call = d.submit(at_boundary)
    assert call.done.wait(10.0)
    got = reader.read()
    assert got is not None
    return got[2], [s.read(call.result) for s in cat.names.values()], list(cat.names)


def _same(decoded: list[Any], read: list[Any], names: list[str]) -> list[str]:
    return [f"{n}: image {a!r}, catalogue {b!r}" for n, a, b in zip(names, decoded, read,
                                                                    strict=True)
            if not (a == b or (a != a and b != b))]


def _compare(d: Daemon, feed: FeedServer) -> None:
    """Every name decoded from the image equals the Catalogue's reading of the same scan
    (the controller's writes paused meanwhile: the feed unhooked for the comparison)."""
    d.remove_listener(feed.on_scan)
    try:
        decoded, read, names = _both_ways(d, feed)
    finally:
        d.add_listener(feed.on_scan)
    assert _same(decoded, read, names) == []


def test_every_name_decoded_from_the_image_is_what_the_catalogue_reads(
        tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        plant = d.plant
        assert feed.image is not None
        # steps active with their times running (the blinker), an input on
        d.submit(lambda: plant.set("io.I0", True)).done.wait(5.0)
        wait_until(lambda: plant.instances["t1"].get("sN") >= 2, 10.0, "t1 blinking")
        _compare(d, feed)
        # a forced point, a forced variable, a jammed chart with its SFCError step string
        d.submit(lambda: plant.force("io.Q0", 1)).done.wait(5.0)
        d.submit(lambda: plant.force("t2.sRate", 2.5)).done.wait(5.0)
        d.submit(lambda: plant.set("t2.sJam", True)).done.wait(5.0)
        wait_until(lambda: bool(plant.instances["t2"].get("SFCError")), 10.0, "t2 error")
        _compare(d, feed)
        # the outputs held off (iocheck: every point written off, the inverted one too)
        d.submit(lambda: plant.unforce()).done.wait(5.0)
        d.submit(lambda: plant.set_iocheck(True)).done.wait(5.0)
        wait_until(lambda: plant.iocheck, 10.0, "iocheck")
        _compare(d, feed)


def test_a_value_beyond_64_bits_is_shown_beyond_and_counted(tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        plant = d.plant
        d.remove_listener(feed.on_scan)
        d.submit(lambda: plant.instances["t1"].set("sN", 1 << 70)).done.wait(5.0)
        image = feed.image
        assert image is not None
        d.submit(lambda: image.write(1, 0)).done.wait(5.0)
        values = ImageReader(_schema(feed)).read()
        assert values is not None
        names = [n[0] for n in _schema(feed)["names"]]
        # shown beyond the 64-bit range (out of range to OPC UA), counted
        assert values[2][names.index("t1.sN")] == 1 << 63
        assert image.lossy == 1
        # back in range (t1 counts on from there): shown as it is again
        d.submit(lambda: plant.instances["t1"].set("sN", 5)).done.wait(5.0)
        d.submit(lambda: image.write(2, 0)).done.wait(5.0)
        values = ImageReader(_schema(feed)).read()
        assert values is not None and 5 <= values[2][names.index("t1.sN")] < 1000


def test_the_file_is_0640_replaces_a_stale_one_and_is_removed_at_stop(
        tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    path = image_path(str(tmp_path / "feed.sock"))
    # an image a crashed controller left: replaced, never reused
    Path(path).write_bytes(MAGIC + b"\0" * 200)
    stale_ino = os.stat(path).st_ino
    with serving(pdef) as (_d, feed):
        st = os.stat(path)
        assert stat.S_IMODE(st.st_mode) == 0o640
        assert st.st_ino != stale_ino
        schema = _schema(feed)
        assert schema["image"]["path"] == path
        ImageReader(schema).close()
        # a reader given a description whose token is not the file's refuses it
        forged = json.loads(json.dumps(schema))
        forged["image"]["token"] = "00" * 16
        with pytest.raises(ImageError, match="not trusted"):
            ImageReader(forged)
    assert not os.path.exists(path)


def test_a_file_that_is_no_image_is_left_alone_and_frames_are_served(
        tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    path = image_path(str(tmp_path / "feed.sock"))
    Path(path).write_text("the user's notes\n", encoding="utf-8")
    with serving(pdef) as (_d, feed):
        assert feed.image is None and _schema(feed)["image"] is None
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: len(r.frames) >= 2, 10.0, "frames")
        finally:
            r.close()
    assert Path(path).read_text(encoding="utf-8") == "the user's notes\n"


def test_an_online_change_makes_a_new_generation_the_clients_follow(
        tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        r = FeedReader(feed.path)
        try:
            wait_until(lambda: r.schemas == 1, 10.0, "schema")
            first = _schema(feed)["image"]
            feed.plant_replaced()
            wait_until(lambda: r.schemas == 2, 10.0, "the new schema")
            second = _schema(feed)["image"]
            assert second["generation"] == first["generation"] + 1
            assert second["token"] != first["token"]
            reader = ImageReader(_schema(feed))
            got = reader.read()
            scan = got[0] if got is not None else -1
            wait_until(lambda: (reader.read() or (-1,))[0] > scan, 10.0, "new writes")
            with pytest.raises(ImageError):
                ImageReader({**_schema(feed), "image": first})
        finally:
            r.close()


def _torn_writer(path: str, stop: Any) -> None:  # pragma: no cover - another process
    """Pack changing patterns: every 8-byte word of a write holds the same number (and
    the write's checksum, as ImageWriter.write stores it)."""
    import mmap as _mmap
    import zlib as _zlib
    fd = os.open(path, os.O_RDWR)
    mm = _mmap.mmap(fd, 0)
    words = (len(mm) - STAMP_AT) // 8
    pattern = struct.Struct(f"<{words}q")
    k = 0
    while not stop.is_set():
        k += 1
        SEQ.pack_into(mm, SEQ_AT, 2 * k - 1)
        pattern.pack_into(mm, STAMP_AT, *([k] * words))
        CRC.pack_into(mm, CRC_AT, _zlib.crc32(mm[STAMP_AT:]))
        SEQ.pack_into(mm, SEQ_AT, 2 * k)
    mm.close()
    os.close(fd)


def test_the_seqlock_never_yields_a_torn_copy(tmp_path: Path) -> None:
    """A writer process packs patterns as fast as it can; every copy the reader keeps is
    one write's (all words equal), and the reader kept many distinct ones."""
    pdef = load_plant(str(_plant(tmp_path)))
    d = Daemon(pdef, sim=True, manage_gc=False)
    writer = ImageWriter(Catalogue(d.plant), str(tmp_path / "img"), 1)
    schema = {"image": writer.describe(), "specs": []}
    reader = ImageReader(json.loads(json.dumps(schema)))
    ctx = multiprocessing.get_context("spawn")
    stop = ctx.Event()
    proc = ctx.Process(target=_torn_writer, args=(writer.path, stop))
    proc.start()
    seen: set[int] = set()
    kept = 0
    try:
        deadline = time.monotonic() + 60.0
        while len(seen) < 200 and time.monotonic() < deadline:
            data = reader.snapshot()
            if data is None:
                continue
            words = struct.unpack_from(f"<{(len(data) - STAMP_AT) // 8}q", data, STAMP_AT)
            assert len(set(words)) == 1, f"a torn copy: {sorted(set(words))[:4]}"
            seen.add(words[0])
            kept += 1
    finally:
        stop.set()
        proc.join(30.0)
        writer.retire()
    assert len(seen) >= 200, f"only {len(seen)} distinct writes seen in {kept} copies"


def test_a_reader_never_writes_the_file(tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    d = Daemon(pdef, sim=True, manage_gc=False)
    writer = ImageWriter(Catalogue(d.plant), str(tmp_path / "img"), 1)
    reader = ImageReader({"image": writer.describe(), "specs": []})
    with pytest.raises(TypeError):
        reader._mm[0:1] = b"x"
    writer.retire()


def test_a_halt_with_a_forced_point_is_read_alike(tmp_path: Path) -> None:
    pdef = load_plant(str(_plant(tmp_path)))
    with serving(pdef) as (d, feed):
        plant = d.plant
        d.submit(lambda: plant.force("io.Q0", 1)).done.wait(5.0)
        wait_until(lambda: plant.drivers["io"].outputs["Q0"] == 1, 10.0, "forced")
        threading.Thread(target=d.require_ack, args=("test",), daemon=True).start()
        wait_until(lambda: d.halted is not None, 10.0, "halted")
        _compare(d, feed)
        reader = ImageReader(_schema(feed))
        names = [n[0] for n in _schema(feed)["names"]]
        got = reader.read()
        assert got is not None and got[2][names.index("io.Q0")] == 0


def test_a_torn_image_with_an_even_unchanged_counter_is_refused(tmp_path: Path) -> None:
    """What a weakly ordered CPU (ARM) may show another core: the counter's and the
    stamp's final stores of write B, the data stores not yet (the data still write A's).
    The counter is even and unchanged around the copy, so the seqlock alone accepts it;
    the checksum must refuse it."""
    pdef = load_plant(str(_plant(tmp_path)))
    d = Daemon(pdef, sim=True, manage_gc=False)
    t1 = d.plant.instances["t1"]
    writer = ImageWriter(Catalogue(d.plant), str(tmp_path / "img"), 1)
    specs = [list(s.spec) for s in Catalogue(d.plant).names.values()]
    reader = ImageReader(json.loads(json.dumps({"image": writer.describe(),
                                                "specs": specs})))
    try:
        t1.set("sN", 7)
        writer.write(1, 0)
        old_data = bytes(writer._mm[DATA_AT:writer.size])
        t1.set("sN", 8)
        writer.write(2, 0)
        good = reader.read()
        assert good is not None and good[0] == 2
        # the torn view: B's counter (even) and stamp, A's data
        writer._mm[DATA_AT:writer.size] = old_data
        assert SEQ.unpack_from(writer._mm, SEQ_AT)[0] % 2 == 0
        assert reader.snapshot() is None
        assert reader.read() is None
        assert reader.age_s() is None  # nor does a torn stamp say how old the image is
        # the next complete write is accepted again
        writer.write(3, 0)
        again = reader.read()
        assert again is not None and again[0] == 3
        age = reader.age_s()
        assert age is not None and age >= 0.0
    finally:
        reader.close()
        writer.retire()


@pytest.mark.parametrize("term", ["c0.__class__", "c0.f()", "open(c0)", "c0.get().x",
                                  "c0[0]", "(lambda: c0)()", "c0)\n import os\n ("])
def test_a_tampered_term_of_the_generated_reader_is_refused(term: str) -> None:
    """The scan thread's reader function is generated text: a term outside its shape (an
    attribute, a call, a subscript, a line) is refused before anything of it runs."""
    assert _reader_code(["c0"], ["(c0, bool(c0.ok), c0.get(), )", "(*c0, )"]).co_freevars \
        == ("c0",)
    for region in (term, f"({term}, )", f"(c0, {term}, )"):
        with pytest.raises(GeneratedCodeRefused, match="image reader"):
            _reader_code(["c0"], [region])


def test_the_generated_reader_passes_the_guard(monkeypatch: pytest.MonkeyPatch) -> None:
    """Its bytecode goes through the guard every generated program passes: a guard that
    refuses everything refuses it."""
    import runtime.controller.image as image_mod

    def refuse(_src: str, filename: str, *_a: Any, **_k: Any) -> Any:
        raise GeneratedCodeRefused(filename, 1, "refused by the test")
    monkeypatch.setattr(image_mod, "checked_code", refuse)
    with pytest.raises(GeneratedCodeRefused, match="refused by the test"):
        _reader_code(["c0"], ["(c0, )"])


@pytest.mark.parametrize("plant", ["blink", "drawers"])
def test_a_change_between_two_writes_is_read_back_whatever_its_region(
        tmp_path: Path, plant: str) -> None:
    """The writer skips a region (or a block of regions) whose values equal those it last
    packed: each change below, alone between two writes, is read back, and every other
    name still equals the Catalogue's reading (a numeric slot of an instance, one in the
    last block, a string slot, a driver's input and output points, its ok flag, a step's
    time as the chart clock advances; in the blink plant a REAL slot to -0.0, which equals
    0.0 but packs apart)."""
    from drivers.base import Health

    # the drawers: bench/jitter.py's plant, without REAL (its numeric regions are
    # compared by blocks, no REAL to check), its driver ``sim``
    path = (str(_plant(tmp_path)) if plant == "blink"
            else plant_file(str(tmp_path), 40, 10, False))
    dname = "io" if plant == "blink" else "sim"
    d = Daemon(load_plant(path), sim=True, manage_gc=False)
    insts, io = d.plant.instances, d.plant.drivers[dname]
    first, last = insts["t1"], insts["t2" if plant == "blink" else "t39"]
    cat = Catalogue(d.plant)
    names = list(cat.names)
    writer = ImageWriter(cat, str(tmp_path / "img"), 1)
    reader = ImageReader(json.loads(json.dumps(
        {"image": writer.describe(), "specs": [list(s.spec) for s in cat.names.values()]})))
    step_t = next(n for n in names if n.startswith("t1.") and n.endswith(".T"))
    x = cat.names[step_t].spec[3]
    err = cat.names["t1.SFCErrorStep"].spec[2]  # a chart flag: the scan writes it
    var = "sN" if plant == "blink" else "sCierres"
    last_name = f"{'t2' if plant == 'blink' else 't39'}.{var}"

    def advance_clock() -> None:
        first.m[x] = first.m[x] + 10**6
    io.health = Health.OK
    changes: list[tuple[str, Callable[[], None]]] = [
        (f"t1.{var}", lambda: first.set(var, 41)),
        (last_name, lambda: last.set(var, 42)),
        ("t1.SFCErrorStep", lambda: first.m.__setitem__(err, "gsB")),
        (f"{dname}.I1", lambda: io.inputs.__setitem__("I1", 1)),
        (f"{dname}.Q0", lambda: io.outputs.__setitem__("Q0", 1)),
        (f"{dname}.ok", lambda: setattr(io, "health", Health.FAULT)),
        (step_t, advance_clock),
    ]
    if plant == "blink":
        last.set("sRate", 0.0)
        changes.append(("t2.sRate", lambda: last.set("sRate", -0.0)))
    try:
        writer.write(1, 0)
        for scan, (name, change) in enumerate(changes, 2):
            before = cat.names[name].read(cat.capture(0))
            change()
            after = cat.names[name].read(cat.capture(0))
            assert repr(after) != repr(before), name  # the change is one
            writer.write(scan, 0)
            got = reader.read()
            assert got is not None and got[0] == scan
            shown = got[2][names.index(name)]
            assert shown == after and str(shown).startswith("-") == str(after).startswith(
                "-"), f"{name}: shown {shown!r}, is {after!r}"
            img = cat.capture(0)
            assert _same(got[2], [s.read(img) for s in cat.names.values()], names) == []
    finally:
        reader.close()
        writer.retire()
