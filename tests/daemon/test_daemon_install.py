"""The template units and ``softplc install-service``: the units pass ``systemd-analyze
verify`` without a warning and score at most 2.0, both units of a plant look in the same
runtime directory, the staged installation runs its plant from /etc/softplc/NAME, a file the
user changed is never overwritten, what the service could not see or use is refused with
one line naming the path and the directive, and ``--now`` restarts or reloads a running
controller and says which (against a stand-in ``systemctl`` that records what it is asked;
tests/systemd/ runs the same under a real systemd)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.controller import install
from runtime.controller.install import (
    CONTROLLER,
    MODBUS,
    MQTT,
    OPCUA,
    WEB,
    InstallError,
    NowRefused,
    apply,
    bring_up,
    opcua_unit_text,
    plan,
    side_unit_text,
    unit_text,
)
from runtime.language.plantfile import load_plant
from tests.change.changekit import without_web

ROOT = Path(__file__).resolve().parents[2]
SOFTPLC = str(Path(sys.executable).parent / "softplc")
DRAWER = ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"
needs_systemd = pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                                   reason="systemd-analyze not installed (Debian: systemd)")


def staged_units(tmp_path: Path) -> list[Path]:
    out = []
    for name, text in ((CONTROLLER, unit_text(SOFTPLC)), (OPCUA, opcua_unit_text(SOFTPLC)),
                       (MQTT, side_unit_text("mqtt", SOFTPLC)),
                       (WEB, side_unit_text("web", SOFTPLC)),
                       (MODBUS, side_unit_text("modbus", SOFTPLC))):
        unit = tmp_path / name.replace("@.", "@demo.")  # an instance, as systemd loads it
        unit.write_text(text, encoding="utf-8")
        out.append(unit)
    return out


@needs_systemd
def test_units_pass_verify_without_warnings(tmp_path: Path) -> None:
    for unit in staged_units(tmp_path):
        r = subprocess.run(["systemd-analyze", "verify", str(unit)],
                           capture_output=True, text=True, timeout=60)
        # verify exits 0 even on warnings: the contract is an empty stderr
        assert r.returncode == 0 and r.stderr.strip() == "", (unit.name, r.stderr)


@needs_systemd
def test_units_exposure_score(tmp_path: Path) -> None:
    for unit in staged_units(tmp_path):
        r = subprocess.run(["systemd-analyze", "security", "--offline=true", str(unit)],
                           capture_output=True, text=True, timeout=60)
        m = re.search(r"Overall exposure level for \S+: (\d+\.\d+) (\w+)", r.stdout)
        assert m, r.stdout + r.stderr
        sys.stderr.write(f"systemd-analyze security {unit.name}: {m.group(1)} {m.group(2)}\n")
        assert float(m.group(1)) <= 2.0 and m.group(2) == "OK"


def test_unit_keeps_the_essentials() -> None:
    text = unit_text("/opt/softplc/venv/bin/softplc", groups=("dialout",))
    for line in ("Type=notify", "WatchdogSec=2s", "Restart=on-failure", "User=softplc",
                 "NoNewPrivileges=yes", "ProtectSystem=strict", "ProtectHome=yes",
                 "PrivateTmp=yes", "StateDirectory=softplc", "RuntimeDirectory=softplc/%i",
                 "RuntimeDirectoryPreserve=yes",
                 "CapabilityBoundingSet=CAP_SYS_NICE CAP_IPC_LOCK",
                 "ExecStart=/opt/softplc/venv/bin/softplc run /etc/softplc/%i/plant.yaml",
                 "ExecReload=/opt/softplc/venv/bin/softplc reload /etc/softplc/%i/plant.yaml",
                 "SupplementaryGroups=dialout"):
        assert line in text.splitlines(), line
    assert "User=root" not in text


def unit_keys(text: str) -> dict[str, str]:
    return {k: v for k, _, v in (line.partition("=") for line in text.splitlines()
                                 if "=" in line and not line.startswith("#"))}


def test_the_side_units_look_for_the_feed_where_the_controller_serves_it(
        tmp_path: Path) -> None:
    """Issue 25: softplc-opcua.service looked for /tmp/softplc-999/feed.sock (no
    RuntimeDirectory=, so ${RUNTIME_DIR} fell back to /tmp, hidden by its PrivateTmp
    anyway) while softplc.service served /run/softplc/feed.sock; issue 28's
    softplc-mqtt.service the same. Each staged unit's plant is loaded with the environment
    systemd gives that unit and the feed found by ``locate`` (what ``softplc opcua`` and
    ``softplc mqtt`` do); all three must name one feed."""
    from tests.opcua.kit import write_plant
    src = tmp_path / "press"
    src.mkdir()
    plant = write_plant(src, port=4840)
    text = plant.read_text(encoding="utf-8") + (
        "mqtt:\n  brokers: [mqtt://127.0.0.1:1883]\n  group_id: plant\n")
    plant.write_text(re.sub(r"  feed: .*\n", "", text), encoding="utf-8")  # the default
    stage = tmp_path / "stage"
    r = subprocess.run([SOFTPLC, "install-service", str(plant), "--root", str(stage)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    feeds = {}
    for unit in sorted((stage / "etc" / "systemd" / "system").glob("softplc*.service")):
        keys = unit_keys(unit.read_text(encoding="utf-8"))
        argv = keys["ExecStart"].replace("%i", "press").split()
        env = {"PATH": os.environ["PATH"], "PYTHONPATH": str(ROOT)}  # a system unit's
        if "RuntimeDirectory" in keys:
            env["RUNTIME_DIRECTORY"] = "/run/" + keys["RuntimeDirectory"].replace("%i", "press")
        probe = ("import sys; from runtime.language.plantfile import load_plant; "
                 "from runtime.language.runtimedir import locate; "
                 "print(locate(load_plant(sys.argv[1])).feed)")
        out = subprocess.run([sys.executable, "-c", probe, str(stage) + argv[2]], env=env,
                             capture_output=True, text=True, timeout=60, cwd=str(stage))
        assert out.returncode == 0, out.stderr
        feeds[unit.name] = out.stdout.strip()
    assert len(feeds) == 3, feeds
    assert len(set(feeds.values())) == 1, feeds
    assert next(iter(feeds.values())) == "/run/softplc/press/feed.sock"


def test_staged_install_runs_from_etc(tmp_path: Path) -> None:
    src = ROOT / "configs" / "pi_mcp23017" / "plant.yaml"
    done = apply(plan(str(src), SOFTPLC, root=str(tmp_path)), root=str(tmp_path))
    etc = tmp_path / "etc" / "softplc" / "pi_mcp23017"
    assert (etc / "drawer_tester.yaml").read_bytes() == \
        (ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml").read_bytes()
    plant_text = (etc / "plant.yaml").read_text()
    assert "grafcet: drawer_tester.yaml" in plant_text
    assert "# Drawer tester on a Raspberry Pi" in plant_text  # comments kept
    pdef = load_plant(str(etc / "plant.yaml"))
    assert pdef.instances["tester1"].grafcet.path == str(etc / "drawer_tester.yaml")
    unit = (tmp_path / "etc" / "systemd" / "system" / "softplc@.service").read_text()
    assert f"ExecStart={SOFTPLC} run /etc/softplc/%i/plant.yaml" in unit
    assert "would run: systemctl enable softplc@pi_mcp23017.service" in done
    # the same installation again changes nothing and is allowed
    p = plan(str(src), SOFTPLC, root=str(tmp_path))
    assert not p.changed and not p.restart_reasons
    apply(p, root=str(tmp_path))


def test_install_never_overwrites_what_the_user_changed(tmp_path: Path) -> None:
    src = ROOT / "configs" / "pi_mcp23017" / "plant.yaml"
    apply(plan(str(src), SOFTPLC, root=str(tmp_path)), root=str(tmp_path))
    mine = tmp_path / "etc" / "softplc" / "pi_mcp23017" / "plant.yaml"
    mine.write_text(mine.read_text() + "# tuned on site\n")
    with pytest.raises(InstallError, match="left alone"):
        apply(plan(str(src), SOFTPLC, root=str(tmp_path)), root=str(tmp_path))
    assert mine.read_text().endswith("# tuned on site\n")
    done = apply(plan(str(src), SOFTPLC, root=str(tmp_path)), root=str(tmp_path), force=True)
    backups = list(mine.parent.glob("plant.yaml.bak-*"))
    assert len(backups) == 1 and backups[0].read_text().endswith("# tuned on site\n")
    assert any("kept the old" in line for line in done)


def test_warnings_name_the_services_paths(tmp_path: Path) -> None:
    """Issue 25: the retain warning named the installer's ${RUNTIME_DIR}
    (/tmp/softplc-0/...), not the service's (/run/softplc/...)."""
    r = subprocess.run([SOFTPLC, "install-service", str(DRAWER), "--root", str(tmp_path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "warning: plc: retain: /run/softplc/drawer_tester/drawer_tester_sim.retain.json " \
           "is in the runtime directory /run/softplc/drawer_tester, emptied at every reboot" \
           in r.stderr
    # no warning names the installer's own runtime directory (the ExecStart warnings may
    # name /tmp when the suite runs from a clone there: they are about the program)
    retain = [ln for ln in r.stderr.splitlines() if "retain" in ln]
    assert retain and not any("/tmp" in ln for ln in retain), r.stderr
    assert "simulated I/O" in r.stderr


def refusals(tmp_path: Path, plant_text: str, softplc: str = SOFTPLC, **kw: object
             ) -> list[str]:
    d = tmp_path / "site"
    d.mkdir(exist_ok=True)
    plant = d / "plant.yaml"
    plant.write_text(plant_text.replace("grafcet: ", f"grafcet: {DRAWER.parent}/"),
                     encoding="utf-8")
    p = plan(str(plant), softplc, root=str(tmp_path / "stage"), **kw)  # type: ignore[arg-type]
    with pytest.raises(InstallError) as exc:
        apply(p, root=str(tmp_path / "stage"))
    assert not (tmp_path / "stage").exists()  # nothing written
    return str(exc.value).splitlines()


def test_paths_the_service_cannot_see_or_write_are_refused(tmp_path: Path) -> None:
    text = DRAWER.read_text(encoding="utf-8")
    got = refusals(tmp_path, text.replace("'${RUNTIME_DIR}/drawer.sock'", "/tmp/drawer.sock")
                   .replace("${RUNTIME_DIR}/drawer_tester_sim.retain.json",
                            "/home/me/drawer.retain.json"))
    assert got == [
        "plc: retain: /home/me/drawer.retain.json is hidden from the service by "
        "ProtectHome=yes: use /var/lib/softplc/site.retain.json",
        "monitor: socket: /tmp/drawer.sock is outside the runtime directory /run/softplc/site:"
        " nobody outside the service would reach it (PrivateTmp=yes); put it in "
        "'${RUNTIME_DIR}/'"]  # the web view's feed stays in the plant's runtime directory
    got = refusals(tmp_path, text.replace("${RUNTIME_DIR}/drawer_tester_sim.retain.json",
                                          "/srv/drawer.retain.json"))
    assert got == ["plc: retain: /srv/drawer.retain.json cannot be written by the service "
                   "(ProtectSystem=strict: it writes only /var/lib/softplc and "
                   "/run/softplc/site): use /var/lib/softplc/site.retain.json"]


def test_certificates_the_service_cannot_see_are_refused(tmp_path: Path) -> None:
    """Issue 25: certificate paths under /tmp were written into the unit without a word."""
    cert, key = tmp_path / "server-cert.der", tmp_path / "server-key.pem"
    cert.write_bytes(b"x")
    key.write_bytes(b"x")  # there (a missing one is refused when the plant is loaded)
    text = DRAWER.read_text(encoding="utf-8") + (
        "opcua:\n  security:\n"
        f"    certificate: {cert}\n    private_key: {key}\n")
    got = refusals(tmp_path, text)
    assert got == [f"opcua: security: certificate: {cert} is hidden from the service by "
                   "PrivateTmp=yes: keep it under /etc/softplc",
                   f"opcua: security: private_key: {key} is hidden from the service by "
                   "PrivateTmp=yes: keep it under /etc/softplc"]


def test_mqtt_files_the_service_cannot_see_or_read_are_refused(tmp_path: Path) -> None:
    """The edge node's TLS and password files, as the OPC UA certificates: what its unit's
    PrivateTmp=/ProtectHome= hide, or its user cannot read, is refused before anything is
    written; a file not there yet is a warning."""
    ca = tmp_path / "ca.pem"
    ca.write_bytes(b"x")
    secret = tmp_path / "secret"
    secret.write_bytes(b"x")
    secret.chmod(0o600)
    base = DRAWER.read_text(encoding="utf-8") + (
        "mqtt:\n  brokers: [mqtts://broker.plant:8883]\n  group_id: plant\n"
        "  username: press\n")
    got = refusals(tmp_path, base + f"  password_file: /home/op/mqtt.pw\n  tls: {{ca: {ca}}}\n")
    assert got == [f"mqtt: tls: ca: {ca} is hidden from the service by PrivateTmp=yes: keep "
                   "it under /etc/softplc",
                   "mqtt: password_file: /home/op/mqtt.pw is hidden from the service by "
                   "ProtectHome=yes: keep it under /etc/softplc"]
    etc = Path("/etc/softplc-test-none")  # not there: a warning only
    (tmp_path / "site" / "plant.yaml").write_text(
        (base + f"  password_file: {etc}/mqtt.pw\n").replace(
            "grafcet: ", f"grafcet: {DRAWER.parent}/"), encoding="utf-8")
    p = plan(str(tmp_path / "site" / "plant.yaml"), SOFTPLC, root=str(tmp_path / "s2"))
    assert not p.refusals
    assert (f"mqtt: password_file: {etc}/mqtt.pw does not exist yet (the edge node cannot "
            "connect without it, docs/mqtt.md)") in p.warnings


def test_a_plant_with_mqtt_gets_the_mqtt_unit_too(tmp_path: Path) -> None:
    from tests.mqtt.kit import write_plant
    src = tmp_path / "press"
    src.mkdir()
    plant = write_plant(src, ["mqtts://broker.plant:8883"])
    plant.write_text(re.sub(r"  feed: .*\n", "", plant.read_text(encoding="utf-8")),
                     encoding="utf-8")
    p = plan(str(plant), SOFTPLC, root=str(tmp_path / "stage"))
    data = p.files[f"/etc/systemd/system/{MQTT}"].data
    assert data is not None
    unit = data.decode().splitlines()
    assert f"ExecStart={SOFTPLC} mqtt /etc/softplc/%i/plant.yaml" in unit
    for line in ("User=softplc", "Nice=10", "RuntimeDirectory=softplc/%i",
                 "RuntimeDirectoryPreserve=yes", "ProtectHome=yes", "PrivateTmp=yes"):
        assert line in unit, line
    assert ["systemctl", "enable", "softplc@press.service", "softplc-mqtt@press.service"] \
        in p.commands
    assert f"/etc/systemd/system/{OPCUA}" not in p.files
    assert p.mqtt and not p.opcua


def test_now_starts_and_restarts_the_edge_node(systemctl: Path) -> None:
    """--now starts softplc-mqtt@NAME beside its controller, restarts it when the plant
    changed (it reads the plant at its start), says it is disabled once mqtt: is gone."""
    p = install.Plan(name="press", mqtt=True, start=True)
    assert bring_up(p) == ["started softplc@press.service", "started softplc-mqtt@press.service"]
    (systemctl / "ACTIVE").write_text("softplc@press.service\nsoftplc-mqtt@press.service\n")
    p = install.Plan(name="press", mqtt=True, opcua=True, start=True)
    assert bring_up(p) == ["reloaded softplc@press.service (online change)",
                           "started softplc-opcua@press.service",
                           "restarted softplc-mqtt@press.service (it reads the plant at its "
                           "start)"]
    p = install.Plan(name="press", mqtt_removed=True, start=True)
    assert bring_up(p)[-1] == ("stopped and disabled softplc-mqtt@press.service: the plant has "
                               "no mqtt: section now")


def fake_venv(tmp_path: Path, interpreter: str) -> str:
    """A venv's ``softplc`` whose ``python`` links to ``interpreter``."""
    venv = tmp_path / "venv" / "bin"
    venv.mkdir(parents=True)
    (venv / "python").symlink_to(interpreter)
    (venv / "softplc").write_text(f"#!{venv / 'python'}\nimport sys\n", encoding="utf-8")
    (venv / "softplc").chmod(0o755)
    return str(venv / "softplc")


def test_a_venv_the_service_cannot_run_is_refused(tmp_path: Path) -> None:
    """Issue 25: a clone's .venv under /tmp, or a venv whose python links to a pyenv Python
    under /root: ExecStart reached what PrivateTmp=/ProtectHome= hide (status=203/EXEC, a
    restart loop) and install-service only said --now failed."""
    softplc = fake_venv(tmp_path, "/root/.pyenv/versions/3.12.3/bin/python3.12")
    got = refusals(tmp_path, DRAWER.read_text(encoding="utf-8"), softplc, check_exec=True)
    assert got[0] == (f"ExecStart: {softplc} (the program) is hidden from the service by "
                      "PrivateTmp=yes: install softplc into a venv the service can see, e.g. "
                      "/opt/softplc/venv (pip install /path/to/softplc, not pip install -e)")
    assert (f"ExecStart: /root/.pyenv/versions/3.12.3/bin/python3.12 (the Python of {softplc}"
            f" ({Path(softplc).parent / 'python'} is a link to it)) is hidden from the "
            "service by ProtectHome=yes: make the venv with the system's Python: "
            "/usr/bin/python3 -m venv /opt/softplc/venv") in got
    # staged (--root), the same is a warning: the staged plant is what is being tried
    p = plan(str(DRAWER), softplc, root=str(tmp_path / "stage2"))
    assert not p.refusals
    assert any(w.startswith(f"ExecStart: {softplc} (the program) is hidden") and
               w.endswith("(refused when installing)") for w in p.warnings)


def test_a_port_or_retain_file_of_another_installed_plant_is_refused(tmp_path: Path) -> None:
    from tests.opcua.kit import write_plant
    stage = tmp_path / "stage"
    for name in ("one", "two"):
        (tmp_path / name).mkdir()
        plant = write_plant(tmp_path / name, port=4841)
        text = plant.read_text(encoding="utf-8")
        plant.write_text(re.sub(r"  feed: .*\n", "", text).replace(
            "plc: {cycle: 10ms, watchdog: 5s}",
            "plc: {cycle: 10ms, watchdog: 5s, retain: /var/lib/softplc/shared.json}"),
            encoding="utf-8")
    apply(plan(str(tmp_path / "one" / "plant.yaml"), SOFTPLC, root=str(stage)),
          root=str(stage))
    p = plan(str(tmp_path / "two" / "plant.yaml"), SOFTPLC, root=str(stage))
    assert p.refusals == [
        "the plc: retain file /var/lib/softplc/shared.json is the one of the installed plant "
        "one (/etc/softplc/one/plant.yaml): give each plant its own",
        "the opcua: endpoint port 4841 is the one of the installed plant one "
        "(/etc/softplc/one/plant.yaml): give each plant its own"]


def test_the_single_plant_layout_is_refused_until_removed(tmp_path: Path) -> None:
    units = tmp_path / "etc" / "systemd" / "system"
    units.mkdir(parents=True)
    (units / "softplc.service").write_text("[Service]\n", encoding="utf-8")
    p = plan(str(DRAWER), SOFTPLC, root=str(tmp_path))
    assert len(p.refusals) == 1
    assert p.refusals[0].startswith("/etc/systemd/system/softplc.service: an installation of "
                                    "the single-plant layout is there")


def test_a_name_that_cannot_name_a_unit_is_refused() -> None:
    with pytest.raises(InstallError, match="cannot name a plant"):
        plan(str(DRAWER), SOFTPLC, name="press 1", root="/nonexistent")


def test_cli_refuses_a_broken_plant(tmp_path: Path) -> None:
    bad = tmp_path / "plant.yaml"
    bad.write_text("instances:\n  t: {grafcet: missing.yaml}\n")
    r = subprocess.run([SOFTPLC, "install-service", str(bad), "--root", str(tmp_path / "r")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "plant.yaml:2:16: error: grafcet file not found" in r.stderr
    assert not (tmp_path / "r").exists()


def test_a_reinstall_knows_what_a_running_controller_needs(tmp_path: Path) -> None:
    """What --now decides from: nothing changed; a chart edit (an online change); an
    ``opcua:`` section added (a restart: the diff refuses it online)."""
    d = tmp_path / "press"
    d.mkdir()
    (d / "drawer_tester.yaml").write_bytes((DRAWER.parent / "drawer_tester.yaml").read_bytes())
    drawer = without_web(DRAWER.read_text(encoding="utf-8"))  # a plant with no feed yet
    (d / "plant.yaml").write_text(drawer, encoding="utf-8")
    stage = str(tmp_path / "stage")
    apply(plan(str(d / "plant.yaml"), SOFTPLC, root=stage), root=stage)
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert (p.changed, p.restart_reasons) == (False, [])
    chart = d / "drawer_tester.yaml"
    chart.write_text(chart.read_text(encoding="utf-8") + "# edited\n", encoding="utf-8")
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert (p.changed, p.restart_reasons) == (True, [])
    (d / "plant.yaml").write_text(drawer + "opcua: {endpoint: 'opc.tcp://127.0.0.1:4850'}\n",
                                  encoding="utf-8")
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert p.changed and p.opcua
    assert p.restart_reasons == [
        "opcua: added: the feed is served from the controller's start: restart the "
        "controller, then start its OPC UA server"]


@pytest.fixture
def systemctl(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A stand-in ``systemctl`` first on PATH: records each call; ``is-active`` answers
    from the file ACTIVE (one unit a line), ``reload`` fails if REFUSE exists."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "calls"
    (bin_dir / "systemctl").write_text(
        "#!/bin/sh\n"
        f'echo "$*" >> {log}\n'
        'if [ "$1" = is-active ]; then\n'
        f'  grep -qx "$3" {tmp_path}/ACTIVE 2>/dev/null; exit $?\n'
        "fi\n"
        f'if [ "$1" = reload ] && [ -e {tmp_path}/REFUSE ]; then exit 1; fi\n'
        "exit 0\n", encoding="utf-8")
    (bin_dir / "systemctl").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}:{os.environ['PATH']}")
    return tmp_path


def calls(d: Path) -> list[str]:
    return (d / "calls").read_text(encoding="utf-8").splitlines()


def test_now_starts_a_plant_that_does_not_run(systemctl: Path) -> None:
    p = install.Plan(name="press", opcua=True, start=True)
    assert bring_up(p) == ["started softplc@press.service", "started softplc-opcua@press.service"]
    assert "start softplc@press.service" in calls(systemctl)


def test_now_restarts_a_running_controller_when_the_diff_refuses_online(
        systemctl: Path) -> None:
    """Issue 25: `systemctl enable --now` left the running controller on its old plant."""
    (systemctl / "ACTIVE").write_text("softplc@press.service\nsoftplc-opcua@press.service\n")
    p = install.Plan(name="press", opcua=True, start=True,
                     restart_reasons=["opcua: added: ..."])
    assert bring_up(p) == ["restarted softplc@press.service: opcua: added: ...",
                           "restarted softplc-opcua@press.service (it reads the plant at "
                           "its start)"]
    assert "restart softplc@press.service" in calls(systemctl)


def test_now_reloads_a_running_controller_when_the_change_applies_online(
        systemctl: Path) -> None:
    (systemctl / "ACTIVE").write_text("softplc@press.service\n")
    p = install.Plan(name="press", start=True)
    assert bring_up(p) == ["reloaded softplc@press.service (online change)"]
    assert "reload softplc@press.service" in calls(systemctl)
    assert not any(c.startswith("restart") for c in calls(systemctl))
    # ...and when the controller refuses it, nothing is restarted behind the operator
    (systemctl / "REFUSE").write_text("")
    with pytest.raises(NowRefused, match="it still runs the previous program"):
        bring_up(p)
    assert not any(c.startswith("restart") for c in calls(systemctl))


def test_now_leaves_a_controller_that_runs_this_plant_alone(systemctl: Path) -> None:
    (systemctl / "ACTIVE").write_text("softplc@press.service\n")
    p = install.Plan(name="press", start=True, changed=False)
    assert bring_up(p) == ["softplc@press.service already runs this plant: left running"]
    assert calls(systemctl) == ["is-active --quiet softplc@press.service"]


def test_every_unit_is_shipped_with_the_package() -> None:
    """install-service of a pip-installed softplc reads the units from share/softplc: one
    left out of pyproject's data-files is 'not found' at the first install (the MQTT unit
    was, found by tests/systemd)."""
    import tomllib
    data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    shipped = data["tool"]["setuptools"]["data-files"]["share/softplc"]
    assert sorted(shipped) == sorted(f"systemd/{u.name}" for u in (ROOT / "systemd").glob("*"))
    assert {f"systemd/{u}" for u in (CONTROLLER, OPCUA, MQTT)} <= set(shipped)


def test_a_plant_with_web_gets_its_web_view_unit(tmp_path: Path, systemctl: Path) -> None:
    """install-service writes softplc-web@.service for a plant with ``web:`` (as for
    ``opcua:``), enables softplc-web@NAME, and --now starts it; a reinstall without the
    section disables it."""
    d = tmp_path / "press"
    d.mkdir()
    (d / "drawer_tester.yaml").write_bytes((DRAWER.parent / "drawer_tester.yaml").read_bytes())
    text = DRAWER.read_text(encoding="utf-8")
    text = text[:text.index("\nmonitor:")] + (
        "\nmonitor:\n  socket: {path: '${RUNTIME_DIR}/console.sock'}\n"
        "web: {listen: 127.0.0.1:8090}\n")
    (d / "plant.yaml").write_text(text, encoding="utf-8")
    stage = str(tmp_path / "stage")
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert p.web and p.web_view == "softplc-web@press.service"
    unit = p.files["/etc/systemd/system/" + WEB].data
    assert unit is not None
    keys = unit_keys(unit.decode())
    assert keys["ExecStart"] == f"{SOFTPLC} web /etc/softplc/%i/plant.yaml"
    assert keys["RuntimeDirectory"] == "softplc/%i" and keys["User"] == "softplc"
    assert ["systemctl", "enable", "softplc@press.service",
            "softplc-web@press.service"] in p.commands
    assert bring_up(install.Plan(name="press", web=True, start=True)) == [
        "started softplc@press.service", "started softplc-web@press.service"]
    apply(p, root=stage)
    (d / "plant.yaml").write_text(text.replace("web: {listen: 127.0.0.1:8090}\n", ""),
                                  encoding="utf-8")
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert p.web_removed and ["systemctl", "disable", "softplc-web@press.service"] in p.commands


def test_a_plant_with_modbus_gets_its_server_unit(tmp_path: Path, systemctl: Path) -> None:
    """install-service writes softplc-modbus@.service for a plant with ``modbus:``, enables
    softplc-modbus@NAME (with the one capability of port 502), --now starts it; another
    installed plant on the same port is refused; a reinstall without the section disables
    it."""
    d = tmp_path / "press"
    d.mkdir()
    (d / "drawer_tester.yaml").write_bytes((DRAWER.parent / "drawer_tester.yaml").read_bytes())
    text = DRAWER.read_text(encoding="utf-8")
    text = text[:text.index("\nmonitor:")] + (
        "\nmonitor:\n  socket: {path: '${RUNTIME_DIR}/console.sock'}\n"
        "modbus: {writable: [tester1.sParo]}\n")
    (d / "plant.yaml").write_text(text, encoding="utf-8")
    stage = str(tmp_path / "stage")
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert p.modbus
    unit = p.files["/etc/systemd/system/" + MODBUS].data
    assert unit is not None
    keys = unit_keys(unit.decode())
    assert keys["ExecStart"] == f"{SOFTPLC} modbus /etc/softplc/%i/plant.yaml"
    assert keys["RuntimeDirectory"] == "softplc/%i" and keys["User"] == "softplc"
    assert keys["AmbientCapabilities"] == "CAP_NET_BIND_SERVICE"
    # the open-file bound of the web view's unit (a server of many client sockets; the
    # largest modbus: limits: connections held at it: tests/modbus/test_server.py)
    assert keys["LimitNOFILE"] == "1024"
    assert ["systemctl", "enable", "softplc@press.service",
            "softplc-modbus@press.service"] in p.commands
    assert bring_up(install.Plan(name="press", modbus=True, start=True)) == [
        "started softplc@press.service", "started softplc-modbus@press.service"]
    apply(p, root=stage)
    other = tmp_path / "line2"
    shutil.copytree(d, other)
    p2 = plan(str(other / "plant.yaml"), SOFTPLC, root=stage)
    assert any("the modbus: listen port 502 is the one of the installed plant press" in r
               for r in p2.refusals), p2.refusals
    (d / "plant.yaml").write_text(text.replace("modbus: {writable: [tester1.sParo]}\n", ""),
                                  encoding="utf-8")
    p = plan(str(d / "plant.yaml"), SOFTPLC, root=stage)
    assert p.modbus_removed and ["systemctl", "disable",
                                 "softplc-modbus@press.service"] in p.commands
