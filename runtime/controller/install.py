"""``softplc install-service``: the plant NAME under /etc/softplc/NAME, a ``softplc`` system
user, the template units softplc@.service (and softplc-opcua@.service for a plant with
``opcua:``, softplc-mqtt@.service for one with ``mqtt:``, softplc-web@.service for one with
``web:``, softplc-modbus@.service for one with ``modbus:``), the instances softplc@NAME (and
softplc-opcua@NAME, softplc-mqtt@NAME, softplc-web@NAME, softplc-modbus@NAME) enabled, and
with ``--now`` put in service.

The plant file and every grafcet file it names are copied into /etc/softplc/NAME, the
plant's ``grafcet:`` paths rewritten to the copies (comments and layout kept). A file
already there with other contents is never overwritten: the command stops and says so
(``--force`` keeps the old one as ``NAME.bak-TIMESTAMP``). With ``--root DIR`` everything is
written below DIR and the user, group and systemctl steps are only printed (for packaging
and for the tests).

Nothing is written for a plant the service could not run: what its sandbox hides or its
user cannot read (``runtime.controller.unitsight``), a socket or retain file it could not
create, a port or retain file another installed plant has: one line each.

With ``--now`` the running controller gets the new plant the way ``softplc diff`` says it
can: an online change (``systemctl reload``) when it can be applied online, else a
restart; ``install-service`` says which it did.

Who may read what (the plant holds the console's PIN hash): /etc/softplc and
/etc/softplc/NAME are 0750 root:softplc and the plant and its charts 0640 root:softplc
(root writes them, the service reads them, nobody else does); /var/lib/softplc, the
service's state directory, is 0750 softplc:softplc. The unit's ``StateDirectory=`` and
``RuntimeDirectory=`` keep that and /run/softplc/NAME owned by the service; it has no
``ConfigurationDirectory=``: systemd would apply its mode to /etc/softplc without ever
changing its group (systemd.exec(5)), locking the service out of its plant when the
directory is root's. A file is written under a temporary name with its final mode and
owner, then renamed: it is never readable by others, not even for a moment.
"""

from __future__ import annotations

import argparse
import contextlib
import grp
import logging
import os
import pwd
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple

from runtime.change.diff import diff_plants
from runtime.controller.unitsight import (
    below,
    exec_chain,
    hidden_by,
    service_identity,
    unreadable,
)
from runtime.errors import SoftplcError
from runtime.language.model import PlantDef
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import (
    INSTALL_DIR,
    INSTALLED_FILE,
    NAME_RE,
    PLACEHOLDER,
    SERVICE_RUNTIME,
    STATE_DIR,
    plant_name,
    service_view,
)
from runtime.language.tlsconf import side_files
from runtime.language.yamlsrc import YMap, load_yaml

log = logging.getLogger(__name__)

#: the unit files: systemd/ of the source tree, or share/softplc/ of an installed package
_SOURCE_TREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
UNIT_DIRS = (os.path.join(_SOURCE_TREE, "systemd"), os.path.join(sys.prefix, "share", "softplc"))
USER = "softplc"
GROUPS = ("gpio", "i2c", "dialout")
#: the template units: the controller, its OPC UA server, its MQTT edge node, its web view
CONTROLLER = "softplc@.service"
OPCUA = "softplc-opcua@.service"
MQTT = "softplc-mqtt@.service"
WEB = "softplc-web@.service"
MODBUS = "softplc-modbus@.service"
#: the side processes: plant section -> (template unit, command, what it is)
SIDES = {"opcua": (OPCUA, "opcua", "OPC UA server"),
         "mqtt": (MQTT, "mqtt", "MQTT edge node"),
         "web": (WEB, "web", "web view"),
         "modbus": (MODBUS, "modbus", "Modbus/TCP server")}
#: the units of the single-plant layout before the templates (refused: remove them first)
LEGACY = ("softplc.service", "softplc-opcua.service")
#: how to make a venv the service can run
VENV_FIX = "make the venv with the system's Python: /usr/bin/python3 -m venv /opt/softplc/venv"


class InstallError(SoftplcError):
    """The installation cannot go on; the message says what to do (one line per reason)."""


