"""node-opcua (a client not built on asyncua, tests/opcua/node, pinned by its lock file)
driven from the tests: the alarm client ``node/alarms.js`` as a process."""

from __future__ import annotations

import json
import os
import queue
import shutil
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest

NODE_DIR = Path(__file__).resolve().parent / "node"
#: how long a node-opcua answer or event may take on a loaded machine, s
DEADLINE_S = 60.0
REFRESH_START, REFRESH_END = "ns=0;i=2787", "ns=0;i=2788"

#: the mark of a test that needs node-opcua
NEEDS_NODE = pytest.mark.skipif(
    shutil.which("node") is None or not (NODE_DIR / "node_modules" / "node-opcua-client").is_dir(),
    reason="node-opcua is not installed: cd tests/opcua/node && npm ci (scripts/test.sh "
           "does it)")


class AlarmClient:
    """tests/opcua/node/alarms.js as a process: events collected, commands answered."""

    def __init__(self, url: str, user: str | None = None, password: str | None = None
                 ) -> None:
        cfg = {"endpoint": url, "user": user, "password": password}
        self.proc = subprocess.Popen(["node", str(NODE_DIR / "alarms.js"), json.dumps(cfg)],
                                     cwd=NODE_DIR, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, env={**os.environ, "NODE_NO_WARNINGS": "1"})
        self.events: list[dict[str, Any]] = []
        self.answers: queue.Queue[dict[str, Any]] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        ready = self.answer()
        assert ready.get("ready"), ready

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if not line.startswith("{"):
                continue
            obj = json.loads(line)
            if "event" in obj:
                self.events.append(obj["event"])
            else:
                self.answers.put(obj)

    def answer(self) -> dict[str, Any]:
        got = self.answers.get(timeout=DEADLINE_S)
        assert "error" not in got, got
        return got

    def ask(self, **cmd: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return self.answer()

    def wait_event(self, pred: Any, what: str) -> dict[str, Any]:
        end = time.monotonic() + DEADLINE_S
        while True:
            found = [e for e in self.events if pred(e)]
            if found:
                return found[-1]
            assert time.monotonic() < end, f"no event: {what}; got {self.events}"
            time.sleep(0.02)

    def refresh(self) -> list[dict[str, Any]]:
        """ConditionRefresh: the condition events between RefreshStart and RefreshEnd."""
        n = len(self.events)
        assert self.ask(refresh=True) == {"refresh": "Good"}
        self.wait_event(lambda e: e["EventType"] == REFRESH_END and
                        self.events.index(e) >= n, "RefreshEnd")
        got = self.events[n:]
        types = [e["EventType"] for e in got]
        start, stop = types.index(REFRESH_START), types.index(REFRESH_END)
        return got[start + 1:stop]

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.write(json.dumps({"quit": True}) + "\n")
            self.proc.stdin.flush()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
