"""``softplc modbus`` beside ``softplc run``, two real processes, read and written by two
Modbus clients that are not ours: pymodbus' client and Debian's mbpoll. Every table read
and compared with what the console says; a writable name written and seen through the
console; a name not writable, an address no name has, half a 32-bit value, a function not
served, another unit: each its exception, nothing written."""

from __future__ import annotations

import re
import socket
import struct
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from tests.modbus.kit import MBPOLL, Rig, mbpoll, mbpoll_values, mbpoll_write, rig
from tests.opcua.feedkit import wait_until

needs_mbpoll = pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (Debian: "
                                                         "mbpoll; scripts/test.sh installs it)")
#: the section's keys beyond kit.write_plant's: an input register, and a 32-bit one
EXTRA = ("  map:\n    tester2.sCierres: IR4\n"
         "    tester1.gsParado.T: {at: IR10, type: UDINT}\n"
         "    tester2.gsParado.T: {at: HR20, type: UDINT}\n")


def client(r: Rig) -> ModbusTcpClient:
    c = ModbusTcpClient("127.0.0.1", port=r.port, timeout=3, retries=0)
    assert c.connect()
    return c


def settle(r: Rig) -> None:
    """Both testers stopped and quiet (stop released, no start), known memory values."""
    r.console("set sim.I0 1", "set sim.I4 1", "set sim.I2 1", "set sim.I7 1",
              "set tester2.sCierres 1234", "set tester1.sCierres 77")
    wait_until(lambda: r.get("tester1.iAbierto") == "1" and r.get("tester2.sCierres") == "1234")
    r.console("set tester1.sParo 0", "set tester2.sParo 0")  # the stop order, released


def test_every_table_as_two_independent_clients_read_it(tmp_path: Path) -> None:
    with rig(tmp_path, EXTRA) as r:
        settle(r)
        names = {"coils": ["tester1.oAbrir", "tester1.oCerrar", "tester1.oParado",
                           "tester1.oTest", "tester2.oAbrir", "tester2.oCerrar",
                           "tester2.oParado", "tester2.oTest", "tester1.sParo"],
                 "inputs": ["tester1.iParo", "tester1.iMarcha", "tester1.iAbierto",
                            "tester1.iCerrado", "tester2.iParo", "tester2.iMarcha",
                            "tester2.iAbierto", "tester2.iCerrado"]}
        want = {k: [int(r.get(n)) for n in v] for k, v in names.items()}
        assert want["inputs"] == [0, 0, 1, 0, 0, 0, 0, 1]  # what settle() pressed
        c = client(r)
        try:
            assert [int(b) for b in c.read_coils(0, count=9, device_id=1).bits[:9]] == \
                want["coils"]
            assert [int(b) for b in c.read_discrete_inputs(0, count=8,
                                                           device_id=1).bits[:8]] == \
                want["inputs"]
            assert c.read_holding_registers(0, count=1, device_id=1).registers == [77]
            assert c.read_input_registers(4, count=1, device_id=1).registers == [1234]
            hi, lo = c.read_input_registers(10, count=2, device_id=1).registers
            t_ms = hi << 16 | lo  # tester1.gsParado.T: ms, high word first
            assert 0 < t_ms < 600_000
            # the unmapped addresses inside a table read 0; past its end, exception 2
            assert c.read_input_registers(0, count=4, device_id=1).registers == [0, 0, 0, 0]
            rr = c.read_input_registers(11, count=2, device_id=1)
            assert rr.isError() and rr.exception_code == 2
        finally:
            c.close()
        if MBPOLL is None:
            pytest.skip("mbpoll not installed: the second client not run")
        out = mbpoll(r.port, "-a", "1", "-t", "0", "-r", "1", "-c", "9").stdout
        assert [int(v) for _, v in sorted(mbpoll_values(out).items())] == want["coils"], out
        out = mbpoll(r.port, "-a", "1", "-t", "1", "-r", "1", "-c", "8").stdout
        assert [int(v) for _, v in sorted(mbpoll_values(out).items())] == want["inputs"], out
        out = mbpoll(r.port, "-a", "1", "-t", "4", "-r", "1", "-c", "1").stdout
        assert mbpoll_values(out) == {1: "77"}, out
        out = mbpoll(r.port, "-a", "1", "-t", "3", "-r", "5", "-c", "1").stdout
        assert mbpoll_values(out) == {5: "1234"}, out
        # a 32-bit value as mbpoll reads one: -B for the high word first
        out = mbpoll(r.port, "-a", "1", "-t", "3:int", "-B", "-r", "11", "-c", "1").stdout
        assert 0 < int(mbpoll_values(out)[11]) < 600_000, out


def test_a_writable_name_written_is_seen_through_the_console(tmp_path: Path) -> None:
    with rig(tmp_path, EXTRA) as r:
        settle(r)
        assert r.get("tester1.sParo") == "0"
        c = client(r)
        try:
            assert not c.write_coil(8, True, device_id=1).isError()  # tester1.sParo
            assert r.get("tester1.sParo") == "1"  # applied before the reply came
            assert not c.write_register(0, 4321, device_id=1).isError()  # tester1.sCierres
            assert r.get("tester1.sCierres") == "4321"
        finally:
            c.close()
        if MBPOLL is not None:
            res = mbpoll_write(r.port, "-a", "1", "-t", "4", "-r", "1", "42")
            assert "Written 1 references" in res.stdout, res.stdout + res.stderr
            assert r.get("tester1.sCierres") == "42"
        wait_until(lambda: "set tester1.sCierres = 4321" in r.server.log(), 10.0,
                   "the server's line")
        assert re.search(r"modbus: 127\.0\.0\.1:\d+ set tester1\.sParo = 1", r.server.log())


