"""The driver contract (drivers.base), run over every driver type on its peer or emulator."""

from __future__ import annotations

import functools
import logging
import operator
from collections.abc import Iterator

import pytest

from drivers.bank import DigitalBank
from drivers.base import Direction, Driver, Health, PointError, PointKind, PolledDriver
from drivers.config import ConfigError
from drivers.registry import DRIVERS, driver_class
from tests.drivers.drvkit import FakeClock, wait_until
from tests.drivers.rigs import RIGS, SETTLE_S, Rig


@pytest.fixture(params=sorted(RIGS))
def rig(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
        clock: FakeClock) -> Iterator[Rig]:
    r = RIGS[request.param](monkeypatch, clock)
    yield r
    r.close()


@pytest.fixture
def driver(rig: Rig) -> Iterator[Driver]:
    d = rig.make()
    yield d
    d.close()


def opened(rig: Rig, d: Driver) -> Driver:
    d.open()
    assert d.health is not Health.FAULT, d.fault_reason
    assert rig.until(d, lambda: d.health is Health.OK), (d.health, d.fault_reason)
    return d


def test_every_registered_type_has_a_rig() -> None:
    assert set(RIGS) == set(DRIVERS)
    for type_name in DRIVERS:
        assert driver_class(type_name).type_name == type_name


def test_unknown_config_key_is_refused(rig: Rig) -> None:
    with pytest.raises(ConfigError, match=r"unknown keys \['colour'\]"):
        rig.make(colour="red")


def test_add_point(rig: Rig) -> None:
    d = rig._make({})
    for p in rig.inputs:
        assert d.add_point(p, Direction.IN) is PointKind.BOOL
    for p in rig.outputs:
        assert d.add_point(p, Direction.OUT) is PointKind.BOOL
    assert set(d.inputs) == set(rig.inputs) and set(d.outputs) == set(rig.outputs)
    for point, direction in rig.bad_points:
        with pytest.raises(PointError, match=point):
            d.add_point(point, direction)
    if d.ONE_DIRECTION_PER_POINT:
        with pytest.raises(PointError):
            d.add_point(rig.outputs[0], Direction.IN)


def test_open_read_write_round_trip(rig: Rig, driver: Driver) -> None:
    d = opened(rig, driver)
    assert d.ok
    a, b = rig.inputs
    rig.set_input(a, 1)
    rig.set_input(b, 0)
    assert rig.until(d, lambda: d.inputs == {a: 1, b: 0}), d.inputs
    rig.set_input(a, 0)
    rig.set_input(b, 1)
    assert rig.until(d, lambda: d.inputs == {a: 0, b: 1}), d.inputs
    q0, q1 = rig.outputs
    d.outputs[q0] = True
    assert rig.until(d, lambda: rig.output(q0) == 1 and rig.output(q1) == 0)
    d.outputs[q0], d.outputs[q1] = 0, 1
    assert rig.until(d, lambda: rig.output(q0) == 0 and rig.output(q1) == 1)


def test_bool_inputs_are_bools(rig: Rig, driver: Driver) -> None:
    """A BOOL point's input value is a bool, whatever path stored it: the driver's own
    read (a hot ``vals[i] =``), an exchange published by its bus thread, a store by name;
    and ``fill`` (the zeros of ``on_fault: zero``). The plant reads such a bit as it is
    (the bindings make no conversion: drivers/image.py); a 1 would reach the chart."""
    d = opened(rig, driver)
    # what the plant does for inputs only BOOL variables read
    d.inputs.declare_bits(d.inputs.index[p] for p in rig.inputs)
    a, b = rig.inputs
    for va, vb in ((1, 0), (0, 1)):
        rig.set_input(a, va)
        rig.set_input(b, vb)
        want: dict[str, int] = {a: va, b: vb}
        assert rig.until(d, functools.partial(operator.eq, d.inputs, want)), d.inputs
        assert [type(v) for v in d.inputs.values()] == [bool, bool], d.inputs
    d.inputs.fill(0)
    assert list(d.inputs.values()) == [False, False]
    assert all(type(v) is bool for v in d.inputs.values())


def test_safe_state_writes_zeros(rig: Rig, driver: Driver) -> None:
    d = opened(rig, driver)
    for q in rig.outputs:
        d.outputs[q] = 1
    assert rig.until(d, lambda: all(rig.output(q) == 1 for q in rig.outputs))
    d.safe_state()
    assert all(v == 0 for v in d.outputs.values())
    assert rig.until(d, lambda: all(rig.output(q) == 0 for q in rig.outputs))


