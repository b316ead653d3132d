"""The feed: snapshots of the process image for the processes beside the controller (the OPC
UA server, ``softplc opcua``; the MQTT edge node, ``softplc mqtt``), over a local socket,
without costing the scan its cycle.

Controller side (``FeedServer``): every ``sample`` ns the scan thread, at the end of a
cycle, packs the image into the shared image file (runtime/controller/image.py,
``ImageWriter``: one C call per sample, nothing per name), and stores the controller's
state of that scan in a one-slot mailbox, with a copy of the image (``Catalogue.capture``)
only while a client takes frames, and a copy of one followed instance's state when its
transitions are to be explained. The side processes map the file and compute every name
in their own process (``FeedClient``). The feed thread takes the mailbox and sends inside
the console's scan window (``ScanWindow``): to each client the schema once, the status
when it changed (built and encoded once per change, the same bytes to every client: per
sample only a key is compared; docs/architecture.md says what a sample costs), and, to
a client that does not read the image
(it did not say ``{"image": true}``: a debugging tool, a side process that could not map
the file), one JSON line per snapshot with the values that changed (the names read from
the copy only then).
A client whose unsent output passes OUT_MAX (it stopped reading) is dropped: the scan and
the other clients never wait for it. Writes come back on the same socket (``set``): only
names of the ``writable:`` list of the side process that asks (``opcua:``, ``mqtt:``),
with values in range (``value_problem``), applied between two scans as the console's
``set`` is (``Daemon.submit``), each answered ok or error. The feed thread never waits for
the scan: a write is handed to the scan thread and answered at a later turn (the writes
of a client taken in one turn are applied in one call, at the same scan boundary). Work
per client per turn is bounded (fairness): at most LINES_PER_TURN requests taken, at most
PENDING_MAX writes waiting for the scan; a client that sends more waits (its socket is not
read meanwhile), so one client pipelining thousands of writes delays nobody's frames.

Client side (``FeedState``): the schema and the values of the last frame, decoded.

Messages, one JSON object per line (``"\\n"``):

- server -> client ``{"schema": {...}}`` first, and again after an online change replaced
  the plant (the client rebuilds what it shows; the next frame is a whole one): ``name``
  and ``home``, whose feed it is (the plant's name and identity, as its lock and retained
  data record them: runtime/language/runtimedir.py ``locate``; a side process of another
  plant refuses it, runtime/controller/feedclient.py), ``plant`` (the file), ``names``
  ([name, type, role] in value order), ``instances``, ``drivers``, ``writable`` (side
  process -> names), ``cycle_ms``, ``sample_ms``, ``image`` (the shared image: path,
  version, generation, token, size, the offsets and struct formats of its regions:
  ``ImageWriter.describe``; null when the controller could make none) and ``specs`` (per
  name, in value order, how to compute it from the image: ``Signal.spec``, plain data);
- ``{"f": [scan, wall_s, values]}``: a whole frame (first after the schema), values in
  schema order; ``{"d": [scan, wall_s, [i, v, i, v, ...]]}``: only the values that changed
  since the previous frame. ``scan`` is the trace's ``cycle`` number; times are in ns;
- ``{"c": {...}}``: the controller's status (state, fault, overruns, skipped, freezes,
  uptime_s, cycle_ms, drivers: name -> [health, fault reason, ok], lateness_us: p50, p99,
  max, alarms: the alarm board's conditions, ``AlarmBoard.as_list``, forced: the forced
  names), before the frame it goes with, only when it changed (the scan count is the
  frame's scan + 1); a client of the image that has not taken what it was sent (its
  event loop busy) gets the latest one once it has, not each one meanwhile (so are the
  transitions, ``w``): states, not events, never piled up until it is dropped;
- ``{"a": [version, {...}]}``: one change of an alarm's state (raised, cleared,
  acknowledged, confirmed: the alarm board's journal, ``AlarmBoard.changes``; the alarm
  as ``Alarm.as_dict``), to every client that has had a status since it connected (or
  since the last schema), each change its own line, in order, never coalesced (a client
  behind gets them all, before the latest status; one so far behind that OUT_MAX fills is
  dropped: on reconnection the status gives the whole board, a state); the lines of a
  turn come before the status of that turn, whose alarms are the board as those lines
  end it;
- ``{"w": {INSTANCE: [[step, T ns, [[transition index, condition, [blocked...],
  [[term, depth, value]...]]...]]...]}}``: what ``why INSTANCE`` says (the console's),
  computed by the feed thread on a copy of the instance's state taken with the frame,
  for the instances the client follows, before the frame it goes with, only when it
  changed, each at most every WHY_EVERY_NS (100 ms: explaining is Python work per
  transition in the controller's process), one instance a sample at most, in turn;
- ``{"r": [id, ok, text, code]}``: the answer to a request, ``code`` an OPC UA status name
  (Good, BadInvalidArgument, BadInvalidState, BadTimeout, BadConditionBranchAlreadyAcked,
  ...);
- client -> server ``{"image": true}``: this client reads the values from the shared
  image: no more ``f``/``d`` frames for it (status, transitions and answers still come);
- client -> server ``{"why": [INSTANCE, ...]}``: follow those instances' transitions
  (at most MAX_WHY; ``[]`` stops);
- client -> server ``{"set": [id, name, value, side]}`` (value in the name's type; times in
  ns; ``side`` is the asking section, ``opcua`` or ``mqtt``: ``opcua`` when left out);
  ``{"call": [id, target, method, who]}``: a method of an instance (``METHODS``:
  Acknowledge, Reset, Pause, Resume; refused while no chart runs: ``charts_stopped``) or
  of ``controller`` (Ack), applied between two scans and logged with ``who`` (the OPC UA
  server lets only writers call them);
  ``{"alarm": [id, key, "ack" | "confirm", who, comment]}``: acknowledge or confirm an
  alarm of the board (runtime/controller/alarms.py).
"""

from __future__ import annotations

