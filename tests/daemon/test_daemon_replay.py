"""``softplc run --sim --script``: the story of the drawer testers played in real time."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from runtime.controller.daemon import Daemon
from runtime.controller.replay import ScriptPlayer
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import wait_until

ROOT = Path(__file__).resolve().parents[2]
PLANT = ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"
STORY = ROOT / "configs" / "drawer_tester" / "story.yaml"


def test_story_moves_the_testers_in_real_time(tmp_path: Path) -> None:
    pdef = load_plant(str(PLANT))
    pdef.retain_path = None
    pdef.consoles = []
    daemon = Daemon(pdef, sim=True, manage_gc=False)
    player = ScriptPlayer(daemon.plant, str(STORY))
    assert daemon.plant.drivers["sim"].inputs["I0"] == 1  # the 0 ms changes are in place
    daemon.add_listener(player)
    daemon.start()
    try:
        inst = daemon.plant.instances["tester1"]
        seen: set[str] = set()

        def cycled() -> bool:
            seen.update(daemon.call(inst.active_steps))
            return {"gsParado", "gsAbrir", "gsCerrar"} <= seen

        wait_until(cycled, 15, "tester1 through gsAbrir and gsCerrar")
        wait_until(lambda: daemon.call(lambda: inst.get("sCierres")) >= 2, 15)
    finally:
        daemon.stop("test")


def test_script_needs_sim() -> None:
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(PLANT), "--script",
                        str(STORY)], capture_output=True, text=True, cwd=str(ROOT), timeout=60)
    assert r.returncode == 2 and "--script plays simulated inputs: add --sim" in r.stderr