def test_close_is_idempotent_and_leaves_outputs_off(rig: Rig, driver: Driver) -> None:
    d = opened(rig, driver)
    d.outputs[rig.outputs[0]] = 1
    assert rig.until(d, lambda: rig.output(rig.outputs[0]) == 1)
    d.close()
    assert d.health is Health.CLOSED and not d.ok
    assert wait_until(lambda: rig.output(rig.outputs[0]) == 0)  # the peer may lag
    d.close()
    assert d.health is Health.CLOSED


def test_fault_has_a_reason(rig: Rig, driver: Driver) -> None:
    d = opened(rig, driver)
    rig.fault(d)
    assert d.health is Health.FAULT and not d.ok
    assert d.fault_reason


@pytest.mark.parametrize("policy", ["zero", "hold"])
def test_on_fault_policy(rig: Rig, policy: str) -> None:
    d = opened(rig, rig.make(on_fault=policy))
    try:
        rig.set_input(rig.inputs[0], 1)
        assert rig.until(d, lambda: d.inputs[rig.inputs[0]] == 1)
        rig.fault(d)
        d.read()
        assert d.inputs[rig.inputs[0]] == (0 if policy == "zero" else 1)
    finally:
        d.close()


def test_recovery_with_back_off(rig: Rig, clock: FakeClock, driver: Driver) -> None:
    d = opened(rig, driver)
    step = d.RECONNECT_MIN_S
    rig.fault(d)  # at t0; first retry due at t0 + step
    clock.advance(step)
    since = d.updates if isinstance(d, PolledDriver) else 0
    d.read()  # retry 1, on a bus still broken: the delay doubles
    rig.settle_retry(d, since)
    d.read()
    assert d.health is Health.FAULT
    rig.heal_bus(d)
    clock.advance(step)  # t0 + 2 step: the next retry is due at t0 + 3 step
    for _ in range(3):
        rig.scan(d)
    assert d.health is Health.FAULT
    clock.advance(step)
    assert rig.until(d, lambda: d.health is Health.OK), d.fault_reason
    rig.set_input(rig.inputs[0], 1)
    assert rig.until(d, lambda: d.inputs[rig.inputs[0]] == 1)
    d.outputs[rig.outputs[0]] = 1
    assert rig.until(d, lambda: rig.output(rig.outputs[0]) == 1)


def _lines(caplog: pytest.LogCaptureFixture, level: int) -> list[str]:
    return [f"{r.levelname} {r.getMessage()}" for r in caplog.records
            if r.name.startswith("drivers") and r.levelno >= level]


def test_one_log_line_per_state_change(rig: Rig, clock: FakeClock, driver: Driver,
                                       caplog: pytest.LogCaptureFixture) -> None:
    d = opened(rig, driver)
    caplog.set_level(logging.DEBUG)
    caplog.clear()
    rig.fault(d)
    for _ in range(3):  # scans and failed reconnects while the bus stays broken
        clock.advance(d.RECONNECT_MAX_S)
        since = d.updates if isinstance(d, PolledDriver) else 0
        d.read()
        rig.settle_retry(d, since)
        for _ in range(5):
            rig.scan(d)
    assert d.health is Health.FAULT
    logged = _lines(caplog, logging.INFO)
    assert len(logged) == 1 and logged[0].startswith("ERROR") and "fault" in logged[0], logged
    caplog.clear()
    rig.heal_bus(d)
    clock.advance(d.RECONNECT_MAX_S)
    assert rig.until(d, lambda: d.health is Health.OK), d.fault_reason
    for _ in range(20):
        rig.scan(d)
    logged = _lines(caplog, logging.WARNING)
    assert len(logged) == 1 and "recovered" in logged[0], logged
    assert len(set(_lines(caplog, logging.INFO))) == len(_lines(caplog, logging.INFO))


