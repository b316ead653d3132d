"""The installation of docs/daemon.md, docs/opcua.md, docs/mqtt.md and docs/modbus.md,
followed as a user follows it, under a real systemd (PID 1 of a container of this
machine's own root, tests/systemd/container.py): booted once for the module, its venv made
from the system's Python as on a Raspberry Pi.

Each test is one journey of issue 25 (and of issue 28's MQTT edge node, issue 41's Modbus/TCP
server); docs/daemon.md
("Tested under a real systemd") says what each does. They run in file order on the one
container (a later journey uses the plants an earlier one installed), and are skipped, with
the reason, only where a container cannot run (not root, no systemd-nspawn, overlay mounts
not permitted)."""

from __future__ import annotations

import asyncio
import json
import re
import select
import shlex
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.compile import chart_text
from tests.systemd.container import Container, Unavailable, reap_stale, why_not

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
VENV = "/opt/softplc/venv"
SOFTPLC = f"{VENV}/bin/softplc"
SRC = "/root/softplc"  # the clone, as docs/daemon.md's `pip install /path/to/softplc`
SIM_PLANTS = ("drawer_tester", "carriage", "compactadora", "reactor", "security_door",
              "seed004_codesys")
#: the example plants on real I/O (their device is not in a container), and what their
#: controller says
HARDWARE_PLANTS = {"pi_mcp23017": "driver exp1 (mcp23017): cannot start",
                   "modbus_module": "driver mb (modbus_rtu): cannot start",
                   "canopen_node": "cannot start"}
#: the host venv's Python (pymodbus for the RTU module), seen in the container through the
#: overlay of the machine's root, and its venv bound at its own path: systemd-nspawn mounts
#: a tmpfs of its own on /tmp, which hides a clone's venv there (CI's first clean-clone run
#: under /tmp: the peer's command not found, exit 127)
PEER_PYTHON = sys.executable
PEER_PREFIX = Path(sys.prefix)

COUNTER = """\
grafcet: Counter
inputs: [iGo]
outputs: [oRun]
memory:
  sN: {init: 0, retain: true}
steps:
  gsCount: {initial: true, actions: [oRun, "N sN := sN + 1"]}
transitions: []
"""


def edge_plant(broker: str | None = None) -> str:
    """A plant on simulated I/O; with ``broker``, its ``mqtt:`` section (feed by default)."""
    text = ("plc: {cycle: 20ms, watchdog: 500ms}\n"
            "drivers: {io: {type: sim}}\n"
            "instances:\n  m:\n    grafcet: counter.yaml\n    inputs: {iGo: io.I0}\n"
            "    outputs: {oRun: io.Q0}\n"
            "monitor:\n  socket: {path: '${RUNTIME_DIR}/console.sock', trusted: true}\n")
    if broker is not None:
        text += (f"mqtt:\n  brokers: [{broker}]\n  group_id: {MQTT_GROUP}\n"
                 f"  edge_node_id: {MQTT_EDGE}\n  keepalive: 2s\n")
    return text


MQTT_GROUP, MQTT_EDGE = "Journeys", "edge"


def press_plant(port: int | None = None) -> str:
    text = ("plc: {cycle: 20ms, watchdog: 500ms, retain: /var/lib/softplc/press.retain.json, "
            "retain_interval: 100ms, realtime: {priority: 50}}\n"
            "drivers: {io: {type: sim}}\n"
            "instances:\n  m:\n    grafcet: counter.yaml\n    inputs: {iGo: io.I0}\n"
            "    outputs: {oRun: io.Q0}\n"
            "monitor:\n  socket: {path: '${RUNTIME_DIR}/console.sock', trusted: true}\n")
    if port is not None:
        text += (f"opcua:\n  endpoint: opc.tcp://127.0.0.1:{port}\n"
                 "  security: {policies: [None]}\n")
    return text


RTU_PLANT = """\
plc: {cycle: 20ms, watchdog: 500ms, retain: /var/lib/softplc/rtu.retain.json,
      retain_interval: 100ms, realtime: {priority: 50}}
drivers:
  mb: {type: modbus_rtu, port: /dev/ttyRTU, baudrate: 115200, unit: 1, timeout: 100ms,
       retries: 1, on_fault: stop}
instances:
  m:
    grafcet: counter.yaml
    inputs: {iGo: mb.I0}
    outputs: {oRun: mb.Q0}
monitor:
  socket: {path: '${RUNTIME_DIR}/console.sock', trusted: true}
"""