class NowRefused(SoftplcError):
    """``--now``: the running controller refused the online change; it runs on with the
    previous program (nothing restarted behind the operator's back)."""


class Owner(Enum):
    """Who owns an installed file or directory (user:group)."""

    ROOT = "root:root"  # the unit: root writes, everybody reads
    CONFIG = f"root:{USER}"  # plant and charts: root writes, the service reads
    SERVICE = f"{USER}:{USER}"  # the state directory: the service writes


class ServiceIds(NamedTuple):
    """The service user's uid and gid."""

    uid: int
    gid: int


#: mode of the configuration directories and of the plant and charts in them
CONFIG_DIR_MODE = 0o750
CONFIG_FILE_MODE = 0o640
#: as the unit's StateDirectoryMode=
STATE_DIR_MODE = 0o750
UNIT_MODE = 0o644


@dataclass(frozen=True)
class Entry:
    """One file (``data``) or directory (``data`` None) to install, with mode and owner."""

    mode: int
    owner: Owner
    data: bytes | None = None


@dataclass
class Plan:
    """What install-service will write and run: directories first, then files."""

    name: str = ""
    files: dict[str, Entry] = field(default_factory=dict)  # absolute path -> entry
    user_commands: list[list[str]] = field(default_factory=list)  # before the files
    commands: list[list[str]] = field(default_factory=list)  # after the files
    warnings: list[str] = field(default_factory=list)
    #: why the service could not run this plant: nothing is installed (one line each)
    refusals: list[str] = field(default_factory=list)
    #: the plant has an ``opcua:`` section (softplc-opcua@NAME is installed)
    opcua: bool = False
    #: the installed plant had one and this one has not (softplc-opcua@NAME is disabled)
    opcua_removed: bool = False
    #: the plant has an ``mqtt:`` section (softplc-mqtt@NAME is installed)
    mqtt: bool = False
    #: the installed plant had one and this one has not (softplc-mqtt@NAME is disabled)
    mqtt_removed: bool = False
    #: the plant has a ``web:`` section (softplc-web@NAME is installed)
    web: bool = False
    #: the installed plant had one and this one has not (softplc-web@NAME is disabled)
    web_removed: bool = False
    #: the plant has a ``modbus:`` section (softplc-modbus@NAME is installed)
    modbus: bool = False
    #: the installed plant had one and this one has not (softplc-modbus@NAME is disabled)
    modbus_removed: bool = False
    #: a file to install differs from what is installed (or nothing is installed)
    changed: bool = True
    #: why a running controller must restart to run this plant (empty: an online change)
    restart_reasons: list[str] = field(default_factory=list)
    #: put the plant in service now (``--now``)
    start: bool = False

    @property
    def controller(self) -> str:
        return instance(CONTROLLER, self.name)

    @property
    def server(self) -> str:
        return instance(OPCUA, self.name)

    @property
    def edge_node(self) -> str:
        return instance(MQTT, self.name)

    @property
    def web_view(self) -> str:
        return instance(WEB, self.name)

    def sides(self) -> list[tuple[str, bool, bool, str]]:
        """(section, installed, removed, its unit) for each side process."""
        return [("opcua", self.opcua, self.opcua_removed, self.server),
                ("mqtt", self.mqtt, self.mqtt_removed, self.edge_node),
                ("web", self.web, self.web_removed, self.web_view),
                ("modbus", self.modbus, self.modbus_removed, instance(MODBUS, self.name))]


def instance(template: str, name: str) -> str:
    """``softplc@.service`` and NAME -> ``softplc@NAME.service``."""
    return template.replace("@.", f"@{name}.")


def _template(name: str) -> str:
    """The text of unit ``name`` as the project ships it."""
    candidates = [os.path.join(d, name) for d in UNIT_DIRS]
    template = next((c for c in candidates if os.path.exists(c)), None)
    if template is None:
        raise InstallError(f"systemd/{name} not found in " + ", ".join(candidates))
    with open(template, encoding="utf-8") as f:
        return f.read()