def test_inhibited_driver_never_energises(rig: Rig, clock: FakeClock, driver: Driver) -> None:
    """``inhibit(True)`` (the daemon's watchdog, a latched fault): outputs off, and nothing
    turns them on again, not a stuck scan's image, not a set-up after a reconnect."""
    d = opened(rig, driver)
    for q in rig.outputs:
        d.outputs[q] = 1
    assert rig.until(d, lambda: all(rig.output(q) == 1 for q in rig.outputs))
    d.inhibit(True)
    assert wait_until(lambda: all(rig.output(q) == 0 for q in rig.outputs), SETTLE_S)
    for q in rig.outputs:  # what a stuck scan thread writes afterwards
        d.outputs[q] = 1
    rig.fault(d)
    rig.heal_bus(d)
    clock.advance(d.RECONNECT_MAX_S)
    assert rig.until(d, lambda: d.health is Health.OK), d.fault_reason
    for _ in range(5):
        rig.scan(d)
    assert all(rig.output(q) == 0 for q in rig.outputs)
    d.inhibit(False)  # acknowledged: the plant's image goes out again
    assert rig.until(d, lambda: all(rig.output(q) == 1 for q in rig.outputs))


# -- the digital bank (drivers/bank.py), covered once, over every bank ------------------------
BANKS = sorted(t for t in RIGS if issubclass(driver_class(t), DigitalBank))


@pytest.fixture(params=BANKS)
def bank_rig(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
             clock: FakeClock) -> Iterator[Rig]:
    r = RIGS[request.param](monkeypatch, clock)
    yield r
    r.close()


def test_the_digital_banks_are_the_gpio_chip_and_the_expanders() -> None:
    assert BANKS == ["gpio", "mcp23017", "pcf8574"]


def test_a_bank_reads_in_one_transfer_and_writes_only_what_changed(
        bank_rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    d = opened(bank_rig, bank_rig.make())
    assert isinstance(d, DigitalBank)
    reads: list[int] = []
    writes: list[tuple[int, int]] = []
    read_word, write_word = d._read_word, d._write_word

    def counted_read() -> int:
        reads.append(1)
        return read_word()

    def counted_write(word: int, changed: int) -> None:
        writes.append((word, changed))
        write_word(word, changed)

    monkeypatch.setattr(d, "_read_word", counted_read)
    monkeypatch.setattr(d, "_write_word", counted_write)
    q0, q1 = (1 << d.line(q) for q in bank_rig.outputs)
    d.read()
    d.write()
    assert (len(reads), writes) == (1, [])  # nothing changed since the set-up
    d.outputs[bank_rig.outputs[0]] = 1
    d.write()
    d.write()
    assert writes == [(q0, q0)] and bank_rig.output(bank_rig.outputs[0]) == 1
    d.outputs[bank_rig.outputs[1]] = True
    d.write()
    assert writes[-1] == (q0 | q1, q1)
    d.safe_state()  # every output, whatever was written last
    assert writes[-1] == (0, q0 | q1) and d.out_mask == q0 | q1
    assert all(bank_rig.output(q) == 0 for q in bank_rig.outputs)
    d.close()


def test_a_bank_debounces_its_inputs(bank_rig: Rig, clock: FakeClock) -> None:
    """A change back within the period is a bounce, never seen; a change held for the
    period is taken (by the GPIO kernel driver, or by the bank where the chip has none)."""
    a, b = bank_rig.inputs
    bank_rig.set_input(a, 1)
    bank_rig.set_input(b, 1)
    clock.advance(0.05)
    d = opened(bank_rig, bank_rig.make(debounce="10ms"))
    d.read()
    assert d.inputs == {a: 1, b: 1}  # the first read takes the levels as they are
    bank_rig.set_input(a, 0)  # a 2 ms bounce
    d.read()
    clock.advance(0.002)
    bank_rig.set_input(a, 1)
    d.read()
    clock.advance(0.05)
    d.read()
    assert d.inputs == {a: 1, b: 1}
    bank_rig.set_input(b, 0)  # held
    d.read()
    clock.advance(0.005)
    d.read()
    assert d.inputs == {a: 1, b: 1}  # 5 ms: not yet
    clock.advance(0.006)
    d.read()
    assert d.inputs == {a: 1, b: 0}
    d.close()


def test_without_debounce_a_bank_takes_a_change_at_the_next_read(bank_rig: Rig) -> None:
    a, _ = bank_rig.inputs
    d = opened(bank_rig, bank_rig.make())
    for level in (1, 0, 1):
        bank_rig.set_input(a, level)
        d.read()
        assert d.inputs[a] == level
    d.close()
