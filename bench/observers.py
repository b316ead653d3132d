"""Benchmark: does the scan pay for who watches it? Not a test: prints a table.

One controller, in this process as in bench/opcua.py (the same Daemon, Scheduler and
generated plant cycle as ``softplc run --sim``, the garbage collector in the scan's idle
time), ``--testers`` drawer testers (default 100) whose drawers move, at ``--cycle``
(default 10 ms), SCHED_FIFO 50 with ``--fifo`` (as the installed unit runs it). The plant
has ``mqtt:``, ``opcua:``, ``web:`` and a console socket, so its feed and its console are
served throughout, as ``softplc run`` serves them. Phases of the same run, the same
daemon and plant, each ``--seconds`` long:

- ``unobserved``: nobody connected;
- ``observed``: all at once: ``softplc mqtt`` (sample 10 ms, every change at a 10 ms
  cycle) publishing to Debian's mosquitto on a loopback port, with a subscriber process
  counting (bench/mqtt.py's); ``softplc opcua`` with ``--opcua-clients`` client processes
  (bench/opcua.py's) holding ``--items`` monitored items in all (split evenly, at 100 ms)
  and the alarm events of the Server object, while alarms come and go (``--alarms`` per
  second, as ``bench.opcua --alarms``); ``softplc web`` with ``--pages`` pages
  (bench/web.py's WebSocket reader: what a browser's page receives, without rendering);
  ``--consoles`` console clients streaming ``trace on`` (bench/console.py's);
- ``unobserved again``: after every observer ended, a control for the machine's load
  having changed meanwhile.

Per phase: the scan's wake-up lateness (p50, p99, max), overruns and how many of them
the controller's process made (the rest the machine made: schedprobe.OverrunProbe, the
kernel's count of the times the scan thread was put on a processor: one that slept
before its deadline, then kept its processor from its first instant on one to its
scan's end, using less than a cycle of it, lost its time to the machine, as did one
that waited for a GIL whose holder could not run; after the table, each phase's
overruns by what made them and the first of each, with their figures), faults, the
ratio of
the phase's p99 to the unobserved one's; a control over the same window: a thread alone
in a process of its own, paced like the scan at the same priority (``tests/console/
schedprobe.py`` ``lone_thread``), its p99, the scan's p99 over it and its wake-ups a
cycle late or more (what the machine, not the controller, did: a lone thread late a
cycle is an overrun no controller could avoid; in brackets those of them put on a
processor more than once in their sleep: 0 for a thread alone, a check of the method
above); the controller process's CPU (all its threads,
and the scan, feed and console threads alone, from /proc/self/task); the feed's frames and
its cost per sample: the feed thread's CPU in ``FeedServer._publish`` per frame and the
scan thread's in ``FeedServer.on_scan`` per snapshot taken, timed with
``time.thread_time_ns`` by wrappers this benchmark installs (the runtime has no such
counter), the feed thread's whole CPU (its turns, I/O and requests too) per snapshot,
and the feed's clients dropped for not reading (``FeedServer.dropped``);
the image's read and write per image written (``ImageWriter.read`` and ``publish``, the
feed thread between two scans), the samples whose image was never written
(``images_missed``) and the images read after a later scan than their sample's
(``images_late``); the host's steal time per processor; the
garbage collections in the scan's idle time (how many, their time, the full ones and the
last one's time, the full ones that waited for idle time enough, every how many young
collections a middle one ran at the window's end: Scheduler.gc_middle_every). With
``--who``, what the controller's other threads were doing at each late wake-up and long
scan of the observed window (``Who``). With
``--profile``, the functions of the feed thread's ``_publish`` in the observed window,
per frame (cProfile on the thread's processor time). With ``--rounds``, each piece of the
feed thread's and the console thread's work in the observed window against the scans'
deadlines, and the pieces running at each of the process's overruns (bench/rounds.py). Per
side process over the observed window: CPU (utime + stime, percent of one core), resident
memory, and what its clients received. The side processes run at nice 10, as their units
run them (``--sides-nice``); clients at nice 10 as in the other benches. With ``--cpu
N`` (and ``--fifo``), the plant says ``plc: realtime: cpu: N``: the controller's threads
on processor N, its side processes on the others (docs/daemon.md); this bench's own
thread, the clients and the control thread are kept off N too, as clients on other
machines would be (the broker, started before, is not). A
missing mosquitto, or a ``softplc opcua`` not serving within ``--start-s``, is said in one
line and that observer left out. A fault between two windows (charts stopped until ack) is
said in one line and acknowledged before the next.

    python -m bench.observers [--seconds 60] [--testers 100] [--cycle 10ms] [--fifo]
                              [--mqtt-sample 10ms] [--opcua-clients 4] [--items 1183]
                              [--alarms 10] [--pages 20] [--consoles 4]
                              [--sides-nice 10] [--client-nice 10] [--start-s 360]
                              [--profile] [--who] [--rounds] [--switch-interval MS]
                              [--cpu N] [--keep]
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import json
import logging
import os
import pstats
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from bench.console import FLOODER, probed_window
from bench.jitter import plant_file, thread_cpu_ns
from bench.mqtt import mqtt_section
from bench.opcua import (
    ROOT,
    START_S,
    AlarmTraffic,
    ack_faults,
    collect_clients,
    counted_s,
    end_process,
    go,
    opcua_section,
    out,
    proc_cpu_s,
    proc_mem_mib,
    start_clients,
    start_daemon,
    stop_clients,
    stop_daemon,
    variable_ids,
    wait_serving,
)
from bench.rounds import Rounds
from bench.web import wait_serving as wait_web
from bench.web import web_section
from runtime.console.server import ConsoleServer
from runtime.console.service import ConsoleService
from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.controller.image import ImageWriter
from tests.console.schedprobe import (
    THREADS_EVERY_NS,
    OtherThreads,
    Overrun,
    OverrunProbe,
    SchedProbe,
    lone_thread,
)

#: the controller's threads whose CPU a row shows apart (name prefix -> column)
THREADS = {"softplc-scan": "scan", "softplc-feed": "feed", "console-": "console"}


def observers_plant(directory: str, testers: int, cycle_ms: int, fifo: bool,
                    broker: str | None, opcua_port: int, web_port: int, clients: int,
                    mqtt_sample: str = "10ms", cpu: int | None = None) -> str:
    """bench/jitter.py's plant with a console socket and the ``mqtt:`` (when ``broker``),
    ``opcua:`` and ``web:`` sections of the benches of each side process; ``cpu``: the
    controller's processor (``plc: realtime: cpu``, with ``fifo``)."""
    path = plant_file(directory, testers, cycle_ms, fifo)
    if cpu is not None:
        with open(path, encoding="utf-8") as f:
            text = f.read()
        assert "realtime: {priority: 50}" in text, "--cpu goes with --fifo"
        with open(path, "w", encoding="utf-8") as f:
            f.write(text.replace("realtime: {priority: 50}",
                                 f"realtime: {{priority: 50, cpu: {cpu}}}", 1))
    with open(path, "a", encoding="utf-8") as f:
        f.write(f"monitor:\n  socket: {{path: {directory}/c.sock, trusted: true}}\n")
        if broker is not None:
            f.write(mqtt_section(directory, broker, mqtt_sample))
        f.write(opcua_section(directory, opcua_port, False, None, clients))
        f.write(web_section(directory, web_port, "100ms"))
    return path


