"""Modbus protocol: the PDU (function code and data) both ways, and its two framings, RTU
(unit + PDU + CRC) and MBAP (Modbus/TCP's header + PDU); pure functions.

No I/O and no state. The masters (``drivers.serial_line.RtuMaster``,
``drivers.modbus_tcp.TcpMaster``) send these frames, the drivers (``drivers.modbus_rtu``,
``drivers.modbus_tcp``) decide which ones, and the plant's Modbus/TCP server
(``runtime.modbus``) reads requests and builds replies with the same PDU layer. The wire
format follows the Modbus application protocol v1.1b3 (the PDU: function codes 1, 2, 3, 4,
5, 6, 15, 16, quantities, exception replies with the function code's high bit set), Modbus
over Serial Line v1.02 (CRC-16, polynomial 0xA001, low byte first) and the Modbus
Messaging on TCP/IP Implementation Guide v1.0b (the 7-byte MBAP header: transaction id,
protocol id 0, length of unit id + PDU, unit id). Addresses are protocol addresses, from 0.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from drivers.base import DriverError

READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS = 1, 2, 3, 4
WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER = 5, 6
WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS = 15, 16
#: the function codes served and used here
FUNCTIONS = (1, 2, 3, 4, 5, 6, 15, 16)

#: most items one request may carry, by function code (Modbus application protocol v1.1b3)
MAX_ITEMS = {1: 2000, 2: 2000, 3: 125, 4: 125, 15: 1968, 16: 123}
#: the longest PDU, bytes (256 bytes of RTU frame less unit and CRC)
MAX_PDU = 253

#: exception codes
ILLEGAL_FUNCTION, ILLEGAL_DATA_ADDRESS, ILLEGAL_DATA_VALUE, SERVER_DEVICE_FAILURE = 1, 2, 3, 4
GATEWAY_PATH_UNAVAILABLE, GATEWAY_TARGET_FAILED = 10, 11
EXCEPTION_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


# -- the PDU, master side ----------------------------------------------------------------------
def read_pdu(function: int, address: int, count: int) -> bytes:
    """A read request (FC 1-4) for ``count`` items from ``address``."""
    return struct.pack(">BHH", function, address, count)


def pack_bits(bits: list[int]) -> bytes:
    """Bits, the first in the lowest bit of the first byte, padded with zeros."""
    packed = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            packed[i // 8] |= 1 << (i % 8)
    return bytes(packed)


def unpack_bits(data: bytes, count: int) -> list[int]:
    """The first ``count`` bits of ``data`` (as ``pack_bits`` packs them), 0 or 1."""
    return [(data[i // 8] >> (i % 8)) & 1 for i in range(count)]


def write_coils_pdu(address: int, bits: list[int]) -> bytes:
    """FC 5 for one coil, FC 15 for several."""
    if len(bits) == 1:
        return struct.pack(">BHH", WRITE_SINGLE_COIL, address, 0xFF00 if bits[0] else 0)
    packed = pack_bits(bits)
    return struct.pack(">BHHB", WRITE_MULTIPLE_COILS, address, len(bits), len(packed)) + packed


def write_registers_pdu(address: int, values: list[int]) -> bytes:
    """FC 6 for one register, FC 16 for several; values are taken modulo 2**16."""
    regs = [v & 0xFFFF for v in values]
    if len(regs) == 1:
        return struct.pack(">BHH", WRITE_SINGLE_REGISTER, address, regs[0])
    n = len(regs)
    return struct.pack(f">BHHB{n}H", WRITE_MULTIPLE_REGISTERS, address, n, 2 * n, *regs)


def reply_length(pdu: bytes) -> int:
    """Length in bytes of the normal reply PDU to request ``pdu`` (an exception reply is 2)."""
    function = pdu[0]
    count = pdu[3] << 8 | pdu[4]
    if function in (READ_COILS, READ_DISCRETE_INPUTS):
        return 2 + (count + 7) // 8
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return 2 + 2 * count
    return 5  # writes echo address and value/quantity


def check_reply(unit: int, pdu: bytes, reply: bytes) -> None:
    """Raise if ``reply`` is no normal reply to ``pdu``: ModbusExceptionReply for an
    exception, ModbusFrameError for another function, a wrong length or a write not
    echoed."""
    function = pdu[0]
    what = f"unit {unit}: FC {function} {describe(pdu)}"
    if not reply or reply[0] & 0x7F != function:
        got = f"FC {reply[0] & 0x7F}" if reply else "an empty PDU"
        raise ModbusFrameError(f"{what}: reply with {got}")
    if reply[0] & 0x80:
        if len(reply) != 2:
            raise ModbusFrameError(f"{what}: exception reply of {len(reply)} bytes")
        raise ModbusExceptionReply(unit, function, reply[1], describe(pdu))
    expected = reply_length(pdu)
    if function <= READ_INPUT_REGISTERS and (len(reply) < 2 or reply[1] != expected - 2):
        count = str(reply[1]) if len(reply) > 1 else "none"
        raise ModbusFrameError(f"{what}: byte count {count}, expected {expected - 2}")
    if len(reply) != expected:
        raise ModbusFrameError(f"{what}: reply of {len(reply)} bytes, expected {expected}")
    if function > READ_INPUT_REGISTERS and reply != pdu[:5]:
        raise ModbusFrameError(f"{what}: reply does not echo the request")


def decode_items(pdu: bytes, reply: bytes) -> list[int]:
    """Items of a checked normal reply to a read request: bits (0/1) or registers."""
    function = pdu[0]
    count = pdu[3] << 8 | pdu[4]
    data = reply[2:]
    if function in (READ_COILS, READ_DISCRETE_INPUTS):
        return unpack_bits(data, count)
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return list(struct.unpack(f">{count}H", data[:2 * count]))
    return []


def describe(pdu: bytes) -> str:
    """``at address 16 (8 items)`` for a request PDU, for fault messages."""
    address = pdu[1] << 8 | pdu[2]
    if pdu[0] in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        return f"at address {address}"
    count = pdu[3] << 8 | pdu[4]
    return f"at address {address} ({count} items)"


# -- the PDU, server side ----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Request:
    """A request PDU as a server reads it: FC 1-4 ``count`` items from ``address``; FC 5,
    6, 15 and 16 ``values`` (bits 0/1, or registers) from ``address``."""

    function: int
    address: int
    count: int
    values: tuple[int, ...] = ()

    @property
    def writes(self) -> bool:
        return self.function >= WRITE_SINGLE_COIL

    @property
    def bits(self) -> bool:
        """It reads or writes coils or discrete inputs (not registers)."""
        return self.function in (READ_COILS, READ_DISCRETE_INPUTS, WRITE_SINGLE_COIL,
                                 WRITE_MULTIPLE_COILS)


class RequestError(ValueError):
    """A request PDU a server answers with an exception; ``code`` is that exception."""

    def __init__(self, code: int, why: str) -> None:
        super().__init__(why)
        self.code = code


def parse_request(pdu: bytes) -> Request:
    """The request in ``pdu``; RequestError with the exception code the specification
    gives: 1 for a function not served, 3 for a quantity out of range, a byte count that
    disagrees with it, a length that lies or a coil value other than 0x0000/0xFF00, 2 for
    addresses past 65535."""
    if not pdu:
        raise RequestError(ILLEGAL_FUNCTION, "an empty PDU")
    function = pdu[0]
    if function not in FUNCTIONS:
        raise RequestError(ILLEGAL_FUNCTION, f"function code {function} is not served")
    if function <= WRITE_SINGLE_REGISTER:
        if len(pdu) != 5:
            raise RequestError(ILLEGAL_DATA_VALUE, f"FC {function} of {len(pdu)} bytes, "
                                                   "expected 5")
        address, value = struct.unpack(">HH", pdu[1:5])
        if function <= READ_INPUT_REGISTERS:
            if not 1 <= value <= MAX_ITEMS[function]:
                raise RequestError(ILLEGAL_DATA_VALUE, f"FC {function} of {value} items "
                                   f"(1 to {MAX_ITEMS[function]})")
            _check_end(address, value)
            return Request(function, address, value)
        if function == WRITE_SINGLE_COIL:
            if value not in (0, 0xFF00):
                raise RequestError(ILLEGAL_DATA_VALUE, f"FC 5 value 0x{value:04x} (0x0000 "
                                                       "or 0xFF00)")
            return Request(function, address, 1, (1 if value else 0,))
        return Request(function, address, 1, (value,))
    if len(pdu) < 6:
        raise RequestError(ILLEGAL_DATA_VALUE, f"FC {function} of {len(pdu)} bytes")
    address, count, nbytes = struct.unpack(">HHB", pdu[1:6])
    want = (count + 7) // 8 if function == WRITE_MULTIPLE_COILS else 2 * count
    if not 1 <= count <= MAX_ITEMS[function] or nbytes != want or len(pdu) != 6 + nbytes:
        raise RequestError(ILLEGAL_DATA_VALUE, f"FC {function} of {count} items, byte count "
                           f"{nbytes}, {len(pdu) - 6} bytes of data")
    _check_end(address, count)
    data = pdu[6:]
    if function == WRITE_MULTIPLE_COILS:
        return Request(function, address, count, tuple(unpack_bits(data, count)))
    return Request(function, address, count, struct.unpack(f">{count}H", data))


def _check_end(address: int, count: int) -> None:
    if address + count > 0x10000:
        raise RequestError(ILLEGAL_DATA_ADDRESS, f"addresses {address} to "
                                                 f"{address + count - 1} (past 65535)")


def exception_pdu(function: int, code: int) -> bytes:
    """The exception reply to ``function``."""
    return bytes((function | 0x80, code))


def read_reply(request: Request, items: list[int]) -> bytes:
    """The normal reply to a read: its bits or registers."""
    if request.bits:
        packed = pack_bits(items)
        return bytes((request.function, len(packed))) + packed
    return struct.pack(f">BB{len(items)}H", request.function, 2 * len(items), *items)


def write_reply(pdu: bytes) -> bytes:
    """The normal reply to a write: the request's first five bytes, echoed."""
    return pdu[:5]


