"""The kernel's own devices the kernel_io tier tests against, inside its guest
(scripts/kernel-io.sh): gpio-sim chips made through configfs, the i2c-stub chips behind
i2c-dev, and vcan interfaces. Each test gets its own chip, zeroed registers and interface
from the fixtures of conftest.py."""

from __future__ import annotations

import itertools
import os
import subprocess
import uuid

import smbus2

#: where gpio-sim devices are made (configfs)
GPIO_SIM = "/sys/kernel/config/gpio-sim"
#: the name i2c-stub gives its adapter
STUB_ADAPTER = "SMBus stub driver"
#: the addresses scripts/kernel-io.sh's guest gives i2c-stub (chip_addr=0x20,0x21)
STUB_ADDRESSES = (0x20, 0x21)
_numbers = itertools.count()


def _write(path: str, text: str) -> None:
    with open(path, "w", encoding="ascii") as f:
        f.write(text)


def _read(path: str) -> str:
    with open(path, encoding="ascii") as f:
        return f.read().strip()


class SimChip:
    """One gpio-sim chip of ``lines`` lines labelled ``label``, live.

    ``pull(line, level)`` is the world outside driving an input (the pull of the simulated
    line); ``value(line)`` is a line's level (an output's as its consumer set it).
    ``remove()`` takes the chip away as an unplugged device, ``restore()`` brings it back:
    the kernel numbers it anew (``path`` follows)."""

    def __init__(self, label: str | None = None, lines: int = 16) -> None:
        self.label = label or f"kio-{uuid.uuid4().hex[:8]}"
        self.lines = lines
        self.dir = f"{GPIO_SIM}/{self.label}"
        self.bank = f"{self.dir}/bank0"
        os.mkdir(self.dir)
        os.mkdir(self.bank)
        _write(f"{self.bank}/num_lines", str(lines))
        _write(f"{self.bank}/label", self.label)
        self.name = self.device = ""
        self.restore()

    @property
    def path(self) -> str:
        """The character device of the chip now: /dev/gpiochipN."""
        return f"/dev/{self.name}"

    @property
    def live(self) -> bool:
        return _read(f"{self.dir}/live") == "1"

    def restore(self) -> None:
        """Make the chip live (again): a new /dev/gpiochipN."""
        _write(f"{self.dir}/live", "1")
        self.name = _read(f"{self.bank}/chip_name")
        self.device = _read(f"{self.dir}/dev_name")

    def remove(self) -> None:
        """Take the chip away, lines held or not (its consumers get ENODEV)."""
        _write(f"{self.dir}/live", "0")

    def _attr(self, line: int, what: str) -> str:
        return f"/sys/devices/platform/{self.device}/{self.name}/sim_gpio{line}/{what}"

    def pull(self, line: int, level: int) -> None:
        """Drive input ``line`` from outside to ``level``."""
        _write(self._attr(line, "pull"), "pull-up" if level else "pull-down")

    def pull_of(self, line: int) -> str:
        """``pull-up`` or ``pull-down``: what pulls the line now (a bias sets it too)."""
        return _read(self._attr(line, "pull"))

    def value(self, line: int) -> int:
        """The line's level: an output's as set, an input's as pulled."""
        return int(_read(self._attr(line, "value")))

    def destroy(self) -> None:
        if self.live:
            self.remove()
        os.rmdir(self.bank)
        os.rmdir(self.dir)


def stub_bus() -> int:
    """The number of the i2c-stub adapter (/dev/i2c-N)."""
    base = "/sys/bus/i2c/devices"
    for name in sorted(os.listdir(base)):
        if name.startswith("i2c-") and _read(f"{base}/{name}/name") == STUB_ADAPTER:
            return int(name.removeprefix("i2c-"))
    raise RuntimeError("no i2c-stub adapter: is i2c-stub loaded?")


class StubChip:
    """The i2c-stub chip at ``address``: 256 byte registers of plain memory, read and
    written through i2c-dev as any I2C device is."""

    def __init__(self, address: int) -> None:
        self.address = address
        self.bus_number = stub_bus()
        self._bus = smbus2.SMBus(self.bus_number)

    def zero(self) -> None:
        """Every register 0 (a chip without memory of an earlier test)."""
        for reg in range(0, 256, 32):
            self._bus.write_i2c_block_data(self.address, reg, [0] * 32)

    def peek(self, reg: int) -> int:
        return int(self._bus.read_byte_data(self.address, reg))

    def poke(self, reg: int, value: int) -> None:
        self._bus.write_byte_data(self.address, reg, value)

    def close(self) -> None:
        self._bus.close()


class Vcan:
    """A virtual CAN interface of the kernel's SocketCAN, up."""

    def __init__(self) -> None:
        self.name = f"kio{os.getpid() % 10000}x{next(_numbers)}"
        self._ip("link", "add", "dev", self.name, "type", "vcan")
        self.up()

    def _ip(self, *args: str) -> None:
        subprocess.run(["ip", *args], check=True, capture_output=True)

    def up(self) -> None:
        self._ip("link", "set", self.name, "up")

    def down(self) -> None:
        self._ip("link", "set", self.name, "down")

    def delete(self) -> None:
        self._ip("link", "delete", self.name)