@pytest.fixture(scope="module")
def plc() -> Iterator[Container]:
    """The container, booted, with softplc installed as docs/daemon.md says."""
    reason = why_not()
    if reason is not None:
        pytest.skip(reason)
    reap_stale()
    c = Container(ROOT, shared=(PEER_PREFIX,))
    try:
        try:
            c.boot()
        except Unavailable as exc:
            pytest.skip(str(exc))
        # the clone (without the test machine's venv and node modules), then the venv from
        # the system's Python: `sudo /usr/bin/python3 -m venv /opt/softplc/venv`...
        c.sh(f"mkdir -p {SRC} && tar -C /srv/co --exclude=./.venv --exclude=./.git "
             "--exclude=./tests/opcua/node/node_modules --exclude='*.egg-info' -cf - . "
             f"| tar -C {SRC} -xf -")
        c.sh(f"/usr/bin/python3 -m venv {VENV} && {VENV}/bin/pip install -q "
             f"'{SRC}[opcua,mqtt,web]' && {SOFTPLC} --version", timeout=900)
        yield c
    finally:
        c.close()


def sh(c: Container, script: str, check: bool = True) -> str:
    """``script`` in the clone's directory, as the administrator types it."""
    return c.sh(f"cd {SRC} && {script}", check=check).stdout


def prop(c: Container, unit: str, name: str) -> str:
    return c.sh(f"systemctl show -p {name} --value {unit}").stdout.strip()


def console(c: Container, sock: str, line: str) -> str:
    """One console request over the plant's socket (socat, as docs/console.md)."""
    return c.sh(f"printf '%s\\n' {shlex.quote(line)} | socat -t 3 - UNIX-CONNECT:{sock}"
                ).stdout


def counter(c: Container, sock: str) -> int:
    out = c.wait(f"printf 'get m.sN\\n' | socat -t 3 - UNIX-CONNECT:{sock} | grep m.sN=",
                 what=f"the counter on {sock}")
    return int(out.split("m.sN=")[1].split()[0])


def write_plant(c: Container, name: str, text: str) -> str:
    """A plant directory of the clone (``SRC/sites/NAME``), its path in the container."""
    d = c.path(f"{SRC}/sites/{name}")
    d.mkdir(parents=True, exist_ok=True)
    (d / "counter.yaml").write_text(COUNTER, encoding="utf-8")
    (d / "plant.yaml").write_text(text, encoding="utf-8")
    return f"sites/{name}/plant.yaml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- 1. every example plant, installed with --now: two plants side by side and more -----
def test_each_example_plant_installs_and_runs(plc: Container) -> None:
    for name in SIM_PLANTS:
        out = sh(plc, f"{SOFTPLC} install-service configs/{name}/plant_sim.yaml --now")
        assert f"started softplc@{name}.service" in out, out
    for name in SIM_PLANTS:
        unit = f"softplc@{name}.service"
        # Type=notify: active only once the controller sent READY=1 after its first cycle
        plc.wait(f"systemctl is-active --quiet {unit}", what=f"{unit} active")
        assert prop(plc, unit, "ActiveState") == "active"
        # the status line (a plant at SCHED_OTHER on a machine shared with other jobs may
        # have faulted on a freeze meanwhile: a fault is a state the line shows too)
        assert re.match(r"(running|fault \(.+\)); \d+ instance\(s\); \d+ cycles; scan p99 "
                        r"\d+ us", prop(plc, unit, "StatusText")), prop(plc, unit, "StatusText")
        log = plc.journal(unit)
        assert f"running /etc/softplc/{name}/plant.yaml: " in log, log
        assert "Traceback" not in log
        assert prop(plc, unit, "User") == "softplc"
    # each its own runtime directory, the drawer testers' console socket in theirs
    assert plc.sh("stat -c '%U:%G %a' /run/softplc/drawer_tester").stdout.strip() == \
        "softplc:softplc 750"
    assert "cycle time 10 ms" in console(plc, "/run/softplc/drawer_tester/drawer.sock",
                                         "status")
    # the drawer testers' web view (web: in their plant) beside them, serving the page
    plc.wait("systemctl is-active --quiet softplc-web@drawer_tester.service",
             what="softplc-web@drawer_tester active")
    plc.wait("/usr/bin/python3 -c 'import urllib.request as u; "
             "u.urlopen(\"http://127.0.0.1:8080/api/plant\", timeout=5)'",
             what="the drawer testers' page served")
    # the plants on real I/O: the device is not in a container; the unit says so in one
    # line and tries again every RestartSec (docs/daemon.md), until it is stopped
    for name, what in HARDWARE_PLANTS.items():
        unit = f"softplc@{name}.service"
        r = plc.sh(f"cd {SRC} && {SOFTPLC} install-service configs/{name}/plant.yaml --now",
                   check=False)
        assert r.returncode == 1, r.stdout + r.stderr
        line = r.stderr.strip().splitlines()[-1]
        assert line.startswith(f"softplc install-service: {unit} did not start: "
                               f"/etc/softplc/{name}/plant.yaml:") and what in line, line
        log = plc.journal(unit)
        assert "Traceback" not in log, log
        assert prop(plc, unit, "ActiveState") in ("activating", "failed")  # auto-restart
        plc.sh(f"systemctl disable --now {unit}")


