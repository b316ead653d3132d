"""Console load generators, run as a separate process, as a real client would be:

    python flooder.py [--nice N] flood SECONDS [RATE]   owns a pty: prints {"port": SLAVE} and, once
                                             "go" arrives on stdin, writes RATE lines/s of
                                             commands, 2000-byte lines and binary garbage
                                             into it, reading every reply
    python flooder.py trace SOCKET SECONDS   a client streaming ``trace on``
    python flooder.py pipeline ADDRESS SECONDS COMMAND...
                                             one client (ADDRESS: a socket path or
                                             127.0.0.1:PORT) sending the COMMANDs round
                                             and round as fast as the replies come, with
                                             PIPELINE_DEPTH requests in flight, from
                                             when "go" arrives on stdin (it prints
                                             {"connected": ADDRESS} first)

Each prints one JSON object with what was sent and received. The load is prepared before
it starts, and the process runs at nice 10 (``--nice N``: another): it stands for a laptop
at the other end of the cable, so the CPU it needs to generate the load must not be what
the daemon's scan competes with on a 2-core test machine. A local user's clients (the
attack of issue 31) run at nice 0. (A pty owned here rather than a null-modem in the
daemon's process, for the same reason: a real UART has no copying thread.)
"""

from __future__ import annotations

import json
import os
import random
import select
import socket
import sys
import threading
import time
import tty

#: one round of the flood: 1 command in 20 needs the scan thread (status), the others are
#: refused or answered by the console thread alone
_R = random.Random(6)
ROUND: list[bytes] = [
    b"status\r\n",
    b"help\r\n",
    b"nonsense\r\n",
    b"x" * 2000 + b"\r\n",
    _R.randbytes(64) + b"\n",
    b"\xff\xfe not utf-8\r\n",
    b"force t1.iMarcha\r\n",
    b"status\x1b[A\r\n",
    _R.randbytes(200) + b"\r",
    b"watch t1.nope\r\n",
    b"\r\n",
    b"set t1.sParo maybe\r\n",
    b"\xc3\r\n",
    b"frobnicate all the things\n",
    b"cycle many\r\n",
    _R.randbytes(1500),
    b"\r\nhelp nope\r\n",
    b"unforce\r\n",
    b"get\r\n",
    b"json maybe\r\n",
]


class Pipe:
    """The master side of a pty, or a Unix socket."""

    def __init__(self, fd: int | None = None, sock: socket.socket | None = None) -> None:
        self.sock = sock
        self.fd = fd if fd is not None else sock.fileno()  # type: ignore[union-attr]
        self.dropped = 0

    def write(self, data: bytes) -> None:
        if self.sock is not None:
            self.sock.sendall(data)
            return
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.fd, view):]
            except BlockingIOError:
                self.dropped += len(view)  # the line is full: lost, as on a real line
                return

    def write_all(self, data: bytes, timeout: float) -> bool:
        """Write all of ``data``, waiting while the line is full (an operator typing after
        a flood): whether it all went within ``timeout`` seconds."""
        view = memoryview(data)
        end = time.monotonic() + timeout
        while view and time.monotonic() < end:
            select.select([], [self.fd], [], 0.05)
            try:
                view = view[os.write(self.fd, view):]
            except BlockingIOError:
                continue
        return not view

    def read(self, timeout: float) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return b""
        try:
            return self.sock.recv(65536) if self.sock is not None else os.read(self.fd, 65536)
        except OSError:
            return b""

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        else:
            os.close(self.fd)


class Counter:
    """Reads everything the console sends; counts lines by kind."""

    def __init__(self, pipe: Pipe) -> None:
        self.pipe = pipe
        self.lines = self.ok = self.errors = self.trace = self.final = 0
        self.bytes = 0
        self._stop = False
        self._buf = b""
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop:
            data = self.pipe.read(0.05)
            self.bytes += len(data)
            self._buf += data
            *lines, self._buf = self._buf.split(b"\n")
            for line in lines:
                self.lines += 1
                if line.startswith(b"ok"):
                    self.ok += 1
                elif line.startswith(b"error"):
                    self.errors += 1
                elif line.startswith(b"trace"):
                    self.trace += 1
                elif line.startswith(b"t1.sCierres="):
                    self.final += 1

    def stop(self, drain_s: float = 0.5) -> None:
        time.sleep(drain_s)
        self._stop = True
        self.thread.join()


