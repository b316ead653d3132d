"""Hostile Modbus/TCP clients, in a process of their own (their work never shares the
controller's interpreter), against ``softplc modbus`` on 127.0.0.1:PORT::

    python -m tests.modbus.attacker PORT SECONDS

At once, each in its thread: a header with another protocol id, a length past 253, a
length that announces more than is sent, 200 requests of function codes the server does
not serve, FLOODERS clients asking as fast as they can (more than the server's rate), a
client that never reads its replies (of 2000 coils each: the plant maps one at Q1999), and
a well-behaved panel polling 10 coils every 100 ms. Prints one JSON object: what each
saw."""

from __future__ import annotations

import json
import socket
import struct
import sys
import threading
import time
from typing import Any

from drivers.modbus_frame import mbap_frame, read_pdu

#: clients that flood
FLOODERS = 5
#: how long a closed connection may take to be seen, seconds (the server's frame timeout
#: is 5 s)
CLOSE_WAIT_S = 15.0


def connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=CLOSE_WAIT_S)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def closed_by_server(s: socket.socket) -> bool:
    """Whether the server closes ``s`` (EOF or reset) within CLOSE_WAIT_S."""
    try:
        while True:
            if not s.recv(4096):
                return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except TimeoutError:
        return False


def bad_protocol(port: int) -> bool:
    with connect(port) as s:
        s.sendall(struct.pack(">HHHB", 1, 0x1234, 6, 1) + read_pdu(1, 0, 1))
        return closed_by_server(s)


def length_too_long(port: int) -> bool:
    with connect(port) as s:
        s.sendall(struct.pack(">HHHB", 2, 0, 1000, 1) + read_pdu(1, 0, 1))
        return closed_by_server(s)


def length_that_lies(port: int) -> bool:
    """200 bytes announced, 5 sent, then nothing."""
    with connect(port) as s:
        s.sendall(struct.pack(">HHHB", 3, 0, 201, 1) + read_pdu(1, 0, 1))
        return closed_by_server(s)


def unserved(port: int) -> list[int]:
    """200 requests of FC 43 and FC 8: the exception codes answered (expected all 1)."""
    codes = []
    with connect(port) as s:
        f = s.makefile("rb")
        for k in range(200):
            fc = 0x2B if k % 2 else 0x08
            s.sendall(mbap_frame(k, 1, bytes((fc, 0, 0, 0, 0))))
            head = f.read(7)
            body = f.read(struct.unpack(">H", head[4:6])[0] - 1)
            codes.append(body[1] if body[0] & 0x80 else -1)
    return codes


def flood(port: int, seconds: float, out: list[int]) -> None:
    """Read 10 coils back to back for ``seconds``; the answers counted into ``out``."""
    n = 0
    with connect(port) as s:
        f = s.makefile("rb")
        end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < end:
            k = (k + 1) & 0xFFFF
            s.sendall(mbap_frame(k, 1, read_pdu(1, 0, 10)))
            head = f.read(7)
            if len(head) < 7:
                break
            f.read(struct.unpack(">H", head[4:6])[0] - 1)
            n += 1
    out.append(n)


def never_reads(port: int) -> bool:
    """Requests of 2000 coils sent and sent, no reply ever read: the server closes."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.settimeout(CLOSE_WAIT_S * 4)
    s.connect(("127.0.0.1", port))
    request = mbap_frame(9, 1, read_pdu(1, 0, 2000))  # a 257-byte reply each
    try:
        deadline = time.monotonic() + CLOSE_WAIT_S * 4
        while time.monotonic() < deadline:
            s.sendall(request * 16)
    except (ConnectionResetError, BrokenPipeError):
        return True
    except TimeoutError:
        return False
    finally:
        s.close()
    return False


def panel(port: int, stop: threading.Event, out: dict[str, Any]) -> None:
    """10 coils every 100 ms, as a panel polls: answers, failures, the slowest answer."""
    ok = failed = 0
    worst = 0.0
    codes: set[int] = set()
    with connect(port) as s:
        f = s.makefile("rb")
        k = 0
        while not stop.is_set():
            k = (k + 1) & 0xFFFF
            t0 = time.monotonic()
            try:
                s.sendall(mbap_frame(k, 1, read_pdu(1, 0, 10)))
                head = f.read(7)
                body = f.read(struct.unpack(">H", head[4:6])[0] - 1)
                if body[0] == 1:
                    ok += 1
                else:
                    failed += 1
                    codes.add(body[1])
            except (OSError, struct.error):
                failed += 1
                break
            worst = max(worst, time.monotonic() - t0)
            stop.wait(0.1)
    out.update({"panel_ok": ok, "panel_failed": failed, "panel_codes": sorted(codes),
                "panel_worst_s": round(worst, 3)})


def main() -> None:
    port, seconds = int(sys.argv[1]), float(sys.argv[2])
    result: dict[str, Any] = {}
    counts: list[int] = []
    stop = threading.Event()
    jobs: dict[str, threading.Thread] = {}

    def job(name: str, fn: Any, *args: Any) -> None:
        def run() -> None:
            result[name] = fn(*args)
        jobs[name] = threading.Thread(target=run, daemon=True)
        jobs[name].start()
    keeper = threading.Thread(target=panel, args=(port, stop, result), daemon=True)
    keeper.start()
    t0 = time.monotonic()
    for k in range(FLOODERS):
        jobs[f"flood{k}"] = threading.Thread(target=flood, args=(port, seconds, counts),
                                             daemon=True)
        jobs[f"flood{k}"].start()
    job("bad_protocol", bad_protocol, port)
    job("length_too_long", length_too_long, port)
    job("length_that_lies", length_that_lies, port)
    job("unserved", unserved, port)
    job("never_reads", never_reads, port)
    for t in jobs.values():
        t.join(seconds + CLOSE_WAIT_S * 5)
    flood_s = max(seconds, 1e-9)
    stop.set()
    keeper.join(5)
    result["flood_requests"] = counts
    result["flood_rate"] = round(sum(counts) / flood_s)
    result["elapsed_s"] = round(time.monotonic() - t0, 1)
    unserved_codes = result.pop("unserved", [])
    result["unserved_answers"] = len(unserved_codes)
    result["unserved_codes"] = sorted(set(unserved_codes))
    sys.stdout.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
