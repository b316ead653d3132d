"""``softplc opcua`` that cannot serve says why at once, in one line, exit status 2: its
port taken by another process, its feed path something other than a socket (issue 25:
46 lines, two asyncua tracebacks and exit 1 after 13 s)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from tests.opcua.kit import write_plant

ROOT = Path(__file__).resolve().parents[2]


def refusal(plant: Path) -> str:
    """``softplc opcua PLANT`` that must refuse: its one line (exit status 2 checked)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("JOURNAL_STREAM", None)
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "opcua", str(plant)],
                       env=env, capture_output=True, text=True, timeout=120)
    sys.stderr.write(f"softplc opcua refused in {time.monotonic() - t0:.2f} s\n")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_a_port_taken_is_one_line_at_once(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as other:
        other.bind(("127.0.0.1", 0))
        other.listen(1)
        port = other.getsockname()[1]
        plant = write_plant(tmp_path, port=port)
        line = refusal(plant)
    assert line == (f"{plant}:14:13: error: opcua endpoint: port {port} of 127.0.0.1 is in "
                    "use (another OPC UA server, or another plant's: give each plant its own "
                    "port): not started")


def test_a_feed_path_that_is_no_socket_is_one_line(tmp_path: Path) -> None:
    plant = write_plant(tmp_path, port=4840)
    (tmp_path / "feed.sock").write_text("not a socket\n", encoding="utf-8")
    assert refusal(plant) == (
        f"{plant}:16:9: error: opcua feed: {tmp_path}/feed.sock is not a socket (a regular "
        "file): the controller serves its feed there; give opcua: feed another path")
    assert (tmp_path / "feed.sock").read_text(encoding="utf-8") == "not a socket\n"