# -- 2. the OPC UA unit beside its controller: a plant that gets opcua: on a reinstall --
async def read_scans(url: str) -> tuple[bool, int]:
    """(good, controller.scans) through the OPC UA server, with asyncua's client."""
    from asyncua import Client

    async with Client(url, timeout=5) as client:
        dv = await client.get_node("ns=2;s=controller.scans").read_data_value(
            raise_on_bad_status=False)
        return dv.StatusCode.is_good(), int(dv.Value.Value or 0)


def wait_read(url: str, good: bool, timeout: float = 60.0) -> int:
    end = time.monotonic() + timeout
    seen: object = None
    while True:
        try:
            ok, scans = asyncio.run(read_scans(url))
            if ok is good:
                return scans
            seen = (ok, scans)
        except (OSError, TimeoutError) as exc:
            seen = exc
        if time.monotonic() > end:
            raise AssertionError(f"no {'good' if good else 'bad'} value at {url}: {seen}")
        time.sleep(0.2)


def test_the_opcua_unit_finds_its_controller(plc: Container) -> None:
    """Issue 25: the OPC UA unit looked for /tmp/softplc-999/feed.sock (BadNodeIdUnknown
    forever), and `install-service --now` with an opcua: section added left the running
    controller on its old plant, serving no feed."""
    plant = write_plant(plc, "press", press_plant())
    out = sh(plc, f"{SOFTPLC} install-service {plant} --now")
    assert "started softplc@press.service" in out
    plc.wait("systemctl is-active --quiet softplc@press.service")
    pid = prop(plc, "softplc@press.service", "MainPID")
    port = free_port()
    write_plant(plc, "press", press_plant(port))
    r = plc.sh(f"cd {SRC} && {SOFTPLC} install-service {plant} --now", check=False)
    assert r.returncode == 2 and "left alone" in r.stderr  # never overwritten unasked
    out = sh(plc, f"{SOFTPLC} install-service {plant} --now --force")
    assert ("restarted softplc@press.service: opcua: added: the feed is served from the "
            "controller's start") in out, out
    assert "started softplc-opcua@press.service" in out, out
    assert prop(plc, "softplc@press.service", "MainPID") != pid
    url = f"opc.tcp://127.0.0.1:{port}"
    before = wait_read(url, good=True)
    log = plc.journal("softplc-opcua@press.service")
    assert f"OPC UA server on {url} (feed /run/softplc/press/feed.sock)" in log, log
    assert before > 0
    # the controller stopped and started again under the server: Bad, then Good again
    plc.sh("systemctl stop softplc@press.service")
    wait_read(url, good=False, timeout=30)
    plc.sh("systemctl start softplc@press.service")
    wait_read(url, good=True)
    assert prop(plc, "softplc-opcua@press.service", "NRestarts") == "0"