def unit_text(softplc: str, etc: str = INSTALL_DIR, groups: tuple[str, ...] = GROUPS) -> str:
    """The template unit systemd/softplc@.service with ExecStart (``softplc run``),
    ExecReload (``softplc reload``, which finds the plant's console) of the plant
    ``etc/%i/plant.yaml`` and SupplementaryGroups set."""
    plant = f"{etc}/%i/{INSTALLED_FILE}"
    out = []
    for line in _template(CONTROLLER).splitlines():
        if line.startswith("ExecStart="):
            line = f"ExecStart={softplc} run {plant}"
        elif line.startswith("ExecReload="):
            line = f"ExecReload={softplc} reload {plant}"
        elif line.startswith("SupplementaryGroups="):
            line = "SupplementaryGroups=" + " ".join(groups)
        out.append(line)
    return "\n".join(out) + "\n"


def side_unit_text(section: str, softplc: str, etc: str = INSTALL_DIR) -> str:
    """The template unit of a side process (systemd/softplc-opcua@.service,
    softplc-mqtt@.service) with ExecStart set."""
    unit, command, _what = SIDES[section]
    plant = f"{etc}/%i/{INSTALLED_FILE}"
    return "".join(f"ExecStart={softplc} {command} {plant}\n" if line.startswith("ExecStart=")
                   else line + "\n" for line in _template(unit).splitlines())


def opcua_unit_text(softplc: str, etc: str = INSTALL_DIR) -> str:
    """The template unit systemd/softplc-opcua@.service with ExecStart set."""
    return side_unit_text("opcua", softplc, etc)


def _rewrite_grafcet_paths(plant_path: str, names: dict[str, str]) -> str:
    """The plant file's text with each instance's ``grafcet:`` value replaced by its copy's
    name, in place (line and column from the YAML nodes)."""
    with open(plant_path, encoding="utf-8") as f:
        lines = f.read().splitlines(keepends=True)
    doc = load_yaml(plant_path)
    assert isinstance(doc, YMap)
    instances = doc["instances"]
    edits = []
    for name, spec in instances.items():
        loc = spec.val_locs["grafcet"]
        edits.append((loc.line, loc.col, str(spec["grafcet"]), names[name]))
    for line, col, old, new in sorted(edits, reverse=True):
        text = lines[line - 1]
        start = col - 1
        end = text.find(old, start)
        if end < 0:  # quoted or unusual scalar: replace the whole value up to a comment
            raise InstallError(f"{plant_path}:{line}:{col}: cannot rewrite the grafcet path; "
                               "write it as a plain path")
        lines[line - 1] = text[:end] + new + text[end + len(old):]
    return "".join(lines)


def _target(path: str, root: str | None) -> str:
    return os.path.join(root, path.lstrip("/")) if root else path


