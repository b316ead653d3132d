"""``softplc run --sim --script S``: a simulation script played against the running plant in
real time, so the demo plant moves by itself while people watch it on the console.

The events are those of ``softplc simulate`` (same file, same keys, same meaning); each is
written into the simulated inputs after the cycle that precedes its time, so the first
scan at or after ``at`` sees it, as in ``simulate``. The script's duration is ignored:
the plant keeps running after the last event.
"""

from __future__ import annotations

import logging

from runtime.engine.plant import Plant
from runtime.engine.script import Event, load_script

log = logging.getLogger(__name__)


class ScriptPlayer:
    """A daemon listener (called in the scan thread after every cycle)."""

    def __init__(self, plant: Plant, path: str) -> None:
        self.plant = plant
        _, _, self.events = load_script(path, plant)
        self.next = 0
        self.path = path
        self(-1)  # the changes at 0 ms are there for the first scan

    def __call__(self, cycle: int) -> None:
        due = self.plant.last_up + self.plant.cycle_ns if cycle >= 0 else 0
        events = self.events
        while self.next < len(events) and events[self.next].at_ns <= due:
            ev: Event = events[self.next]
            ev.apply()
            self.next += 1
        if self.next == len(events) and events:
            log.info("script %s: last event played", self.path)
            self.next += 1
