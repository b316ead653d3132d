"""CANopen CiA 401 digital I/O node (``canopen`` over python-can).

The driver is the node's NMT master and heartbeat consumer:

* the PDO mapping is read from the node by SDO (TPDO/RPDO communication and mapping
  objects 0x1800/0x1A00 and 0x1400/0x1600), or taken from the EDS/DCF given as ``eds``,
  or from ``pdo:`` in the config (then the mapping needs no SDO read);
* the node's producer heartbeat time (0x1017) is set to a quarter of our ``heartbeat``
  timeout if it is off or too slow for it;
* NMT start; then the TPDOs (inputs, 0x6000) are received by python-can's receive thread
  and the RPDOs (outputs, 0x6200) sent by the scan's ``write()``: every cycle, or, when
  ``sync`` is configured, on change only, while a SYNC producer runs at that period (the
  node's PDO transmission types decide what it does on SYNC);
* after NMT start, the bound input bytes (0x6000) are read once by SDO, so the input image
  is right at once whether or not the node sends its TPDOs on entering OPERATIONAL (a
  TPDO that comes meanwhile is newer and wins);
* our own heartbeat consumer: the age of the node's last heartbeat on the monotonic
  clock; older than ``heartbeat``, a boot-up, or any state but OPERATIONAL means the node
  is lost (fault). Recovery is always a restart by the background configuration thread at
  the next back-off time (NMT start, inputs read again: TPDOs may have been lost with the
  heartbeats), so the scan never waits for an SDO.

Points ``I0``-``I63`` (0x6000 sub 1 bit 0 is I0, sub 2 bit 0 is I8, ...), ``Q0``-``Q63``
(0x6200 likewise). Config::

    rio: {type: canopen, interface: socketcan, channel: can0, bitrate: 250000, node: 5,
          heartbeat: 500ms, sync: 10ms}
    # the node's mapping given, COB-IDs of the predefined connection set
    rio2: {type: canopen, channel: can0, node: 6,
           pdo: {tpdo1: ["6000:1", "6000:2"], rpdo1: ["6200:1"]}}
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from drivers.base import DriverError, PolledDriver
from drivers.registry import CANOPEN_KEYS, PdoEntry, pdo_config

log = logging.getLogger(__name__)

DIGITAL_INPUTS = 0x6000
DIGITAL_OUTPUTS = 0x6200
TPDO_COMM, TPDO_MAP, RPDO_COMM, RPDO_MAP = 0x1800, 0x1A00, 0x1400, 0x1600
PRODUCER_HEARTBEAT = 0x1017
#: COB-ID bit 31: PDO not valid
PDO_NOT_VALID = 1 << 31
#: NMT states as carried by heartbeats
BOOTUP, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F
NMT_STATE_NAMES = {BOOTUP: "boot-up", STOPPED: "STOPPED", OPERATIONAL: "OPERATIONAL",
                   PRE_OPERATIONAL: "PRE-OPERATIONAL"}
NMT_START = 0x01

__all__ = ["CanopenDriver", "PdoEntry"]


@dataclass
class Pdo:
    """One PDO: its COB-ID and mapped objects, and which points sit at which bits."""

    name: str  # "TPDO1", "RPDO2"
    cob_id: int
    entries: list[PdoEntry]
    #: (byte, bit, point) of every bound point it carries
    bits: list[tuple[int, int, str]] = field(default_factory=list)

    @property
    def length(self) -> int:
        return (sum(e.bits for e in self.entries) + 7) // 8

    def __str__(self) -> str:
        mapped = " ".join(f"{e.index:04X}:{e.subindex:02X}" for e in self.entries)
        return f"{self.name} 0x{self.cob_id:03X} [{mapped}]"


@dataclass(frozen=True)
class CanopenConfig:
    """A canopen driver's configuration, as checked by its declaration (CANOPEN_KEYS, which
    holds the defaults and ranges), with the ``pdo`` mapping parsed."""

    node: int
    interface: str
    channel: str
    bitrate: int | None
    heartbeat_s: float
    eds: str | None
    sync_s: float | None
    tpdos: list[list[PdoEntry]] | None
    rpdos: list[list[PdoEntry]] | None

    @classmethod
    def from_params(cls, name: str, params: Mapping[str, Any]) -> CanopenConfig:
        """From driver ``name``'s ``params``, checked by ``ConfigKeys.validate`` (the ``pdo``
        mapping too)."""
        tpdos = rpdos = None
        if params["pdo"] is not None:
            tpdos, rpdos = pdo_config(params["pdo"])
        return cls(params["node"], params["interface"], str(params["channel"]),
                   params["bitrate"], params["heartbeat"], params["eds"], params["sync"],
                   tpdos, rpdos)



def _u(data: bytes) -> int:
    return int.from_bytes(data, "little")


class CanopenDriver(PolledDriver):
    """One CiA 401 node; inputs by TPDO callbacks, outputs by RPDO from the scan."""

    type_name = "canopen"
    config_keys = CANOPEN_KEYS
    ONE_DIRECTION_PER_POINT = True
    STALE_AFTER_S = None  # TPDOs are sent on change: old inputs are not stale
    #: node loss is watched every scan; a returning node is started at most this often, s
    RECONNECT_MAX_S = 1.0
    #: longest a python-can receive thread blocks, seconds (bounds close())
    NOTIFIER_CYCLE_S = 0.05
    #: PDOs looked for when the mapping is read from the node (1..MAX_PDOS)
    MAX_PDOS = 8
    #: seconds to wait for the configuration thread to end on close
    JOIN_TIMEOUT_S = 5.0

    def _init(self) -> None:
        super()._init()
        self.cfg = CanopenConfig.from_params(self.name, self.params)
        self.first_data_timeout_s = max(self.FIRST_DATA_TIMEOUT_S, 3 * self.cfg.heartbeat_s)
        self._network: canopen.Network | None = None
        self._node: canopen.RemoteNode | None = None
        self._tpdos: list[Pdo] | None = None
        self._rpdos: list[Pdo] = []
        self._hb_lock = threading.Condition()
        self._hb_ns: int | None = None  # clock() at the last heartbeat
        self._hb_state: int | None = None
        #: True from a successful (re)start until the node is seen lost
        self._configured = False
        #: orders TPDO decoding against the SDO read of the inputs after a start
        self._tpdo_lock = threading.Lock()
        #: points set by TPDOs since the SDO read of the inputs began (None: not reading)
        self._tpdo_touched: set[str] | None = None
        self._configurator: threading.Thread | None = None
        self._sent: dict[int, bytes] = {}
        self._send_all = True
        self._stopping = False
        self._bus_dead = False
        #: how many times the node was (re)started with NMT
        self.starts = 0

    def _where(self) -> str:
        return f"node {self.cfg.node} on {self.cfg.interface}:{self.cfg.channel}"

    # -- start and stop (PolledDriver hooks) --------------------------------------------
    def _start(self) -> None:
        cfg = self.cfg
        network = canopen.Network()
        network.NOTIFIER_CYCLE = self.NOTIFIER_CYCLE_S
        kwargs: dict[str, Any] = {"interface": cfg.interface, "channel": cfg.channel}
        if cfg.bitrate is not None:
            kwargs["bitrate"] = cfg.bitrate
        try:
            network.connect(**kwargs)
        except (can.CanError, OSError, ValueError) as exc:
            raise DriverError(f"{self._where()}: cannot open the bus: {exc}") from exc
        self._network = network
        od = canopen.ObjectDictionary()  # type: ignore[no-untyped-call]
        if cfg.eds is not None:
            try:
                od = canopen.import_od(cfg.eds, cfg.node)
            except (OSError, ValueError) as exc:
                self._stop()
                raise DriverError(f"{self._where()}: cannot read eds {cfg.eds}: {exc}") from exc
        self._node = canopen.RemoteNode(cfg.node, od)
        network.add_node(self._node)
        network.subscribe(0x700 + cfg.node, self._on_heartbeat)
        self._stopping = False
        self._start_configurator()

    def _stop(self) -> None:
        self._stopping = True
        with self._hb_lock:
            self._hb_lock.notify_all()
        thread, self._configurator = self._configurator, None
        if thread is not None:
            thread.join(self.JOIN_TIMEOUT_S)
        network, self._network = self._network, None
        self._node = None
        self._configured = False
        if network is not None:
            try:
                if self.cfg.sync_s is not None:
                    network.sync.stop()  # type: ignore[no-untyped-call]
                network.disconnect()  # also re-raises a stored receive-thread error
            except Exception as exc:  # best effort on shutdown: the error was reported
                log.warning("driver %s: disconnect: %s", self.name, exc)

    def _retry(self) -> None:
        if self._configurator is not None and self._configurator.is_alive():
            return  # the last attempt is still running: never wait for it in the scan
        if self._bus_dead or self._network is None:  # receiving stopped: a new connection
            self._stop()
            self._bus_dead = False
            self._start()
        else:
            self._start_configurator()

    def _start_configurator(self) -> None:
        if self._configurator is not None:
            if self._configurator.is_alive():
                return
            self._configurator.join()
        self._configurator = threading.Thread(target=self._configure, daemon=True,
                                              name=f"canopen {self.name} configure")
        self._configurator.start()

    # -- configuration thread ---------------------------------------------------------
    def _configure(self) -> None:
        """Mapping (once), heartbeat producer, NMT start, wait for OPERATIONAL, inputs read.

        A failure is reported as the driver's fault reason (the scan logs it once, on the
        change to FAULT); the scan asks for another attempt at its back-off times."""
        try:
            if self._tpdos is None:
                self._tpdos, self._rpdos = self._read_layout()
            self._subscribe()
            self._set_producer_heartbeat()
            self._nmt_start()
            self._read_inputs()
            self._send_all = True
            self._configured = True
            self.report_ok()
            return
        except DriverError as exc:
            reason = str(exc)
        except (SdoCommunicationError, SdoAbortedError, can.CanError, OSError) as exc:
            reason = f"{self._where()}: {exc}"
        except BaseException as exc:  # a bug: re-raised in the scan thread
            log.exception("driver %s: configuration failed", self.name)
            self.report_error(exc)
            return
        self.report_fault(reason)

    def _read_layout(self) -> tuple[list[Pdo], list[Pdo]]:
        cfg = self.cfg
        if cfg.tpdos is not None and cfg.rpdos is not None:
            tp = [Pdo(f"TPDO{n + 1}", 0x180 + 0x100 * n + cfg.node, e)
                  for n, e in enumerate(cfg.tpdos) if e]
            rp = [Pdo(f"RPDO{n + 1}", 0x200 + 0x100 * n + cfg.node, e)
                  for n, e in enumerate(cfg.rpdos) if e]
        elif cfg.eds is not None:
            tp, rp = self._layout_from(self._od_value, "EDS " + cfg.eds)
        else:
            tp, rp = self._layout_from(self._sdo_value, "SDO")
        self._assign_points(tp, DIGITAL_INPUTS, "I", self.inputs, "TPDO")
        self._assign_points(rp, DIGITAL_OUTPUTS, "Q", self.outputs, "RPDO")
        for pdo in rp:
            others = [e for e in pdo.entries if e.index != DIGITAL_OUTPUTS]
            if pdo.bits and others:
                log.warning("driver %s: %s of node %d also maps %s: written as 0", self.name,
                            pdo.name, cfg.node,
                            ", ".join(f"{e.index:04X}:{e.subindex:02X}" for e in others))
        log.info("driver %s: %s", self.name, ", ".join(str(p) for p in tp + rp))
        return tp, rp

    def _sdo_value(self, index: int, subindex: int) -> int | None:
        assert self._node is not None
        try:
            return _u(self._node.sdo.upload(index, subindex))
        except SdoAbortedError as exc:
            if exc.code in (0x06020000, 0x06090011):  # object / sub-index does not exist
                return None
            raise

    def _od_value(self, index: int, subindex: int) -> int | None:
        assert self._node is not None
        od = self._node.object_dictionary
        try:
            obj = od[index]
            var = obj if isinstance(obj, ODVariable) else obj[subindex]
        except KeyError:
            return None
        if isinstance(obj, ODVariable) and subindex != 0:
            return None
        value = var.value if var.value is not None else var.default
        return None if value is None else int(value)

    def _layout_from(self, get: Callable[[int, int], int | None],
                     source: str) -> tuple[list[Pdo], list[Pdo]]:
        out: tuple[list[Pdo], list[Pdo]] = ([], [])
        for kind, comm, mapping, layout in (("TPDO", TPDO_COMM, TPDO_MAP, out[0]),
                                            ("RPDO", RPDO_COMM, RPDO_MAP, out[1])):
            for n in range(self.MAX_PDOS):
                cob = get(comm + n, 1)
                if cob is None:
                    break
                if cob & PDO_NOT_VALID:
                    continue
                count = get(mapping + n, 0) or 0
                entries = []
                for sub in range(1, count + 1):
                    raw = get(mapping + n, sub) or 0
                    entries.append(PdoEntry(raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF))
                layout.append(Pdo(f"{kind}{n + 1}", cob & 0x7FF, entries))
        log.debug("driver %s: PDO mapping read by %s", self.name, source)
        return out

    def _assign_points(self, pdos: list[Pdo], index: int, prefix: str,
                       bound: Mapping[str, Any], kind: str) -> None:
        where: dict[str, tuple[int, int, Pdo]] = {}
        for pdo in pdos:
            offset = 0
            for e in pdo.entries:
                if e.index == index and e.bits == 8 and e.subindex >= 1:
                    for bit in range(8):
                        where[f"{prefix}{(e.subindex - 1) * 8 + bit}"] = (offset // 8, bit, pdo)
                offset += e.bits
        for point in bound:
            if point not in where:
                sub = int(point[1:]) // 8 + 1
                raise DriverError(f"{self._where()}: {point} ({index:04X}:{sub:02X}) is mapped "
                                  f"in no enabled {kind}")
            byte, bit, pdo = where[point]
            pdo.bits.append((byte, bit, point))

    def _subscribe(self) -> None:
        assert self._network is not None and self._tpdos is not None
        for pdo in self._tpdos:
            if pdo.bits:
                self._network.subscribe(pdo.cob_id, self._on_tpdo)

    def _set_producer_heartbeat(self) -> None:
        assert self._node is not None
        want_ms = max(1, int(self.cfg.heartbeat_s * 1000 / 4))
        try:
            have = _u(self._node.sdo.upload(PRODUCER_HEARTBEAT, 0))
            if have == 0 or have > self.cfg.heartbeat_s * 1000 / 2:
                self._node.sdo.download(PRODUCER_HEARTBEAT, 0, struct.pack("<H", want_ms))
                log.info("driver %s: node %d producer heartbeat %d -> %d ms", self.name,
                         self.cfg.node, have, want_ms)
        except SdoAbortedError as exc:
            log.warning("driver %s: node %d heartbeat producer not set: %s", self.name,
                        self.cfg.node, exc)

    def _nmt_start(self) -> None:
        """NMT start, then wait for a heartbeat that says OPERATIONAL."""
        network = self._network
        assert network is not None
        with self._hb_lock:
            self._hb_state = None
        network.send_message(0, bytes((NMT_START, self.cfg.node)))
        self.starts += 1
        deadline = time.monotonic() + 2 * self.cfg.heartbeat_s
        with self._hb_lock:
            while self._hb_state != OPERATIONAL:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stopping:
                    raise DriverError(f"{self._where()}: no heartbeat in OPERATIONAL within "
                                      f"{2 * self.cfg.heartbeat_s * 1000:.0f} ms of NMT start")
                self._hb_lock.wait(remaining)
        if self.cfg.sync_s is not None:
            network.sync.stop()
            network.sync.start(self.cfg.sync_s)

    def _read_inputs(self) -> None:
        """Read the bound input bytes (0x6000) by SDO and publish them, except points a TPDO
        set meanwhile (newer). An object the node refuses leaves its points to the TPDOs."""
        node = self._node
        assert node is not None
        by_sub: dict[int, list[str]] = {}
        for point in self.inputs:
            by_sub.setdefault(int(point[1:]) // 8 + 1, []).append(point)
        if not by_sub:
            return
        with self._tpdo_lock:
            self._tpdo_touched = set()
        values: dict[str, int] = {}
        try:
            for sub, points in sorted(by_sub.items()):
                try:
                    byte = _u(node.sdo.upload(DIGITAL_INPUTS, sub))
                except SdoAbortedError as exc:
                    log.warning("driver %s: inputs %s not read by SDO (%s): known at the "
                                "next TPDO", self.name, ", ".join(points), exc)
                    continue
                for point in points:
                    values[point] = (byte >> int(point[1:]) % 8) & 1
        finally:
            with self._tpdo_lock:
                touched, self._tpdo_touched = self._tpdo_touched or set(), None
                fresh = {p: v for p, v in values.items() if p not in touched}
                if fresh:
                    self.publish_inputs(fresh, ok=False)

    # -- receive thread -----------------------------------------------------------------
    # canopen logs and swallows a callback's exception: ours hand it to the scan thread
    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            state = data[0] & 0x7F if data else BOOTUP
            with self._hb_lock:
                self._hb_ns = self.clock()
                self._hb_state = state
                self._hb_lock.notify_all()
        except BaseException as exc:
            self.report_error(exc)

    def _on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            self._decode_tpdo(can_id, data)
        except BaseException as exc:
            self.report_error(exc)

    def _decode_tpdo(self, can_id: int, data: bytearray) -> None:
        assert self._tpdos is not None
        for pdo in self._tpdos:
            if pdo.cob_id == can_id:
                if len(data) < pdo.length:
                    log.warning("driver %s: %s of %d bytes, expected %d", self.name, pdo.name,
                                len(data), pdo.length)
                    return
                values = {point: (data[byte] >> bit) & 1 for byte, bit, point in pdo.bits}
                with self._tpdo_lock:
                    if self._tpdo_touched is not None:
                        self._tpdo_touched.update(values)
                    self.publish_inputs(values, ok=False)

    # -- scan thread ------------------------------------------------------------------------
    def _check(self) -> None:
        network = self._network
        error = network.notifier.exception if network and network.notifier else None
        if error is not None:
            if isinstance(error, (can.CanError, OSError)):
                self._bus_dead = True
                raise DriverError(f"{self._where()}: receiving stopped: {error}")
            raise error  # a bug in the receive thread
        with self._hb_lock:
            hb_ns, state = self._hb_ns, self._hb_state
        timeout_ns = self.cfg.heartbeat_s * 1e9
        lost: str | None = None
        if hb_ns is None or self.clock() - hb_ns > timeout_ns:
            age = "none" if hb_ns is None else f"none for {(self.clock() - hb_ns) / 1e6:.0f} ms"
            lost = f"heartbeat lost ({age}, timeout {timeout_ns / 1e6:.0f} ms)"
        elif state is None:
            lost = "node being started"
        elif state != OPERATIONAL:
            name = NMT_STATE_NAMES.get(state) or f"in NMT state 0x{state:02X}"
            lost = f"node is {name}, not OPERATIONAL"
        if self._configured:
            if lost is None:
                return
            # lost: only a restart (NMT start, inputs read again) makes it OK again
            self._configured = False
            raise DriverError(f"{self._where()}: {lost}")
        raise DriverError(f"{self._where()}: {lost or 'node back, being started again'}")

    def _write(self) -> None:
        network = self._network
        if network is None or not self._configured:
            return
        send_all, self._send_all = self._send_all, False
        if self.cfg.sync_s is None:
            send_all = True  # every cycle
        index, vals = self.outputs.index, self.outputs.vals  # by position: no call per point
        for pdo in self._rpdos:
            if not pdo.bits:
                continue
            data = bytearray(pdo.length)
            for byte, bit, point in pdo.bits:
                i = index.get(point)
                if i is not None and vals[i]:
                    data[byte] |= 1 << bit
            payload = bytes(data)
            if send_all or self._sent.get(pdo.cob_id) != payload:
                try:
                    network.send_message(pdo.cob_id, payload)
                except can.CanError as exc:
                    self._send_all = True
                    raise DriverError(f"{self._where()}: {pdo.name} not sent: {exc}") from exc
                self._sent[pdo.cob_id] = payload

    def _try_recover(self) -> bool:
        recovered = super()._try_recover()
        if recovered:
            self._send_all = True
        return recovered