class FeedMeter:
    """CPU the feed costs: ``FeedServer._publish`` (feed thread, per frame) and
    ``FeedServer.on_scan`` (scan thread, per snapshot taken), timed by wrappers installed
    on the instance before it starts (``install``). Without those methods (another
    feed), ``ok`` is False and nothing is timed. With ``profile`` (``--profile``), every
    ``_publish`` of the observed window runs under ``cProfile`` on the feed thread's
    processor time (its overhead shows in that window's figures: a run for the profile,
    not for the times)."""

    def __init__(self, profile: bool = False) -> None:
        self.fs: FeedServer | None = None
        self.ok = False
        self.publish_ns = self.publishes = self.scan_ns = self.captures = 0
        #: ``ImageWriter.read`` and ``publish`` (the feed thread, between two scans):
        #: processor ns, images written
        self.write_ns = self.writes = 0
        # the feed thread's processor time, not the wall clock: its waits for the GIL
        # (the scan, the console) are not its work
        self.profiler = cProfile.Profile(time.thread_time) if profile else None
        #: ``_publish`` runs under the profiler (set for the observed window)
        self.profiling = False
        self.profiled = 0

    def install(self, fs: FeedServer | None) -> None:
        self.fs = fs
        if fs is None:
            return
        publish = getattr(fs, "_publish", None)
        on_scan = getattr(fs, "on_scan", None)
        if publish is None or on_scan is None or not hasattr(fs, "_slot"):
            return
        self.ok = True

        def timed_publish(*args: Any) -> Any:
            t0 = time.thread_time_ns()
            try:
                if self.profiling and self.profiler is not None:
                    self.profiled += 1
                    return self.profiler.runcall(publish, *args)
                return publish(*args)
            finally:
                self.publish_ns += time.thread_time_ns() - t0
                self.publishes += 1

        def timed_scan(n: int) -> None:
            slot = fs._slot
            t0 = time.thread_time_ns()
            on_scan(n)
            self.scan_ns += time.thread_time_ns() - t0
            if fs._slot is not slot:
                self.captures += 1

        setattr(fs, "_publish", timed_publish)  # noqa: B010 - a method replaced on the instance
        setattr(fs, "on_scan", timed_scan)  # noqa: B010
        read, publish_image = ImageWriter.read, ImageWriter.publish

        def timed_read(writer: ImageWriter) -> Any:
            t0 = time.thread_time_ns()
            got = read(writer)
            self.write_ns += time.thread_time_ns() - t0
            return got

        def timed_publish_image(writer: ImageWriter, got: Any, scan: int, wall_ns: int
                                ) -> None:
            t0 = time.thread_time_ns()
            publish_image(writer, got, scan, wall_ns)
            self.write_ns += time.thread_time_ns() - t0
            self.writes += 1
        # the class's: the writer is made when the feed starts (and again at a reload)
        setattr(ImageWriter, "read", timed_read)  # noqa: B010
        setattr(ImageWriter, "publish", timed_publish_image)  # noqa: B010

    def report(self, top: int = 25) -> None:
        """The profile of the observed window: the functions of most own time, per frame."""
        if self.profiler is None or not self.profiled:
            return
        stats = pstats.Stats(self.profiler)
        rows = sorted(stats.stats.items(),  # type: ignore[attr-defined]
                      key=lambda kv: -kv[1][2])[:top]
        out(f"\nfeed thread, _publish profiled over {self.profiled} frames (cProfile, the "
            "thread's processor time, its overhead included), per frame:")
        out("| function | calls/frame | own us/frame | cumulative us/frame |")
        out("|---|---|---|---|")
        for (file, line, fn), (_cc, nc, tt, ct, _callers) in rows:
            where = f"{os.path.relpath(file, ROOT)}:{line}" if file != "~" else ""
            out(f"| {fn} {where} | {nc / self.profiled:.1f} | "
                f"{1e6 * tt / self.profiled:.1f} | {1e6 * ct / self.profiled:.1f} |")

    def reading(self) -> tuple[int, int, int, int, int, int, int, int, int, int]:
        frames = getattr(self.fs, "frames", -1)
        dropped = getattr(self.fs, "dropped", -1)
        return (frames, self.publish_ns, self.publishes, self.scan_ns, self.captures,
                dropped, self.write_ns, self.writes, getattr(self.fs, "images_missed", -1),
                getattr(self.fs, "images_late", -1))


