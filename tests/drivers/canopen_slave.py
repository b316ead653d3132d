"""A simulated CiA 401 digital I/O node on a python-can bus, built on canopen's LocalNode.

LocalNode gives the object dictionary and the SDO server; what it leaves out, a real node
does, and so does this simulator:

* PDOs are gated by the NMT state: TPDOs go out and RPDOs are taken only in OPERATIONAL;
* a received RPDO is copied into the object dictionary (0x6200), at once for transmission
  types 254/255, at the next SYNC for synchronous types; synchronous TPDOs go out on SYNC,
  event-driven ones on an input change and on entering OPERATIONAL;
* boot-up: the boot-up message, then PRE-OPERATIONAL, and the first heartbeat only one
  period later, so a master waiting for the boot-up does not race with a heartbeat;
* its own heartbeat producer (0x1017, changeable by SDO), which can be paused;
* power off/on: silence (no SDO, no NMT, no heartbeat), then a cold boot with outputs off;
* a cut cable: the node runs on (state, outputs, inputs that change) but no frame passes
  either way until the cable is mended;
* ``tpdo_on_start=False``: a node that does not send its event-driven TPDOs on entering
  OPERATIONAL (CiA 301 leaves that to the device), so only an SDO read shows its inputs.

``echo`` copies every output byte to the input byte of the same sub-index (a loop-back
for round-trip measurements). Run as a process (for the udp_multicast test)::

    python canopen_slave.py --interface udp_multicast --channel 239.74.163.2 --node 5
"""

from __future__ import annotations

import argparse
import signal
import struct
import sys
import threading
from typing import Any

import canopen
from canopen.objectdictionary import ODRecord, ODVariable
from canopen.objectdictionary.datatypes import UNSIGNED8, UNSIGNED16, UNSIGNED32

Entry = tuple[int, int, int]  # index, sub-index, bits

BOOTUP, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x05, 0x7F


def _var(name: str, index: int, sub: int, dtype: int, default: int, access: str) -> ODVariable:
    v = ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    return v


def cia401_od(node_id: int, tpdos: list[list[Entry]], rpdos: list[list[Entry]],
              in_bytes: int = 8, out_bytes: int = 8, transmission: int = 255,
              heartbeat_ms: int = 0, extra: tuple[int, ...] = ()) -> canopen.ObjectDictionary:
    """Object dictionary of a CiA 401 node: ``in_bytes`` x 8 inputs, ``out_bytes`` x 8
    outputs, PDOs mapped as given (COB-IDs of the predefined connection set)."""
    od = canopen.ObjectDictionary()
    od.add_object(_var("Device type", 0x1000, 0, UNSIGNED32, 0x000F0191, "ro"))
    od.add_object(_var("Producer heartbeat time", 0x1017, 0, UNSIGNED16, heartbeat_ms, "rw"))
    for kind, comm, mapping, base, maps in (("RPDO", 0x1400, 0x1600, 0x200, rpdos),
                                            ("TPDO", 0x1800, 0x1A00, 0x180, tpdos)):
        for n, entries in enumerate(maps):
            rec = ODRecord(f"{kind}{n + 1} communication", comm + n)
            rec.add_member(_var("Highest sub-index", comm + n, 0, UNSIGNED8, 2, "const"))
            rec.add_member(_var("COB-ID", comm + n, 1, UNSIGNED32,
                                base + 0x100 * n + node_id, "rw"))
            rec.add_member(_var("Transmission type", comm + n, 2, UNSIGNED8, transmission,
                                "rw"))
            od.add_object(rec)
            rec = ODRecord(f"{kind}{n + 1} mapping", mapping + n)
            rec.add_member(_var("Count", mapping + n, 0, UNSIGNED8, len(entries), "rw"))
            for i in range(8):
                idx, sub, bits = entries[i] if i < len(entries) else (0, 0, 0)
                rec.add_member(_var(f"Entry {i + 1}", mapping + n, i + 1, UNSIGNED32,
                                    idx << 16 | sub << 8 | bits, "rw"))
            od.add_object(rec)
    for index, count, access, name in ((0x6000, in_bytes, "ro", "Read input 8-bit"),
                                       (0x6200, out_bytes, "rw", "Write output 8-bit")):
        rec = ODRecord(name, index)
        rec.add_member(_var("Count", index, 0, UNSIGNED8, count, "ro"))
        for sub in range(1, count + 1):
            rec.add_member(_var(f"{name} {sub}", index, sub, UNSIGNED8, 0, access))
        od.add_object(rec)
    for index in extra:  # e.g. an analogue value mapped next to the digital bytes
        od.add_object(_var(f"Extra 0x{index:04X}", index, 0, UNSIGNED16, 0, "rw"))
    return od