import json
import logging
import math
import os
import selectors
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from drivers.durations import format_ns
from runtime.compiler.program import Memory
from runtime.controller.alarms import JOURNAL_MAX, AlarmRefused
from runtime.controller.image import ImageWriter, image_path, refuse_foreign
from runtime.controller.paths import remove_socket, unix_listener
from runtime.controller.window import ScanWindow
from runtime.engine.commands import CommandRefused
from runtime.engine.instance import coerce, explain
from runtime.engine.names import Catalogue, Image
from runtime.language import ast as A
from runtime.language.feedconf import SIDE_NAMES
from runtime.language.flagtexts import sfcerror_cause
from runtime.language.model import FeedDef
from runtime.language.runtimedir import locate
from runtime.language.yamlsrc import INT_MAX, INT_MIN, TIME_MAX_NS

if TYPE_CHECKING:
    from runtime.controller.daemon import Daemon, ScanCall
    from runtime.engine.plant import Plant

log = logging.getLogger(__name__)

#: the feed thread waits this long between two looks at the scan thread still busy after
#: a scan (the idle work: requests, the listeners) before it reads the image, seconds
IMAGE_POLL_S = 0.0002

#: unsent bytes a client may have before it is dropped (it stopped reading)
OUT_MAX = 1 << 20
#: bytes of client input waiting to be handled before the client is dropped
IN_MAX = 65536
#: bytes read from a client at a time
READ_CHUNK = 4096
#: connections served at once
MAX_CLIENTS = 8
#: the controller's lateness percentiles are refreshed this often, ns
STATS_EVERY_NS = 1_000_000_000
#: how long the feed thread waits for I/O when there is nothing to do, seconds
POLL_S = 0.05
#: instances whose transitions one client may follow (``{"why": [...]}``)
MAX_WHY = 8
#: the transitions clients follow are explained at most this often, ns (a person reads
#: them; each explanation is Python work per transition in the controller's process, and
#: needs a copy of the state taken by the scan thread)
WHY_EVERY_NS = 100_000_000
#: a write not applied by the scan thread in this long is answered with an error, seconds
SET_TIMEOUT_S = 2.0
#: the methods of an instance: name -> (the chart flag, and True to pulse it for one scan
#: or the value it is set to)
METHODS: dict[str, tuple[str, bool | None]] = {
    "Acknowledge": ("SFCQuitError", None), "Reset": ("SFCReset", None),
    "Pause": ("SFCPause", True), "Resume": ("SFCPause", False)}
#: requests taken from one client per turn of the feed thread (a turn per scan window)
LINES_PER_TURN = 8
#: writes of one client handed to the scan thread and not yet answered; more wait
PENDING_MAX = 8


#: the mailbox: (scan, wall seconds, the image's copy or None, the catalogue that took it,
#: the controller's and drivers' state at that scan, and a copy of the state of each
#: instance some client follows when their transitions are explained on it, else None)
_Slot = tuple[int, float, "Image | None", Catalogue, tuple[Any, ...],
              "dict[str, Memory] | None"]


@dataclass(slots=True)
class _Client:
    sock: socket.socket
    peer: str
    out: bytearray = field(default_factory=bytearray)
    inbuf: bytearray = field(default_factory=bytearray)
    #: the next frame it gets is a whole one (it has none yet)
    fresh: bool = True
    #: the status line it was last sent (``FeedServer._status_line``: the very bytes
    #: object every client shares, compared by identity)
    status: bytes | None = None
    #: its writes and method calls handed to the scan thread, oldest first: (id, the
    #: call, its place in the call's results, monotonic deadline, the text of its
    #: answer); answered in this order
    pending: deque[tuple[Any, ScanCall, int, float, Callable[[Any], str]]] = field(
        default_factory=deque)
    #: its socket is watched for input (not while its unhandled input is at IN_MAX)
    reading: bool = True
    #: the selector events its socket is registered for (0: not registered)
    events: int = 0
    #: the instances whose transitions it follows (``{"why": [...]}``), and what it was
    #: last sent of each
    why: list[str] = field(default_factory=list)
    whys: dict[str, Any] = field(default_factory=dict)
    #: it reads the values from the shared image (``{"image": true}``): no frames
    image: bool = False