class Who:
    """With ``--who``, in the observed window: at each wake-up of the scan later than
    ``late_ns`` and at the end of each scan that took longer than ``long_ns``, the
    innermost frames of the controller's other threads (``sys._current_frames``): which
    thread was running Python when the scan was due or while it ran (the GIL's holder
    shows mid-work; a thread waiting shows in its wait). At a late wake-up also the
    thread that used the most processor time while the scan thread slept and waited
    (each thread's CPU clock read at the sleep's start and at the wake-up:
    schedprobe.OtherThreads, about 1 µs a thread; the threads listed again every
    second), its time and its frames then: the GIL's holder, and where it let the GIL
    go (a frame's line is the call it made last). A diagnostic: its own cost (the
    clocks read each cycle, a frame walk per event) shows in that window's figures.
    (Until 30 November 2026 it read each thread's /proc schedstat, a file opened and
    read per thread per cycle, with the GIL released, whose figure for a running thread
    is up to a tick stale: too costly at 1 ms, and wrong for the busiest thread.)"""

    DEPTH = 3

    def __init__(self, late_ns: int, long_ns: int) -> None:
        self.late_ns, self.long_ns = late_ns, long_ns
        self.on = False
        self.late: dict[tuple[str, str], int] = {}
        self.long: dict[tuple[str, str], int] = {}
        self.events = {"late": 0, "long": 0}
        #: per late wake-up: (lateness, the busiest thread, its processor time, frames)
        self.busiest: list[tuple[int, str, int, str]] = []

    def _frames(self) -> dict[int, str]:
        got = {}
        for tid, frame in sys._current_frames().items():
            where: list[str] = []
            f: Any = frame
            while f is not None and len(where) < self.DEPTH:
                code = f.f_code
                where.append(f"{os.path.basename(code.co_filename)}:{f.f_lineno}:"
                             f"{code.co_name}")
                f = f.f_back
            got[tid] = " < ".join(where)
        return got

    def _sample(self, into: dict[tuple[str, str], int], kind: str) -> dict[int, str]:
        self.events[kind] += 1
        me = threading.get_ident()
        names = {t.ident: t.name for t in threading.enumerate()}
        frames = self._frames()
        for tid, where in frames.items():
            if tid == me:
                continue
            key = (names.get(tid, "?"), where)
            into[key] = into.get(key, 0) + 1
        return frames

    def install(self, d: Daemon) -> None:
        sched = d.scheduler
        sleep_until, body, mono = sched.sleep_until, sched.body, time.monotonic_ns
        others = OtherThreads()

        def sampled_sleep(deadline: int) -> None:
            if not self.on:
                sleep_until(deadline)
                return
            if mono() >= others.listed + THREADS_EVERY_NS:
                others.list(mono())
            others.read(0)
            sleep_until(deadline)
            if mono() - deadline > self.late_ns:
                others.read(1)
                late = mono() - deadline
                frames = self._sample(self.late, "late")
                ran = others.each()
                if ran:
                    top = max(ran, key=lambda t: ran[t])
                    by_native = {t.native_id: t for t in threading.enumerate()}
                    th = by_native.get(top)
                    self.busiest.append((late, th.name if th else f"tid {top}", ran[top],
                                         frames.get(th.ident, "-") if th and th.ident
                                         else "-"))

        def sampled_body(wake: int) -> Any:
            try:
                return body(wake)
            finally:
                if self.on and mono() - wake > self.long_ns:
                    self._sample(self.long, "long")
        sched.sleep_until = sampled_sleep
        sched.body = sampled_body

    def report(self, top: int = 20) -> None:
        for kind, seen, what in (("late", self.late, f"wake-ups later than "
                                  f"{self.late_ns / 1e3:.0f} us"),
                                 ("long", self.long, f"scans longer than "
                                  f"{self.long_ns / 1e3:.0f} us")):
            out(f"\n{self.events[kind]} {what} in the observed window; the other threads "
                "then (count, thread, innermost frames):")
            for (name, where), n in sorted(seen.items(), key=lambda kv: -kv[1])[:top]:
                out(f"    {n:6d} {name}: {where}")
        out("\nat each late wake-up, the thread that ran the most while the scan thread "
            "slept and waited (late us, thread, its processor time us, its frames then):")
        for late, name, ran, where in sorted(self.busiest, reverse=True)[:top]:
            out(f"    {late / 1e3:8.0f} {name}: {ran / 1e3:.0f}: {where}")


