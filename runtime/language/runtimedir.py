"""Where the processes of one plant find each other: its name, its runtime directory
(``${RUNTIME_DIR}`` in plant paths), its lock, its console and feed sockets.

This is the one home of that question. The controller (``softplc run``) creates what is
named here; every process beside it (``softplc opcua``, ``softplc reload``, and any later
side process: ``softplc mqtt``, a web view) reads the same plant file and calls
``locate(pdef)`` to find the controller, never a path of its own.

``${RUNTIME_DIR}`` is, first found:

1. ``$RUNTIME_DIRECTORY``: set by systemd for a unit with ``RuntimeDirectory=``. Every unit
   of an installed plant NAME (``softplc@NAME.service``, ``softplc-opcua@NAME.service``,
   ``softplc-mqtt@NAME.service``) declares ``RuntimeDirectory=softplc/%i`` with
   ``RuntimeDirectoryPreserve=yes``, so all get /run/softplc/NAME, by construction;
2. /run/softplc/NAME for an installed plant, whoever runs it: a plant file at
   /etc/softplc/NAME/plant.yaml (what ``softplc install-service`` writes). So a process
   started by hand on an installed plant (``sudo softplc opcua /etc/softplc/NAME/plant.yaml``,
   a second ``softplc run`` by mistake) looks where the service is;
3. ``$XDG_RUNTIME_DIR/softplc/KEY`` when ``$XDG_RUNTIME_DIR`` is an absolute path to a
   directory of this user (a login session: /run/user/UID);
4. ``${TMPDIR:-/tmp}/softplc-UID/KEY`` otherwise.

A plant is its directory: the plant files of one directory are versions of one plant (an
installed plant has a directory of its own, /etc/softplc/NAME). Its **name** is the NAME of
an installed plant, else the name of that directory (``configs/drawer_tester/plant_sim.yaml``:
drawer_tester); its **home** is the real path of that directory: the key of its lock and the
owner recorded with its retained data.

A plant run by hand has a runtime directory of its own, as an installed plant has: KEY is
``NAME-HASH`` (``plant_key``: the name, at most KEY_NAME_MAX characters of it, and the
first KEY_HASH hexadecimal digits of the sha256 of its home). So what two plants name in
``${RUNTIME_DIR}`` (``${RUNTIME_DIR}/drawer.sock``, a retain file) and their default feed
socket are never the same file, even for two clones of one project (the same name, two
homes). ``runtime_dir`` without a plant is the directory of those directories. A plant file
loaded as a version of a running plant (``softplc diff OLD NEW``, ``reload NEW`` of a copy
kept elsewhere) has the running plant's: ``version_of``.

This module only names things; ``runtime.controller.paths`` creates and checks the
directories, ``runtime.controller.plantlock`` takes the lock. Nothing else is expanded in a
path: any other ``${`` is an error, so that a misspelt placeholder never becomes a
directory named ``${...}``.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import os
import re
import stat
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from runtime.errors import Loc, SourceError
from runtime.language.model import PlantDef

PLACEHOLDER = "${RUNTIME_DIR}"
#: where ``softplc install-service`` puts the plant NAME: INSTALL_DIR/NAME/plant.yaml
INSTALL_DIR = "/etc/softplc"
#: the file name of an installed plant in its directory
INSTALLED_FILE = "plant.yaml"
#: the runtime directories of installed plants: SERVICE_RUNTIME/NAME (the units'
#: ``RuntimeDirectory=softplc/%i``)
SERVICE_RUNTIME = "/run/softplc"
#: the state directory of the units (``StateDirectory=softplc``): retained data
STATE_DIR = "/var/lib/softplc"
#: what a plant name (a unit's instance name) may be
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
#: the feed socket's name when the plant does not give one
FEED_FILE = "feed.sock"
#: a plant's runtime directory by hand, NAME-HASH: at most this much of the name, and this
#: many hexadecimal digits of its home's sha256 (a socket's whole path is at most 107
#: bytes: /run/user/1000/softplc/drawer_tester-4be1c2d0/drawer.sock is 58)
KEY_NAME_MAX = 16
KEY_HASH = 8

#: install-service loads the plant as the service will see it (``service_view``)
_SERVICE_VIEW: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "softplc_service_view", default=None)
#: the plant file whose runtime directory a load uses (``version_of``)
_VERSION_OF: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "softplc_version_of", default=None)


def installed_name(plant: str) -> str | None:
    """NAME when ``plant`` is an installed plant, INSTALL_DIR/NAME/plant.yaml (symbolic links
    resolved); None otherwise."""
    real = os.path.realpath(plant)
    directory, file = os.path.split(real)
    parent, name = os.path.split(directory)
    if file == INSTALLED_FILE and parent == INSTALL_DIR and NAME_RE.match(name):
        return name
    return None


def plant_name(plant: str) -> str:
    """The plant's name: an installed plant's NAME, else its directory's name."""
    name = installed_name(plant)
    if name is not None:
        return name
    return os.path.basename(os.path.dirname(os.path.realpath(plant))) or "plant"


def plant_home(plant: str) -> str:
    """The plant's identity: the real path of its file's directory."""
    return os.path.dirname(os.path.realpath(plant))


def _digest(home: str) -> str:
    return hashlib.sha256(home.encode()).hexdigest()


def plant_key(plant: str) -> str:
    """``NAME-HASH``: the name of the runtime directory of the plant file ``plant`` run by
    hand (see the module's docstring)."""
    return f"{plant_name(plant)[:KEY_NAME_MAX]}-{_digest(plant_home(plant))[:KEY_HASH]}"