def plan(plant_path: str, softplc: str, etc: str = INSTALL_DIR,
         unit_dir: str = "/etc/systemd/system", enable: bool = True,
         start: bool = False, name: str | None = None, root: str | None = None,
         check_exec: bool | None = None) -> Plan:
    """Work out the files and commands of an installation of the plant as NAME (nothing is
    written). ``root``: where an installation is staged (what is installed is read
    there). ``check_exec``: refuse an ``ExecStart`` the service could not run; by default
    when really installing (``root`` None), else only warned."""
    check_exec = root is None if check_exec is None else check_exec
    name = name or plant_name(plant_path)
    if not NAME_RE.match(name):
        raise InstallError(f"'{name}' cannot name a plant (a unit's instance): use letters, "
                           "digits, '_' and '-' (at most 64), e.g. --name press1")
    with service_view(name):  # ${RUNTIME_DIR} as the service sees it: /run/softplc/NAME
        pdef = load_plant(plant_path)  # refuses a broken plant before anything is installed
    home = os.path.join(etc, name)
    p = Plan(name=name, start=start, opcua=pdef.opcua is not None, mqtt=pdef.mqtt is not None,
             web=pdef.web is not None, modbus=pdef.modbus is not None)
    p.files[etc] = Entry(CONFIG_DIR_MODE, Owner.CONFIG)
    p.files[home] = Entry(CONFIG_DIR_MODE, Owner.CONFIG)
    p.files[STATE_DIR] = Entry(STATE_DIR_MODE, Owner.SERVICE)
    copies: dict[str, str] = {}  # source path -> name in home
    names: dict[str, str] = {}
    for iname, inst in pdef.instances.items():
        src = os.path.abspath(inst.grafcet.path)
        if src not in copies:
            base = os.path.basename(src)
            taken = set(copies.values()) | {INSTALLED_FILE}
            stem, ext = os.path.splitext(base)
            n = 2
            while base in taken:
                base = f"{stem}-{n}{ext}"
                n += 1
            copies[src] = base
        names[iname] = copies[src]
    for src, base in copies.items():
        with open(src, "rb") as f:
            p.files[os.path.join(home, base)] = Entry(CONFIG_FILE_MODE, Owner.CONFIG, f.read())
    p.files[os.path.join(home, INSTALLED_FILE)] = Entry(
        CONFIG_FILE_MODE, Owner.CONFIG, _rewrite_grafcet_paths(plant_path, names).encode())
    p.files[os.path.join(unit_dir, CONTROLLER)] = Entry(
        UNIT_MODE, Owner.ROOT, unit_text(softplc, etc).encode())
    units = [p.controller]
    for section, there, _removed, unit in p.sides():
        if there:
            p.files[os.path.join(unit_dir, SIDES[section][0])] = Entry(
                UNIT_MODE, Owner.ROOT, side_unit_text(section, softplc, etc).encode())
            units.append(unit)
    _sight(p, pdef, softplc, check_exec)
    _conflicts(p, pdef, etc, unit_dir, root)
    _changes(p, pdef, home, root)
    p.user_commands = _user_commands()
    p.commands.append(["systemctl", "daemon-reload"])
    if enable:
        p.commands.append(["systemctl", "enable", *units])
        for _section, _there, removed, unit in p.sides():
            if removed:
                p.commands.append(["systemctl", "disable", *(["--now"] if start else []),
                                   unit])
    return p


def _sight(p: Plan, pdef: PlantDef, softplc: str, check_exec: bool) -> None:
    """Refusals (and warnings) for what the service could not see, create or read."""
    name = p.name
    rdir = os.path.join(SERVICE_RUNTIME, name)
    uid, gids = service_identity(USER, (USER, *GROUPS))
    chain = exec_chain(softplc)
    listed = {path for _, path in chain}
    for what, path in chain:
        python = what.startswith("the Python")
        # a link whose target is in the chain too is said once, at the target
        to_listed = os.path.realpath(path) in listed - {path}
        directive = hidden_by(path, follow=not to_listed)
        if directive is not None:
            fix = VENV_FIX if python else ("install softplc into a venv the service can "
                                           "see, e.g. /opt/softplc/venv (pip install "
                                           "/path/to/softplc, not pip install -e)")
            line = (f"ExecStart: {path} ({what}) is hidden from the service by "
                    f"{directive}: {fix}")
        elif to_listed:  # whether the service may use it is said at the target
            line = ""
        else:
            why = unreadable(path, uid, gids, execute=what == "the program" or python)
            line = "" if why is None else \
                f"ExecStart: {path} ({what}) cannot be used by the user {USER}: {why}"
        if line:
            (p.refusals if check_exec else p.warnings).append(
                line if check_exec else f"{line} (refused when installing)")
    own = f"{STATE_DIR}/{name}.retain.json"
    if pdef.retain_path:
        path = pdef.retain_path
        directive = hidden_by(path)
        if directive is not None:
            p.refusals.append(f"plc: retain: {path} is hidden from the service by "
                              f"{directive}: use {own}")
        elif below(os.path.abspath(path), rdir):
            p.warnings.append(f"plc: retain: {path} is in the runtime directory {rdir}, "
                              f"emptied at every reboot: keep retained data in {STATE_DIR} "
                              f"(e.g. {own})")
        elif not below(os.path.abspath(path), STATE_DIR):
            p.refusals.append(f"plc: retain: {path} cannot be written by the service "
                              f"(ProtectSystem=strict: it writes only {STATE_DIR} and "
                              f"{rdir}): use {own}")
    sockets = [("monitor: socket", c.address) for c in pdef.consoles if c.kind == "socket"]
    if pdef.opcua is not None:
        sockets.append(("opcua: feed", pdef.opcua.feed))
    elif pdef.mqtt is not None:  # (one feed: opcua's is mqtt's when both are there)
        sockets.append(("mqtt: feed", pdef.mqtt.feed))
    elif pdef.web is not None:
        sockets.append(("web: feed", pdef.web.feed))
    elif pdef.modbus is not None:
        sockets.append(("modbus: feed", pdef.modbus.feed))
    for key, path in sockets:
        if below(os.path.abspath(path), rdir):
            continue
        directive = hidden_by(path)
        why = (f"nobody outside the service would reach it ({directive})" if directive
               else "the service cannot create it (ProtectSystem=strict)")
        p.refusals.append(f"{key}: {path} is outside the runtime directory {rdir}: {why}; "
                          f"put it in '{PLACEHOLDER}/'")
    if pdef.opcua is not None:
        sec = pdef.opcua.security
        _service_reads(p, [(f"opcua: security: {key}", getattr(sec, key)) for key in
                           ("certificate", "private_key", "trusted_clients",
                            "trusted_readers")],
                       "softplc opcua-cert makes a certificate, docs/opcua.md", uid, gids)
    # the files of the web view, the Modbus server and the edge node: one list, the
    # checker's (runtime/language/tlsconf.py), each named as its key ("mqtt: tls: ca")
    hints = {"mqtt": "the edge node cannot connect without it, docs/mqtt.md",
             "web": "docs/web.md says how to make one",
             "modbus": "docs/modbus.md says how to make them"}
    files = side_files(pdef)
    for side, hint in hints.items():
        _service_reads(p, [(what.replace(" ", ": "), path)
                           for s, what, path, _loc in files if s == side], hint, uid, gids)
    if not pdef.consoles or all(c.kind == "serial" for c in pdef.consoles):
        p.warnings.append(f"monitor: no console socket or TCP port: `systemctl reload "
                          f"{p.controller}` (online change) needs one; add monitor: socket: "
                          f"{{path: '{PLACEHOLDER}/console.sock'}}")
    for c in pdef.consoles:
        if c.trusted and any(d.type != "sim" for d in pdef.drivers.values()):
            p.warnings.append(f"monitor: the {c.kind} console is trusted (no PIN) on a plant "
                              "that drives real I/O: set pin_hash (softplc hash-pin) instead")
    if any(d.type == "sim" for d in pdef.drivers.values()):
        p.warnings.append("the plant uses simulated I/O (type: sim): nothing physical moves")


