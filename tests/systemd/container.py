"""A real systemd, booted as PID 1 of a container of this machine's own root.

The root file system is made writable by an overlay whose upper layer is on tmpfs
(/dev/shm): whatever the journeys install, start or break stays in the container and goes
with it. ``systemd-nspawn --boot`` runs the container's systemd; every command is run in
all its namespaces with ``nsenter``, as root, with a clean environment. The source tree is
bound read-only at /srv/co. The container shares the machine's network (as the recipe of
issue 25 does): an OPC UA server inside listens on the machine's 127.0.0.1.

``Container.close()`` powers the container off (SIGKILL after a minute), unmounts the
overlay and removes its directories; nothing is left running or mounted.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

#: how long a boot may take until ``systemctl is-system-running --wait`` answers, seconds
BOOT_TIMEOUT_S = 180.0
#: how long an orderly power-off may take before the container is killed, seconds
POWEROFF_TIMEOUT_S = 60.0
#: the environment of every command run inside
ENV = ["PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin", "HOME=/root",
       "LANG=C.UTF-8", "SYSTEMD_PAGER=", "SYSTEMD_COLORS=0"]
PREFIX = "softplc-ns-"


class Unavailable(Exception):
    """No container here (not root, no systemd-nspawn, overlay mounts not permitted...):
    the reason, for the test's skip."""


def why_not() -> str | None:
    """Why a container cannot run here, or None."""
    if os.geteuid() != 0:
        return "needs root (overlay mount, systemd-nspawn)"
    if shutil.which("systemd-nspawn") is None:
        return "systemd-nspawn not installed (Debian: systemd-container)"
    if shutil.which("nsenter") is None:
        return "nsenter not installed (util-linux)"
    if not os.path.isdir("/dev/shm"):
        return "no /dev/shm for the overlay's upper layer"
    return None


def reap_stale() -> None:
    """Unmount and remove the overlays of earlier runs whose container is gone (a test
    process killed before its teardown): only this module's, never a running one's."""
    for d in Path("/dev/shm").glob(PREFIX + "*"):
        pid_file = d / "nspawn.pid"
        try:
            pid = int(pid_file.read_text())
            os.kill(pid, 0)
            continue  # still running: another test process's
        except (OSError, ValueError):
            pass
        subprocess.run(["umount", "-l", str(d / "m")], capture_output=True, check=False)
        shutil.rmtree(d, ignore_errors=True)