# -- 2b. the MQTT unit beside its controller: a plant that gets mqtt: on a reinstall -----
def test_the_mqtt_unit_finds_its_controller(plc: Container, tmp_path: Path) -> None:
    """Issue 28 on issue 25's design: softplc-mqtt.service was a single-plant unit reading
    /etc/softplc/plant.yaml, install-service no longer wrote it, and `mqtt:` added to a
    running plant was `reloaded (online change)`: no feed, so no device ever born. Here a
    real mosquitto on this machine's 127.0.0.1 (the container shares its network) and the
    pysparkplug host application (tests/mqtt/host) see the edge node's births."""
    from tests.mqtt.kit import Broker, Host

    broker = Broker(tmp_path).start()
    host = Host(broker)
    try:
        plant = write_plant(plc, "edge", edge_plant())
        out = sh(plc, f"{SOFTPLC} install-service {plant} --now")
        assert "started softplc@edge.service" in out, out
        assert "softplc-mqtt@edge" not in out, out
        plc.wait("systemctl is-active --quiet softplc@edge.service")
        pid = prop(plc, "softplc@edge.service", "MainPID")
        write_plant(plc, "edge", edge_plant(broker.url))
        # (the installed plant's ${RUNTIME_DIR} is the service's, the clone's the shell's:
        # the consoles differ too)
        out = sh(plc, f"{SOFTPLC} diff /etc/softplc/edge/plant.yaml {plant}", check=False)
        assert "plant: mqtt: added" in out.splitlines(), out
        assert ("  mqtt: added: the feed is served from the controller's start: restart the "
                "controller, then start its MQTT edge node") in out.splitlines(), out
        out = sh(plc, f"{SOFTPLC} install-service {plant} --now --force")
        assert ("restarted softplc@edge.service: mqtt: added: the feed is served from the "
                "controller's start") in out, out
        assert "started softplc-mqtt@edge.service" in out, out
        assert prop(plc, "softplc@edge.service", "MainPID") != pid
        unit = "softplc-mqtt@edge.service"
        assert prop(plc, unit, "User") == "softplc"
        # the node's birth, then its instance's: the feed was found where the controller
        # serves it (a device is born only from the feed's schema)
        host.wait(lambda _r: bool(host.of("NBIRTH")) and bool(host.of("DBIRTH", "m")), 90,
                  "NBIRTH and DBIRTH of m from the installed edge node")
        nb = host.of("NBIRTH")[0]
        assert nb["topic"] == f"spBv1.0/{MQTT_GROUP}/NBIRTH/{MQTT_EDGE}", nb
        log = plc.journal(unit)
        assert "connected to the controller's feed /run/softplc/edge/feed.sock" in log, log
        assert "Traceback" not in log, log
        # the controller restarted under the edge node: its device dies and is born again,
        # the edge node itself runs on
        births = len(host.of("DBIRTH", "m"))
        plc.sh("systemctl restart softplc@edge.service")
        host.wait(lambda _r: len(host.of("DBIRTH", "m")) > births, 90,
                  "DBIRTH of m again after the controller's restart")
        assert host.of("DDEATH", "m"), [r["topic"] for r in host.rows]
        assert prop(plc, unit, "NRestarts") == "0"
        # mqtt: removed: the edge node is stopped and disabled
        write_plant(plc, "edge", edge_plant())
        out = sh(plc, f"{SOFTPLC} install-service {plant} --now --force")
        assert (f"stopped and disabled {unit}: the plant has no mqtt: section now") in out, out
        assert prop(plc, unit, "ActiveState") == "inactive"
        host.wait(lambda _r: bool(host.of("NDEATH")), 30, "NDEATH once the node stopped")
    finally:
        host.close()
        broker.kill()


# -- 2c. the Modbus/TCP unit beside its controller, on a privileged port ----------------
def privileged_port() -> int:
    """A free port below 1024 (the unit binds it with CAP_NET_BIND_SERVICE, as it binds
    Modbus/TCP's 502: this machine's own 502 may be another test's)."""
    for port in range(900, 1000):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise AssertionError("no free port in 900-999")


def hmi_plant(port: int | None) -> str:
    text = edge_plant()
    if port is not None:
        text += f"modbus:\n  listen: 127.0.0.1:{port}\n  writable: [m.sN]\n"
    return text