def _service_reads(p: Plan, files: list[tuple[str, str | None]], missing: str, uid: int,
                   gids: set[int]) -> None:
    """Refusals for the files a unit reads (certificates, keys, a password file: KEY and
    path) that it could not see or its user could not read; a warning for one not there yet
    (``missing``: what makes it, or what it is for)."""
    for key, path in files:
        if not path:
            continue
        directive = hidden_by(path)
        if directive is not None:
            p.refusals.append(f"{key}: {path} is hidden from the service by {directive}: "
                              "keep it under /etc/softplc")
        elif not os.path.exists(path):
            p.warnings.append(f"{key}: {path} does not exist yet ({missing})")
        else:
            why = unreadable(path, uid, gids)
            if why is not None:
                p.refusals.append(f"{key}: {path} cannot be read by the user {USER}: {why}")


def _ports(pdef: PlantDef) -> dict[str, str]:
    """What of ``pdef`` no other plant may have: its OPC UA and console TCP ports, its
    retain file -> how to name it."""
    out = {}
    if pdef.opcua is not None:
        port = pdef.opcua.endpoint.rsplit(":", 1)[1].split("/")[0]
        out[f"port {port}"] = f"the opcua: endpoint port {port}"
    if pdef.web is not None and pdef.web.port:
        out[f"port {pdef.web.port}"] = f"the web: listen port {pdef.web.port}"
    if pdef.modbus is not None:
        if pdef.modbus.host and pdef.modbus.port:
            out[f"port {pdef.modbus.port}"] = f"the modbus: listen port {pdef.modbus.port}"
        if pdef.modbus.tls is not None and pdef.modbus.tls.port:
            out[f"port {pdef.modbus.tls.port}"] = (f"the modbus: tls: listen port "
                                                    f"{pdef.modbus.tls.port}")
    for c in pdef.consoles:
        if c.kind == "tcp":
            port = c.address.rsplit(":", 1)[1]
            out[f"port {port}"] = f"the monitor: tcp port {port}"
    if pdef.retain_path:
        out[f"file {pdef.retain_path}"] = f"the plc: retain file {pdef.retain_path}"
    return out