class Container:
    """One container; ``boot()`` it, ``sh()`` in it, ``reboot()`` it, ``close()`` it."""

    def __init__(self, source: Path, machine: str = "plc", shared: tuple[Path, ...] = ()
                 ) -> None:
        """``source`` is bound read-only at /srv/co; each of ``shared`` read-only at its own
        path (the container's /tmp is its own tmpfs: a host directory there is hidden)."""
        self.source = source
        self.shared = shared
        self.machine = machine
        self.base = Path(tempfile.mkdtemp(prefix=PREFIX, dir="/dev/shm"))
        self.upper, self.work, self.root = (self.base / "u", self.base / "w", self.base / "m")
        for d in (self.upper, self.work, self.root):
            d.mkdir()
        self.mounted = False
        self.nspawn: subprocess.Popen[bytes] | None = None
        self.pid1 = 0
        self.boots = 0
        #: processes started in the container (they end with its boot), reaped at close
        self.children: list[subprocess.Popen[str]] = []

    # -- life --------------------------------------------------------------------------
    def boot(self) -> None:
        """Mount the overlay (once) and boot; Unavailable if it cannot."""
        if not self.mounted:
            r = subprocess.run(["mount", "-t", "overlay", "overlay", "-o",
                                f"lowerdir=/,upperdir={self.upper},workdir={self.work}",
                                str(self.root)], capture_output=True, text=True, check=False)
            if r.returncode != 0:
                raise Unavailable(f"overlay mount not permitted: {r.stderr.strip()}")
            self.mounted = True
        self.boots += 1
        log = open(self.base / f"boot{self.boots}.log", "wb")  # noqa: SIM115
        self.nspawn = subprocess.Popen(
            ["systemd-nspawn", "-q", "--keep-unit", "--register=no",
             f"--machine={self.machine}", f"--bind-ro={self.source}:/srv/co",
             *(f"--bind-ro={p}:{p}" for p in self.shared),
             "-D", str(self.root), "--boot", "--", "systemd.firstboot=no"],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True)
        log.close()
        (self.base / "nspawn.pid").write_text(str(self.nspawn.pid))
        end = time.monotonic() + BOOT_TIMEOUT_S
        while not self.pid1:
            if self.nspawn.poll() is not None:
                raise Unavailable("systemd-nspawn ended at once: "
                                  + (self.base / f"boot{self.boots}.log").read_text()[-500:])
            if time.monotonic() > end:
                raise Unavailable("the container's systemd did not start")
            self.pid1 = self._child_systemd()
            time.sleep(0.1)
        state = ""
        while not state:  # empty until the system bus is up
            r = self.sh("systemctl is-system-running --wait", check=False,
                        timeout=BOOT_TIMEOUT_S)
            state = r.stdout.strip()
            if not state and time.monotonic() > end:
                raise Unavailable(f"the container's systemd does not answer: {r.stderr}")
            time.sleep(0.1)
        if state not in ("running", "degraded"):
            raise Unavailable(f"the container's systemd is {state!r}")

    def _child_systemd(self) -> int:
        assert self.nspawn is not None
        try:
            children = Path(f"/proc/{self.nspawn.pid}/task/{self.nspawn.pid}/children")
            for pid in children.read_text().split():
                if Path(f"/proc/{pid}/comm").read_text().strip() == "systemd":
                    return int(pid)
        except OSError:
            pass
        return 0

    def poweroff(self) -> None:
        """An orderly power-off of the container; SIGKILL if it does not end in time."""
        if self.nspawn is None:
            return
        for child in self.children:  # what the tests started in it, first: the
            with contextlib.suppress(OSError):  # container's shutdown would wait for them
                os.killpg(child.pid, signal.SIGKILL)
        if self.nspawn.poll() is None:
            self.nspawn.send_signal(signal.SIGTERM)  # nspawn --boot: an orderly shutdown
            try:
                self.nspawn.wait(POWEROFF_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                os.killpg(self.nspawn.pid, signal.SIGKILL)
                self.nspawn.wait()
        self.nspawn = None
        self.pid1 = 0
        for child in self.children:
            child.wait()
            for stream in (child.stdout, child.stderr):
                if stream is not None:
                    stream.close()
        self.children.clear()

    def reboot(self) -> None:
        """Power off and boot again on the same disk: /run is empty again, /var and /etc
        are as the container left them."""
        self.poweroff()
        self.boot()

    def close(self) -> None:
        self.poweroff()
        if self.mounted:
            for _ in range(50):
                r = subprocess.run(["umount", str(self.root)], capture_output=True,
                                   check=False)
                if r.returncode == 0:
                    break
                time.sleep(0.1)
            else:
                subprocess.run(["umount", "-l", str(self.root)], capture_output=True,
                               check=False)
            self.mounted = False
        shutil.rmtree(self.base, ignore_errors=True)

    # -- inside --------------------------------------------------------------------------
    def argv(self, *cmd: str) -> list[str]:
        """``cmd`` run inside, in every namespace of the container, clean environment."""
        assert self.pid1, "not booted"
        return ["nsenter", "-t", str(self.pid1), "-a", "--", "env", "-i", *ENV, *cmd]

    def sh(self, script: str, check: bool = True, timeout: float = 120.0
           ) -> subprocess.CompletedProcess[str]:
        """Run ``script`` with /bin/sh inside; CalledProcessError with its output if it
        fails and ``check``."""
        r = subprocess.run(self.argv("/bin/sh", "-c", script), capture_output=True,
                           text=True, timeout=timeout, check=False)
        if check and r.returncode != 0:
            raise AssertionError(f"in the container: {script}\nexit {r.returncode}\n"
                                 f"{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
        return r

    def popen(self, script: str) -> subprocess.Popen[str]:
        """``script`` started inside (its own process group: ``poweroff`` kills it)."""
        child = subprocess.Popen(self.argv("/bin/sh", "-c", script), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.children.append(child)
        return child

    def path(self, inside: str) -> Path:
        """A file of the container, seen from the machine (through the overlay)."""
        return self.root / inside.lstrip("/")

    def wait(self, script: str, timeout: float = 60.0, what: str = "") -> str:
        """Run ``script`` until it succeeds; its output. AssertionError after ``timeout``."""
        end = time.monotonic() + timeout
        while True:
            r = self.sh(script, check=False)
            if r.returncode == 0:
                return r.stdout
            if time.monotonic() > end:
                raise AssertionError(f"timed out waiting for {what or script}: "
                                     f"{r.stdout[-2000:]} {r.stderr[-2000:]}")
            time.sleep(0.3)

    def journal(self, unit: str, since: str = "") -> str:
        args = f" --since '{since}'" if since else ""
        return self.sh(f"journalctl -q -o cat --no-pager -u {unit}{args}").stdout

    def __enter__(self) -> Container:
        return self

    def __exit__(self, *exc: object) -> None:
        with contextlib.suppress(Exception):
            self.close()
