"""``softplc install-service``: the plant under /etc/softplc, a ``softplc`` system user, and
the systemd unit, enabled.

The plant file and every grafcet file it names are copied into the configuration
directory, the plant's ``grafcet:`` paths rewritten to the copies (comments and layout
kept). A file already there with other contents is never overwritten: the command stops
and says so (``--force`` keeps the old one as ``NAME.bak-TIMESTAMP``). With ``--root DIR``
everything is written below DIR and the user, group and systemctl steps are only printed
(for packaging and for the tests).

Who may read what (the plant holds the console's PIN hash): /etc/softplc is 0750
root:softplc and the plant and its charts 0640 root:softplc (root writes them, the service
reads them, nobody else does); /var/lib/softplc, the service's state directory, is 0750
softplc:softplc. The unit's ``StateDirectory=`` and ``RuntimeDirectory=`` keep those two
owned by the service; it has no ``ConfigurationDirectory=``: systemd would apply its mode to
/etc/softplc without ever changing its group (systemd.exec(5)), locking the service out of
its plant when the directory is root's. A file is written under a temporary name with its
final mode and owner, then renamed: it is never readable by others, not even for a moment.
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

from runtime.errors import SoftplcError
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import runtime_dir
from runtime.language.yamlsrc import YMap, load_yaml

log = logging.getLogger(__name__)

#: the unit files: systemd/ of the source tree, or share/softplc/ of an installed package
_SOURCE_TREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
UNIT_DIRS = (os.path.join(_SOURCE_TREE, "systemd"), os.path.join(sys.prefix, "share", "softplc"))
#: the console socket ExecReload= talks to when the plant names none under /run/softplc
DEFAULT_RELOAD_SOCKET = "/run/softplc/console.sock"
USER = "softplc"
GROUPS = ("gpio", "i2c", "dialout")
STATE_DIR = "/var/lib/softplc"
RUNTIME_DIR = "/run/softplc"


class InstallError(SoftplcError):
    """The installation cannot go on; the message says what to do."""


class Owner(Enum):
    """Who owns an installed file or directory (user:group)."""

    ROOT = "root:root"  # the unit: root writes, everybody reads
    CONFIG = f"root:{USER}"  # plant and charts: root writes, the service reads
    SERVICE = f"{USER}:{USER}"  # the state directory: the service writes


class ServiceIds(NamedTuple):
    """The service user's uid and gid."""

    uid: int
    gid: int


#: mode of the configuration directory and of the plant and charts in it
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

    files: dict[str, Entry] = field(default_factory=dict)  # absolute path -> entry
    user_commands: list[list[str]] = field(default_factory=list)  # before the files
    commands: list[list[str]] = field(default_factory=list)  # after the files
    warnings: list[str] = field(default_factory=list)


def _template(name: str) -> str:
    """The text of unit ``name`` as the project ships it."""
    candidates = [os.path.join(d, name) for d in UNIT_DIRS]
    template = next((c for c in candidates if os.path.exists(c)), None)
    if template is None:
        raise InstallError(f"systemd/{name} not found in " + ", ".join(candidates))
    with open(template, encoding="utf-8") as f:
        return f.read()


def unit_text(softplc: str, plant: str, groups: tuple[str, ...] = GROUPS,
              reload_socket: str = DEFAULT_RELOAD_SOCKET) -> str:
    """The unit of systemd/softplc.service with ExecStart, ExecReload (``softplc reload``
    on ``reload_socket``, the plant's console socket) and SupplementaryGroups set."""
    out = []
    for line in _template("softplc.service").splitlines():
        if line.startswith("ExecStart="):
            line = f"ExecStart={softplc} run {plant}"
        elif line.startswith("ExecReload="):
            line = f"ExecReload={softplc} reload {reload_socket}"
        elif line.startswith("SupplementaryGroups="):
            line = "SupplementaryGroups=" + " ".join(groups)
        out.append(line)
    return "\n".join(out) + "\n"


def opcua_unit_text(softplc: str, plant: str) -> str:
    """The unit of systemd/softplc-opcua.service with ExecStart set."""
    return "".join(f"ExecStart={softplc} opcua {plant}\n" if line.startswith("ExecStart=")
                   else line + "\n" for line in _template("softplc-opcua.service").splitlines())


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


