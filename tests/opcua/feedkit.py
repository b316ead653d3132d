"""A controller with its feed, in this process, and a feed client reading in a thread."""

from __future__ import annotations

import asyncio
import inspect
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer, FeedState, request_line, set_request
from runtime.engine.plant import Plant
from runtime.language.model import PlantDef
from runtime.language.plantfile import load_plant
from runtime.opcua.server import PlantServer, serve
from tests.opcua.kit import write_plant


def wait_until(pred: Callable[[], bool], timeout: float = 10.0, what: str = "") -> None:
    """Poll ``pred`` until it holds; fail after ``timeout`` s (generous: a loaded machine)."""
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what or pred}")
        time.sleep(0.005)


def wait_shown(srv: ServerThread, timeout: float = 30.0) -> None:
    """Until the server has written a frame after the controller's first status on this
    connection: the plant's values, and the controller's and the drivers' nodes (before
    that status they are BadWaitingForInitialData: frames from the shared image can come
    first)."""
    wait_until(lambda: srv.ps is not None and srv.ps.frames > 0 and bool(srv.ps.state.status),
               timeout, "a first frame and the controller's first status")
    assert srv.ps is not None
    ps, seen = srv.ps, srv.ps.frames
    wait_until(lambda: ps.frames > seen, timeout, "a frame after the first status")


async def until(pred: Callable[[], Any], timeout: float = 15.0,
                what: str | Callable[[], str] = "") -> None:
    """In an event loop: poll ``pred`` (a value or an awaitable) until it holds; fail
    after ``timeout`` s, saying ``what`` (or what it returns then)."""
    end = asyncio.get_running_loop().time() + timeout
    while True:
        got = pred()
        if inspect.isawaitable(got):
            got = await got
        if got:
            return
        if asyncio.get_running_loop().time() > end:
            said = what() if callable(what) else what
            raise AssertionError(f"timed out waiting for {said or pred}")
        await asyncio.sleep(0.01)


@contextmanager
def serving(pdef: PlantDef, plant: Plant | None = None, trace: IO[str] | None = None,
            manage_gc: bool = True) -> Iterator[tuple[Daemon, FeedServer]]:
    """A running Daemon of ``pdef`` (on sim I/O, or on ``plant``) with its FeedServer;
    ``manage_gc``: the scheduler's own garbage collection, as ``softplc run`` has it (a
    full collection of the test process's heap left to the interpreter holds the GIL
    wherever it falls: a freeze fault, values shown stale)."""
    feed_def = pdef.feed()
    assert feed_def is not None
    d = Daemon(pdef, plant=plant, sim=plant is None, trace=trace, manage_gc=manage_gc)
    d.start()
    feed = FeedServer(d, feed_def)
    feed.start()
    try:
        yield d, feed
    finally:
        feed.stop()
        d.stop("end of test")


@contextmanager
def controller(tmp: Path, trace: bool = True, port: int = 4840, manage_gc: bool = True,
               **plant: Any) -> Iterator[tuple[Daemon, FeedServer, Path]]:
    """A running Daemon on sim I/O with its FeedServer; (daemon, feed, trace path)."""
    path = write_plant(tmp, port=port, **plant)
    pdef = load_plant(str(path))
    trace_path = tmp / "trace.jsonl"
    out = open(trace_path, "w", encoding="utf-8") if trace else None  # noqa: SIM115
    try:
        with serving(pdef, trace=out, manage_gc=manage_gc) as (d, feed):
            yield d, feed, trace_path
    finally:
        if out is not None:
            out.close()


def read_trace(path: Path) -> dict[int, dict[str, Any]]:
    rows = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    return {r["cycle"]: r for r in rows}


class FeedReader:
    """A feed client: every frame kept as (scan, wall, values copy), replies by id."""

    def __init__(self, path: str, read: bool = True) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(path)
        self.state = FeedState()
        self.frames: list[tuple[int, float, list[Any]]] = []
        self.statuses: list[dict[str, Any]] = []
        #: the alarm changes (``{"a": ...}``): (version, alarm)
        self.alarms: list[tuple[int, dict[str, Any]]] = []
        #: the kind of every line, in order
        self.kinds: list[str] = []
        #: how many schemas came (one at the start, one more after each online change)
        self.schemas = 0
        self.replies: dict[int, tuple[bool, str]] = {}
        #: the OPC UA status name of each reply
        self.codes: dict[int, str] = {}
        self.closed = threading.Event()
        self._ids = 0
        self._thread: threading.Thread | None = None
        if read:
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()

    def _run(self) -> None:
        buf = b""
        try:
            while True:
                data = self.sock.recv(1 << 16)
                if not data:
                    break
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    kind = self.state.apply(line)
                    self.kinds.append(kind)
                    if kind == "frame":
                        st = self.state
                        self.frames.append((st.scan, st.wall, list(st.values)))
                    elif kind == "schema":
                        self.schemas += 1
                    elif kind == "status":
                        self.statuses.append(dict(self.state.status))
                    elif kind == "alarm":
                        assert self.state.alarm is not None
                        self.alarms.append(self.state.alarm)
                    elif kind == "reply":
                        ident, ok, text, code = json.loads(line)["r"]
                        self.replies[ident] = (ok, text)
                        self.codes[ident] = code
        except OSError:
            pass
        finally:
            self.closed.set()

    def set(self, name: str, value: Any, timeout: float = 10.0) -> tuple[bool, str]:
        self._ids += 1
        ident = self._ids
        self.sock.sendall(set_request(ident, name, value))
        wait_until(lambda: ident in self.replies, timeout, f"the answer to set {name}")
        return self.replies[ident]

    def request(self, kind: str, *args: Any, timeout: float = 10.0) -> tuple[bool, str, str]:
        """A ``call`` or ``alarm`` request: (ok, text, code)."""
        self._ids += 1
        ident = self._ids
        self.sock.sendall(request_line(kind, ident, *args))
        wait_until(lambda: ident in self.replies, timeout, f"the answer to {kind}")
        return (*self.replies[ident], self.codes[ident])

    def close(self) -> None:
        self.sock.close()
        if self._thread is not None:
            self._thread.join(timeout=5.0)


