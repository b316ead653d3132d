"""Where a controller started by hand puts its socket and retained data: ``${RUNTIME_DIR}``,
a directory of the user's own (0700, checked), never a /tmp path another user can take first.
The attacks are played by a second uid (root in these tests chowns for it)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.controller.paths import PathError, check_dir, ensure_private_dir, prepare
from runtime.errors import Loc, SourceError
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import (
    expand,
    installed_name,
    locate,
    plant_key,
    plant_name,
    runtime_dir,
)

ROOT = Path(__file__).resolve().parents[1]
SOFTPLC = str(Path(sys.executable).parent / "softplc")
ATTACKER = 64124
as_root = pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another uid")
LOC = Loc("plant.yaml", 3, 11)


@pytest.fixture
def tmp() -> Iterator[Path]:
    """A stand-in for /tmp: world-writable with the sticky bit, owned by root."""
    d = Path(tempfile.mkdtemp(prefix="softplc-tmp-"))
    d.chmod(0o1777)
    try:
        yield d
    finally:
        shutil.rmtree(d)


def mode(p: Path) -> int:
    return stat.S_IMODE(os.lstat(p).st_mode)


def test_runtime_dir_is_systemds_then_the_sessions_then_a_private_tmp_one(tmp: Path) -> None:
    uid = os.geteuid()
    mine = tmp / "xdg"
    mine.mkdir(mode=0o700)
    assert runtime_dir({"RUNTIME_DIRECTORY": "/run/softplc", "XDG_RUNTIME_DIR": str(mine)},
                       uid) == "/run/softplc"
    assert runtime_dir({"XDG_RUNTIME_DIR": str(mine)}, uid) == f"{mine}/softplc"
    assert runtime_dir({}, uid) == f"/tmp/softplc-{uid}"
    assert runtime_dir({"TMPDIR": str(tmp)}, uid) == f"{tmp}/softplc-{uid}"
    # su keeps the caller's XDG_RUNTIME_DIR: a directory of another uid is not ours
    assert runtime_dir({"XDG_RUNTIME_DIR": str(mine), "TMPDIR": str(tmp)}, uid + 1) == \
        f"{tmp}/softplc-{uid + 1}"
    assert runtime_dir({"XDG_RUNTIME_DIR": "relative", "TMPDIR": "also"}, 7) == \
        "/tmp/softplc-7"


def test_an_installed_plant_has_its_runtime_dir_whoever_reads_it(tmp: Path) -> None:
    """/etc/softplc/NAME/plant.yaml is the plant NAME: every process that reads it, under
    its unit ($RUNTIME_DIRECTORY) or by hand, looks in /run/softplc/NAME."""
    uid = os.geteuid()
    installed = "/etc/softplc/press1/plant.yaml"
    assert runtime_dir({"TMPDIR": str(tmp)}, uid, plant=installed) == "/run/softplc/press1"
    assert runtime_dir({"RUNTIME_DIRECTORY": "/run/softplc/press1"}, uid,
                       plant=installed) == "/run/softplc/press1"
    assert expand("${RUNTIME_DIR}/console.sock", Loc(installed, 9, 3), {}) == \
        "/run/softplc/press1/console.sock"
    assert installed_name(installed) == "press1" and plant_name(installed) == "press1"
    # anything else is a plant run by hand, named by its directory
    assert installed_name("/etc/softplc/press1/other.yaml") is None
    assert installed_name("/etc/softplc/plant.yaml") is None
    assert plant_name(str(ROOT / "configs" / "drawer_tester" / "plant_sim.yaml")) == \
        "drawer_tester"
    # a plant run by hand has a directory of its own below the user's: NAME-HASH
    assert runtime_dir({"TMPDIR": str(tmp)}, uid, plant="/srv/press1/plant.yaml") == \
        f"{tmp}/softplc-{uid}/{plant_key('/srv/press1/plant.yaml')}"
    assert re.fullmatch(r"press1-[0-9a-f]{8}", plant_key("/srv/press1/plant.yaml"))


def test_locate_is_where_every_process_of_a_plant_finds_the_controller(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RUNTIME_DIRECTORY", str(tmp_path / "run"))
    d = tmp_path / "press"
    d.mkdir()
    (d / "drawer_tester.yaml").write_bytes(
        (ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml").read_bytes())
    plant = d / "plant.yaml"
    plant.write_text((ROOT / "configs" / "drawer_tester" / "plant_sim.yaml").read_text(
        encoding="utf-8") + "opcua: {endpoint: 'opc.tcp://127.0.0.1:4850'}\n",
        encoding="utf-8")
    where = locate(load_plant(str(plant)))
    assert (where.name, where.plant, where.home) == ("press", str(plant), str(d))
    assert where.runtime_dir == str(tmp_path / "run")
    assert where.console == str(tmp_path / "run" / "drawer.sock")
    assert where.feed == str(tmp_path / "run" / "feed.sock")  # beside the console
    assert re.fullmatch(re.escape(str(tmp_path / "run" / "press-")) + r"[0-9a-f]{12}\.lock",
                        where.lock)
    # another plant file of the same directory is the same plant: the same lock
    (d / "other.yaml").write_bytes(plant.read_bytes())
    assert locate(load_plant(str(d / "other.yaml"))).lock == where.lock


def test_expand_knows_one_placeholder() -> None:
    env = {"RUNTIME_DIRECTORY": "/run/softplc"}
    assert expand("${RUNTIME_DIR}/drawer.sock", LOC, env) == "/run/softplc/drawer.sock"
    assert expand("/var/lib/softplc/x.json", LOC, env) == "/var/lib/softplc/x.json"
    with pytest.raises(SourceError, match=r"plant.yaml:3:11: error: unknown placeholder in "
                                          r"'\$\{RUNTIME_DIRECTORY\}/x.sock'"):
        expand("${RUNTIME_DIRECTORY}/x.sock", LOC, env)


def test_the_example_plants_keep_their_files_in_the_runtime_dir(
        monkeypatch: pytest.MonkeyPatch, tmp: Path) -> None:
    """Attack: /tmp/softplc, named by the examples, pre-created by another user."""
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp))
    rdir = f"{tmp}/softplc-{os.geteuid()}"
    plants = sorted(ROOT.glob("configs/*/plant_sim.yaml"))
    assert plants
    for plant in plants:
        text = plant.read_text(encoding="utf-8")
        pdef = load_plant(str(plant))
        files = ([pdef.retain_path] if pdef.retain_path else []) + \
            [c.address for c in pdef.consoles if c.kind == "socket"]
        for f in files:
            assert f.startswith(rdir + "/"), (plant, f)
        assert "/tmp/softplc/" not in text, plant
    demo = load_plant(str(ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"))
    assert [c.address for c in demo.consoles] == [f"{rdir}/{plant_key(demo.path)}/drawer.sock"]


def test_the_runtime_dir_is_created_private(tmp: Path) -> None:
    d = tmp / f"softplc-{os.geteuid()}"
    ensure_private_dir(str(d))
    assert d.is_dir() and mode(d) == 0o700 and d.stat().st_uid == os.geteuid()
    ensure_private_dir(str(d))  # and used again as it is
    d.chmod(0o755)
    with pytest.raises(PathError, match=rf"^{d} has mode 0755, open to other users: "
                                        rf"chmod 700 {d}$"):
        ensure_private_dir(str(d))


@as_root
def test_a_runtime_dir_taken_by_another_user_is_refused(tmp: Path) -> None:
    theirs = tmp / "softplc-0"
    theirs.mkdir(mode=0o777)
    os.chown(theirs, ATTACKER, ATTACKER)
    with pytest.raises(PathError, match=f"belongs to uid {ATTACKER}, not to you"):
        ensure_private_dir(str(theirs))
    theirs.rmdir()
    evil = tmp / "evil"
    evil.mkdir()
    os.chown(evil, ATTACKER, ATTACKER)
    theirs.symlink_to(evil)
    os.lchown(theirs, ATTACKER, ATTACKER)
    with pytest.raises(PathError, match="is a symbolic link"):
        ensure_private_dir(str(theirs))
    assert list(evil.iterdir()) == []


@as_root
def test_files_in_a_directory_others_control_are_refused(tmp: Path) -> None:
    theirs = tmp / "softplc"
    theirs.mkdir(mode=0o755)
    os.chown(theirs, ATTACKER, ATTACKER)
    with pytest.raises(PathError, match=rf"belongs to uid {ATTACKER}, not to you \(uid 0\) "
                                        r"or root: put d.sock in a directory of yours, e\.g\. "
                                        r"\$\{RUNTIME_DIR\}/d\.sock"):
        check_dir(str(theirs), str(theirs / "d.sock"))
    with pytest.raises(PathError, match="writable by every user"):
        check_dir(str(tmp), str(tmp / "d.sock"))
    with pytest.raises(PathError, match="would be created in .*, writable by every user"):
        check_dir(str(tmp / "not-yet"), str(tmp / "not-yet" / "d.sock"))
    link = tmp / "link"
    link.symlink_to("/var/lib")
    os.lchown(link, ATTACKER, ATTACKER)
    with pytest.raises(PathError, match="is a symbolic link of uid"):
        check_dir(str(link), str(link / "r.json"))
    check_dir("/var/lib", "/var/lib/softplc/r.json")  # root's directories are fine


def test_prepare_makes_the_runtime_dir_for_the_plants_files(
        monkeypatch: pytest.MonkeyPatch, tmp: Path) -> None:
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp))
    rdir = tmp / f"softplc-{os.geteuid()}"
    prepare([f"{rdir}/drawer.sock", f"{rdir}/sub/r.json"])
    assert mode(rdir) == 0o700


def run_plant(plant: Path, tmp: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("RUNTIME_DIRECTORY", "XDG_RUNTIME_DIR")}
    env["TMPDIR"] = str(tmp)
    return subprocess.run([SOFTPLC, "run", str(plant), "--sim", "--for", "0.3s"],
                          capture_output=True, text=True, timeout=60, env=env)


def demo_plant(tmp: Path, socket_path: str, retain: str) -> Path:
    text = (ROOT / "configs" / "drawer_tester" / "plant_sim.yaml").read_text(encoding="utf-8")
    out = []
    for line in text.splitlines():
        if line.strip().startswith("retain:"):
            line = f"  retain: {retain}"
        elif line.strip().startswith("socket:"):
            line = f"  socket: {{path: '{socket_path}', trusted: true}}"
        out.append(line.replace("grafcet: ", f"grafcet: {ROOT}/configs/drawer_tester/"))
    plant = tmp / "plant.yaml"
    plant.write_text("\n".join(out) + "\n", encoding="utf-8")
    return plant


@as_root
def test_run_refuses_a_socket_dir_planted_by_another_user(tmp: Path) -> None:
    """Attack: another user makes /tmp/softplc a link to a directory of theirs; the
    controller put its console socket and retained data there."""
    evil = tmp / "evil"
    evil.mkdir()
    os.chown(evil, ATTACKER, ATTACKER)
    planted = tmp / "softplc"
    planted.symlink_to(evil)
    os.lchown(planted, ATTACKER, ATTACKER)
    plant = demo_plant(tmp, f"{planted}/drawer.sock", f"{planted}/r.json")
    r = run_plant(plant, tmp)
    assert list(evil.iterdir()) == [], r.stderr
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[-1] == (f"softplc run: error: {planted}/r.json: {planted} is a symbolic "
                         f"link of uid {ATTACKER}: put r.json in a directory of yours, e.g. "
                         "${RUNTIME_DIR}/r.json"), r.stderr


def test_run_uses_the_private_runtime_dir(tmp: Path) -> None:
    plant = demo_plant(tmp, "${RUNTIME_DIR}/drawer.sock", "${RUNTIME_DIR}/r.json")
    r = run_plant(plant, tmp)
    rdir = tmp / f"softplc-{os.geteuid()}" / plant_key(str(plant))
    assert r.returncode == 0, r.stderr
    assert f"console listening on {rdir}/drawer.sock" in r.stderr
    assert mode(rdir) == 0o700 and (rdir / "r.json").exists()
    assert mode(rdir.parent) == 0o700


def demo_env(tmp: Path) -> tuple[Path, dict[str, str]]:
    """scripts/run-demo.sh as shipped in a tree of ``tmp``, its venv set-up replaced by the
    existing .venv; the environment to run it in (runtime directory below ``tmp``, the page
    on any free port)."""
    tree = tmp / "tree"
    (tree / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "run-demo.sh", tree / "scripts" / "run-demo.sh")
    (tree / "scripts" / "setup.sh").write_text("#!/bin/sh\nexit 0\n")
    (tree / "scripts" / "setup.sh").chmod(0o755)
    (tree / "configs").symlink_to(ROOT / "configs")
    (tree / ".venv").symlink_to(Path(sys.executable).parent.parent)
    env = {k: v for k, v in os.environ.items()
           if k not in ("RUNTIME_DIRECTORY", "XDG_RUNTIME_DIR")}
    env["TMPDIR"] = str(tmp)
    env["WEB_LISTEN"] = "127.0.0.1:0"  # any free port (the demo's is 8080)
    return tree, env


def test_the_demo_script_prints_the_socket_it_opens(tmp: Path) -> None:
    """scripts/run-demo.sh as shipped, its venv set-up replaced by the existing .venv."""
    tree, env = demo_env(tmp)
    r = subprocess.run([str(tree / "scripts" / "run-demo.sh"), "--for", "4s"],
                       capture_output=True, text=True, timeout=120, env=env)
    key = plant_key(str(tree / "configs" / "drawer_tester" / "plant_sim.yaml"))
    sock = f"{tmp}/softplc-{os.geteuid()}/{key}/drawer.sock"
    assert r.returncode == 0, r.stderr
    assert f"run-demo: console on {sock}; in a second terminal: .venv/bin/softplc monitor " \
           f"{sock}\n" in r.stderr
    assert f"console listening on {sock} (trusted)" in r.stderr
    # softplc web beside it: it said where its page is, followed the feed, and stopped
    at = re.search(r"web: the page of \S+ is at (http://127\.0\.0\.1:\d+/)", r.stderr)
    assert at, r.stderr
    assert f"run-demo: the live page on {at.group(1)} " in r.stderr
    assert "connected to the controller's feed" in r.stderr


def two_plants(tmp: Path) -> tuple[Path, Path]:
    """Two plants in two directories naming the same files in ``${RUNTIME_DIR}`` (their
    console, their retained data) and the default feed (a web: section without feed:)."""
    out = []
    for name in ("press", "tank"):
        d = tmp / name
        d.mkdir()
        (d / "runner.yaml").write_bytes(
            (ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml").read_bytes())
        plant = d / "plant.yaml"
        plant.write_text(
            (ROOT / "configs" / "drawer_tester" / "plant_sim.yaml").read_text(encoding="utf-8")
            .replace("drawer_tester.yaml", "runner.yaml"), encoding="utf-8")
        out.append(plant)
    return out[0], out[1]


def test_two_plants_never_share_a_path_by_default(monkeypatch: pytest.MonkeyPatch,
                                                   tmp: Path) -> None:
    """Issue: two plants started in the same runtime directory both had its feed.sock, and
    the same ``${RUNTIME_DIR}/drawer.sock`` and retain file when their files named them
    alike (two clones of the project: the second demo was refused on the first's retained
    data). ``${RUNTIME_DIR}`` of a plant run by hand is the plant's own directory, named
    as its lock is (NAME-HASH), so nothing a plant names there, nor its default feed, is
    another plant's."""
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp / "xdg"))
    (tmp / "xdg").mkdir(mode=0o700)
    a, b = two_plants(tmp)
    wa, wb = locate(load_plant(str(a))), locate(load_plant(str(b)))
    pa, pb = load_plant(str(a)), load_plant(str(b))
    assert wa.runtime_dir != wb.runtime_dir
    for where, p, name in ((wa, pa, "press"), (wb, pb, "tank")):
        assert re.fullmatch(re.escape(f"{tmp}/xdg/softplc/{name}-") + "[0-9a-f]{8}",
                            where.runtime_dir), where.runtime_dir
        assert where.console == f"{where.runtime_dir}/drawer.sock"
        assert where.feed == f"{where.runtime_dir}/feed.sock"
        assert p.retain_path == f"{where.runtime_dir}/drawer_tester_sim.retain.json"
        assert os.path.dirname(where.lock) == where.runtime_dir
    # the plant files of one directory are versions of one plant: one directory
    (tmp / "press" / "other.yaml").write_bytes(a.read_bytes())
    assert locate(load_plant(str(tmp / "press" / "other.yaml"))).runtime_dir == wa.runtime_dir