def runtime_dir(env: Mapping[str, str] | None = None, uid: int | None = None,
                plant: str | None = None) -> str:
    """The directory ``${RUNTIME_DIR}`` stands for, for the plant file ``plant``; without
    a plant, the directory of the runtime directories of the plants run by hand (nothing
    is created or checked here but whether ``$XDG_RUNTIME_DIR`` is this user's)."""
    viewed = _SERVICE_VIEW.get()
    if viewed is not None:
        return os.path.join(SERVICE_RUNTIME, viewed)
    if plant is not None:
        plant = _VERSION_OF.get() or plant
    env = os.environ if env is None else env
    uid = os.geteuid() if uid is None else uid
    systemd = env.get("RUNTIME_DIRECTORY", "").split(":")[0]
    if os.path.isabs(systemd):
        return os.path.normpath(systemd)
    name = installed_name(plant) if plant else None
    if name is not None:
        return os.path.join(SERVICE_RUNTIME, name)
    xdg = env.get("XDG_RUNTIME_DIR", "")
    if os.path.isabs(xdg):
        try:
            st = os.lstat(xdg)
        except OSError:
            st = None
        # su keeps the caller's XDG_RUNTIME_DIR: only a directory of this user counts
        if st is not None and stat.S_ISDIR(st.st_mode) and st.st_uid == uid:
            base = os.path.join(os.path.normpath(xdg), "softplc")
            return os.path.join(base, plant_key(plant)) if plant else base
    tmp = env.get("TMPDIR", "")
    base = os.path.join(os.path.normpath(tmp) if os.path.isabs(tmp) else "/tmp",
                        f"softplc-{uid}")
    return os.path.join(base, plant_key(plant)) if plant else base


def managed_by_systemd(directory: str, env: Mapping[str, str] | None = None) -> bool:
    """Whether ``directory`` is a runtime directory systemd makes (mode 0750 there, group
    softplc): the service's ``$RUNTIME_DIRECTORY``, or an installed plant's."""
    env = os.environ if env is None else env
    if os.path.isabs(env.get("RUNTIME_DIRECTORY", "")):
        return True
    return os.path.dirname(os.path.normpath(directory)) == SERVICE_RUNTIME


@contextlib.contextmanager
def service_view(name: str) -> Iterator[None]:
    """Within it, ``${RUNTIME_DIR}`` is /run/softplc/NAME whatever the environment: how
    ``install-service`` reads a plant as its unit will (its warnings name the service's
    paths, not the installer's)."""
    token = _SERVICE_VIEW.set(name)
    try:
        yield
    finally:
        _SERVICE_VIEW.reset(token)


@contextlib.contextmanager
def version_of(plant: str) -> Iterator[None]:
    """Within it, ``${RUNTIME_DIR}`` is the plant file ``plant``'s, whatever file is
    loaded: how a new version of a running plant is read (``softplc diff OLD NEW``, a
    reload), so that the files it names there are the running plant's, wherever the new
    version is kept."""
    token = _VERSION_OF.set(plant)
    try:
        yield
    finally:
        _VERSION_OF.reset(token)


def expand(path: str, loc: Loc, env: Mapping[str, str] | None = None) -> str:
    """``path`` with ``${RUNTIME_DIR}`` replaced (for the plant file ``loc.file``);
    SourceError at ``loc`` for any other ``${...}``."""
    if "${" not in path:
        return path
    rest = path.replace(PLACEHOLDER, "")
    if "${" in rest:
        raise SourceError(loc, f"unknown placeholder in '{path}': the only one is "
                               f"{PLACEHOLDER}")
    return path.replace(PLACEHOLDER, runtime_dir(env, plant=loc.file))


def default_feed(loc: Loc) -> str:
    """The feed socket when no section (``opcua:``, ``mqtt:``, ``web:``) names one:
    ``${RUNTIME_DIR}/feed.sock`` of the plant file ``loc.file``, the plant's own."""
    return expand(f"{PLACEHOLDER}/{FEED_FILE}", loc)


@dataclass(frozen=True, slots=True)
class Whereabouts:
    """Where a plant's controller is, as every process of the plant finds it."""

    #: the plant's name (an installed plant's NAME, else its directory's name)
    name: str
    #: the real path of its plant file
    plant: str
    #: its identity: the real path of its directory (the lock's key, the retained data's
    #: owner)
    home: str
    #: ``${RUNTIME_DIR}`` for this plant
    runtime_dir: str
    #: the lock the controller holds for its life: RUNTIME_DIR/NAME-HASH.lock (HASH: of
    #: ``home``)
    lock: str
    #: the console to reach it by: its first socket, else its first TCP port
    #: ("127.0.0.1:PORT"); None without either
    console: str | None
    #: the feed socket of its side processes; None without a side process section
    #: (``opcua:``, ``mqtt:``, ``web:``)
    feed: str | None


def locate(pdef: PlantDef) -> Whereabouts:
    """Where the controller of ``pdef`` is (``pdef`` loaded by ``load_plant``: its paths are
    already expanded the way the controller's are)."""
    real = os.path.realpath(pdef.path)
    home = plant_home(pdef.path)
    rdir = runtime_dir(plant=pdef.path)
    name = plant_name(pdef.path)
    digest = _digest(home)[:12]
    console = next((c.address for c in pdef.consoles if c.kind == "socket"), None)
    if console is None:
        console = next((c.address for c in pdef.consoles if c.kind == "tcp"), None)
    feed = pdef.feed()
    return Whereabouts(name=name, plant=real, home=home, runtime_dir=rdir,
                       lock=os.path.join(rdir, f"{name}-{digest}.lock"), console=console,
                       feed=feed.path if feed is not None else None)
