"""Modbus RTU protocol: building and checking frames (PDU + unit + CRC), pure functions.

No I/O and no state: ``drivers.serial_line`` sends these frames on a port, the driver
(``drivers.modbus_rtu``) decides which ones. The wire format follows the Modbus over Serial
Line specification v1.02 and the application protocol v1.1b3: CRC-16 (polynomial 0xA001,
low byte first), exception replies with the function code's high bit set. Addresses are
protocol addresses, from 0.
"""

from __future__ import annotations

from drivers.base import DriverError

READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS = 1, 2, 3, 4
WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER = 5, 6
WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS = 15, 16

#: most items one request may carry, by function code (Modbus application protocol v1.1b3)
MAX_ITEMS = {1: 2000, 2: 2000, 3: 125, 4: 125, 15: 1968, 16: 123}

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


def read_request(unit: int, function: int, address: int, count: int) -> bytes:
    """A read request (FC 1-4) for ``count`` items from ``address``."""
    return frame(bytes((unit, function, address >> 8, address & 0xFF, count >> 8, count & 0xFF)))


def write_coils_request(unit: int, address: int, bits: list[int]) -> bytes:
    """FC 5 for one coil, FC 15 for several."""
    if len(bits) == 1:
        value = 0xFF00 if bits[0] else 0x0000
        return frame(bytes((unit, WRITE_SINGLE_COIL, address >> 8, address & 0xFF,
                            value >> 8, value & 0xFF)))
    packed = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            packed[i // 8] |= 1 << (i % 8)
    n = len(bits)
    return frame(bytes((unit, WRITE_MULTIPLE_COILS, address >> 8, address & 0xFF, n >> 8,
                        n & 0xFF, len(packed))) + bytes(packed))


def write_registers_request(unit: int, address: int, values: list[int]) -> bytes:
    """FC 6 for one register, FC 16 for several; values are taken modulo 2**16."""
    regs = [v & 0xFFFF for v in values]
    if len(regs) == 1:
        return frame(bytes((unit, WRITE_SINGLE_REGISTER, address >> 8, address & 0xFF,
                            regs[0] >> 8, regs[0] & 0xFF)))
    n = len(regs)
    data = b"".join(bytes((v >> 8, v & 0xFF)) for v in regs)
    return frame(bytes((unit, WRITE_MULTIPLE_REGISTERS, address >> 8, address & 0xFF, n >> 8,
                        n & 0xFF, 2 * n)) + data)


def response_length(request: bytes) -> int:
    """Length in bytes of the normal reply to ``request`` (an exception reply is 5)."""
    function = request[1]
    if function in (READ_COILS, READ_DISCRETE_INPUTS):
        count = request[4] << 8 | request[5]
        return 5 + (count + 7) // 8
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        count = request[4] << 8 | request[5]
        return 5 + 2 * count
    return 8  # writes echo address and value/quantity


def decode_reply(request: bytes, reply: bytes) -> list[int]:
    """Items of a checked normal reply to a read request: bits (0/1) or registers."""
    function = request[1]
    count = request[4] << 8 | request[5]
    data = reply[3:-2]
    if function in (READ_COILS, READ_DISCRETE_INPUTS):
        return [(data[i // 8] >> (i % 8)) & 1 for i in range(count)]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return [data[2 * i] << 8 | data[2 * i + 1] for i in range(count)]
    return []


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


def describe(request: bytes) -> str:
    """``at address 16 (8 items)`` for a request, for fault messages."""
    address = request[2] << 8 | request[3]
    if request[1] in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        return f"at address {address}"
    count = request[4] << 8 | request[5]
    return f"at address {address} ({count} items)"