def test_a_per_plant_runtime_dir_is_made_private_with_its_parent(
        monkeypatch: pytest.MonkeyPatch, tmp: Path) -> None:
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp))
    a, _ = two_plants(tmp)
    where = locate(load_plant(str(a)))
    assert os.path.dirname(where.runtime_dir) == f"{tmp}/softplc-{os.geteuid()}"
    prepare([where.lock, f"{where.runtime_dir}/drawer.sock"], where.runtime_dir)
    assert mode(Path(where.runtime_dir)) == 0o700
    assert mode(Path(where.runtime_dir).parent) == 0o700


def demo_tree(where: Path) -> Path:
    """A clone of the project for scripts/run-demo.sh: the script, the demo's plant (a
    copy: a clone's own files), the existing .venv for its set-up."""
    (where / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "run-demo.sh", where / "scripts" / "run-demo.sh")
    (where / "scripts" / "setup.sh").write_text("#!/bin/sh\nexit 0\n")
    (where / "scripts" / "setup.sh").chmod(0o755)
    shutil.copytree(ROOT / "configs" / "drawer_tester", where / "configs" / "drawer_tester")
    (where / ".venv").symlink_to(Path(sys.executable).parent.parent)
    return where / "scripts" / "run-demo.sh"


def test_the_demos_of_two_clones_run_side_by_side(tmp: Path) -> None:
    """Issue: the second clone's demo was refused on the first's retained data (the same
    ``${RUNTIME_DIR}/drawer_tester_sim.retain.json``), and its console socket, feed and
    page port were the first's too. Each runs beside the other, on files of its own."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("RUNTIME_DIRECTORY", "XDG_RUNTIME_DIR", "WEB_LISTEN")}
    env["TMPDIR"] = str(tmp)
    first = subprocess.Popen([str(demo_tree(tmp / "clone-a")), "--for", "60s"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             env=env, start_new_session=True)
    seen: list[str] = []
    try:
        assert first.stderr is not None
        end = time.monotonic() + 60
        while not any("connected to the controller's feed" in x for x in seen):
            line = first.stderr.readline()
            assert line and time.monotonic() < end, seen
            seen.append(line)
        second = subprocess.run([str(demo_tree(tmp / "clone-b")), "--for", "3s"],
                                capture_output=True, text=True, timeout=120, env=env)
        assert first.poll() is None, "the first demo stopped"
    finally:
        os.killpg(first.pid, signal.SIGINT)  # Ctrl-C, as a person stops it
        _, rest = first.communicate(timeout=60)
    seen += rest.splitlines(keepends=True)
    assert second.returncode == 0, second.stderr
    assert "error" not in second.stderr.lower(), second.stderr
    assert not any("error" in x.lower() for x in seen), "".join(seen)
    socks = [re.search(r"console listening on (\S+)", text) for text in
             ("".join(seen), second.stderr)]
    feeds = [re.search(r"connected to the controller's feed (\S+)", text) for text in
             ("".join(seen), second.stderr)]
    pages = [re.search(r"web: the page of \S+ is at (\S+)", text) for text in
             ("".join(seen), second.stderr)]
    for found in (socks, feeds, pages):
        assert found[0] and found[1], (seen, second.stderr)
        assert found[0].group(1) != found[1].group(1)


def test_the_demo_script_says_the_page_s_address_once_it_listens(tmp: Path) -> None:
    """A browser opened at the address run-demo.sh prints gets the page: the address is
    printed once ``softplc web`` listens, the port it listens on (it was printed before
    softplc web started: the port of --listen, 0 here, a browser opened at once refused)."""
    import urllib.request

    env = {k: v for k, v in os.environ.items()
           if k not in ("RUNTIME_DIRECTORY", "XDG_RUNTIME_DIR", "WEB_LISTEN")}
    env["TMPDIR"] = str(tmp)
    p = subprocess.Popen([str(demo_tree(tmp / "clone")), "--for", "20s"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    seen: list[str] = []
    try:
        assert p.stderr is not None
        for line in p.stderr:
            seen.append(line)
            m = re.match(r"run-demo: the live page on (\S+) ", line)
            if m:
                with urllib.request.urlopen(m.group(1), timeout=10) as page:  # noqa: S310
                    assert page.status == 200 and b"softplc" in page.read()
                break
        else:
            raise AssertionError("".join(seen))
    finally:
        p.terminate()
        p.wait(timeout=60)