def test_the_modbus_unit_finds_its_controller(plc: Container) -> None:
    """Issue 41: `softplc modbus` as softplc-modbus@NAME, installed by install-service
    beside its controller, on a port below 1024 (the capability of its unit), read and
    written by pymodbus' client from outside the container; the controller stopped under
    it is exception 11, then values again; the section removed disables the unit."""
    from pymodbus.client import ModbusTcpClient

    port = privileged_port()
    plant = write_plant(plc, "hmi", hmi_plant(port))
    out = sh(plc, f"{SOFTPLC} install-service {plant} --now")
    assert "started softplc@hmi.service" in out and "started softplc-modbus@hmi.service" in \
        out, out
    unit = "softplc-modbus@hmi.service"
    assert prop(plc, unit, "User") == "softplc"
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)

    def counter_read() -> int | None:
        try:
            if not client.connected and not client.connect():
                return None
            rr = client.read_holding_registers(0, count=1, device_id=1)
        except Exception:  # noqa: BLE001 - not up yet, or the connection closed
            client.close()
            return None
        return None if rr.isError() else int(rr.registers[0])
    try:
        plc.wait(f"systemctl is-active --quiet {unit}", what=f"{unit} active")
        end = time.monotonic() + 60
        first = counter_read()
        while first is None and time.monotonic() < end:
            time.sleep(0.5)
            first = counter_read()
        assert first is not None, plc.journal(unit)
        # the counter moves; a write of 0 is applied between two scans and seen
        end = time.monotonic() + 30
        while (counter_read() or 0) <= first + 20 and time.monotonic() < end:
            time.sleep(0.2)
        before = counter_read()
        assert before is not None and before > first
        assert not client.write_register(0, 0, device_id=1).isError()
        after = counter_read()
        assert after is not None and after < before
        rr = client.write_coil(0, True, device_id=1)  # m.oRun: an output, not writable
        assert rr.isError() and rr.exception_code == 2
        log = plc.journal(unit)
        assert f"Modbus/TCP server on 127.0.0.1:{port} (feed /run/softplc/hmi/feed.sock)" \
            in log, log
        assert "set m.sN = 0" in log and "Traceback" not in log, log
        # the controller stopped under the server: exception 11, then values again
        plc.sh("systemctl stop softplc@hmi.service")
        end = time.monotonic() + 30
        while time.monotonic() < end:
            try:
                rr = client.read_holding_registers(0, count=1, device_id=1)
            except Exception:  # noqa: BLE001
                client.close()
                client.connect()
                continue
            if rr.isError() and rr.exception_code == 11:
                break
            time.sleep(0.2)
        else:
            raise AssertionError("no exception 11 with the controller stopped")
        plc.sh("systemctl start softplc@hmi.service")
        end = time.monotonic() + 60
        while counter_read() is None and time.monotonic() < end:
            time.sleep(0.5)
        assert counter_read() is not None
        assert prop(plc, unit, "NRestarts") == "0"
    finally:
        client.close()
    # modbus: removed: the server is stopped and disabled
    write_plant(plc, "hmi", hmi_plant(None))
    out = sh(plc, f"{SOFTPLC} install-service {plant} --now --force")
    assert f"stopped and disabled {unit}: the plant has no modbus: section now" in out, out
    assert prop(plc, unit, "ActiveState") == "inactive"


# -- 3. systemctl reload: an edit applied, an edit refused ----------------------------
def test_reload_applies_an_edit_and_refuses_another(plc: Container) -> None:
    unit = "softplc@drawer_tester.service"
    chart = "/etc/softplc/drawer_tester/drawer_tester.yaml"
    plant = "/etc/softplc/drawer_tester/plant.yaml"
    pid = prop(plc, unit, "MainPID")
    plc.sh(f"sed -i 's/^memory:$/memory:\\n  sReloaded: 7/' {chart}")
    plc.sh(f"systemctl reload {unit}")
    assert "reload applied" in plc.journal(unit)
    assert "tester1.sReloaded=7" in console(plc, "/run/softplc/drawer_tester/drawer.sock",
                                            "get tester1.sReloaded")
    # a change a running controller cannot take: refused, the journal says why, the old
    # program runs on
    plc.sh(f"sed -i 's/^  cycle: 10ms/  cycle: 20ms/' {plant}")
    r = plc.sh(f"systemctl reload {unit}", check=False)
    assert r.returncode != 0
    log = plc.journal(unit)
    assert "refused: plant: the cycle time changed: restart the controller" in log, log
    assert prop(plc, unit, "MainPID") == pid and prop(plc, unit, "ActiveState") == "active"
    status = console(plc, "/run/softplc/drawer_tester/drawer.sock", "status")
    assert "cycle time 10 ms" in status, status
    plc.sh(f"sed -i 's/^  cycle: 20ms/  cycle: 10ms/' {plant}")  # back as installed


