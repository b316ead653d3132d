"""The host application's virtual environment (tests/mqtt/host): made by the tests on first
use from Python's own venv and pip, kept in tests/mqtt/host/.venv while its requirements
file is unchanged."""

from __future__ import annotations

import fcntl
import hashlib
import subprocess
import sys
from pathlib import Path

HOST_DIR = Path(__file__).resolve().parent / "host"
VENV = HOST_DIR / ".venv"


def host_python() -> str:
    """The host application's interpreter; the environment made or remade if needed
    (RuntimeError with pip's output if it cannot be)."""
    req = HOST_DIR / "requirements.txt"
    digest = hashlib.sha256(req.read_bytes()).hexdigest()
    python = VENV / "bin" / "python"
    marker = VENV / "requirements.sha256"
    HOST_DIR.mkdir(exist_ok=True)
    with open(HOST_DIR / ".venv.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one maker at a time
        if python.exists() and marker.exists() and marker.read_text() == digest:
            return str(python)
        steps = [[sys.executable, "-m", "venv", "--clear", str(VENV)],
                 [str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                  "-r", str(req)]]
        for cmd in steps:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
            if r.returncode != 0:
                raise RuntimeError(f"{' '.join(cmd)}: {r.stdout}{r.stderr}")
        marker.write_text(digest)
    return str(python)