def steal_ms() -> list[int]:
    """Per processor, the time the host of this virtual machine ran something else while
    this guest wanted to run, ms since boot (/proc/stat ``steal``, USER_HZ ticks); empty
    where the kernel does not say."""
    hz = os.sysconf("SC_CLK_TCK")
    out = []
    try:
        with open("/proc/stat", encoding="ascii") as f:
            for line in f:
                parts = line.split()
                if parts and parts[0].startswith("cpu") and parts[0] != "cpu" \
                        and len(parts) > 8:
                    out.append(int(parts[8]) * 1000 // hz)
    except OSError:
        return []
    return out


def threads_cpu_ns() -> dict[str, int]:
    """CPU of this process's threads by column of THREADS (summed per column), ns."""
    got = dict.fromkeys(THREADS.values(), 0)
    for t in threading.enumerate():
        for prefix, col in THREADS.items():
            if t.name.startswith(prefix) and t.native_id is not None:
                try:
                    got[col] += thread_cpu_ns(t.native_id)
                except OSError:
                    pass  # ended meanwhile
    return got


def cpu_s(procs: list[subprocess.Popen[Any]]) -> float:
    """utime + stime of ``procs`` together, s (those ended not counted)."""
    total = 0.0
    for p in procs:
        try:
            total += proc_cpu_s(p.pid)
        except OSError:
            pass
    return total


def rss_mib(procs: list[subprocess.Popen[Any]]) -> float:
    total = 0.0
    for p in procs:
        try:
            total += proc_mem_mib(p.pid)[0]
        except OSError:
            pass
    return total


def measure(daemon: Daemon, probe: SchedProbe, meter: FeedMeter, seconds: float,
            sides: dict[str, list[subprocess.Popen[Any]]], cycle_ms: float,
            priority: int, overruns: OverrunProbe, who: Who | None = None
            ) -> dict[str, Any]:
    """One phase: ``probed_window``'s scan figures (no statistics reset: the feed counts
    scans), the controller's CPU and the feed's, and the CPU of each group of side
    processes (``sides``: label -> processes). Over the same window, a control: a thread
    alone in a process of its own, paced like the scan (``cycle_ms``, SCHED_FIFO
    ``priority`` if not 0), which nothing of the controller's process can hold: what
    the machine (its other processes, the virtual machine's host) does to a scan's
    wake-ups in that phase (``lone_p99``...). Each overrun, and whether the machine or
    the process made it (``overruns``: schedprobe.OverrunProbe). ``who``, if given, stops
    sampling as the window ends (the figures computed after it are the bench's)."""
    side0 = {k: cpu_s(v) for k, v in sides.items()}
    th0, feed0, p0, t0 = threads_cpu_ns(), meter.reading(), time.process_time(), \
        time.monotonic()
    steal0 = steal_ms()
    st = daemon.scan_stats
    gc0 = (st.gc_runs, st.gc_ns, st.gc_full_runs, st.gc_full_deferred)

    def ended() -> list[Overrun]:
        if who is not None:
            who.on = False
        return overruns.stop()
    with lone_thread(cycle_ms, priority) as lone:
        overruns.start()
        w = probed_window(daemon, probe, seconds, int(cycle_ms * 1e6), ended)
        w["overrun_list"] = w.pop("on_end")
    w["overruns_ours"] = sum(1 for o in w["overrun_list"]
                             if not o.machines(overruns.cycle_ns))
    runs, gc_ns, fulls, waited = (b - a for a, b in zip(
        gc0, (st.gc_runs, st.gc_ns, st.gc_full_runs, st.gc_full_deferred), strict=True))
    w["gc"] = (f"{runs}, {gc_ns / 1e6:.1f} ms; full {fulls}"
               + (f" (last {st.gc_full_last / 1e6:.1f} ms)" if fulls else "")
               + f", waited {waited}; middle every {daemon.scheduler.gc_middle_every}")
    w["steal"] = [b - a for a, b in zip(steal0, steal_ms(), strict=False)]
    w["lone_p99"], w["lone_max"] = lone[0].late_p99, lone[0].late_max
    w["lone_blocked_p99"] = lone[0].blocked_p99
    w["lone_missed"] = lone[0].missed  # its wake-ups a cycle late or more
    w["lone_rescheduled"] = lone[0].rescheduled  # of those, put on a processor twice
    th1, feed1, p1 = threads_cpu_ns(), meter.reading(), time.process_time()
    wall = time.monotonic() - t0
    w["cpu"] = 100 * (p1 - p0) / wall
    w["threads"] = {k: 100 * (th1[k] - th0[k]) / 1e9 / wall for k in th0}
    w["feed_ns"] = th1["feed"] - th0["feed"]
    frames, pub_ns, pubs, scan_ns, caps, dropped, write_ns, writes, missed, late = (
        b - a for a, b in zip(feed0, feed1, strict=True))
    w["images_missed"] = missed if feed1[8] >= 0 else None
    w["images_late"] = late if feed1[9] >= 0 else None
    w["frames"] = frames if feed1[0] >= 0 else None
    w["dropped"] = dropped if feed1[5] >= 0 else None
    w["publish_us"] = pub_ns / pubs / 1e3 if meter.ok and pubs else None
    # the feed thread's whole CPU (its turns, I/O, requests too) per sample taken
    w["feed_us"] = w["feed_ns"] / caps / 1e3 if meter.ok and caps else None
    w["capture_us"] = scan_ns / caps / 1e3 if meter.ok and caps else None
    w["write_us"] = write_ns / writes / 1e3 if meter.ok and writes else None
    w["sides"] = {k: (100 * (cpu_s(v) - side0[k]) / wall, rss_mib(v))
                  for k, v in sides.items()}
    return w


def overrun_kind(o: Overrun, cycle_ns: int) -> str:
    """What made an overrun, in a few words (schedprobe.Overrun's fields)."""
    if o.machines(cycle_ns):
        return "the machine"
    if not o.slept:
        return "the process: idle work past the deadline"
    if o.ran >= cycle_ns:
        return "the process: a cycle of processor time"
    if o.scan_slices > 0:
        return "the process: the scan lost its processor"
    return "the process: the GIL's holder ran"


def overrun_table(rows: list[tuple[str, dict[str, Any]]], cycle_ns: int,
                  per_kind: int = 4) -> None:
    """Each phase's overruns by what made them, and the first ``per_kind`` of each kind
    in each phase, µs (schedprobe.Overrun)."""
    out("\noverruns by what made them (late: the wake-up after its deadline; other threads "
        "ran: the process's other threads' processor time from the sleep's start to the "
        "wake-up; slices: the times the scan thread was put on a processor in its sleep, "
        "in its scan; idle work: from the scan before to the sleep; the machine's: it "
        "slept before its deadline, used less than a cycle of processor time, kept its "
        "processor through the scan, and either kept it from its first instant on one or "
        "waited for a GIL whose holder ran less than half of that wait: "
        "schedprobe.Overrun):")
    seen = []  # the first ``per_kind`` of each kind in each phase, in their order
    for label, r in rows:
        kinds: dict[str, int] = {}
        for o in r["overrun_list"]:
            k = overrun_kind(o, cycle_ns)
            kinds[k] = kinds.get(k, 0) + 1
            if kinds[k] <= per_kind:
                seen.append((label, o, k))
        out(f"- {label}: {len(r['overrun_list'])}"
            + "".join(f"; {k} {n}" for k, n in sorted(kinds.items(), key=lambda kv: -kv[1])))
    if not seen:
        return
    out("\n| phase | late us | scan us | ran us | runq us | other threads ran us | slept | "
        "slices | idle work us: time, ran, slices | whose |")
    out("|---|---|---|---|---|---|---|---|---|---|")
    for label, o, kind in seen:
        out(f"| {label} | {o.late / 1e3:.0f} | {o.scan / 1e3:.0f} | {o.ran / 1e3:.0f} | "
            f"{o.runq / 1e3:.0f} | {o.others_ran / 1e3:.0f} | "
            f"{'yes' if o.slept else 'no'} | {o.sleep_slices}, "
            f"{o.scan_slices} | {o.idle / 1e3:.0f}, {o.idle_ran / 1e3:.0f}, "
            f"{o.idle_slices} | {kind} |")


def node_files(tmp: str, ids: list[str], items: int, clients: int) -> list[tuple[str, int]]:
    """``items`` node ids split evenly over ``clients`` files, taken in turn from ``ids``
    (round again when the plant has fewer variables): [(file, items in it)]."""
    files = []
    k = 0
    for c in range(clients):
        n = items // clients + (1 if c < items % clients else 0)
        mine = [ids[(k + j) % len(ids)] for j in range(n)]
        k += n
        path = os.path.join(tmp, f"nodes{c + 1}.json")
        with open(path, "w", encoding="utf-8") as f:
            json.dump(mine, f)
        files.append((path, n))
    return files


def side(cmd: list[str], tmp: str, name: str) -> subprocess.Popen[bytes]:
    """A side process (``softplc opcua``...) in ROOT, its stderr in ``tmp/NAME.log``
    (kept with --keep)."""
    with open(os.path.join(tmp, f"{name}.log"), "wb") as err:
        return subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)


