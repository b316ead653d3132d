"""Jenkins' JUnit XML schema (``junit-10.xsd``, from the Jenkins xunit plugin, MIT) for the
tests, fetched at test time and never committed: pytest's source distribution carries it
(``testing/example_scripts/junit-10.xsd``, which pytest validates its own --junitxml
against), checked against its SHA-256 and cached under the virtual environment.

``python -m tests.scenario.junitschema`` fetches it (scripts/test.sh does, before the tests).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

#: the release whose sdist holds the schema, and the schema's SHA-256 in it
PACKAGE = "pytest==9.2.0"
MEMBER = "pytest-9.2.0/testing/example_scripts/junit-10.xsd"
SHA256 = "a1a816f58d1bf95ebabf371994df0b9246dee66ea9572fbec4f9296f1b2c0ff6"
#: where it is kept: under the virtual environment the tests run in
CACHE = Path(sys.prefix) / "share" / "softplc-tests" / "junit-10.xsd"


def _good(data: bytes) -> bool:
    return hashlib.sha256(data).hexdigest() == SHA256


def schema_path() -> Path:
    """The cached schema, fetched first if it is not there (RuntimeError if it cannot be)."""
    if CACHE.exists() and _good(CACHE.read_bytes()):
        return CACHE
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, "-m", "pip", "download", "--no-binary", ":all:",
                            "--no-deps", "--disable-pip-version-check", "-q", PACKAGE,
                            "-d", tmp], capture_output=True, text=True, timeout=600,
                           check=False)
        sdists = sorted(Path(tmp).glob("pytest-*.tar.gz"))
        if r.returncode != 0 or not sdists:
            raise RuntimeError(f"pip download {PACKAGE} failed ({r.returncode}): "
                               f"{(r.stderr or r.stdout).strip()[-2000:]}")
        with tarfile.open(sdists[0]) as tar:
            f = tar.extractfile(MEMBER)
            if f is None:
                raise RuntimeError(f"{sdists[0].name} has no {MEMBER}")
            data = f.read()
    if not _good(data):
        raise RuntimeError(f"{MEMBER} of {PACKAGE}: SHA-256 {hashlib.sha256(data).hexdigest()}"
                           f", expected {SHA256}")
    CACHE.parent.mkdir(parents=True, exist_ok=True)
    part = CACHE.with_suffix(f".{os.getpid()}.part")
    part.write_bytes(data)
    part.replace(CACHE)
    return CACHE


if __name__ == "__main__":
    sys.stdout.write(f"{schema_path()}\n")
