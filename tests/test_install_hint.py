"""A missing extra is named with the command that installs it into the environment that
runs softplc, from the source tree it was installed from (``drivers/registry.py``
``install_hint``): never ``pip install 'softplc[mqtt]'``, a name this project does not
publish on a package index (following it would fetch whatever owns that name)."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.opcua.kit import free_port
from tests.web.kit import write_plant

ROOT = Path(__file__).resolve().parents[1]
#: what the test environment is: scripts/setup.sh's editable install of this checkout
HERE = f"{shlex.quote(sys.executable)} -m pip install -e {shlex.quote(f'{ROOT}[mqtt]')}"

CHILD = """
import sys
sys.modules[sys.argv[1]] = None  # import raises ModuleNotFoundError: the extra is missing
from runtime.cli import main
sys.exit(main(sys.argv[2:]))
"""


def test_the_hint_is_this_environment_s_pip_and_this_checkout() -> None:
    from drivers.registry import install_hint

    assert install_hint("mqtt") == HERE


@pytest.mark.parametrize("library,command,extra", [
    ("aiomqtt", "mqtt", "mqtt"), ("aiohttp", "web", "web"), ("asyncua", "opcua", "opcua")])
def test_a_side_process_without_its_extra_names_the_checkout_s_install(
        tmp_path: Path, library: str, command: str, extra: str) -> None:
    plant = write_plant(tmp_path, web="mqtt:\n  brokers: [mqtt://127.0.0.1:1]\n  group_id: g\n"
                        "  edge_node_id: e\nopcua:\n  endpoint: opc.tcp://127.0.0.1:"
                        f"{free_port()}\n")
    r = subprocess.run([sys.executable, "-c", CHILD, library, command, str(plant)],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path, check=False)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "'softplc[" not in r.stderr, r.stderr
    want = HERE.replace("[mqtt]", f"[{extra}]")
    assert r.stderr.rstrip().endswith(f"install the {extra} extra: {want}"), r.stderr