class Cia401Slave:
    """One simulated node. ``start()``, then drive inputs, read outputs; ``stop()``."""

    #: heartbeat period used when 0x1017 is 0 but a test wants beats anyway, seconds
    IDLE_WAIT_S = 0.02

    def __init__(self, node_id: int = 5, *, interface: str = "virtual", channel: str = "test",
                 tpdos: list[list[Entry]] | None = None, rpdos: list[list[Entry]] | None = None,
                 transmission: int = 255, heartbeat_ms: int = 0, echo: bool = False,
                 extra: tuple[int, ...] = (), tpdo_on_start: bool = True,
                 **bus_kwargs: Any) -> None:
        self.node_id = node_id
        self.tpdos = tpdos if tpdos is not None else [[(0x6000, 1, 8), (0x6000, 2, 8)]]
        self.rpdos = rpdos if rpdos is not None else [[(0x6200, 1, 8), (0x6200, 2, 8)]]
        self.od = cia401_od(node_id, self.tpdos, self.rpdos, transmission=transmission,
                            heartbeat_ms=heartbeat_ms, extra=extra)
        self.echo = echo
        self.tpdo_on_start = tpdo_on_start
        #: the cable is cut: nothing sent, nothing received (see cut_cable)
        self.cut = False
        self.bus_kwargs = {"interface": interface, "channel": channel, **bus_kwargs}
        self.powered = False
        #: stop sending heartbeats while otherwise alive (a heartbeat-only loss)
        self.heartbeat_paused = False
        #: NMT commands received (command, node) and SYNCs seen
        self.nmt_log: list[int] = []
        self.syncs = 0
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05
        self.node = canopen.LocalNode(node_id, self.od)
        self._pending_rpdo: dict[int, bytes] = {}
        self._lock = threading.RLock()
        self._hb_stop = threading.Event()
        self._hb_kick = threading.Event()
        self._hb_thread: threading.Thread | None = None

    # -- life -------------------------------------------------------------------------
    def start(self) -> Cia401Slave:
        self.network.connect(**self.bus_kwargs)
        self.network.add_node(self.node)
        # our own heartbeat producer replaces NmtSlave's
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_write)
        self.network.subscribe(0, self._on_nmt)  # after NmtSlave.on_command
        self.network.subscribe(0x80, self._on_sync)
        for n in range(len(self.rpdos)):
            self.network.subscribe(self._cob(0x1400 + n), self._on_rpdo)
        self._hb_thread = threading.Thread(target=self._heartbeats, daemon=True,
                                           name=f"cia401 node {self.node_id} heartbeat")
        self._hb_thread.start()
        self.power_on()
        return self

    def stop(self) -> None:
        self.power_off()
        self._hb_stop.set()
        self._hb_kick.set()
        if self._hb_thread is not None:
            self._hb_thread.join()
            self._hb_thread = None
        self.network.disconnect()

    def __enter__(self) -> Cia401Slave:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def power_off(self) -> None:
        with self._lock:
            if not self.powered:
                return
            self.powered = False
            if not self.cut:
                self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)

    def power_on(self) -> None:
        """Cold boot: outputs off, boot-up message, PRE-OPERATIONAL."""
        with self._lock:
            if not self.powered and not self.cut:
                self.network.subscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
            self.powered = True
            self.node.data_store.pop(0x6200, None)
            self.node.data_store.pop(0x1017, None)
            self._boot()

    def cut_cable(self) -> None:
        """The node runs on, but no frame reaches it or leaves it."""
        with self._lock:
            self.cut = True
            self.network.unsubscribe(0, self.node.nmt.on_command)
            if self.powered:
                self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)

    def mend_cable(self) -> None:
        with self._lock:
            self.cut = False
            self.network.unsubscribe(0, self._on_nmt)  # keep NmtSlave's callback first
            self.network.subscribe(0, self.node.nmt.on_command)
            self.network.subscribe(0, self._on_nmt)
            if self.powered:
                self.network.subscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)

    def _send(self, can_id: int, data: bytes) -> None:
        if not self.cut:
            self.network.send_message(can_id, data)

    def _boot(self) -> None:
        self._pending_rpdo.clear()
        self.node.nmt._state = BOOTUP
        self._send(0x700 + self.node_id, bytes([BOOTUP]))
        self.node.nmt._state = PRE_OPERATIONAL
        self._hb_kick.set()  # restart the period: first heartbeat one period after boot-up

    def drain(self, network: canopen.Network, timeout: float = 3.0) -> None:
        """Wait until ``network`` (the master's) has handled every frame sent so far: a
        marker frame goes out behind them on the same bus."""
        seen = threading.Event()
        network.subscribe(0x7F0, lambda *_: seen.set())
        self.network.send_message(0x7F0, b"")
        try:
            if not seen.wait(timeout):
                raise TimeoutError("the master's receive thread did not keep up")
        finally:
            network.unsubscribe(0x7F0)

    @property
    def state(self) -> int:
        return int(self.node.nmt._state)

    # -- process image --------------------------------------------------------------
    def _u(self, index: int, sub: int) -> int:
        return int.from_bytes(self.node.get_data(index, sub), "little")

    def set_input(self, n: int, value: int) -> None:
        """Drive input ``n`` (0-63): bit n % 8 of 0x6000 sub n // 8 + 1."""
        with self._lock:
            sub = n // 8 + 1
            byte = self._u(0x6000, sub)
            byte = byte | (1 << n % 8) if value else byte & ~(1 << n % 8)
            self.node.set_data(0x6000, sub, bytes([byte]))
            self._send_tpdos(event=True, only_sub=sub)

    def input(self, n: int) -> int:
        return (self._u(0x6000, n // 8 + 1) >> n % 8) & 1

    def output(self, n: int) -> int:
        """Output ``n`` (0-63) as the node drives it now."""
        return (self._u(0x6200, n // 8 + 1) >> n % 8) & 1

    # -- protocol -----------------------------------------------------------------------
    def _cob(self, comm: int) -> int:
        return self._u(comm, 1) & 0x7FF

    def _entries(self, mapping: int) -> list[Entry]:
        out = []
        for sub in range(1, self._u(mapping, 0) + 1):
            raw = self._u(mapping, sub)
            out.append((raw >> 16, raw >> 8 & 0xFF, raw & 0xFF))
        return out

    def _send_tpdos(self, event: bool, only_sub: int | None = None) -> None:
        if not self.powered or self.state != OPERATIONAL:
            return
        for n in range(len(self.tpdos)):
            sync_type = self._u(0x1800 + n, 2) <= 240
            if event == sync_type:
                continue
            entries = self._entries(0x1A00 + n)
            if only_sub is not None and (0x6000, only_sub, 8) not in entries:
                continue
            data = b"".join(self.node.get_data(i, s)[: b // 8] for i, s, b in entries)
            self._send(self._cob(0x1800 + n), data)

    def _apply_rpdo(self, n: int, data: bytes) -> None:
        offset = 0
        for index, sub, bits in self._entries(0x1600 + n):
            chunk = bytes(data[offset // 8: offset // 8 + bits // 8])
            self.node.set_data(index, sub, chunk)
            offset += bits
            if self.echo and index == 0x6200:
                self.node.set_data(0x6000, sub, chunk)
        if self.echo:
            self._send_tpdos(event=True)

    def _on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self.cut or not self.powered or self.state != OPERATIONAL:
                return
            for n in range(len(self.rpdos)):
                if self._cob(0x1400 + n) == can_id:
                    if self._u(0x1400 + n, 2) <= 240:
                        self._pending_rpdo[n] = bytes(data)  # applied at the next SYNC
                    else:
                        self._apply_rpdo(n, bytes(data))

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self.cut or not self.powered or self.state != OPERATIONAL:
                return
            self.syncs += 1
            pending, self._pending_rpdo = self._pending_rpdo, {}
            for n, payload in pending.items():
                self._apply_rpdo(n, payload)
            self._send_tpdos(event=False)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        command, node = data[0], data[1]
        with self._lock:
            if self.cut or not self.powered or node not in (0, self.node_id):
                return
            self.nmt_log.append(command)
            if command in (0x81, 0x82):  # reset node / reset communication
                if command == 0x81:
                    self.node.data_store.pop(0x6200, None)
                self._boot()
            elif command == 0x01 and self.tpdo_on_start:
                self._send_tpdos(event=True)  # event-driven TPDOs on entering OPERATIONAL
            self._hb_kick.set()

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if index == 0x1017:
            self._hb_kick.set()

    def _heartbeats(self) -> None:
        period = 0.0
        while not self._hb_stop.is_set():
            kicked = self._hb_kick.wait(period if period > 0 else self.IDLE_WAIT_S)
            if kicked:
                self._hb_kick.clear()
            with self._lock:
                ms = struct.unpack("<H", self.node.get_data(0x1017, 0))[0]
                period = ms / 1000.0
                if kicked or ms == 0 or not self.powered or self.heartbeat_paused:
                    continue
                try:
                    self._send(0x700 + self.node_id, bytes([self.state]))
                except Exception:  # the bus went away while stopping
                    if not self._hb_stop.is_set():
                        raise


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--interface", default="udp_multicast")
    ap.add_argument("--channel", default="239.74.163.2")
    ap.add_argument("--node", type=int, default=5)
    ap.add_argument("--echo", action="store_true")
    args = ap.parse_args(argv)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    slave = Cia401Slave(args.node, interface=args.interface, channel=args.channel,
                        echo=args.echo).start()
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    done.wait()
    slave.stop()


if __name__ == "__main__":
    main()
