"""The kernel_io tier: tests marked ``kernel_io`` run inside the guest scripts/kernel-io.sh
boots (a real Linux kernel, its gpio-sim, i2c-stub, vcan and dm-log-writes), which sets
SOFTPLC_KERNEL_IO=guest; anywhere else they skip. Fixtures give each test its own gpio-sim
chip, its own zeroed i2c-stub registers and its own vcan interface."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

# the driver tests' fixtures, as they are: the injected clock and the check that no test
# leaves a thread running or a terminal open
from tests.drivers.conftest import clock, system_health_check  # noqa: F401
from tests.kernel_io.kio import STUB_ADDRESSES, SimChip, StubChip, Vcan

#: True inside the kernel_io guest
IN_GUEST = os.environ.get("SOFTPLC_KERNEL_IO") == "guest"
SKIP = pytest.mark.skip(reason="runs in the kernel_io guest only: scripts/kernel-io.sh")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    if IN_GUEST:
        return
    for item in items:
        if item.get_closest_marker("kernel_io") is not None:
            item.add_marker(SKIP)


@pytest.fixture
def sim_chip() -> Iterator[SimChip]:
    """A gpio-sim chip of 16 lines with a label of its own, removed after the test."""
    chip = SimChip()
    try:
        yield chip
    finally:
        chip.destroy()


@pytest.fixture
def stub() -> Iterator[StubChip]:
    """The i2c-stub chip at 0x20, every register zeroed."""
    chip = StubChip(STUB_ADDRESSES[0])
    chip.zero()
    try:
        yield chip
    finally:
        chip.close()


@pytest.fixture
def vcan() -> Iterator[Vcan]:
    """A vcan interface of its own, up; deleted after the test."""
    can = Vcan()
    try:
        yield can
    finally:
        can.delete()