def test_every_other_write_gets_its_exception_and_writes_nothing(tmp_path: Path) -> None:
    with rig(tmp_path, EXTRA) as r:
        settle(r)
        before = {n: r.get(n) for n in ("tester1.oAbrir", "tester2.sCierres",
                                         "tester1.sCierres")}
        c = client(r)
        try:
            rr = c.write_coil(0, True, device_id=1)  # tester1.oAbrir: an output
            assert rr.isError() and rr.exception_code == 2
            rr = c.write_registers(20, [0, 1], device_id=1)  # tester2.gsParado.T
            assert rr.isError() and rr.exception_code == 2
            rr = c.write_register(20, 1, device_id=1)  # half of it
            assert rr.isError() and rr.exception_code == 2
            rr = c.write_register(5, 1, device_id=1)  # no name there
            assert rr.isError() and rr.exception_code == 2
            # a run covering a writable name and a name that is not: nothing written
            rr = c.write_registers(0, [5, 6], device_id=1)
            assert rr.isError() and rr.exception_code == 2
        finally:
            c.close()
        assert {n: r.get(n) for n in before} == before
        if MBPOLL is not None:
            res = mbpoll_write(r.port, "-a", "1", "-t", "0", "-r", "1", "1")
            assert "Illegal data address" in res.stdout + res.stderr, res.stdout + res.stderr
        # what pymodbus' client will not send: a function not served (FC 43, read device
        # identification): exception 1; 3000 coils (2000 at most): exception 3
        with socket.create_connection(("127.0.0.1", r.port), timeout=5) as s:
            s.sendall(struct.pack(">HHHB", 7, 0, 4, 1) + bytes((0x2B, 0x0E, 0x01)))
            assert s.recv(64) == struct.pack(">HHHB", 7, 0, 3, 1) + bytes((0xAB, 0x01))
            s.sendall(struct.pack(">HHHBBHH", 8, 0, 6, 1, 1, 0, 3000))
            assert s.recv(64) == struct.pack(">HHHB", 8, 0, 3, 1) + bytes((0x81, 0x03))
        assert r.get("tester1.oAbrir") == before["tester1.oAbrir"]
        wait_until(lambda: "function code 43 is not served" in r.server.log(), 10.0,
                   "the server's line: " + r.server.log())
        assert "tester1.oAbrir is not writable" in r.server.log()


def test_another_unit_and_a_stopped_controller_get_exception_11(tmp_path: Path) -> None:
    with rig(tmp_path, EXTRA + "  unit: 1\n") as r:
        c = client(r)
        try:
            assert not c.read_coils(0, count=1, device_id=1).isError()
            rr = c.read_coils(0, count=1, device_id=2)
            assert rr.isError() and rr.exception_code == 11
            r.ctl.popen.terminate()  # the controller stops: no values, never old ones
            r.ctl.popen.wait(30)

            def refused() -> bool:
                rr = c.read_coils(0, count=1, device_id=1)
                return rr.isError() and rr.exception_code == 11
            wait_until(refused, 20.0, "exception 11 once the controller stopped")
            rr = c.write_coil(8, True, device_id=1)
            assert rr.isError() and rr.exception_code == 11
        finally:
            c.close()
        assert r.server.popen.poll() is None  # it waits for the controller to come back


def test_the_largest_connection_limit_holds_at_the_units_open_file_limit(
        tmp_path: Path) -> None:
    """``softplc modbus`` at its unit's open-file limit (``LimitNOFILE=``) with ``limits:
    connections`` at its largest: that many clients held at once (one of them served),
    the ten beyond closed by the server, no descriptor short (EMFILE: it would stop
    accepting), and once they are gone a new client is served."""
    import os

    from runtime.language.modbusconf import LIMITS
    from tests.web.kit import unit_nofile

    top = LIMITS["connections"].high
    nofile = unit_nofile("softplc-modbus@.service")

    def closed(s: socket.socket) -> bool:
        try:
            return s.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
        except BlockingIOError:
            return False

    with rig(tmp_path, f"  limits: {{connections: {top}}}\n", nofile=nofile) as r:
        held: list[socket.socket] = []
        try:
            for _ in range(top + 10):
                held.append(socket.create_connection(("127.0.0.1", r.port), timeout=10))
                held[-1].setblocking(False)
            wait_until(lambda: sum(map(closed, held)) >= 10, 60.0,
                       "the ten connections beyond the limit closed by the server")
            fds = len(os.listdir(f"/proc/{r.server.popen.pid}/fd"))
            still = [s for s in held if not closed(s)]
            assert (len(still), fds <= nofile) == (top, True), (len(still), fds)
            # one of them is served: read HR0 (MBAP: transaction 7, length 6, unit 1)
            still[-1].settimeout(10)
            still[-1].sendall(struct.pack(">HHHBBHH", 7, 0, 6, 1, 3, 0, 1))
            reply = still[-1].recv(64)
            assert reply[:2] == b"\x00\x07" and reply[7] == 3, reply
        finally:
            for s in held:
                s.close()

        def served() -> bool:
            c = ModbusTcpClient("127.0.0.1", port=r.port, timeout=3, retries=0)
            try:
                return bool(c.connect()) and not c.read_holding_registers(0, count=1).isError()
            finally:
                c.close()
        wait_until(served, 60.0, "a new client served")
        log = r.server.log()
        assert "Too many open files" not in log and r.server.popen.poll() is None, log[-2000:]
        print(f"descriptors at {top} connections: {fds} of {nofile}")  # noqa: T201
