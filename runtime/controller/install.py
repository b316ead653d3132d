"""``softplc install-service``: the plant under /etc/softplc, a ``softplc`` system user, and
the systemd unit, enabled.

The plant file and every grafcet file it names are copied into the configuration
directory, the plant's ``grafcet:`` paths rewritten to the copies (comments and layout
kept). A file already there with other contents is never overwritten: the command stops
and says so (``--force`` keeps the old one as ``NAME.bak-TIMESTAMP``). With ``--root DIR``
everything is written below DIR and the user, group and systemctl steps are only printed
(for packaging and for the tests).
"""

from __future__ import annotations

import argparse
import grp
import logging
import os
import pwd
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field

from runtime.errors import SoftplcError
from runtime.language.plantfile import load_plant
from runtime.language.yamlsrc import YMap, load_yaml

log = logging.getLogger(__name__)

#: the unit file: systemd/ of the source tree, or share/softplc/ of an installed package
_SOURCE_TREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
UNIT_CANDIDATES = (
    os.path.join(_SOURCE_TREE, "systemd", "softplc.service"),
    os.path.join(sys.prefix, "share", "softplc", "softplc.service"),
)
USER = "softplc"
GROUPS = ("gpio", "i2c", "dialout")
STATE_DIR = "/var/lib/softplc"
RUNTIME_DIR = "/run/softplc"


class InstallError(SoftplcError):
    """The installation cannot go on; the message says what to do."""


@dataclass
class Plan:
    """What install-service will write and run."""

    files: dict[str, bytes] = field(default_factory=dict)  # absolute path -> contents
    commands: list[list[str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def unit_text(softplc: str, plant: str, groups: tuple[str, ...] = GROUPS) -> str:
    """The unit of systemd/softplc.service with ExecStart and SupplementaryGroups set."""
    template = next((c for c in UNIT_CANDIDATES if os.path.exists(c)), None)
    if template is None:
        raise InstallError("systemd/softplc.service not found in " + ", ".join(UNIT_CANDIDATES))
    with open(template, encoding="utf-8") as f:
        text = f.read()
    out = []
    for line in text.splitlines():
        if line.startswith("ExecStart="):
            line = f"ExecStart={softplc} run {plant}"
        elif line.startswith("SupplementaryGroups="):
            line = "SupplementaryGroups=" + " ".join(groups)
        out.append(line)
    return "\n".join(out) + "\n"


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
            p.files[os.path.join(etc, base)] = f.read()
    plant_target = os.path.join(etc, "plant.yaml")
    p.files[plant_target] = _rewrite_grafcet_paths(plant_path, names).encode()
    p.files[os.path.join(unit_dir, "softplc.service")] = unit_text(
        softplc, plant_target).encode()
    if pdef.retain_path and not pdef.retain_path.startswith(STATE_DIR + "/"):
        p.warnings.append(f"plc: retain: {pdef.retain_path} is outside {STATE_DIR}: the "
                          "service may not write there (ProtectSystem=strict); use "
                          f"{STATE_DIR}/retain.json")
    for c in pdef.consoles:
        if c.kind == "socket" and not c.address.startswith(RUNTIME_DIR + "/"):
            p.warnings.append(f"monitor: socket: {c.address} is outside {RUNTIME_DIR}: "
                              "other users will not reach it (PrivateTmp); use "
                              f"{RUNTIME_DIR}/console.sock")
        if c.trusted and any(d.type != "sim" for d in pdef.drivers.values()):
            p.warnings.append(f"monitor: the {c.kind} console is trusted (no PIN) on a plant "
                              "that drives real I/O: set pin_hash (softplc hash-pin) instead")
    if any(d.type == "sim" for d in pdef.drivers.values()):
        p.warnings.append("the plant uses simulated I/O (type: sim): nothing physical moves")
    p.commands += _user_commands()
    p.commands.append(["systemctl", "daemon-reload"])
    if enable:
        p.commands.append(["systemctl", "enable", *(["--now"] if start else []),
                           "softplc.service"])
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


def apply(p: Plan, root: str | None = None, force: bool = False) -> list[str]:
    """Write the files (below ``root`` if given) and run the commands (only printed with
    ``root``). Returns what was done, one line each. Raises InstallError before writing
    anything if a file the user wrote would be overwritten."""
    done: list[str] = []

    def target(path: str) -> str:
        return os.path.join(root, path.lstrip("/")) if root else path

    clashes = []
    for path, data in p.files.items():
        t = target(path)
        if os.path.exists(t):
            with open(t, "rb") as old:
                if old.read() != data:
                    clashes.append(t)
    if clashes and not force:
        raise InstallError("these files exist with other contents and are left alone: "
                           + ", ".join(clashes) + " (compare them, then run again with "
                           "--force to keep each old one as NAME.bak-TIMESTAMP)")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for path, data in p.files.items():
        t = target(path)
        os.makedirs(os.path.dirname(t), exist_ok=True)
        if t in clashes:
            shutil.copy2(t, f"{t}.bak-{stamp}")
            done.append(f"kept the old {t} as {t}.bak-{stamp}")
        with open(t, "wb") as out:
            out.write(data)
        os.chmod(t, 0o644)
        done.append(f"wrote {t}")
    for cmd in p.commands:
        if root:
            done.append("would run: " + " ".join(cmd))
            continue
        subprocess.run(cmd, check=True)
        done.append("ran: " + " ".join(cmd))
    return done


def cmd_install_service(args: argparse.Namespace) -> int:
    softplc = shutil.which("softplc") or os.path.join(os.path.dirname(sys.executable),
                                                       "softplc")
    softplc = os.path.abspath(softplc)
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
