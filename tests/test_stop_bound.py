"""A side process always ends after its stop signal (runtime/controller/aio.py,
``run_until_signal``): a task that never ends, or an event loop stuck in Python, cannot
keep it alive; it says so in one line, with every thread's stack, and exits 1 within its
bound. An orderly stop exits 0 and says nothing of the kind."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: a failure deadline for the process to end, seconds (never a speed assertion)
END_S = 20.0

SERVE = {
    # stop taken: the orderly end
    "orderly": "await stop.wait()",
    # a task that swallows every cancel (Python 3.11's wait_for did it once): asyncio.run
    # waits for it forever
    "a task that never ends": """await stop.wait()
    async def forever():
        while True:
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                pass
    asyncio.ensure_future(forever())""",
    # the event loop itself stuck in Python: its own signal handling never runs
    "a loop stuck in Python": """while True:
        pass""",
}

PROGRAM = """
import asyncio, logging, sys
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
from runtime.controller.aio import run_until_signal
async def serve(stop):
    print("ready", flush=True)
    {body}
run_until_signal(serve, bound_s=0.5)
"""


@pytest.mark.parametrize("case", list(SERVE))
def test_a_side_process_ends_after_its_stop_signal(case: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", PROGRAM.format(body=SERVE[case])],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert p.stdout is not None
        ready, _, _ = select.select([p.stdout], [], [], END_S)
        assert ready and p.stdout.readline() == "ready\n"
        time.sleep(0.05)  # into the loop (or the Python loop) past the first line
        p.send_signal(signal.SIGTERM)
        status = p.wait(timeout=END_S)
        err = p.stderr.read() if p.stderr is not None else ""
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    said = [ln for ln in err.splitlines() if "not stopped" in ln]
    if case == "orderly":
        assert status == 0 and said == [], err
        return
    assert status == 1, err
    assert said == ["ERROR runtime.controller.aio: not stopped 0.5 s after SIGTERM: every "
                    "thread's stack follows; exiting"], err
    assert 'File "<string>"' in err, err  # the stack: where it was stuck