def _conflicts(p: Plan, pdef: PlantDef, etc: str, unit_dir: str, root: str | None) -> None:
    """Refusals for what another installed plant has, and for the single-plant layout."""
    for unit in LEGACY:
        if os.path.exists(_target(os.path.join(unit_dir, unit), root)):
            p.refusals.append(
                f"{os.path.join(unit_dir, unit)}: an installation of the single-plant layout "
                "is there, whose controller would drive the same I/O: remove it first "
                f"(systemctl disable --now {' '.join(LEGACY)}; rm "
                f"{' '.join(os.path.join(unit_dir, u) for u in LEGACY)})")
            break
    mine = _ports(pdef)
    base = _target(etc, root)
    try:
        others = sorted(os.listdir(base))
    except OSError:
        others = []
    for other in others:
        path = os.path.join(base, other, INSTALLED_FILE)
        if other == p.name or not NAME_RE.match(other) or not os.path.isfile(path):
            continue
        try:
            with service_view(other):
                theirs = _ports(load_plant(path))
        except SoftplcError:
            continue  # a broken plant of its own: its unit says so
        for key in sorted(mine.keys() & theirs.keys()):
            p.refusals.append(f"{mine[key]} is the one of the installed plant {other} "
                              f"({os.path.join(etc, other, INSTALLED_FILE)}): give each "
                              "plant its own")


def _changes(p: Plan, pdef: PlantDef, home: str, root: str | None) -> None:
    """Compare with what is installed: whether anything changes, and why a running
    controller must restart for it (empty: an online change applies it)."""
    differ = []
    for path, entry in p.files.items():
        if entry.data is None:
            continue
        try:
            with open(_target(path, root), "rb") as f:
                same = f.read() == entry.data
        except OSError:
            same = False
        if not same:
            differ.append(path)
    p.changed = bool(differ)
    units = [path for path in differ if os.path.basename(path) == CONTROLLER]
    if units:  # (the OPC UA server's unit is the server's: it restarts anyway)
        p.restart_reasons.append(f"its unit changed ({units[0]})")
    installed = _target(os.path.join(home, INSTALLED_FILE), root)
    if not os.path.exists(installed):
        return
    try:
        with service_view(p.name):
            old = load_plant(installed)
    except SoftplcError as exc:
        p.restart_reasons.append(f"the installed plant could not be read: {exc}")
        return
    p.opcua_removed = old.opcua is not None and pdef.opcua is None
    p.mqtt_removed = old.mqtt is not None and pdef.mqtt is None
    p.web_removed = old.web is not None and pdef.web is None
    p.modbus_removed = old.modbus is not None and pdef.modbus is None
    p.restart_reasons += diff_plants(old, pdef).static_refusals()


def _user_commands() -> list[list[str]]:
    cmds: list[list[str]] = []
    for g in GROUPS:
        try:
            grp.getgrnam(g)
        except KeyError:
            cmds.append(["groupadd", "--system", g])
    try:
        pwd.getpwnam(USER)
    except KeyError:
        cmds.append(["useradd", "--system", "--no-create-home", "--home-dir", STATE_DIR,
                     "--shell", "/usr/sbin/nologin", "--user-group", USER])
    cmds.append(["usermod", "--append", "--groups", ",".join(GROUPS), USER])
    return cmds


def service_ids() -> ServiceIds:
    """The uid and gid of the installed service user."""
    try:
        user = pwd.getpwnam(USER)
    except KeyError:
        raise InstallError(f"user {USER} not found after creating it") from None
    return ServiceIds(user.pw_uid, user.pw_gid)


def _ids_of(owner: Owner, ids: ServiceIds) -> tuple[int, int]:
    return {Owner.ROOT: (0, 0), Owner.CONFIG: (0, ids.gid),
            Owner.SERVICE: (ids.uid, ids.gid)}[owner]


