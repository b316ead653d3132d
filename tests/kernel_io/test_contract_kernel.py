"""The driver contract of tests/drivers/test_contract.py, its own tests, run over the
kernel's devices (tests/kernel_io/rigs.py): gpio on gpio-sim, mcp23017 on i2c-stub,
canopen over SocketCAN (vcan).

Two kinds of contract test do not apply to a rig, and are not generated for it: those that
break the bus, on the i2c-stub (it always answers; the mcp23017's power loss is
test_mcp23017_kernel.py's), and the bank's debounce on the injected clock, on gpio-sim
(the kernel debounces a GPIO chip's inputs in real time: test_gpio_kernel.py)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

# the contract's tests and its driver fixture, collected here again with this module's
# rigs (pytest finds a test's fixtures from where it is collected)
from tests.drivers.drvkit import FakeClock
from tests.drivers.rigs import Rig
from tests.drivers.test_contract import (  # noqa: F401
    driver,
    test_a_bank_debounces_its_inputs,
    test_a_bank_reads_in_one_transfer_and_writes_only_what_changed,
    test_add_point,
    test_bool_inputs_are_bools,
    test_close_is_idempotent_and_leaves_outputs_off,
    test_fault_has_a_reason,
    test_inhibited_driver_never_energises,
    test_on_fault_policy,
    test_one_log_line_per_state_change,
    test_open_read_write_round_trip,
    test_recovery_with_back_off,
    test_safe_state_writes_zeros,
    test_without_debounce_a_bank_takes_a_change_at_the_next_read,
)
from tests.kernel_io.rigs import KERNEL_RIGS

pytestmark = pytest.mark.kernel_io

#: the contract tests that break the bus
BREAK_THE_BUS = {"test_fault_has_a_reason", "test_on_fault_policy",
                 "test_recovery_with_back_off", "test_one_log_line_per_state_change",
                 "test_inhibited_driver_never_energises"}
#: the bank's debounce on the injected clock
CLOCKED_DEBOUNCE = {"test_a_bank_debounces_its_inputs"}
#: the rigs whose bus cannot break, whose debounce is the kernel's
UNBREAKABLE = {"mcp23017-i2c-stub"}
KERNEL_DEBOUNCE = {"gpio-sim"}
BANKS = ["gpio-sim", "mcp23017-i2c-stub"]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    name = metafunc.function.__name__
    if "rig" in metafunc.fixturenames:
        metafunc.parametrize("rig", [r for r in KERNEL_RIGS if not (
            name in BREAK_THE_BUS and r in UNBREAKABLE)], indirect=True)
    if "bank_rig" in metafunc.fixturenames:
        metafunc.parametrize("bank_rig", [r for r in BANKS if not (
            name in CLOCKED_DEBOUNCE and r in KERNEL_DEBOUNCE)], indirect=True)


def _rig(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
         clock: FakeClock) -> Iterator[Rig]:
    r = KERNEL_RIGS[request.param](monkeypatch, clock)
    try:
        yield r
    finally:
        r.close()


@pytest.fixture
def rig(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
        clock: FakeClock) -> Iterator[Rig]:
    yield from _rig(request, monkeypatch, clock)


@pytest.fixture
def bank_rig(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
             clock: FakeClock) -> Iterator[Rig]:
    yield from _rig(request, monkeypatch, clock)


def test_every_rig_is_a_kernel_device_of_a_driver_type() -> None:
    assert sorted(KERNEL_RIGS) == ["canopen-vcan", "gpio-sim", "mcp23017-i2c-stub"]