class ServerThread:
    """``PlantServer`` in a thread of its own with its own event loop (the fast cases;
    test_process.py runs the real ``softplc opcua``)."""

    def __init__(self, pdef: PlantDef) -> None:
        self.pdef = pdef
        self.ps: PlantServer | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="opcua-test-server",
                                        daemon=True)

    def __enter__(self) -> ServerThread:
        self._thread.start()
        if not self._ready.wait(30.0):
            raise AssertionError("the OPC UA server did not start")
        if self.error is not None:
            raise self.error
        return self

    def __exit__(self, *exc: object) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=30.0)

    def _run(self) -> None:
        async def main() -> None:
            self._loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()

            def ready(ps: PlantServer) -> None:
                self.ps = ps
                self._ready.set()
            await serve(self.pdef, ready=ready, stop=self._stop)
        try:
            asyncio.run(main())
        except BaseException as exc:  # handed to the test
            self.error = exc
            self._ready.set()

    def call(self, coro: Any, timeout: float = 10.0) -> Any:
        """Run ``coro`` in the server's event loop and return its result."""
        assert self._loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def stall(self, timeout: float = 120.0) -> threading.Event:
        """Block the server's event loop (as a loaded machine stalls it: nothing read,
        nothing published) until the returned event is set, or ``timeout`` s."""
        assert self._loop is not None
        release = threading.Event()
        self._loop.call_soon_threadsafe(release.wait, timeout)
        return release

    @property
    def url(self) -> str:
        assert self.pdef.opcua is not None
        return self.pdef.opcua.endpoint


def lines_until(sock: socket.socket, buf: bytearray, pred: Callable[[bytes], bool]
                ) -> list[bytes]:
    """The feed's lines from ``sock`` (``buf``: what came after the last line) up to and
    with the first one ``pred`` takes, 30 s at most."""
    got: list[bytes] = []
    end = time.monotonic() + 30.0
    while time.monotonic() < end:
        cut = buf.find(b"\n")
        if cut >= 0:
            line = bytes(buf[:cut + 1])
            del buf[:cut + 1]
            got.append(line)
            if pred(line):
                return got
            continue
        buf += sock.recv(1 << 16)
    raise AssertionError("the feed never sent such a line")


def driver_health(line: bytes) -> str | None:
    """The health of driver io a status line says (None: not a status)."""
    msg = json.loads(line)
    return msg["c"]["drivers"]["io"][0] if "c" in msg else None


def running_status(line: bytes) -> bool:
    """Whether ``line`` is a status line saying the controller runs."""
    return line.startswith(b'{"c"') and json.loads(line)["c"].get("state") == "running"


class HeldStatusFeed:
    """A real controller's lines played again to one feed client over two connections,
    each connection's status held back: its frames first, its status (and a frame) only
    at the test's step. The controller's schema is made to offer no shared image, so
    the frames come as lines. ``steps``: the first connection's status, the end of the
    first connection, the second connection's status, the end of the test (``close``).
    The frames are of scans ``scan + k``: k = 0 and 1 on the first connection (before
    and after its status), 2 and 3 on the second."""

    def __init__(self, pdef: PlantDef, path: str) -> None:
        with serving(pdef) as (_d, feed):
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.connect(feed.path)
            buf = bytearray()
            schema, *_ = lines_until(sock, buf, lambda ln: ln.startswith(b'{"schema"'))
            self.status = lines_until(sock, buf, running_status)[-1]
            frame = lines_until(sock, buf, lambda ln: ln.startswith(b'{"f"'))[-1]
            sock.close()
        plain = json.loads(schema)
        plain["schema"]["image"] = None
        self.head = json.dumps(plain).encode() + b"\n"
        self.scan, self._wall, self._values = json.loads(frame)["f"]
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.listener.bind(path)
        self.listener.listen(1)
        self.steps = [threading.Event() for _ in range(4)]
        threading.Thread(target=self._play, daemon=True).start()

    def at(self, k: int) -> bytes:
        """The frame of scan ``scan + k``, one line."""
        return json.dumps({"f": [self.scan + k, self._wall + k / 100,
                                 self._values]}).encode() + b"\n"

    def _play(self) -> None:
        try:
            for first, last in ((0, 1), (2, 3)):
                conn, _ = self.listener.accept()  # the client connects (again)
                with conn:
                    conn.sendall(self.head + self.at(first))  # frames, no status yet
                    self.steps[first].wait(30.0)
                    conn.sendall(self.status + self.at(last))
                    self.steps[last].wait(60.0)
        except OSError:  # the client went (a test that failed), or ``close``
            return

    def close(self) -> None:
        for step in self.steps:
            step.set()
        self.listener.close()