# -- RTU framing: unit + PDU + CRC ------------------------------------------------------------
def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Modbus CRC-16 of ``data`` (sent low byte first)."""
    crc = 0xFFFF
    table = _CRC_TABLE
    for b in data:
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def frame(body: bytes) -> bytes:
    """``body`` (unit, function, data) with its CRC appended."""
    crc = crc16(body)
    return body + bytes((crc & 0xFF, crc >> 8))


def rtu_frame(unit: int, pdu: bytes) -> bytes:
    """The RTU frame of ``pdu`` for ``unit``."""
    return frame(bytes((unit,)) + pdu)


def read_request(unit: int, function: int, address: int, count: int) -> bytes:
    """An RTU read request (FC 1-4) for ``count`` items from ``address``."""
    return rtu_frame(unit, read_pdu(function, address, count))


def write_coils_request(unit: int, address: int, bits: list[int]) -> bytes:
    """An RTU FC 5 for one coil, FC 15 for several."""
    return rtu_frame(unit, write_coils_pdu(address, bits))


def write_registers_request(unit: int, address: int, values: list[int]) -> bytes:
    """An RTU FC 6 for one register, FC 16 for several; values modulo 2**16."""
    return rtu_frame(unit, write_registers_pdu(address, values))


def response_length(request: bytes) -> int:
    """Length in bytes of the normal RTU reply to RTU ``request`` (an exception reply is
    5)."""
    return reply_length(request[1:-2]) + 3


def decode_reply(request: bytes, reply: bytes) -> list[int]:
    """Items of a checked normal RTU reply to an RTU read request."""
    return decode_items(request[1:-2], reply[1:-2])


# -- MBAP framing (Modbus/TCP) ---------------------------------------------------------------
#: the MBAP header: transaction id, protocol id (0), length (unit id + PDU), unit id
MBAP = struct.Struct(">HHHB")
MBAP_SIZE = MBAP.size  # 7


def mbap_frame(transaction: int, unit: int, pdu: bytes) -> bytes:
    """``pdu`` for ``unit`` behind its MBAP header."""
    return MBAP.pack(transaction & 0xFFFF, 0, len(pdu) + 1, unit) + pdu


def mbap_header(header: bytes) -> tuple[int, int, int, int]:
    """(transaction, protocol, PDU length, unit) of a 7-byte MBAP header; the PDU length
    is the header's length field less the unit id (it may lie: the caller checks it
    against 1..MAX_PDU and the protocol against 0)."""
    transaction, protocol, length, unit = MBAP.unpack(header)
    return transaction, protocol, length - 1, unit


class ModbusError(DriverError):
    """A failed Modbus transaction; the message says which unit, function and address."""


class ModbusTimeout(ModbusError):
    """No (complete) reply within the timeout: unit absent, cable cut, wrong baud rate."""


class ModbusCrcError(ModbusError):
    """A reply with a bad CRC: noise on the line, a missing terminator, two masters."""


class ModbusFrameError(ModbusError):
    """A reply from another unit or function, or of the wrong length (a late reply)."""


class ModbusExceptionReply(ModbusError):
    """The unit answered with an exception: e.g. code 2 for an address it does not have."""

    def __init__(self, unit: int, function: int, code: int, what: str) -> None:
        self.unit, self.function, self.code = unit, function, code
        name = EXCEPTION_NAMES.get(code, "unknown exception")
        super().__init__(f"unit {unit}: exception {code} ({name}) to FC {function} {what}")
