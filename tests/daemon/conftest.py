"""Fixtures of the daemon tests: a plant on a recording driver, daemons that are always
stopped, and a check that no test leaves a softplc thread running."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.controller.daemon import Daemon
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import CHART, MakeDaemon, RecordingDriver, plant_yaml


@pytest.fixture(autouse=True)
def no_leaked_threads() -> Iterator[None]:
    before = set(threading.enumerate())
    yield
    import time

    end = time.monotonic() + 3.0
    while True:
        left = [t for t in threading.enumerate() if t not in before and t.is_alive()
                and t.name.startswith(("softplc-", "console"))]
        if not left or time.monotonic() > end:
            break
        time.sleep(0.01)
    assert not left, f"threads left running: {[t.name for t in left]}"


@pytest.fixture
def make_daemon(tmp_path: Path) -> Iterator[MakeDaemon]:
    """make_daemon(**plant_yaml options) -> (started daemon, its recording driver).

    The daemon runs the garbage collector as ``softplc run`` does (``manage_gc``: off,
    then run in the scan's idle time): left to the interpreter, a full collection of the
    test process's heap (0.2-0.8 s late in a suite) holds the GIL wherever it falls, and
    a scan waiting for it is a freeze fault at this plant's 100 ms watchdog."""
    made: list[Daemon] = []
    (tmp_path / "runner.yaml").write_text(CHART, encoding="utf-8")

    def make(start: bool = True, manage_gc: bool = True,
             **options: str) -> tuple[Daemon, RecordingDriver]:
        path = tmp_path / f"plant{len(made)}.yaml"
        path.write_text(plant_yaml(**options), encoding="utf-8")
        pdef = load_plant(str(path))
        drv = RecordingDriver("io", {"on_fault": options.get("on_fault", "stop")})
        daemon = Daemon(pdef, plant=Plant(pdef, drivers={"io": drv}), manage_gc=manage_gc)
        made.append(daemon)
        if start:
            daemon.start()
        return daemon, drv

    yield make
    for d in made:
        d.stop("end of test")