def test_the_compiled_code_is_cached_under_the_unit(plc: Container) -> None:
    """A chart big enough for the code cache (96 steps: its generated code is over
    MIN_SOURCE), installed and run by the unit: the service writes the compiled code to
    its CacheDirectory (0600 in the 0700 /var/cache/softplc/NAME, the user softplc's:
    before, the unit had no cache and compiled at every start), and at a restart loads
    it from there (no entry written again: same inodes, same mtimes)."""
    d = plc.path(f"{SRC}/sites/big")
    d.mkdir(parents=True, exist_ok=True)
    (d / "big.yaml").write_text(chart_text(96), encoding="utf-8")
    (d / "plant.yaml").write_text(
        "plc: {cycle: 20ms, watchdog: 500ms}\n"
        "drivers: {io: {type: sim}}\n"
        "instances:\n  b:\n    grafcet: big.yaml\n"
        "    inputs: {iA: io.I0, iB: io.I1, iC: io.I2, iD: io.I3, iE: io.I4, iG: io.I5}\n"
        "    outputs: {" + ", ".join(f"o{k}: io.Q{k}" for k in range(8)) + "}\n",
        encoding="utf-8")
    unit = "softplc@big.service"
    out = sh(plc, f"{SOFTPLC} install-service sites/big/plant.yaml --now")
    assert f"started {unit}" in out, out
    plc.wait(f"systemctl is-active --quiet {unit}", what=f"{unit} active")
    cache = "/var/cache/softplc/big"
    assert plc.sh(f"stat -c '%U %a' {cache}").stdout.strip() == "softplc 700"
    entries = f"find {cache} -type f -name '*.code' -printf '%i %T@ %u %m\\n' | sort"
    first = plc.wait(f"{entries} | grep .", what="the compiled code in the cache"
                     ).strip().split("\n")
    # the chart's scan and the plant's cycle code (each over the threshold here)
    assert first and all(e.endswith(" softplc 600") for e in first), first
    plc.sh(f"systemctl restart {unit}")
    plc.wait(f"systemctl is-active --quiet {unit}", what=f"{unit} active again")
    assert plc.sh(entries).stdout.strip().split("\n") == first, "an entry was written again"
    assert "code cache" not in plc.journal(unit)  # no entry refused, no cache refused
    plc.sh(f"systemctl disable --now {unit}")


# -- 4. freezes and kills under a real watchdog, outputs at a real Modbus RTU module -----
def peer_writes(plc: Container) -> list[dict[str, object]]:
    text = plc.path("/root/rtu.jsonl").read_text(encoding="utf-8")
    return [json.loads(line) for line in text.splitlines()]


def start_peer(plc: Container) -> None:
    """The RTU module, a process in the container (it dies with the container's boot)."""
    peer = plc.popen(f"{PEER_PYTHON} /srv/co/tests/systemd/rtu_peer.py --link /dev/ttyRTU "
                     "--log /root/rtu.jsonl")
    assert peer.stdout is not None
    ready, _, _ = select.select([peer.stdout], [], [], 60)
    line = peer.stdout.readline().strip() if ready else ""
    if line != "ready":
        code = peer.poll()
        why = peer.stderr.read()[-2000:] if code is not None and peer.stderr else ""
        raise AssertionError(f"the RTU peer did not start: {line!r}, exit {code}: {why}")


