"""Files of an installed controller: the plant (with its PIN hash) and its charts are
readable by the service and by nobody else, the service writes only its state directory.
The staged tree is checked with real uids (setpriv) as systemd would run the service."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.controller.install import STATE_DIR_MODE, ServiceIds, apply, plan, unit_text

ROOT = Path(__file__).resolve().parents[2]
SOFTPLC = str(Path(sys.executable).parent / "softplc")
#: numeric ids no account uses here: the service user and an ordinary local user
SERVICE = ServiceIds(uid=64123, gid=64123)
OTHER = 64124
#: the snippets run under the system Python: the venv's may live below /root (0700)
PYTHON = "/usr/bin/python3"
as_root = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None or not os.path.exists(PYTHON),
    reason="needs root, setpriv (util-linux) and /usr/bin/python3 to switch uids")


def plant_with_pin(tmp: Path) -> Path:
    """configs/pi_mcp23017 with a PIN hash, as a site would install it."""
    text = (ROOT / "configs" / "pi_mcp23017" / "plant.yaml").read_text(encoding="utf-8")
    text = text.replace("../drawer_tester/", str(ROOT / "configs" / "drawer_tester") + "/")
    text += "monitor:\n  tcp: {port: 5020}\n  pin_hash: 'scrypt$16$1$1$00$00'\n"
    src = tmp / "site.yaml"
    src.write_text(text, encoding="utf-8")
    return src


@pytest.fixture
def staged() -> Iterator[Path]:
    """A staging root that other uids may traverse (pytest's tmp_path is 0700 root)."""
    d = Path(tempfile.mkdtemp(prefix="softplc-stage-"))
    d.chmod(0o755)
    try:
        yield d
    finally:
        shutil.rmtree(d)


def mode(p: Path) -> int:
    return stat.S_IMODE(os.lstat(p).st_mode)


def test_the_pin_hash_is_not_world_readable(staged: Path) -> None:
    """Attack: any local user read plant.yaml (0644) and searched the PIN offline."""
    r = str(staged / "r")
    apply(plan(str(plant_with_pin(staged)), SOFTPLC, name="site", root=r), root=r)
    etc = staged / "r" / "etc" / "softplc" / "site"
    assert mode(etc / "plant.yaml") == 0o640
    assert mode(etc / "drawer_tester.yaml") == 0o640
    assert mode(etc) == 0o750 and mode(etc.parent) == 0o750
    assert mode(staged / "r" / "etc" / "systemd" / "system" / "softplc@.service") == 0o644
    assert mode(staged / "r" / "var" / "lib" / "softplc") == 0o750
    assert not list(etc.glob(".*"))  # no temporary file left behind


def test_a_reinstall_narrows_an_old_world_readable_tree(staged: Path) -> None:
    src = plant_with_pin(staged)
    etc = staged / "r" / "etc" / "softplc" / "site"
    etc.mkdir(parents=True, mode=0o755)
    (etc / "plant.yaml").write_bytes(plan(str(src), SOFTPLC, name="site").files[
        "/etc/softplc/site/plant.yaml"].data or b"")
    (etc / "plant.yaml").chmod(0o644)  # what an older install-service wrote
    (etc / "plant.yaml").write_text((etc / "plant.yaml").read_text() + "# tuned\n")
    apply(plan(str(src), SOFTPLC, name="site", root=str(staged / "r")), root=str(staged / "r"),
          force=True)
    assert mode(etc) == 0o750 and mode(etc / "plant.yaml") == 0o640
    (backup,) = etc.glob("plant.yaml.bak-*")
    assert mode(backup) == 0o640 and backup.read_text().endswith("# tuned\n")


def test_ownership_is_printed_when_staging(staged: Path) -> None:
    r = str(staged / "r")
    done = apply(plan(str(plant_with_pin(staged)), SOFTPLC, name="site", root=r), root=r)
    text = "\n".join(done)
    assert f"wrote {staged}/r/etc/softplc/site/plant.yaml (0640, would chown root:softplc)" \
        in text
    assert f"{staged}/r/var/lib/softplc (0750, would chown softplc:softplc)" in text
    assert os.lstat(staged / "r" / "etc" / "softplc" / "site" / "plant.yaml").st_uid == \
        os.geteuid()


def run_as(uid: int, gid: int, code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["setpriv", f"--reuid={uid}", f"--regid={gid}", "--clear-groups",
                           PYTHON, "-c", code], capture_output=True, text=True, timeout=60)


PROBE = """
import os
def can(what, fn):
    try:
        fn()
        print(what, "yes")
    except OSError as e:
        print(what, "no", e.errno)
etc, state, run = %r, %r, %r
can("read plant", lambda: open(os.path.join(etc, "plant.yaml")).read())
can("read chart", lambda: open(os.path.join(etc, "drawer_tester.yaml")).read())
can("write plant", lambda: open(os.path.join(etc, "plant.yaml"), "a").close())
can("create in etc", lambda: open(os.path.join(etc, "new.yaml"), "w").close())
can("create in state", lambda: open(os.path.join(state, "retain.json"), "w").close())
can("create in run", lambda: open(os.path.join(run, "console.sock"), "w").close())
can("create in /etc", lambda: open(os.path.join(etc, "..", "..", "softplc.conf"), "w").close())
"""


def probe(uid: int, gid: int, root: Path) -> dict[str, bool]:
    code = PROBE % (str(root / "etc" / "softplc" / "site"),
                    str(root / "var" / "lib" / "softplc"), str(root / "run" / "softplc" / "site"))
    r = run_as(uid, gid, code)
    assert r.returncode == 0, r.stderr
    answers: dict[str, bool] = {}
    for line in r.stdout.splitlines():  # "WHAT yes" or "WHAT no ERRNO"
        words = line.split()
        if words[-1] == "yes":
            answers[" ".join(words[:-1])] = True
        else:
            answers[" ".join(words[:-2])] = False
    return answers


def systemd_prepares(unit: str, root: Path, ids: ServiceIds) -> None:
    """What systemd does to the *Directory= of the unit at start (systemd.exec(5)): creates
    each below its base, chowns it to User=/Group= except ConfigurationDirectory=, and
    sets its *DirectoryMode= (default 0755)."""
    settings = dict(line.split("=", 1) for line in unit.splitlines()
                    if "=" in line and not line.startswith("#"))
    for kind, base in (("Configuration", "etc"), ("State", "var/lib"), ("Runtime", "run")):
        name = settings.get(f"{kind}Directory", "").replace("%i", "site")
        if not name:
            continue
        d = root / base / name
        d.mkdir(parents=True, exist_ok=True)
        if kind != "Configuration":
            os.chown(d, ids.uid, ids.gid)
        d.chmod(int(settings.get(f"{kind}DirectoryMode", "0755"), 8))


@as_root
def test_the_service_reads_its_plant_and_writes_only_its_state(staged: Path) -> None:
    r = staged / "r"
    apply(plan(str(plant_with_pin(staged)), SOFTPLC, name="site", root=str(r)), root=str(r),
          ids=SERVICE)
    unit = (r / "etc" / "systemd" / "system" / "softplc@.service").read_text()
    systemd_prepares(unit, r, SERVICE)
    service = probe(SERVICE.uid, SERVICE.gid, r)
    assert service == {"read plant": True, "read chart": True, "write plant": False,
                       "create in etc": False, "create in state": True,
                       "create in run": True, "create in /etc": False}, service
    other = probe(OTHER, OTHER, r)
    assert other == {"read plant": False, "read chart": False, "write plant": False,
                     "create in etc": False, "create in state": False,
                     "create in run": False, "create in /etc": False}, other
    etc = r / "etc" / "softplc" / "site"
    assert (os.lstat(etc).st_uid, os.lstat(etc).st_gid) == (0, SERVICE.gid)
    assert (os.lstat(etc.parent).st_uid, os.lstat(etc.parent).st_gid) == (0, SERVICE.gid)
    assert (os.lstat(etc / "plant.yaml").st_uid, os.lstat(etc / "plant.yaml").st_gid) == \
        (0, SERVICE.gid)


@as_root
def test_the_service_user_loads_the_installed_plant(staged: Path) -> None:
    """The real loader, run as the service's uid, reads the plant and its charts."""
    r = staged / "r"
    apply(plan(str(plant_with_pin(staged)), SOFTPLC, name="site", root=str(r)), root=str(r),
          ids=SERVICE)
    plant = r / "etc" / "softplc" / "site" / "plant.yaml"
    code = (f"import sys; sys.path.insert(0, {str(ROOT)!r})\n"
            "from runtime.language.plantfile import load_plant\n"
            f"p = load_plant({str(plant)!r}); print(sorted(p.instances), p.pin_hash)")
    try:
        ok = run_as(SERVICE.uid, SERVICE.gid, code)
    except subprocess.TimeoutExpired:
        pytest.fail("the loader hung")
    if "No module named 'yaml'" in ok.stderr:
        pytest.skip("the system Python has no PyYAML")
    assert ok.returncode == 0, ok.stderr
    assert "['tester1'] scrypt$16$1$1$00$00" in ok.stdout
    denied = run_as(OTHER, OTHER, code)
    assert denied.returncode != 0 and "Permission denied" in denied.stderr


@pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                    reason="systemd-analyze not installed (Debian: systemd)")
def test_unit_directories_match_systemd_exec(tmp_path: Path) -> None:
    """systemd chowns StateDirectory= and RuntimeDirectory= to the service but never
    ConfigurationDirectory=: a ConfigurationDirectoryMode=0750 on a root-owned /etc/softplc
    locks the service out of its plant. The unit leaves /etc/softplc to install-service."""
    unit = unit_text(SOFTPLC)
    lines = unit.splitlines()
    assert not any(line.startswith("ConfigurationDirectory") for line in lines), unit
    for line in ("StateDirectory=softplc", f"StateDirectoryMode={STATE_DIR_MODE:04o}",
                 "RuntimeDirectory=softplc/%i", "RuntimeDirectoryMode=0750", "UMask=0077"):
        assert line in lines, line
    path = tmp_path / "softplc@demo.service"
    path.write_text(unit, encoding="utf-8")
    r = subprocess.run(["systemd-analyze", "verify", str(path)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and r.stderr.strip() == "", r.stderr