class FeedServer:
    """Serves the feed of ``daemon`` on ``feed.path`` until ``stop()``."""

    def __init__(self, daemon: Daemon, feed: FeedDef,
                 wall: Callable[[], float] = time.time) -> None:
        self.daemon = daemon
        self.feed = feed
        self.path = feed.path
        self.wall = wall
        cycle_ns = daemon.plant.cycle_ns
        #: a snapshot every this many scans
        self.every = max(1, feed.sample_ns // cycle_ns)
        #: closed a quiet time before the next scan's deadline, as the console's: not a
        #: cycle after the last scan's end (a scan that ended late would shorten it)
        self.window = ScanWindow(cycle_ns / 1e9, due=daemon.next_scan_due)
        #: whose feed this is, for the side processes (the plant the controller started
        #: with: its lock's, whatever file a reload loads)
        self.owner = locate(daemon.pdef)
        self._cat = Catalogue(daemon.plant)
        #: the names of the plant an online change is about to put in (built with it, in
        #: the reload's worker: ``_prepare``), taken by the feed thread after the swap
        self._ready: Catalogue | None = None
        #: the shared image of the catalogue's plant (None: none could be made, every
        #: client gets frames) and its generation (one more per plant object)
        self._image: ImageWriter | None = None
        self._generation = 0
        #: the image to write (scan thread, each sample; the feed thread reads and writes
        #: it between that scan and the next): (the scan's start, the scheduler's
        #: ``last_wake``; the scan; its wall clock ns; the writer); and the last taken
        self._image_due: tuple[int, int, int, ImageWriter] | None = None
        self._image_taken: tuple[int, int, int, ImageWriter] | None = None
        #: the sample whose image is not written yet
        self._image_pending: tuple[int, int, int, ImageWriter] | None = None
        #: samples whose image was never written (the next sample came first), and
        #: images read after a later scan than their sample's (stamped with that scan)
        self.images_missed = 0
        self.images_late = 0
        #: the scan thread copies the image into the mailbox (Catalogue.capture) while a
        #: client takes frames (every sample), and the state of the instances clients
        #: follow (``_why``, their names; every WHY_EVERY_NS): set by the feed thread
        self._copy = False
        self._why: tuple[str, ...] = ()
        #: scans between two explanations of one instance followed, the scan of the next
        #: explanation (of one instance), and the turn of the instances followed
        self.why_every = max(1, WHY_EVERY_NS // cycle_ns)
        self._why_next = 0
        self._why_turn = 0
        self._next = 0
        #: the mailbox (``_Slot``), written by the scan thread only
        self._slot: _Slot | None = None
        self._taken: _Slot | None = None
        self._stop = threading.Event()
        self._replaced = False
        self._sock: socket.socket | None = None
        self._sel: selectors.BaseSelector | None = None
        self._thread: threading.Thread | None = None
        self._clients: list[_Client] = []
        self._values: list[Any] | None = None
        self._schema_line = b""
        self._stats: dict[str, Any] = {}
        self._stats_at = 0
        #: one more each time the lateness percentiles or the alarms differ (the status's
        #: key: ``_status_of``)
        self._stats_changes = 0
        self._alarms_changes = 0
        #: the status line now (encoded once per change, shared by every client) and the
        #: key of what it says
        self._status_line = b""
        self._status_key: tuple[Any, ...] | None = None
        #: the alarms (AlarmBoard.as_list) as of the board's version (the last change
        #: of its journal read: ``AlarmBoard.changes``)
        self._alarms: list[dict[str, Any]] = []
        self._alarms_version = -1
        #: counters (tests, logs): frames built, clients dropped for not reading
        self.frames = 0
        self.dropped = 0

    # -- life cycle ----------------------------------------------------------------
    def start(self) -> None:
        """Bind the socket (errors raised here), hook into the scan, start the thread."""
        srv = unix_listener(self.path, "feed")
        srv.listen(MAX_CLIENTS)
        srv.setblocking(False)
        self._sock = srv
        self._sel = selectors.DefaultSelector()
        self._sel.register(srv, selectors.EVENT_READ, None)
        self._image = self._new_image(self._cat)
        self._schema_line = self._schema()
        # the sample first, then the window: the feed thread, woken by the window, finds
        # the sample of the scan that opened it
        self.daemon.add_listener(self.on_scan)
        self.daemon.add_listener(self.window.on_scan)
        on_reload = getattr(self.daemon, "on_reload", None)
        if on_reload is not None:
            on_reload(self._prepare)
        self._thread = threading.Thread(target=self._run, name="softplc-feed", daemon=True)
        self._thread.start()
        log.info("feed listening on %s (a snapshot every %d scan(s))", self.path, self.every)

    def stop(self) -> None:
        """Unhook from the scan, close every client and the socket. Idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self.daemon.remove_listener(self.on_scan)
        self.daemon.remove_listener(self.window.on_scan)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for c in list(self._clients):
            self._drop(c, None)
        if self._sock is not None:
            self._sock.close()
            remove_socket(self.path)  # only if still the one it bound
        if self._sel is not None:
            self._sel.close()
        if self._image is not None:
            self._image.retire()

    def plant_replaced(self) -> None:
        """The controller's plant object was replaced (an online change): every client gets
        the new schema, then a whole frame, on the connection it has. Any thread. (The
        feed thread also notices by itself when ``daemon.plant`` is another object.)"""
        self._replaced = True

    def _prepare(self, plant: Plant) -> Callable[[], None]:
        """Reload worker thread: the new plant's names, built now, with the plant (the
        reload freezes them with it: out of the scan thread's collections, about 30 000
        objects at 100 testers); the returned function (scan thread, at the swap) hands
        them to the feed thread."""
        if self._stop.is_set():
            return lambda: None
        cat = Catalogue(plant)

        def commit() -> None:
            self._ready = cat
        return commit

    # -- the scan thread -------------------------------------------------------------
    def on_scan(self, n: int) -> None:
        """Scan thread, after cycle ``n``: every ``every`` scans, the image into the slot."""
        if n < self._next:
            return
        self._next = n + self.every
        cat, d, image = self._cat, self.daemon, self._image
        wall = self.wall()
        st = d.scan_stats
        # the state of that scan too (a few attributes), so that a frame never shows the
        # image of one scan beside the controller's or a driver's state of a later one
        live = (d.state.value, d.fault or d.halted, st.overruns, st.skipped, st.freezes,
                {name: [drv.health.value, drv.fault_reason or "", drv.ok]
                 for name, drv in d.plant.drivers.items()},
                d.plant.forced_names() if d.plant.forced or d.plant.forced_points else (),
                d.plant.last_up)
        followed = None
        names = self._why
        if names and n >= self._why_next:
            # one followed instance a copy, in turn: each explained every WHY_EVERY_NS,
            # never all of them in one sample (one explanation a sample at most)
            self._why_next = n + max(1, self.why_every // len(names))
            self._why_turn += 1
            followed = self._copy_followed(cat, (names[self._why_turn % len(names)],))
        self._slot = (n - 1, wall, cat.capture(n - 1) if self._copy else None, cat, live,
                      followed)
        # the shared image: read and written by the feed thread once this scan's idle
        # work is done and before the next scan (``_write_image``), never older than the
        # copy and the state beside it (a safe state written by another thread
        # meanwhile, a halt, shows in both)
        if image is not None and image.plant is d.plant:
            self._image_due = (d.scheduler.last_wake, n - 1, int(wall * 1e9), image)

    @staticmethod
    def _copy_followed(cat: Catalogue, names: tuple[str, ...]) -> dict[str, Memory]:
        """Scan thread: a copy of the state of each instance in ``names`` (the instances
        clients follow: at most MAX_WHY a client), nothing of the others."""
        insts = cat.plant.instances
        return {name: insts[name].m.values() for name in names if name in insts}

    # -- the feed thread ------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if not self._clients:
                    self._idle()
                self._round()
        except Exception:  # noqa: BLE001 - the feed dies, never the controller
            log.exception("feed thread failed: OPC UA clients see no more values")
            # said to the clients too: their connection ends, so that a server shows its
            # values as BadNoCommunication instead of the last ones as good
            for c in list(self._clients):
                self._drop(c, "the feed failed")
            if self._sock is not None:
                self._sock.close()

    def _round(self) -> None:
        """One window's work: the image, the clients' requests, the new snapshot to them,
        their sockets. Each piece begins only while the window is open: the image's
        read may wait for the scan thread until the window closes, and what is left then
        waits for the next window, never done in the quiet time before the next scan
        (bench.observers --rounds: a fifth of the publications and flushes began there,
        one ran across the deadline of an overrun)."""
        clock = self.window.clock
        closes = self.window.until()
        if self._stop.is_set():
            return
        if self._replaced or self.daemon.plant is not self._cat.plant:
            self._reload()
        self._write_image(closes)
        # the clients' requests before the new snapshot: what a side process said
        # (``{"image": true}`` as soon as it has the schema) decides what it is sent; a
        # whole frame sent to a side process that reads the image filled its buffers
        # while it built its names, and the controller dropped it
        if clock() < closes:
            self._io(0.0, closes)
        if clock() < closes:
            self._serve()
        # then the new snapshot, while the window is young (a scan has just ended)
        slot = self._slot
        if (slot is not None and slot is not self._taken and self._clients
                and clock() < closes):
            self._taken = slot
            if slot[3] is self._cat:  # not an image of a replaced plant
                self._publish(slot[0], slot[1], slot[2], slot[4], slot[5])
                if clock() < closes:
                    self._flush()
        now = clock()
        if now < closes:
            self._io(min(closes - now, POLL_S), closes)

    def _write_image(self, closes: float) -> None:
        """The image of the last sample, read from the state between two scans (the
        scheduler's ``seq`` even and unchanged across the read: the scan thread changed
        nothing meanwhile) and written to the file, before ``closes`` (monotonic s). Read
        between the sampled scan and the next, it is that scan's (a request served after
        it included); read in a later gap (the feed thread got no processor in time), it
        is the last scan's, stamped with that scan (``images_late``). Not read before
        ``closes``: tried again in the next window; a sample whose image was still not
        written when the next sample came is lost (``images_missed``). So the scan thread
        pays nothing per name for the image (``on_scan`` stores a tuple)."""
        due = self._image_due
        if due is None or due is self._image_taken:
            return
        pending = self._image_pending
        if pending is not None and pending is not due:
            self.images_missed += 1  # a newer sample came before its image was written
        self._image_pending = due
        wake, scan, wall_ns, image = due
        d = self.daemon
        sched = d.scheduler
        seq = sched.seq
        while True:
            if time.monotonic() >= closes:
                return  # the next window: a read now could hold the GIL at the deadline
            if not seq & 1:
                break
            time.sleep(IMAGE_POLL_S)  # the scan thread is in a scan or its idle work
            seq = sched.seq
        if image is not self._image or image.plant is not d.plant:
            self._image_taken, self._image_pending = due, None
            return  # the plant was replaced: the new image comes with the next sample
        if sched.last_wake != wake:  # a later scan ran: the state is the last scan's
            scan, wall_ns = d.scan_stats.count - 1, int(self.wall() * 1e9)
        got = image.read()
        if sched.seq != seq:  # the scan thread ran meanwhile: not one moment's state
            return  # the next window
        if scan != due[1]:
            self.images_late += 1
        self._image_taken, self._image_pending = due, None
        image.publish(got, scan, wall_ns)

    def _idle(self) -> None:
        """No client: wait for a connection (the listening socket alone is registered) or
        POLL_S, not for every scan: a feed nobody reads costs nothing per sample. The
        connection is accepted in the next scan window (``_io``)."""
        assert self._sel is not None
        self._sel.select(POLL_S)

    def _reload(self) -> None:
        self._replaced = False
        # the new plant file's writable names; none for a side whose section is removed
        # (the feed serves values until the controller restarts: change/diff.py says so)
        new = self.daemon.pdef.feed()
        self.feed.writable = new.writable if new is not None else {}
        plant, ready, self._ready = self.daemon.plant, self._ready, None
        self._cat = ready if ready is not None and ready.plant is plant else Catalogue(plant)
        old, self._image = self._image, self._new_image(self._cat)
        if old is not None:
            old.retire()
        self._schema_line = self._schema()
        self._values = None
        for c in list(self._clients):
            c.fresh, c.status = True, None
            c.why = [n for n in c.why if n in self._cat.plant.instances]
            c.whys = {}
            self._queue(c, self._schema_line)
        self._wanted()
        log.info("feed: plant replaced: the new schema sent to %d client(s)",
                 len(self._clients))

    def _io(self, timeout: float, closes: float) -> None:
        """The sockets ready within ``timeout`` s served: reads, sends, a connection
        accepted; none once ``closes`` (the window's clock) has passed: they stay ready
        for the next window."""
        assert self._sel is not None
        ready = self._sel.select(timeout)
        if self.window.clock() >= closes:
            return
        for key, mask in ready:
            c = key.data
            if c is None:
                self._accept()
            elif isinstance(c, _Client):
                if mask & selectors.EVENT_READ:
                    self._read(c)
                if mask & selectors.EVENT_WRITE and c in self._clients:
                    self._send(c)

    def _accept(self) -> None:
        assert self._sock is not None and self._sel is not None
        try:
            conn, _ = self._sock.accept()
        except (BlockingIOError, InterruptedError):
            return
        cred = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
        pid, uid, _gid = struct.unpack("3i", cred)
        if uid not in (0, os.geteuid()):
            log.warning("feed: connection from uid %d refused (only uid %d or root)", uid,
                        os.geteuid())
            conn.close()
            return
        if len(self._clients) >= MAX_CLIENTS:
            log.warning("feed: connection from pid %d refused: %d clients already", pid,
                        MAX_CLIENTS)
            conn.close()
            return
        conn.setblocking(False)
        c = _Client(conn, f"pid {pid} uid {uid}")
        c.out += self._schema_line
        self._clients.append(c)
        self._interest(c)
        log.info("feed: client connected (%s)", c.peer)
        self._send(c)

    def _read(self, c: _Client) -> None:
        """Take what the client sent into its input buffer (handled by ``_serve``)."""
        try:
            data = c.sock.recv(READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._drop(c, str(exc))
            return
        if not data:
            self._drop(c, None)
            return
        c.inbuf += data
        if len(c.inbuf) > IN_MAX and b"\n" not in c.inbuf:
            self._drop(c, "a line too long")
            return
        self._watch(c)

    def _serve(self) -> None:
        """One turn for every client: the answers of its writes the scan thread has
        applied (or that timed out), then at most LINES_PER_TURN of its requests while it
        has fewer than PENDING_MAX writes waiting. The writes and method calls taken in
        one turn go to the scan thread as one call (``_together``): they are applied at
        the same scan boundary, in the order sent (an MQTT command's writes together)."""
        now = time.monotonic()
        for c in list(self._clients):
            pending = c.pending
            while (pending and c in self._clients
                   and (pending[0][1].done.is_set() or now > pending[0][3])):
                self._answer(c, *pending.popleft())
            taken = 0
            batch: list[tuple[Any, Callable[[], Any], Callable[[Any], str]]] = []
            while (taken < LINES_PER_TURN and len(pending) + len(batch) < PENDING_MAX
                   and c in self._clients):
                cut = c.inbuf.find(b"\n")
                if cut < 0:
                    break
                line = bytes(c.inbuf[:cut])
                del c.inbuf[:cut + 1]
                taken += 1
                try:
                    asked = self._request(c, line)
                except Exception as exc:  # noqa: BLE001 - one client's line never ends the feed
                    log.warning("feed: a request of %s failed (%s: %s): client dropped",
                                c.peer, type(exc).__name__, exc)
                    self._drop(c, "a request that failed")
                    break
                if asked is not None:
                    batch.append(asked)
            if batch and c in self._clients:
                call = self.daemon.submit(_together([fn for _i, fn, _d in batch]))
                deadline = time.monotonic() + SET_TIMEOUT_S
                for k, (ident, _fn, done) in enumerate(batch):
                    pending.append((ident, call, k, deadline, done))
            if c in self._clients:
                self._watch(c)

    def _watch(self, c: _Client) -> None:
        """Read from the client only while its unhandled input is below IN_MAX: a client
        that sends faster than its turns take waits, in its own socket buffer."""
        reading = len(c.inbuf) < IN_MAX
        if reading != c.reading:
            c.reading = reading
            self._interest(c)

    def _interest(self, c: _Client) -> None:
        """Watch the client's socket for what it waits for: input while ``reading``,
        room to send while it has output; for neither, not at all."""
        assert self._sel is not None
        events = ((selectors.EVENT_READ if c.reading else 0)
                  | (selectors.EVENT_WRITE if c.out else 0))
        if events == c.events:
            return
        if not c.events:
            self._sel.register(c.sock, events, c)
        elif events:
            self._sel.modify(c.sock, events, c)
        else:
            self._sel.unregister(c.sock)
        c.events = events

    def _request(self, c: _Client, line: bytes
                 ) -> tuple[Any, Callable[[], Any], Callable[[Any], str]] | None:
        """One request line: answered here (a refusal, an alarm's acknowledgement), or
        (id, the function the scan thread runs, the text of its answer)."""
        try:
            msg = json.loads(line)
            if "why" in msg:
                self._follow_why(c, msg["why"])
                return None
            if "image" in msg:
                c.image = bool(msg["image"]) and self._image is not None
                self._wanted()
                return None
            if "set" in msg:
                ident, name, value, *side = msg["set"]
                if len(side) > 1 or (side and side[0] not in SIDE_NAMES):
                    raise ValueError(side)
                refused, fn, done = self._prepare_set(str(name), value,
                                                      str(side[0]) if side else "opcua")
            elif "call" in msg:
                ident, target, method, who = msg["call"]
                refused, fn, done = self._prepare_call(str(target), str(method), str(who))
            elif "alarm" in msg:
                ident, key, action, who, comment = msg["alarm"]
                self._queue(c, _line({"r": [ident, *self._alarm(str(key), str(action),
                                                                str(who), str(comment))]}))
                return None
            else:
                raise KeyError("set, call, alarm or why")
        except (ValueError, KeyError, TypeError, RecursionError):
            self._drop(c, "a malformed request")
            return None
        if refused is not None:
            self._queue(c, _line({"r": [ident, False, refused, "BadInvalidArgument"]}))
            return None
        assert fn is not None and done is not None
        return ident, fn, done

    def _answer(self, c: _Client, ident: Any, call: ScanCall, k: int, deadline: float,
                done: Callable[[Any], str]) -> None:
        """The answer to a write or a method call, the ``k``-th of ``call`` (``_together``),
        the scan thread ran (or did not)."""
        code = "Good"
        if not call.done.is_set():
            call.abandoned = True
            ok, text, code = False, "the scan did not answer in time", "BadTimeout"
        else:
            result, error = call.result[k] if call.error is None else (None, call.error)
            if error is not None:
                ok, text, code = False, str(error) or type(error).__name__, "BadInvalidState"
            else:
                ok, text = True, done(result)
        self._queue(c, _line({"r": [ident, ok, text, code]}))

    def _prepare_set(self, name: str, value: Any, side: str
                     ) -> tuple[str | None, Callable[[], Any] | None,
                                Callable[[Any], str] | None]:
        """A client's write checked: (None, the function the scan thread runs, the text
        of its answer), or (why it is refused, None, None). Only a name of the asking side
        process's ``writable:`` (``opcua``, ``mqtt``), a value of its type and in range."""
        if name not in self.feed.writable.get(side, ()):
            return (f"{name} is not writable over {SIDE_NAMES[side]} ({side}: writable)",
                    None, None)
        sig = self._cat.names.get(name)
        if sig is None:
            return f"unknown name '{name}'", None, None
        try:
            if sig.type is A.Type.BOOL and isinstance(value, float):
                raise ValueError(f"expected a bool, found {value!r}")
            v = coerce(sig.type, value)
        except (ValueError, TypeError, OverflowError) as exc:
            return f"bad value for {name}: {exc}", None, None
        problem = value_problem(sig.type, v)
        if problem is not None:
            return f"bad value for {name}: {problem}", None, None
        daemon, shown = self.daemon, sig.show(v)

        def done(result: Any) -> str:
            log.info("%s: set %s = %s", side, name, shown)
            return f"{name} set to {shown}"
        # the running plant, read in the scan thread: an online change may replace it
        return None, lambda: daemon.plant.set(name, v), done

    def _prepare_call(self, target: str, method: str, who: str
                      ) -> tuple[str | None, Callable[[], Any] | None,
                                 Callable[[Any], str] | None]:
        """A method of an instance (``METHODS``) or of the controller (``Ack``), for a
        writer ``who`` (the server checked it): (None, the function the scan thread runs,
        the text of its answer), or (why it is refused, None, None)."""
        daemon = self.daemon
        if target == "controller":
            if method != "Ack":
                return f"the controller has no method '{method}' (Ack)", None, None
            fn: Callable[[], Any] = daemon.ack
        elif target in daemon.pdef.instances:
            if method not in METHODS:
                return (f"{target} has no method '{method}' ({', '.join(METHODS)})", None,
                        None)
            flag, value = METHODS[method]
            bound = daemon.pdef.instances[target].inputs.get(flag)
            if bound is not None:
                return (f"{target}.{flag} is bound to {bound.source}, which sets it before "
                        "every scan", None, None)
            fn = _instance_method(daemon, target, flag, value)
        else:
            return f"no instance '{target}'", None, None

        def done(result: Any) -> str:
            text = str(result) if result else f"{target}.{method} done"
            log.warning("opcua: %s called %s.%s: %s", who, target, method, text)
            return text
        return None, fn, done

    def _alarm(self, key: str, action: str, who: str, comment: str) -> list[Any]:
        """Acknowledge or confirm an alarm (the board's lock, no wait for the scan):
        [ok, text, OPC UA status name]."""
        board = self.daemon.alarms
        try:
            if action == "ack":
                text = board.acknowledge(key, who, comment)
            elif action == "confirm":
                text = board.confirm(key, who, comment)
            else:
                return [False, f"unknown alarm action '{action}'", "BadInvalidArgument"]
        except AlarmRefused as exc:
            return [False, str(exc), exc.code]
        return [True, text, "Good"]

    def _wanted(self) -> None:
        """What the scan thread must copy for the clients (``_copy``, ``_why``)."""
        self._copy = any(not c.image for c in self._clients)
        self._why = tuple(dict.fromkeys(n for c in self._clients for n in c.why))

    def _publish(self, scan: int, wall: float, img: Image | None, live: tuple[Any, ...],
                 followed: dict[str, Memory] | None = None) -> None:
        """One frame to every client that takes frames: whole to new ones, the changes to
        the others; the status to all. The names are read only while a client takes
        frames (the others read the shared image in their own process); the transitions
        followed are explained on ``followed`` (the copies of the followed instances'
        state, every WHY_EVERY_NS; None between)."""
        # a client counts for the copy from the turn after it connected (it says at once
        # whether it reads the image: a side process then gets no frame at all)
        self._copy = any(not c.image for c in self._clients)
        if img is None or all(c.image for c in self._clients):
            values: list[Any] = []
            self._values = None
        else:
            values = [s.read(img) for s in self._cat.names.values()]
        prev = self._values
        self._values = values or None
        delta = None
        if prev is not None and values:
            changes: list[Any] = []
            for i, v in enumerate(values):
                if v != prev[i] or type(v) is not type(prev[i]):
                    changes += (i, v)
            delta = _line({"d": [scan, wall, changes]})
        whole = None
        explained: dict[str, Any] = {}
        alarm_lines = self._alarm_changes()
        status = self._status_of(live)
        self.frames += 1
        for c in list(self._clients):
            # a client of the image that has not taken what it was sent (its event loop
            # busy: an OPC UA server building thousands of nodes) gets the latest status
            # and transitions once it has, not every one meanwhile: they are states, not
            # events, and piling them up would get it dropped for not reading
            behind = c.image and bool(c.out)
            # every change of an alarm, its own line, even to a client behind: events,
            # not states (a client that has had no status yet gets the whole board in
            # its first one instead)
            if alarm_lines and c.status is not None:
                for line in alarm_lines:
                    self._queue(c, line)
                if c not in self._clients:
                    continue
            if status is not c.status and not behind:
                c.status = status
                self._queue(c, status)
            if c.why and followed is not None and not behind:
                self._queue_why(c, followed, live[-1], explained)
            if c.image or not values:
                continue
            if c.fresh or delta is None:
                if whole is None:
                    whole = _line({"f": [scan, wall, values]})
                c.fresh = False
                self._queue(c, whole)
            else:
                self._queue(c, delta)

    def _follow_why(self, c: _Client, names: Any) -> None:
        """``{"why": [INSTANCE, ...]}``: from the next frame on, ``c`` gets the
        transitions of those instances (``{"w": ...}``) whenever they change; ``[]`` stops
        it. At most MAX_WHY instances per client; unknown names are left out."""
        if not isinstance(names, list):
            raise ValueError("why: expected a list of instances")
        known = self.daemon.plant.instances
        c.why = [str(n) for n in names if isinstance(n, str) and n in known][:MAX_WHY]
        c.whys = {}
        self._wanted()

    def _queue_why(self, c: _Client, followed: dict[str, Memory], up: int,
                   explained: dict[str, Any]) -> None:
        """The explanations of ``c``'s instances that changed since it was last sent them,
        each computed once per frame (``explained``) on the copy of its state (an
        instance followed since the copy was taken: at the next one)."""
        changed: dict[str, Any] = {}
        for name in c.why:
            why = explained.get(name)
            if why is None:
                m = followed.get(name)
                if m is None:
                    continue
                why = explained[name] = self._explain(name, m, up)
            if c.whys.get(name) != why:
                c.whys[name] = why
                changed[name] = why
        if changed:
            self._queue(c, _line({"w": changed}))

    def _explain(self, name: str, m: Memory, up: int) -> list[Any]:
        """``Instance.explain`` of instance ``name`` on the copy ``m`` of its state (feed
        thread: never in the scan's), as plain lists: [step, T ns, [[transition index,
        condition, [blocked...], [[term, depth, value]...]]...]] per active step."""
        prog = self._cat.plant.instances[name].program
        return [[sw.step, sw.time_ns,
                 [[t.index, t.condition, t.blocked, [[x.text, x.depth, x.value]
                                                      for x in t.terms]]
                  for t in sw.transitions]]
                for sw in explain(prog, m, up)]

    def _alarm_changes(self) -> list[bytes]:
        """The changes of the alarm board since the last turn (``AlarmBoard.changes``),
        one line each (``{"a": [version, alarm]}``), and the board's conditions for the
        status read with them (nothing per alarm while the board's version is still)."""
        board = self.daemon.alarms
        changes, self._alarms_version, alarms, lost = board.changes(self._alarms_version)
        if alarms is None:
            return []
        if alarms != self._alarms:
            self._alarms = alarms
            self._alarms_changes += 1
        if lost and any(c.status is not None for c in self._clients):
            log.warning("feed: the alarm board changed more than %d times since the last "
                        "turn: the oldest changes are not sent (the status has the whole "
                        "board)", JOURNAL_MAX)
        return [_line({"a": [version, alarm]}) for version, alarm in changes]

    def _status_of(self, live: tuple[Any, ...]) -> bytes:
        """The status line (``{"c": ...}``) with a frame: the same bytes object while what
        it says is unchanged. Per sample only a key is compared (the frame's state
        ``live``: a few numbers and one entry per driver, the uptime in whole seconds and
        the versions of the lateness percentiles and of the alarms); the status is built
        and encoded once per change, nothing per alarm, name or client."""
        d = self.daemon
        now = time.monotonic_ns()
        if now - self._stats_at >= STATS_EVERY_NS:
            self._stats_at = now
            # the percentiles in slices inside this thread's scan windows
            # (ScanWindow.pause, as the console's ``stats``), never in one stretch
            # holding the GIL
            st = d.scan_stats
            late = st.lateness(st.lateness_quantiles(self.window.pause)).as_dict()
            stats = {k: late[k] for k in ("p50", "p99", "max")}
            if stats != self._stats:
                self._stats = stats
                self._stats_changes += 1
        uptime_s = round(d.uptime_s())
        key = (live[:-1], uptime_s, d.plant.cycle_ns, self._stats_changes,
               self._alarms_changes)
        if key != self._status_key:
            self._status_key = key
            self._status_line = _line({"c": self._status(live, uptime_s)})
        return self._status_line

    def _status(self, live: tuple[Any, ...], uptime_s: int) -> dict[str, Any]:
        """The controller's status: its state, fault, counters and drivers as they were
        at the frame's scan (``live``, taken with the image); the lateness percentiles (of
        the last scans, sorted every STATS_EVERY_NS), the alarms and the uptime (whole
        seconds) as they are now. Built only when its key changed (``_status_of``)."""
        d = self.daemon
        state, fault, overruns, skipped, freezes, drivers, forced, _up = live
        return {"state": state, "fault": fault, "overruns": overruns, "skipped": skipped,
                "freezes": freezes, "uptime_s": uptime_s,
                "cycle_ms": d.plant.cycle_ns / 1e6, "lateness_us": self._stats,
                "drivers": drivers, "alarms": self._alarms, "forced": list(forced)}

    def _queue(self, c: _Client, data: bytes) -> None:
        if c not in self._clients:  # dropped meanwhile (its answers overflowed)
            return
        c.out += data
        if len(c.out) > OUT_MAX:
            self.dropped += 1
            self._drop(c, f"it took no data for too long ({len(c.out)} bytes waiting)")

    def _flush(self) -> None:
        for c in list(self._clients):
            if c.out:
                self._send(c)

    def _send(self, c: _Client) -> None:
        assert self._sel is not None
        try:
            n = c.sock.send(c.out)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            self._drop(c, str(exc))
            return
        del c.out[:n]
        self._interest(c)

    def _drop(self, c: _Client, why: str | None) -> None:
        if c in self._clients:
            self._clients.remove(c)
            self._wanted()
        if self._sel is not None:
            try:
                self._sel.unregister(c.sock)
            except (KeyError, ValueError):
                pass
        c.events = 0
        c.sock.close()
        if why is None:
            log.info("feed: client gone (%s)", c.peer)
        else:
            log.warning("feed: client dropped (%s): %s", c.peer, why)

    def _schema(self) -> bytes:
        pdef = self.daemon.pdef
        return _line({"schema": {
            "name": self.owner.name, "home": self.owner.home,
            "plant": pdef.path,
            "names": [[s.text, s.type.value, s.role] for s in self._cat.names.values()],
            "instances": {n: i.grafcet.name for n, i in pdef.instances.items()},
            "drivers": list(self.daemon.plant.drivers),
            "writable": {k: list(v) for k, v in self.feed.writable.items()},
            "cycle_ms": self.daemon.plant.cycle_ns / 1e6,
            "sample_ms": self.every * self.daemon.plant.cycle_ns / 1e6,
            "image": self._image.describe() if self._image is not None else None,
            "specs": ([list(s.spec) for s in self._cat.names.values()]
                      if self._image is not None else [])}})

    def _new_image(self, cat: Catalogue) -> ImageWriter | None:
        """The shared image of ``cat``'s plant, a new generation; None (said in one line:
        every client then gets frames) if it cannot be made."""
        path = image_path(os.path.abspath(self.path))
        refused = refuse_foreign(path)
        if refused is not None:
            log.warning("feed: no shared image (%s): the side processes get frames", refused)
            return None
        self._generation += 1
        try:
            return ImageWriter(cat, path, self._generation)
        except OSError as exc:
            log.warning("feed: no shared image (%s: %s): the side processes get frames",
                        path, exc.strerror)
            return None

    @property
    def image(self) -> ImageWriter | None:
        """The shared image now written (tests)."""
        return self._image

    @property
    def clients(self) -> int:
        return len(self._clients)


def _together(fns: list[Callable[[], Any]]) -> Callable[[], list[tuple[Any, Exception | None]]]:
    """Scan thread: ``fns`` one after the other, in one call: (result, None) or (None, the
    exception) for each (one refused write never stops the others)."""
    def run() -> list[tuple[Any, Exception | None]]:
        out: list[tuple[Any, Exception | None]] = []
        for fn in fns:
            try:
                out.append((fn(), None))
            except Exception as exc:  # noqa: BLE001 - the client gets the reason
                out.append((None, exc))
        return out
    return run


def _instance_method(daemon: Daemon, name: str, flag: str, value: bool | None
                     ) -> Callable[[], str]:
    """Scan thread: a method of instance ``name`` on its running plant: pulse ``flag``
    for one scan (``value`` None; Acknowledge only while SFCError is set), or set it.
    Refused while the charts are stopped (``charts_stopped``): it would be lost."""
    def run() -> str:
        stopped = charts_stopped(daemon)
        if stopped is not None:
            raise CommandRefused(stopped)
        plant = daemon.plant
        inst = plant.instances.get(name)
        if inst is None:
            raise CommandRefused(f"no instance '{name}' (an online change removed it)")
        if value is None:
            if flag == "SFCQuitError" and not inst.get("SFCError"):
                raise CommandRefused(f"nothing to acknowledge: {name} has no SFCError")
            step = inst.get("SFCErrorStep") if flag == "SFCQuitError" else ""
            plant.pulse(name, flag)
            return (f"{name}: SFCError ({sfcerror_cause(step)}) acknowledged"
                    if flag == "SFCQuitError" else f"{name}: {flag} for one scan")
        plant.set(f"{name}.{flag}", value)
        return f"{name}: {flag} {'set' if value else 'cleared'}"
    return run


def charts_stopped(daemon: Daemon) -> str | None:
    """Scan thread: why no chart runs now, so that a method of an instance would do
    nothing (the controller's Ack restarts every chart from its initial situation, which
    drops what was set or pulsed meanwhile); None while the charts run."""
    if daemon.fault is not None:
        return (f"the controller is in fault ({daemon.fault}): Ack it first (the "
                "Controller's Ack, the console's 'ack'; it restarts the charts)")
    if daemon.halted is not None:
        return (f"the controller is halted ({daemon.halted}): Ack it first (the "
                "Controller's Ack, the console's 'ack'; it restarts the charts)")
    if daemon.plant.iocheck:
        return "iocheck on: the charts are stopped"
    return None


def value_problem(t: A.Type, value: Any) -> str | None:
    """Why ``value`` (already of type ``t``, times in ns) may not be written to a plant
    variable from outside (None if it may): a REAL or TIME must be finite, a TIME within
    64-bit nanoseconds, an INT within the language's 64-bit range."""
    if t is A.Type.REAL and not math.isfinite(value):
        return f"{value!r} is not a finite number"
    if t is A.Type.TIME and not -TIME_MAX_NS <= value <= TIME_MAX_NS:
        return (f"out of range: a time is at most {format_ns(TIME_MAX_NS)} (64-bit "
                "nanoseconds)")
    if t is A.Type.INT and not INT_MIN <= value <= INT_MAX:
        return f"out of range: an int is from {INT_MIN} to {INT_MAX} (64 bits)"
    return None


def _line(msg: dict[str, Any]) -> bytes:
    return (json.dumps(msg, separators=(",", ":"), ensure_ascii=False) + "\n").encode()


@dataclass(slots=True)
class FeedState:
    """Client side: the schema and the last frame, decoded line by line (``apply``)."""

    names: list[str] = field(default_factory=list)
    types: list[str] = field(default_factory=list)
    roles: list[str] = field(default_factory=list)
    index: dict[str, int] = field(default_factory=dict)
    schema: dict[str, Any] = field(default_factory=dict)
    values: list[Any] = field(default_factory=list)
    status: dict[str, Any] = field(default_factory=dict)
    #: whether ``status`` came on the feed's current connection (the client sets it False
    #: on each connection: until the controller's first status, the one kept is the last
    #: connection's, or none; frames can come before it)
    status_current: bool = False
    #: instance -> its transitions as the feed last sent them (``{"w": ...}``)
    whys: dict[str, Any] = field(default_factory=dict)
    #: the last change of an alarm the feed sent (``{"a": ...}``): (the board's version,
    #: the alarm as ``Alarm.as_dict``); None before the first
    alarm: tuple[int, dict[str, Any]] | None = None
    scan: int = -1
    wall: float = 0.0

    def apply(self, line: bytes) -> str:
        """Decode one line: returns its kind (schema, frame, status, alarm, why, reply)
        and keeps the state (an alarm's change in ``alarm``). ValueError if malformed."""
        msg = json.loads(line)
        if "f" in msg:
            self.scan, self.wall, self.values = msg["f"]
            return "frame"
        if "d" in msg:
            self.scan, self.wall, changes = msg["d"]
            vals = self.values
            for k in range(0, len(changes), 2):
                vals[changes[k]] = changes[k + 1]
            return "frame"
        if "c" in msg:
            self.status = msg["c"]
            self.status_current = True
            return "status"
        if "w" in msg:
            self.whys.update(msg["w"])
            return "why"
        if "a" in msg:
            version, alarm = msg["a"]
            if not isinstance(alarm, dict):
                raise ValueError(f"malformed alarm change: {line[:80]!r}")
            self.alarm = (int(version), alarm)
            return "alarm"
        if "schema" in msg:
            self.schema = msg["schema"]
            self.names = [n[0] for n in self.schema["names"]]
            self.types = [n[1] for n in self.schema["names"]]
            self.roles = [n[2] for n in self.schema["names"]]
            self.index = {n: i for i, n in enumerate(self.names)}
            self.values = []
            self.whys = {}
            return "schema"
        if "r" in msg:
            return "reply"
        raise ValueError(f"unknown feed message: {line[:80]!r}")

    def get(self, name: str) -> Any:
        return self.values[self.index[name]]


def request_line(kind: str, ident: int, *args: Any) -> bytes:
    """A client's request (``set``, ``call``, ``alarm``: the module docstring), one line."""
    return _line({kind: [ident, *args]})


def why_request(instances: list[str]) -> bytes:
    """A client's request to follow these instances' transitions (``[]``: none)."""
    return _line({"why": instances})


def set_request(ident: int, name: str, value: Any, side: str = "opcua") -> bytes:
    """A client's write request, as one line (``side``: the asking section)."""
    return request_line("set", ident, name, value, side)