def fmt(x: float | None, spec: str = ".0f") -> str:
    return "-" if x is None else format(x, spec)


def table(rows: list[tuple[str, dict[str, Any]]]) -> None:
    base = rows[0][1]["p99"]
    out("| phase | cycles | overruns | of them the process's | faults | lateness p50 us | "
        "p99 us | max us | p99 / unobserved p99 | lone thread p99 us | p99 / lone p99 | "
        "wake-ups a cycle late | "
        "lone wake-ups a cycle late (rescheduled) | "
        "runq p99 us | "
        "blocked p99 us | lone blocked p99 us | controller CPU | scan thread | "
        "feed thread | console thread | feed frames | feed clients dropped | "
        "_publish us/frame | feed thread us/sample | on_scan us/snapshot | "
        "image read + write us (feed thread) | images missed, late | "
        "steal ms per cpu | collections (idle time) |")
    out("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
        "---|---|---|---|---|---|---|---|")
    for label, r in rows:
        th = r["threads"]
        out(f"| {label} | {r['cycles']} | {r['overruns']} | {r['overruns_ours']} | "
            f"{r['faults']} | {r['p50']:.0f} | "
            f"{r['p99']:.0f} | {r['max']:.0f} | {r['p99'] / base:.2f} | {r['lone_p99']:.0f} | "
            f"{r['p99'] / max(r['lone_p99'], 1.0):.2f} | {r['missed']} | "
            f"{r['lone_missed']} ({r['lone_rescheduled']}) | "
            f"{r['runq_p99']:.0f} | "
            f"{r['blocked_p99']:.0f} | {r['lone_blocked_p99']:.0f} | {r['cpu']:.1f} % | "
            f"{th['scan']:.1f} % | {th['feed']:.1f} % | {th['console']:.1f} % | "
            f"{fmt(r['frames'], 'd')} | {fmt(r['dropped'], 'd')} | "
            f"{fmt(r['publish_us'], '.1f')} | {fmt(r['feed_us'], '.1f')} | "
            f"{fmt(r['capture_us'], '.1f')} | {fmt(r['write_us'], '.1f')} | "
            f"{fmt(r['images_missed'], 'd')}, {fmt(r['images_late'], 'd')} | "
            f"{' '.join(str(x) for x in r['steal']) or '-'} | {r['gc']} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each phase (60)")
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--cycle", default="10ms", help="the plant's cycle, whole ms (10ms)")
    ap.add_argument("--fifo", action="store_true",
                    help="the scan at SCHED_FIFO 50 (plc: realtime: needs root)")
    ap.add_argument("--mqtt-sample", default="10ms",
                    help="mqtt: sample (10ms). The feed's frames come at the smallest "
                         "sample of the plant's sections, to every side process")
    ap.add_argument("--opcua-clients", type=int, default=4)
    ap.add_argument("--items", type=int, default=1183,
                    help="monitored items of all OPC UA clients together (1183)")
    ap.add_argument("--alarms", type=float, default=10.0,
                    help="alarms raised (cleared 0.5 s later) per second while observed")
    ap.add_argument("--pages", type=int, default=20)
    ap.add_argument("--consoles", type=int, default=4, help="console clients streaming "
                    "'trace on' (4)")
    ap.add_argument("--sides-nice", type=int, default=10, metavar="N",
                    help="nice level of softplc opcua, mqtt and web (10, as their units run "
                         "them: Nice=10; before 2026-11-30 opcua and web ran at 0 here)")
    ap.add_argument("--client-nice", type=int, default=10, metavar="N",
                    help="nice level of the OPC UA client processes (10, as bench.opcua; 0 "
                         "when a loaded machine starves them until they time out)")
    ap.add_argument("--start-s", type=float, default=2 * START_S, metavar="S",
                    help="how long softplc opcua may take to serve (360 s: its 3900 nodes "
                         "of 100 testers at nice 10 on a loaded machine)")
    ap.add_argument("--profile", action="store_true",
                    help="profile the feed thread's _publish in the observed window "
                         "(cProfile; its overhead inflates that window's times)")
    ap.add_argument("--who", action="store_true",
                    help="in the observed window, what the controller's other threads were "
                         "doing at each late wake-up of the scan (over a third of the "
                         "cycle) and each long scan (over half of it): Who")
    ap.add_argument("--rounds", action="store_true",
                    help="in the observed window, each piece of the feed thread's and the "
                         "console thread's work timed (wall and processor time) against "
                         "the scans' deadlines, and the pieces running at each of the "
                         "process's overruns: bench/rounds.py")
    ap.add_argument("--switch-interval", type=float, metavar="MS",
                    help="set the GIL switch interval once the controller started (it "
                         "sets a tenth of the cycle, 0.5 ms at most)")
    ap.add_argument("--cpu", type=int, metavar="N",
                    help="the controller's processor (plc: realtime: cpu N, with --fifo): "
                         "its threads there, its side processes on the others; this "
                         "bench's own thread and what it starts (the clients, the control "
                         "thread) on the others too, as if on other machines")
    ap.add_argument("--keep", action="store_true",
                    help="keep the temporary directory (plant, client logs) and say where")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    # the feed's warnings: a side process dropped for not reading is why its clients
    # get nothing
    logging.getLogger("runtime.controller.feed").setLevel(logging.WARNING)
    try:
        cycle_ms = int(args.cycle.removesuffix("ms"))
        prio = 50 if args.fifo else 0  # the control's, as the scan's
    except ValueError:
        ap.error(f"--cycle {args.cycle}: whole milliseconds, e.g. 10ms")

    def ended(signum: int, frame: Any) -> None:
        raise SystemExit(128 + signum)  # the finally below ends every child

    signal.signal(signal.SIGTERM, ended)
    signal.signal(signal.SIGHUP, ended)
    from tests.mqtt.kit import MOSQUITTO, Broker
    from tests.opcua.kit import free_port

    tmp = tempfile.mkdtemp(prefix="bv", dir="/tmp")
    broker: Broker | None = None
    daemon: Daemon | None = None
    fs: FeedServer | None = None
    console: ConsoleServer | None = None
    traffic: AlarmTraffic | None = None
    sides: dict[str, list[subprocess.Popen[Any]]] = {}
    clients: list[subprocess.Popen[str]] = []
    try:
        if os.access(MOSQUITTO, os.X_OK):
            broker = Broker(Path(tmp)).start()
        else:
            out(f"({MOSQUITTO} missing (apt-get install mosquitto): no MQTT observer)")
        opcua_port, web_port = free_port(), free_port()
        path = observers_plant(tmp, args.testers, cycle_ms, args.fifo,
                               broker.url if broker else None, opcua_port, web_port,
                               args.opcua_clients, args.mqtt_sample, args.cpu)
        meter, probe = FeedMeter(args.profile), SchedProbe()
        overruns = OverrunProbe(cycle_ms * 1_000_000)

        who = Who(cycle_ms * 1_000_000 // 3, cycle_ms * 1_000_000 // 2) if args.who else None

        services: list[ConsoleService] = []

        def setup(d: Daemon, f: FeedServer | None) -> None:
            overruns.install(d.scheduler)  # innermost: the sleep and the scan alone
            if who is not None:
                who.install(d)  # inside the probe: the probe times the sleep alone
            d.scheduler.sleep_until = probe.wrap(d.scheduler.sleep_until)
            meter.install(f)
            # the console's names before the controller starts, as ``softplc run``
            # builds them (the start-up freeze of the collector keeps them out of it)
            pdef = d.pdef
            services.append(ConsoleService(d, pdef.pin_hash,
                                           pdef.release_forces_on_disconnect))

        daemon, fs = start_daemon(path, args.testers, True, setup=setup)
        if args.switch_interval is not None:
            sys.setswitchinterval(args.switch_interval / 1e3)
        console = ConsoleServer(services[0], daemon.pdef.consoles)
        rounds = Rounds() if args.rounds else None
        if rounds is not None:
            if fs is not None:
                rounds.install(fs, "feed", fs.window)
            rounds.install(console, "console", console.window)
        console.start()
        if args.cpu is not None:
            # the daemon pinned this whole process (plc: realtime: cpu); this thread
            # is the bench's, not the controller's: it and what it starts go elsewhere
            os.sched_setaffinity(0, set(range(os.cpu_count() or 1)) - {args.cpu})
        sock = os.path.join(tmp, "c.sock")
        out(f"{args.testers} drawer testers, cycle {cycle_ms} ms, {args.seconds:g} s per "
            f"phase, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}, scan "
            f"{'SCHED_FIFO 50' if args.fifo else 'SCHED_OTHER'}, GIL switch interval "
            f"{sys.getswitchinterval() * 1e3:g} ms")
        faults0 = len(daemon.faults)
        rows = [("unobserved", measure(daemon, probe, meter, args.seconds, {}, cycle_ms,
                                       prio, overruns))]

        faults0 = ack_faults(daemon, faults0, "in the unobserved window")
        # the observers: the OPC UA server and its clients first (the slowest to start)
        t0 = time.monotonic()
        server = side(["nice", "-n", str(args.sides_nice), sys.executable, "-m", "runtime.cli",
                       "opcua", path], tmp, "opcua")
        sides["softplc opcua"] = [server]
        url = f"opc.tcp://127.0.0.1:{opcua_port}"
        # the MQTT subscriber counts a little past the window (the OPC UA clients until
        # told to stop once the last alarm is cleared, and DRAIN_S more: bench.opcua)
        count_s = args.seconds + 2
        ids: list[str] = []
        files: list[tuple[str, int]] = []
        try:
            asyncio.run(wait_serving(url, None, t0 + args.start_s))
        except TimeoutError:
            out(f"(softplc opcua not serving after {args.start_s:g} s on this machine: no "
                "OPC UA observer in this run; its log: opcua.log with --keep)")
            end_process(server, 30)
            del sides["softplc opcua"]
        else:
            ids = asyncio.run(variable_ids(url, None))
            files = node_files(tmp, ids, args.items, args.opcua_clients)
            sides["OPC UA clients"] = clients  # filled as they subscribe
            start_clients(url, [f for f, _ in files], args.seconds, None, tmp, t0, clients,
                          args.client_nice)
        sub: subprocess.Popen[str] | None = None
        if broker is not None:
            edge = side(["nice", "-n", str(args.sides_nice), sys.executable, "-m",
                         "runtime.cli", "mqtt", path], tmp, "mqtt")
            sides["softplc mqtt"] = [edge]
            sub = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "bench.mqtt",
                                    "--count", json.dumps([broker.bind, broker.port,
                                                           count_s])],
                                   cwd=ROOT, text=True, stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE)
            sides["MQTT subscriber"] = [sub]
            assert sub.stdout is not None
            if sub.stdout.readline().strip() != "ready":
                raise RuntimeError("the MQTT subscriber did not connect")
            assert broker.proc is not None
            sides["mosquitto"] = [broker.proc]
        web = side(["nice", "-n", str(args.sides_nice), sys.executable, "-m", "runtime.cli",
                    "web", path], tmp, "web")
        sides["softplc web"] = [web]
        web_url = f"http://127.0.0.1:{web_port}/"
        wait_web(web_url, time.monotonic() + START_S)
        time.sleep(3.0)  # the MQTT births, the edge node settled
        # the pages and the console streams run 2 s before the window and 2 s after it
        reader_s = args.seconds + 4
        result = os.path.join(tmp, "pages.json")
        reader = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "bench.web",
                                   "--reader", json.dumps({"url": web_url,
                                                           "pages": args.pages,
                                                           "seconds": reader_s,
                                                           "result": result})], cwd=ROOT)
        sides[f"{args.pages} web pages"] = [reader]
        tracers: list[subprocess.Popen[str]] = []
        sides[f"{args.consoles} console traces"] = tracers
        for _ in range(args.consoles):
            tracers.append(subprocess.Popen([sys.executable, FLOODER, "trace", sock,
                                             str(reader_s)], stdout=subprocess.PIPE,
                                            text=True))
        time.sleep(2.0)  # the pages have their whole frame, the traces stream
        faults0 = ack_faults(daemon, faults0, "while the observers started")
        if args.alarms > 0:
            traffic = AlarmTraffic(daemon, args.testers, args.alarms)
            traffic.thread.start()
        go(clients)
        if sub is not None:
            assert sub.stdin is not None
            sub.stdin.write("go\n")
            sub.stdin.flush()
        meter.profiling = True
        if who is not None:
            who.on = True
        if rounds is not None:
            rounds.on = True
        rows.append(("observed", measure(daemon, probe, meter, args.seconds, sides,
                                         cycle_ms, prio, overruns, who)))
        meter.profiling = False
        if rounds is not None:
            rounds.on = False
        observed_sides = rows[-1][1]["sides"]
        raised = 0
        if traffic is not None:
            traffic.stop.set()
            traffic.thread.join(10)
            raised, traffic = traffic.raised, None
        stop_clients(clients)  # after the last alarm cleared: they count DRAIN_S more
        got = collect_clients(clients)
        mqtt_got = json.loads(sub.communicate(timeout=60)[0]) if sub is not None else None
        reader.wait(reader_s + 60)
        with open(result, encoding="utf-8") as f:
            pages = json.load(f)
        traced = [json.loads(t.communicate(timeout=60)[0]) for t in tracers]
        for group in sides.values():
            for p in group:
                if p.poll() is None and p is not (broker.proc if broker else None):
                    end_process(p, 30)
        ack_faults(daemon, faults0, "in the observed window or while the observers ended")
        rows.append(("unobserved again", measure(daemon, probe, meter, args.seconds, {},
                                                 cycle_ms, prio, overruns)))

        table(rows)
        overrun_table(rows, overruns.cycle_ns)
        meter.report()
        if who is not None:
            who.report()
        if rounds is not None:
            rounds.report(rows[1][1]["overrun_list"],
                          lambda o: not o.machines(overruns.cycle_ns))
        obs = rows[1][1]
        ratio = obs["p99"] / rows[0][1]["p99"]
        out(f"\nobserved p99 / unobserved p99 = {ratio:.2f} (goal <= 1.2: "
            f"{'met' if ratio <= 1.2 else 'NOT met'}), overruns observed {obs['overruns']}"
            f" (goal 0: {'met' if obs['overruns'] == 0 else 'NOT met'}), of them the "
            f"process's {obs['overruns_ours']} (0 of the process's: "
            f"{'met' if obs['overruns_ours'] == 0 else 'NOT met'}; the rest the machine's)")
        base = rows[0][1]
        beyond = (obs["p99"] / max(obs["lone_p99"], 1.0)) / (
            base["p99"] / max(base["lone_p99"], 1.0))
        out(f"the same ratio with each phase's p99 over its lone thread's (what the machine "
            f"did to a thread no controller holds): {beyond:.2f}; the lone thread's observed "
            f"p99 / unobserved p99 = {obs['lone_p99'] / max(base['lone_p99'], 1.0):.2f}\n")
        per = ", ".join(str(n) for _, n in files[:len(clients)]) or "-"
        notif_s = sum(g.get("notifications", 0) for g in got) / counted_s(got, count_s)
        notes = {
            "softplc opcua": f"{len(ids)} variables" if ids else "skipped: not serving",
            "OPC UA clients":
                f"{len(clients)} of {args.opcua_clients} subscribed, "
                f"{sum(n for _, n in files[:len(clients)])} monitored items ({per} per "
                f"client), {notif_s:.0f} "
                f"notifications/s; alarms raised {raised} (each cleared 0.5 s later), "
                "alarm events received per client "
                + ", ".join(str(g.get("events", "-")) for g in got)
                + f"; of them SFCError's (the raised ones: {2 * raised} each) "
                + ", ".join(str(g.get("sfcerror", "-")) for g in got),
            "softplc mqtt": f"sample {args.mqtt_sample}",
            "MQTT subscriber": (f"{mqtt_got['messages'] / count_s:.0f} messages/s, "
                                f"{mqtt_got['bytes'] / count_s / 1024:.0f} KiB/s"
                                if mqtt_got else ""),
            "softplc web": "sample 100 ms",
            f"{args.pages} web pages": (f"{pages['messages'] / reader_s:.0f} messages/s, "
                                        f"{pages['bytes'] / reader_s / 1024:.0f} KiB/s "
                                        "(all pages)"),
            f"{args.consoles} console traces":
                f"{sum(t['trace_lines'] for t in traced) / reader_s:.0f} trace lines/s "
                "(all)",
        }
        if broker is None:
            notes["softplc mqtt"] = "skipped: mosquitto missing"
        out("| side process (observed window) | CPU, % of one core | RSS MiB | received |")
        out("|---|---|---|---|")
        for label in notes:
            if label in observed_sides:
                cpu, rss = observed_sides[label]
                out(f"| {label} | {cpu:.1f} % | {rss:.0f} | {notes[label]} |")
            else:
                out(f"| {label} | - | - | {notes[label]} |")
    finally:
        if traffic is not None:
            traffic.stop.set()
            traffic.thread.join(10)
        for group in sides.values():
            for p in group:
                if broker is None or p is not broker.proc:
                    end_process(p, 30)
        if console is not None:
            console.stop()
        if daemon is not None:
            stop_daemon(daemon, fs)
        if broker is not None:
            broker.kill()
        if args.keep:
            out(f"(kept {tmp})")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
