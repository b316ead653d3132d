"""``softplc --version``: the installed package's version (importlib.metadata)."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

SOFTPLC = str(Path(sys.executable).parent / "softplc")


def test_version_is_the_installed_package_version() -> None:
    r = subprocess.run([SOFTPLC, "--version"], capture_output=True, text=True, timeout=60,
                       check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"softplc {version('softplc')}\n"
    assert version("softplc").count(".") >= 2  # the version of pyproject.toml, not a stub