def flood(seconds: float, rate: int) -> dict[str, float]:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    sys.stdout.write(json.dumps({"port": os.ttyname(slave)}) + "\n")
    sys.stdout.flush()
    if sys.stdin.readline().strip() != "go":
        return {}
    pipe = Pipe(master)
    counter = Counter(pipe)
    tick = 0.01
    per_tick = max(1, round(rate * tick))
    chunks = [b"".join(ROUND[(k * per_tick + i) % len(ROUND)] for i in range(per_tick))
              for k in range(len(ROUND))]
    sent = sent_bytes = k = 0
    start = next_t = time.monotonic()
    while time.monotonic() - start < seconds:
        pipe.write(chunks[k % len(chunks)])
        sent += per_tick
        sent_bytes += len(chunks[k % len(chunks)])
        k += 1
        next_t += tick
        time.sleep(max(0.0, next_t - time.monotonic()))
    elapsed = time.monotonic() - start
    # the console still answers on the same line once the flood is over (typed as an
    # operator types: after the line has room again)
    pipe.write_all(b"\x03get t1.sCierres\r\n", 10.0)
    end = time.monotonic() + 10
    while not counter.final and time.monotonic() < end:
        time.sleep(0.01)
    counter.stop()
    answered = counter.final > 0
    pipe.close()
    os.close(slave)
    return {"sent_lines": sent, "sent_bytes": sent_bytes, "dropped_bytes": pipe.dropped,
            "seconds": round(elapsed, 2), "rate": round(sent / elapsed),
            "received_lines": counter.lines, "ok": counter.ok, "errors": counter.errors,
            "answers_after": answered}


def trace(target: str, seconds: float) -> dict[str, float]:
    sock = socket.socket(socket.AF_UNIX)
    sock.connect(target)
    pipe = Pipe(sock=sock)
    counter = Counter(pipe)
    pipe.write(b"trace on\r\n")
    time.sleep(seconds)
    pipe.write(b"\r\n")
    counter.stop()
    pipe.close()
    return {"seconds": seconds, "trace_lines": counter.trace, "received_bytes": counter.bytes}


#: requests a pipelining client keeps in flight
PIPELINE_DEPTH = 32


def connect(address: str) -> socket.socket:
    """A Unix socket path, or 127.0.0.1:PORT."""
    if address.startswith("/"):
        sock = socket.socket(socket.AF_UNIX)
        sock.connect(address)
        return sock
    host, port = address.rsplit(":", 1)
    return socket.create_connection((host, int(port)))


def pipeline(address: str, seconds: float, commands: list[str]) -> dict[str, float]:
    """Send ``commands`` round and round, PIPELINE_DEPTH in flight, for ``seconds``; count
    the replies (their final lines) and how they ended."""
    sock = connect(address)
    sock.setblocking(False)
    sys.stdout.write(json.dumps({"connected": address}) + "\n")
    sys.stdout.flush()
    if sys.stdin.readline().strip() != "go":
        return {}
    wire = [(c + "\r\n").encode() for c in commands]
    sent = replies = ok = refused = errors = 0
    buf = b""
    out = b""
    lost = False
    start = time.monotonic()
    end = start + seconds
    drain_end = end + 10.0
    k = 0
    while True:
        now = time.monotonic()
        if now >= drain_end or (now >= end and replies >= sent):
            break
        while now < end and sent - replies < PIPELINE_DEPTH:
            out += wire[k % len(wire)]
            k += 1
            sent += 1
        rd, wr, _ = select.select([sock], [sock] if out else [], [], 0.05)
        if wr:
            try:
                out = out[sock.send(out):]
            except BlockingIOError:
                pass
        if rd:
            try:
                data: bytes | None = sock.recv(65536)
            except BlockingIOError:
                data = None
            except OSError:
                data = b""
            if data == b"":
                lost = True
                break
            if data is None:
                continue
            buf += data
            *lines, buf = buf.split(b"\n")
            for line in lines:
                if line.startswith(b"ok"):
                    replies += 1
                    ok += 1
                elif line.startswith(b"error too many requests"):
                    replies += 1
                    refused += 1
                elif line.startswith(b"error"):
                    replies += 1
                    errors += 1
    elapsed = time.monotonic() - start
    sock.close()
    return {"sent": sent, "replies": replies, "ok": ok, "refused": refused,
            "errors": errors, "closed_by_server": lost, "seconds": round(elapsed, 2),
            "rate": round(replies / min(elapsed, seconds))}


def main(argv: list[str]) -> int:
    nice = 10
    if argv[0] == "--nice":
        nice, argv = int(argv[1]), argv[2:]
    os.nice(nice)
    if argv[0] == "flood":
        out = flood(float(argv[1]), int(argv[2]) if len(argv) > 2 else 1000)
    elif argv[0] == "pipeline":
        out = pipeline(argv[1], float(argv[2]), argv[3:])
    else:
        out = trace(argv[1], float(argv[2]))
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