def test_a_frozen_or_killed_controller_is_restarted_with_outputs_off(plc: Container) -> None:
    start_peer(plc)
    # the module is on a pseudo-terminal: the one change from the installed unit is a
    # drop-in letting the service open one (a real adapter is /dev/ttyUSB0, allowed)
    dropin = plc.path("/etc/systemd/system/softplc@rtu.service.d/pty.conf")
    dropin.parent.mkdir(parents=True)
    dropin.write_text("[Service]\nDeviceAllow=char-pts rw\n", encoding="utf-8")
    plant = write_plant(plc, "rtu", RTU_PLANT)
    sh(plc, f"{SOFTPLC} install-service {plant} --now")
    unit, sock = "softplc@rtu.service", "/run/softplc/rtu/console.sock"
    plc.wait(f"systemctl is-active --quiet {unit}")
    for how in ("SIGSTOP", "SIGKILL"):
        pid = prop(plc, unit, "MainPID")
        restarts = int(prop(plc, unit, "NRestarts"))
        counted = counter(plc, sock)
        assert counted > 0
        t_kill = time.time()
        plc.sh(f"kill -{how[3:]} {pid}")
        # a frozen one: systemd's watchdog (WatchdogSec=2s) aborts it; a killed one is gone
        plc.wait(f"test $(systemctl show -p NRestarts --value {unit}) -gt {restarts}", 60,
                 f"{unit} restarted after {how}")
        plc.wait(f"systemctl is-active --quiet {unit}", 60)
        assert prop(plc, unit, "MainPID") != pid
        restored = counter(plc, sock)
        # retained data restored: at most one retain_interval (100 ms: 5 scans) and the
        # write's own time (up to 200 ms on a busy machine, as the kill loop allows: 10
        # scans) older than what the console read before the signal
        assert restored >= counted - (100 + 200) // 20, (how, counted, restored)
        after = [w for w in peer_writes(plc) if float(w["t"]) > t_kill]  # type: ignore[arg-type]
        # the restarted controller wrote every output off before its first scan, then its
        # chart switched oRun on again
        values = [w["values"] for w in after]
        assert [0] in values and values.index([0]) < values.index([1]), (how, values)
        log = plc.journal(unit)
        if how == "SIGSTOP":
            assert "Watchdog timeout" in plc.sh(f"journalctl -q -o cat -u {unit} "
                                                "SYSLOG_IDENTIFIER=systemd").stdout
    assert "Traceback" not in log


# -- 5. systemctl stop, and a reboot --------------------------------------------------
def test_stop_saves_and_switches_off_and_a_reboot_starts_the_plants(plc: Container) -> None:
    unit, sock = "softplc@rtu.service", "/run/softplc/rtu/console.sock"
    last = counter(plc, sock)
    t_stop = time.time()
    plc.sh(f"systemctl stop {unit}")
    writes = [w for w in peer_writes(plc) if float(w["t"]) > t_stop]  # type: ignore[arg-type]
    assert writes and writes[-1]["values"] == [0], writes
    saved = json.loads(plc.path("/var/lib/softplc/rtu.retain.json").read_text())
    assert saved["data"]["m"]["sN"] >= last
    assert saved["plant"] == {"name": "rtu", "path": "/etc/softplc/rtu"}
    plc.sh(f"systemctl start {unit}")
    plc.wait(f"systemctl is-active --quiet {unit}")
    plc.reboot()
    # enabled plants start at boot; the RTU module's pty is gone with the old boot: its
    # controller says so and tries again every 5 s, and comes up once the module is back
    for name in SIM_PLANTS + ("press",):
        plc.wait(f"systemctl is-active --quiet softplc@{name}.service", 60,
                 f"softplc@{name} after the reboot")
    plc.wait("systemctl is-active --quiet softplc-opcua@press.service", 60)
    plc.wait(f"journalctl -q -o cat -b -u {unit} | grep -q 'cannot start'", 60)
    start_peer(plc)
    plc.wait(f"systemctl is-active --quiet {unit}", 60, f"{unit} once its module is back")
    assert counter(plc, sock) >= saved["data"]["m"]["sN"]