def _make_dir(path: str, entry: Entry, ids: ServiceIds | None) -> None:
    os.makedirs(path, exist_ok=True)
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):  # a symbolic link or a file: never follow or replace
        raise InstallError(f"{path} is not a directory (a symbolic link?): remove it first")
    if ids is not None:
        os.chown(path, *_ids_of(entry.owner, ids))
    os.chmod(path, entry.mode)


def _write_file(path: str, entry: Entry, ids: ServiceIds | None) -> None:
    """Write under a temporary name created 0600, give it its owner and mode, then rename:
    the contents are never readable by others, not even while being written."""
    assert entry.data is not None
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path),
                               prefix="." + os.path.basename(path) + ".")
    try:
        with os.fdopen(fd, "wb") as out:
            if ids is not None:
                os.fchown(out.fileno(), *_ids_of(entry.owner, ids))
            os.fchmod(out.fileno(), entry.mode)
            out.write(entry.data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def apply(p: Plan, root: str | None = None, force: bool = False,
          ids: ServiceIds | None = None) -> list[str]:
    """Write the files (below ``root`` if given) and run the commands (only printed with
    ``root``); with ``p.start``, put the plant in service (``bring_up``). Ownership is
    applied when really installing, or with ``ids`` below ``root`` (tests); otherwise only
    printed. Returns what was done, one line each. Raises InstallError before writing
    anything for a plant the service could not run (``p.refusals``) or if a file the user
    wrote would be overwritten; NowRefused if the running controller refused the online
    change."""
    if p.refusals:
        raise InstallError("\n".join(p.refusals))
    done: list[str] = []
    clashes = []
    for path, entry in p.files.items():
        t = _target(path, root)
        if entry.data is not None and os.path.exists(t):
            with open(t, "rb") as old:
                if old.read() != entry.data:
                    clashes.append(t)
    if clashes and not force:
        raise InstallError("these files exist with other contents and are left alone: "
                           + ", ".join(clashes) + " (compare them, then run again with "
                           "--force to keep each old one as NAME.bak-TIMESTAMP)")
    for cmd in p.user_commands:  # the softplc group must exist before files get it
        done.append(_run(cmd, root))
    if root is None:
        ids = service_ids()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for path, entry in p.files.items():
        t = _target(path, root)
        how = f"{entry.mode:04o}, " + (f"{entry.owner.value}" if ids is not None
                                        else f"would chown {entry.owner.value}")
        if entry.data is None:
            _make_dir(t, entry, ids)
            done.append(f"directory {t} ({how})")
            continue
        os.makedirs(os.path.dirname(t), exist_ok=True)
        if t in clashes:  # the old file may hold a PIN hash: the backup gets the new mode
            with open(t, "rb") as old:
                _write_file(f"{t}.bak-{stamp}", Entry(entry.mode, entry.owner, old.read()),
                            ids)
            done.append(f"kept the old {t} as {t}.bak-{stamp}")
        _write_file(t, entry, ids)
        done.append(f"wrote {t} ({how})")
    for cmd in p.commands:
        done.append(_run(cmd, root))
    if p.start:
        done += bring_up(p, root)
    elif root is None and p.changed and _active(p.controller):
        done.append(f"{p.controller} runs the previous plant: `systemctl reload "
                    f"{p.controller}` (or restart) applies this one")
    return done


def _active(unit: str) -> bool:
    return subprocess.run(["systemctl", "is-active", "--quiet", unit],
                          check=False).returncode == 0


def bring_up(p: Plan, root: str | None = None) -> list[str]:
    """``--now``: start the plant, or give the running controller the new plant the way
    the diff allows (an online change, else a restart), and say which; the same for its
    side processes (its OPC UA server, its MQTT edge node, its web view: each reads the plant
    at its start). NowRefused if the controller refused the online change (it runs on with its
    previous program)."""
    ctl = p.controller
    if root:
        return [" ".join([f"would run: systemctl start {ctl}",
                          *(unit for _s, there, _r, unit in p.sides() if there)])]
    done = []
    if not _active(ctl):
        _start(ctl, "start")
        done.append(f"started {ctl}")
    elif not p.changed:
        done.append(f"{ctl} already runs this plant: left running")
    elif p.restart_reasons:
        _start(ctl, "restart")
        done.append(f"restarted {ctl}: {'; '.join(p.restart_reasons)}")
    else:
        r = subprocess.run(["systemctl", "reload", ctl], check=False)
        if r.returncode != 0:
            raise NowRefused(f"{ctl} refused the online change (journalctl -u {ctl}): it "
                             "still runs the previous program; systemctl restart "
                             f"{ctl} applies it with a restart")
        done.append(f"reloaded {ctl} (online change)")
    for section, there, removed, unit in p.sides():
        if there:
            if not _active(unit):
                _start(unit, "start")
                done.append(f"started {unit}")
            elif p.changed:
                _start(unit, "restart")
                done.append(f"restarted {unit} (it reads the plant at its start)")
        elif removed:
            done.append(f"stopped and disabled {unit}: the plant has no {section}: section "
                        "now")
    return done


def _start(unit: str, how: str) -> None:
    """``systemctl start|restart UNIT``; NowRefused with the unit's own last line (its
    error: a device missing, a plant it refuses) if it did not start."""
    if subprocess.run(["systemctl", how, unit], check=False).returncode == 0:
        return
    r = subprocess.run(["journalctl", "-q", "-o", "cat", "-n", "1", f"_SYSTEMD_UNIT={unit}"],
                       capture_output=True, text=True, check=False)  # its own, not systemd's
    why = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else "see journalctl"
    raise NowRefused(f"{unit} did not start: {why} (journalctl -u {unit}; the unit tries "
                     "again every RestartSec)")


def _run(cmd: list[str], root: str | None) -> str:
    if root:
        return "would run: " + " ".join(cmd)
    subprocess.run(cmd, check=True)
    return "ran: " + " ".join(cmd)


def _this_softplc() -> str:
    """The ``softplc`` program of the environment running this command (the unit must start
    the same installation, not whichever ``softplc`` comes first on PATH)."""
    beside = os.path.join(os.path.dirname(sys.executable), "softplc")
    if os.access(beside, os.X_OK):
        return beside
    return shutil.which("softplc") or beside


def cmd_install_service(args: argparse.Namespace) -> int:
    softplc = os.path.abspath(_this_softplc())
    if not args.root and os.geteuid() != 0:
        sys.stderr.write("softplc install-service: error: run it as root (it creates a "
                         "user and writes /etc), or with --root DIR to stage the files\n")
        return 2
    try:
        p = plan(args.plant, softplc, args.etc, args.unit_dir, enable=not args.no_enable,
                 start=args.now, name=args.name, root=args.root)
        for w in p.warnings:
            sys.stderr.write(f"warning: {w}\n")
        for line in apply(p, args.root, args.force):
            sys.stdout.write(line + "\n")
    except InstallError as exc:
        for line in str(exc).splitlines():
            sys.stderr.write(f"softplc install-service: error: {line}\n")
        return 2
    except NowRefused as exc:
        sys.stderr.write(f"softplc install-service: {exc}\n")
        return 1
    except subprocess.CalledProcessError as exc:
        sys.stderr.write(f"softplc install-service: error: {' '.join(exc.cmd)} failed with "
                         f"status {exc.returncode}\n")
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    c = sub.add_parser("install-service", help="install the plant as a systemd service",
                       description="Copy the plant and its charts to /etc/softplc/NAME, "
                                   "create the softplc user, install the template units "
                                   "and enable softplc@NAME (and softplc-opcua@NAME, "
                                   "softplc-mqtt@NAME, softplc-web@NAME, "
                                   "softplc-modbus@NAME).")
    c.add_argument("plant", help="the plant file to run")
    c.add_argument("--name", help="the plant's name, its unit's instance (default: the "
                                  "name of the plant file's directory)")
    c.add_argument("--etc", default=INSTALL_DIR, help="configuration directory")
    c.add_argument("--unit-dir", default="/etc/systemd/system")
    c.add_argument("--root", help="write below this directory; only print the commands")
    c.add_argument("--force", action="store_true",
                   help="replace changed files (the old ones are kept as .bak-TIMESTAMP)")
    c.add_argument("--no-enable", action="store_true", help="do not enable the units")
    c.add_argument("--now", action="store_true",
                   help="put the plant in service: start it, or give the running controller "
                        "the new plant (online change, or a restart) and say which")
    c.set_defaults(func=cmd_install_service)