def plan(plant_path: str, softplc: str, etc: str = "/etc/softplc",
         unit_dir: str = "/etc/systemd/system", enable: bool = True,
         start: bool = False) -> Plan:
    """Work out the files and commands of an installation (nothing is written)."""
    pdef = load_plant(plant_path)  # refuses a broken plant before anything is installed
    p = Plan()
    p.files[etc] = Entry(CONFIG_DIR_MODE, Owner.CONFIG)
    p.files[STATE_DIR] = Entry(STATE_DIR_MODE, Owner.SERVICE)
    copies: dict[str, str] = {}  # source path -> name in etc
    names: dict[str, str] = {}
    for name, inst in pdef.instances.items():
        src = os.path.abspath(inst.grafcet.path)
        if src not in copies:
            base = os.path.basename(src)
            taken = set(copies.values()) | {"plant.yaml"}
            stem, ext = os.path.splitext(base)
            n = 2
            while base in taken:
                base = f"{stem}-{n}{ext}"
                n += 1
            copies[src] = base
        names[name] = copies[src]
    for src, base in copies.items():
        with open(src, "rb") as f:
            p.files[os.path.join(etc, base)] = Entry(CONFIG_FILE_MODE, Owner.CONFIG, f.read())
    plant_target = os.path.join(etc, "plant.yaml")
    p.files[plant_target] = Entry(CONFIG_FILE_MODE, Owner.CONFIG,
                                  _rewrite_grafcet_paths(plant_path, names).encode())
    mine = runtime_dir()  # ${RUNTIME_DIR} here; /run/softplc under the service
    sockets = [RUNTIME_DIR + c.address[len(mine):] if c.address.startswith(mine + "/")
               else c.address for c in pdef.consoles if c.kind == "socket"]
    served = [s for s in sockets if s.startswith(RUNTIME_DIR + "/")]
    p.files[os.path.join(unit_dir, "softplc.service")] = Entry(
        UNIT_MODE, Owner.ROOT, unit_text(softplc, plant_target, reload_socket=(
            served[0] if served else DEFAULT_RELOAD_SOCKET)).encode())
    units = ["softplc.service"]
    if pdef.opcua is not None:
        p.files[os.path.join(unit_dir, "softplc-opcua.service")] = Entry(
            UNIT_MODE, Owner.ROOT, opcua_unit_text(softplc, plant_target).encode())
        units.append("softplc-opcua.service")
    if not served:
        p.warnings.append("monitor: no console socket under /run/softplc: `systemctl reload "
                          "softplc` (online change) needs one; add monitor: socket: {path: "
                          "'${RUNTIME_DIR}/console.sock'}")
    if pdef.retain_path and not pdef.retain_path.startswith(STATE_DIR + "/"):
        p.warnings.append(f"plc: retain: {pdef.retain_path} is outside {STATE_DIR}: the "
                          "service may not write there (ProtectSystem=strict); use "
                          f"{STATE_DIR}/retain.json")
    for c in pdef.consoles:
        if c.kind == "socket" and not c.address.startswith((RUNTIME_DIR + "/", mine + "/")):
            p.warnings.append(f"monitor: socket: {c.address} is outside {RUNTIME_DIR}: "
                              "other users will not reach it (PrivateTmp); use "
                              "${RUNTIME_DIR}/console.sock")
        if c.trusted and any(d.type != "sim" for d in pdef.drivers.values()):
            p.warnings.append(f"monitor: the {c.kind} console is trusted (no PIN) on a plant "
                              "that drives real I/O: set pin_hash (softplc hash-pin) instead")
    if any(d.type == "sim" for d in pdef.drivers.values()):
        p.warnings.append("the plant uses simulated I/O (type: sim): nothing physical moves")
    p.user_commands = _user_commands()
    p.commands.append(["systemctl", "daemon-reload"])
    if enable:
        p.commands.append(["systemctl", "enable", *(["--now"] if start else []), *units])
    return p


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
    ``root``). Ownership is applied when really installing, or with ``ids`` below ``root``
    (tests); otherwise only printed. Returns what was done, one line each. Raises
    InstallError before writing anything if a file the user wrote would be overwritten."""
    done: list[str] = []

    def target(path: str) -> str:
        return os.path.join(root, path.lstrip("/")) if root else path

    clashes = []
    for path, entry in p.files.items():
        t = target(path)
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
        t = target(path)
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
    return done


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
    if not args.root:
        if os.geteuid() != 0:
            sys.stderr.write("softplc install-service: error: run it as root (it creates a "
                             "user and writes /etc), or with --root DIR to stage the files\n")
            return 2
        if softplc.startswith(("/home/", "/root/")):
            sys.stderr.write(f"softplc install-service: error: {softplc} is under /home or "
                             "/root, which the service cannot read (ProtectHome=yes): install "
                             "softplc in a venv such as /opt/softplc/venv first\n")
            return 2
    try:
        p = plan(args.plant, softplc, args.etc, args.unit_dir, enable=not args.no_enable,
                 start=args.now)
        for w in p.warnings:
            sys.stderr.write(f"warning: {w}\n")
        for line in apply(p, args.root, args.force):
            sys.stdout.write(line + "\n")
    except InstallError as exc:
        sys.stderr.write(f"softplc install-service: error: {exc}\n")
        return 2
    except subprocess.CalledProcessError as exc:
        sys.stderr.write(f"softplc install-service: error: {' '.join(exc.cmd)} failed with "
                         f"status {exc.returncode}\n")
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    c = sub.add_parser("install-service", help="install the plant as a systemd service",
                       description="Copy the plant and its charts to /etc/softplc, create "
                                   "the softplc user, install and enable the systemd unit.")
    c.add_argument("plant", help="the plant file to run")
    c.add_argument("--etc", default="/etc/softplc", help="configuration directory")
    c.add_argument("--unit-dir", default="/etc/systemd/system")
    c.add_argument("--root", help="write below this directory; only print the commands")
    c.add_argument("--force", action="store_true",
                   help="replace changed files (the old ones are kept as .bak-TIMESTAMP)")
    c.add_argument("--no-enable", action="store_true", help="do not enable the unit")
    c.add_argument("--now", action="store_true", help="start the service at once")
    c.set_defaults(func=cmd_install_service)
