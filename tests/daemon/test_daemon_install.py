"""The systemd unit and ``softplc install-service``: the unit passes ``systemd-analyze
verify`` without a warning, its exposure score is at most 2.0, the staged installation
runs its plant from /etc/softplc, and a file the user changed is never overwritten."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.controller.install import InstallError, apply, plan, unit_text
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import runtime_dir

ROOT = Path(__file__).resolve().parents[2]
SOFTPLC = str(Path(sys.executable).parent / "softplc")
needs_systemd = pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                                   reason="systemd-analyze not installed (Debian: systemd)")


def staged_unit(tmp_path: Path) -> Path:
    unit = tmp_path / "softplc.service"
    unit.write_text(unit_text(SOFTPLC, "/etc/softplc/plant.yaml"), encoding="utf-8")
    return unit


@needs_systemd
def test_unit_passes_verify_without_warnings(tmp_path: Path) -> None:
    r = subprocess.run(["systemd-analyze", "verify", str(staged_unit(tmp_path))],
                       capture_output=True, text=True, timeout=60)
    # verify exits 0 even on warnings: the contract is an empty stderr
    assert r.returncode == 0 and r.stderr.strip() == "", r.stderr


@needs_systemd
def test_unit_exposure_score(tmp_path: Path) -> None:
    r = subprocess.run(["systemd-analyze", "security", "--offline=true",
                        str(staged_unit(tmp_path))], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+) (\w+)", r.stdout)
    assert m, r.stdout + r.stderr
    sys.stderr.write(f"systemd-analyze security: {m.group(1)} {m.group(2)}\n")
    assert float(m.group(1)) <= 2.0 and m.group(2) == "OK"


def test_unit_keeps_the_essentials() -> None:
    text = unit_text("/opt/softplc/venv/bin/softplc", "/etc/softplc/plant.yaml",
                     ("dialout",))
    for line in ("Type=notify", "WatchdogSec=2s", "Restart=on-failure", "User=softplc",
                 "NoNewPrivileges=yes", "ProtectSystem=strict", "ProtectHome=yes",
                 "PrivateTmp=yes", "ReadWritePaths=/var/lib/softplc",
                 "CapabilityBoundingSet=CAP_SYS_NICE CAP_IPC_LOCK",
                 "ExecStart=/opt/softplc/venv/bin/softplc run /etc/softplc/plant.yaml",
                 "SupplementaryGroups=dialout"):
        assert line in text.splitlines(), line
    assert "User=root" not in text


def test_staged_install_runs_from_etc(tmp_path: Path) -> None:
    src = ROOT / "configs" / "pi_mcp23017" / "plant.yaml"
    done = apply(plan(str(src), SOFTPLC), root=str(tmp_path))
    etc = tmp_path / "etc" / "softplc"
    assert (etc / "drawer_tester.yaml").read_bytes() == \
        (ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml").read_bytes()
    plant_text = (etc / "plant.yaml").read_text()
    assert "grafcet: drawer_tester.yaml" in plant_text
    assert "# Drawer tester on a Raspberry Pi" in plant_text  # comments kept
    pdef = load_plant(str(etc / "plant.yaml"))
    assert pdef.instances["tester1"].grafcet.path == str(etc / "drawer_tester.yaml")
    unit = (tmp_path / "etc" / "systemd" / "system" / "softplc.service").read_text()
    assert f"ExecStart={SOFTPLC} run /etc/softplc/plant.yaml" in unit
    assert any(line.startswith("would run: systemctl enable") for line in done)
    # the same installation again changes nothing and is allowed
    apply(plan(str(src), SOFTPLC), root=str(tmp_path))


def test_install_never_overwrites_what_the_user_changed(tmp_path: Path) -> None:
    src = ROOT / "configs" / "pi_mcp23017" / "plant.yaml"
    apply(plan(str(src), SOFTPLC), root=str(tmp_path))
    mine = tmp_path / "etc" / "softplc" / "plant.yaml"
    mine.write_text(mine.read_text() + "# tuned on site\n")
    with pytest.raises(InstallError, match="left alone"):
        apply(plan(str(src), SOFTPLC), root=str(tmp_path))
    assert mine.read_text().endswith("# tuned on site\n")
    done = apply(plan(str(src), SOFTPLC), root=str(tmp_path), force=True)
    backups = list(mine.parent.glob("plant.yaml.bak-*"))
    assert len(backups) == 1 and backups[0].read_text().endswith("# tuned on site\n")
    assert any("kept the old" in line for line in done)


def test_install_warns_about_paths_the_service_cannot_use(tmp_path: Path) -> None:
    p = plan(str(ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"), SOFTPLC)
    text = "\n".join(p.warnings)
    # ${RUNTIME_DIR}: a runtime directory is emptied at every stop, no place for retain
    assert f"retain: {runtime_dir()}/drawer_tester_sim.retain.json is outside " \
        "/var/lib/softplc" in text
    # and it is /run/softplc under the service: the socket is where it should be
    assert "socket:" not in text
    assert "simulated I/O" in text
    plant = tmp_path / "plant.yaml"
    plant.write_text((ROOT / "configs" / "drawer_tester" / "plant_sim.yaml").read_text()
                     .replace("grafcet: ", f"grafcet: {ROOT}/configs/drawer_tester/")
                     .replace("'${RUNTIME_DIR}/drawer.sock'", "/tmp/softplc/drawer.sock"))
    text = "\n".join(plan(str(plant), SOFTPLC).warnings)
    assert "socket: /tmp/softplc/drawer.sock is outside /run/softplc" in text


def test_cli_refuses_a_broken_plant(tmp_path: Path) -> None:
    bad = tmp_path / "plant.yaml"
    bad.write_text("instances:\n  t: {grafcet: missing.yaml}\n")
    r = subprocess.run([SOFTPLC, "install-service", str(bad), "--root", str(tmp_path / "r")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "plant.yaml:2:16: error: grafcet file not found" in r.stderr
    assert not (tmp_path / "r").exists()


def test_exec_reload_talks_to_the_plants_own_console_socket() -> None:
    p = plan(str(ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"), SOFTPLC)
    data = p.files["/etc/systemd/system/softplc.service"].data
    assert data is not None
    unit = data.decode()
    # ${RUNTIME_DIR}/drawer.sock is /run/softplc/drawer.sock under the service
    assert f"ExecReload={SOFTPLC} reload /run/softplc/drawer.sock" in unit.splitlines()
    assert not any("systemctl reload" in w for w in p.warnings)
    assert "/etc/systemd/system/softplc-opcua.service" not in p.files


def test_a_plant_with_opcua_gets_the_opcua_unit_too(tmp_path: Path) -> None:
    """And a plant with no console socket is told that `systemctl reload` needs one."""
    from tests.opcua.kit import write_plant
    plant = write_plant(tmp_path, port=4840)
    p = plan(str(plant), SOFTPLC)
    data = p.files["/etc/systemd/system/softplc-opcua.service"].data
    assert data is not None
    unit = data.decode()
    assert f"ExecStart={SOFTPLC} opcua /etc/softplc/plant.yaml" in unit.splitlines()
    assert ["systemctl", "enable", "softplc.service", "softplc-opcua.service"] in p.commands
    assert any("systemctl reload" in w and "console.sock" in w for w in p.warnings)
    data = p.files["/etc/systemd/system/softplc.service"].data
    assert data is not None
    main = data.decode()
    assert f"ExecReload={SOFTPLC} reload /run/softplc/console.sock" in main.splitlines()
    if shutil.which("systemd-analyze"):
        staged = tmp_path / "softplc-opcua.service"
        staged.write_text(unit, encoding="utf-8")
        r = subprocess.run(["systemd-analyze", "verify", str(staged)], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 0 and r.stderr.strip() == "", r.stderr