# -- 6. a second controller of an installed plant ---------------------------------------
def test_a_second_run_of_an_installed_plant_is_refused(plc: Container) -> None:
    unit = "softplc@drawer_tester.service"
    pid = prop(plc, unit, "MainPID")
    for who in ("", "runuser -u softplc -- "):
        r = plc.sh(f"{who}{SOFTPLC} run /etc/softplc/drawer_tester/plant.yaml --for 5s",
                   check=False)
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip() == (
            f"softplc run: error: plant drawer_tester is already running: PID {pid} "
            "(/etc/softplc/drawer_tester/plant.yaml, lock /run/softplc/drawer_tester/"
            f"{lock_name(plc, 'drawer_tester')})"), r.stderr
    assert prop(plc, unit, "MainPID") == pid and prop(plc, unit, "ActiveState") == "active"
    assert "cycle time 10 ms" in console(plc, "/run/softplc/drawer_tester/drawer.sock",
                                         "status")


def lock_name(plc: Container, name: str) -> str:
    out = plc.sh(f"ls /run/softplc/{name}").stdout.split()
    (lock,) = [f for f in out if f.endswith(".lock")]
    return lock


# -- 7. what the service could not run is refused -------------------------------------
def make_venv(plc: Container, python: str, venv: str) -> str:
    """A venv made by ``python`` with a ``softplc`` program of its own; the package it
    imports is the one installed in /opt/softplc/venv (through a .pth file: a second
    ``pip install`` would only cost time), its data files (the unit templates in
    share/softplc) copied as ``pip install`` puts them. Its ``softplc``'s path."""
    site = plc.sh(f"{VENV}/bin/python -c 'import sysconfig; "
                  "print(sysconfig.get_paths()[\"purelib\"])'").stdout.strip()
    plc.sh(f"{python} -m venv --without-pip {venv} && "
           f"echo {site} > $({venv}/bin/python -c 'import sysconfig; "
           "print(sysconfig.get_paths()[\"purelib\"])')/softplc-installed.pth && "
           f"printf '#!{venv}/bin/python\\nimport sys\\nfrom runtime.cli import main\\n"
           f"sys.exit(main())\\n' > {venv}/bin/softplc && chmod 755 {venv}/bin/softplc && "
           f"mkdir -p {venv}/share && cp -r {VENV}/share/softplc {venv}/share/")
    return f"{venv}/bin/softplc"


def errors(stderr: str) -> list[str]:
    """install-service's error lines (its warnings about the plant come first)."""
    return [line for line in stderr.splitlines()
            if line.startswith("softplc install-service: error: ")]


def test_a_venv_the_service_cannot_run_is_refused(plc: Container) -> None:
    """Issue 25: a clone's .venv under /tmp, a venv of a Python under /root: the unit was
    written, then failed at every start (status=203/EXEC)."""
    clone = make_venv(plc, "/usr/bin/python3", "/tmp/clone/.venv")
    r = plc.sh(f"cd {SRC} && {clone} install-service configs/carriage/plant_sim.yaml "
               "--name clone --now", check=False)
    assert r.returncode == 2, r.stdout + r.stderr
    assert errors(r.stderr)[0] == (
        "softplc install-service: error: ExecStart: /tmp/clone/.venv/bin/softplc (the "
        "program) is hidden from the service by PrivateTmp=yes: install softplc into a venv "
        "the service can see, e.g. /opt/softplc/venv (pip install /path/to/softplc, not pip "
        "install -e)"), r.stderr
    # a Python under /root (where pyenv puts one), its venv in /opt
    plc.sh("mkdir -p /root/py/bin && cp /usr/bin/python3 /root/py/bin/python3")
    pyenv = make_venv(plc, "/root/py/bin/python3", "/opt/pyenv-venv")
    r = plc.sh(f"cd {SRC} && {pyenv} install-service configs/carriage/plant_sim.yaml "
               "--name clone --now", check=False)
    assert r.returncode == 2, r.stdout + r.stderr
    assert errors(r.stderr) == [
        "softplc install-service: error: ExecStart: /root/py/bin/python3 (the Python of "
        "/opt/pyenv-venv/bin/softplc (/opt/pyenv-venv/bin/python is a link to it)) is hidden "
        "from the service by ProtectHome=yes: make the venv with the system's Python: "
        "/usr/bin/python3 -m venv /opt/softplc/venv"], r.stderr
    assert not plc.path("/etc/softplc/clone").exists()
    assert plc.sh("systemctl is-enabled softplc@clone.service", check=False).returncode != 0
