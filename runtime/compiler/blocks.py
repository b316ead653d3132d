"""IEC 61131-3 function blocks and the seed-000 timers, on an injected clock (ns)."""

from __future__ import annotations


class TON:
    """On-delay: Q rises PT after IN rises; ET elapsed time (ns), capped at PT."""

    __slots__ = ("IN", "PT", "Q", "ET", "_start", "_prev")

    def __init__(self) -> None:
        self.IN = False
        self.PT = 0
        self.Q = False
        self.ET = 0
        self._start = 0
        self._prev = False

    def update(self, now: int) -> None:
        if self.IN:
            if not self._prev:
                self._start = now
            self.ET = min(now - self._start, self.PT)
            self.Q = self.ET >= self.PT
        else:
            self.Q = False
            self.ET = 0
        self._prev = self.IN


class TOF:
    """Off-delay: Q true while IN, and for PT after IN falls."""

    __slots__ = ("IN", "PT", "Q", "ET", "_start", "_prev")

    def __init__(self) -> None:
        self.IN = False
        self.PT = 0
        self.Q = False
        self.ET = 0
        self._start = 0
        self._prev = False

    def update(self, now: int) -> None:
        if self.IN:
            self.Q = True
            self.ET = 0
        else:
            if self._prev:
                self._start = now
            if self.Q:
                self.ET = min(now - self._start, self.PT)
                self.Q = self.ET < self.PT
        self._prev = self.IN


class TP:
    """Pulse: Q true for PT from a rising IN, not retriggerable while running."""

    __slots__ = ("IN", "PT", "Q", "ET", "_start", "_prev", "_running")

    def __init__(self) -> None:
        self.IN = False
        self.PT = 0
        self.Q = False
        self.ET = 0
        self._start = 0
        self._prev = False
        self._running = False

    def update(self, now: int) -> None:
        if self.IN and not self._prev and not self._running:
            self._running = True
            self._start = now
        if self._running:
            self.ET = min(now - self._start, self.PT)
            self.Q = self.ET < self.PT
            if not self.Q and not self.IN:
                self._running = False
                self.ET = 0
        else:
            self.Q = False
            self.ET = 0
        self._prev = self.IN


class CTU:
    """Up counter: CV counts rising CU; R resets; Q = CV >= PV."""

    __slots__ = ("CU", "R", "PV", "Q", "CV", "_prev")

    def __init__(self) -> None:
        self.CU = self.R = self.Q = self._prev = False
        self.PV = self.CV = 0

    def update(self, now: int) -> None:
        if self.R:
            self.CV = 0
        elif self.CU and not self._prev:
            self.CV += 1
        self._prev = self.CU
        self.Q = self.CV >= self.PV


class CTD:
    """Down counter: LD loads PV; CV counts down on rising CD; Q = CV <= 0."""

    __slots__ = ("CD", "LD", "PV", "Q", "CV", "_prev")

    def __init__(self) -> None:
        self.CD = self.LD = self.Q = self._prev = False
        self.PV = self.CV = 0

    def update(self, now: int) -> None:
        if self.LD:
            self.CV = self.PV
        elif self.CD and not self._prev:
            self.CV -= 1
        self._prev = self.CD
        self.Q = self.CV <= 0


class CTUD:
    """Up/down counter: R resets, LD loads PV, rising CU/CD count; QU = CV>=PV, QD = CV<=0."""

    __slots__ = ("CU", "CD", "R", "LD", "PV", "QU", "QD", "CV", "_pu", "_pd")

    def __init__(self) -> None:
        self.CU = self.CD = self.R = self.LD = self.QU = self.QD = False
        self._pu = self._pd = False
        self.PV = self.CV = 0

    def update(self, now: int) -> None:
        if self.R:
            self.CV = 0
        elif self.LD:
            self.CV = self.PV
        else:
            up = self.CU and not self._pu
            down = self.CD and not self._pd
            if up and not down:
                self.CV += 1
            elif down and not up:
                self.CV -= 1
        self._pu, self._pd = self.CU, self.CD
        self.QU = self.CV >= self.PV
        self.QD = self.CV <= 0


class R_TRIG:  # noqa: N801 - IEC name
    """Rising edge of CLK; memory starts false (IEC), so a true CLK at the first call gives Q."""

    __slots__ = ("CLK", "Q", "_m")

    def __init__(self) -> None:
        self.CLK = self.Q = self._m = False

    def update(self, now: int) -> None:
        self.Q = self.CLK and not self._m
        self._m = self.CLK


class F_TRIG:  # noqa: N801 - IEC name
    """Falling edge of CLK, IEC form: Q := NOT CLK AND NOT M; M := NOT CLK (M starts false)."""

    __slots__ = ("CLK", "Q", "_m")

    def __init__(self) -> None:
        self.CLK = self.Q = self._m = False

    def update(self, now: int) -> None:
        self.Q = not self.CLK and not self._m
        self._m = not self.CLK


class SR:
    """Set-dominant bistable: Q1 := S1 OR (NOT R AND Q1)."""

    __slots__ = ("S1", "R", "Q1")

    def __init__(self) -> None:
        self.S1 = self.R = self.Q1 = False

    def update(self, now: int) -> None:
        self.Q1 = self.S1 or (not self.R and self.Q1)


class RS:
    """Reset-dominant bistable: Q1 := NOT R1 AND (S OR Q1)."""

    __slots__ = ("S", "R1", "Q1")

    def __init__(self) -> None:
        self.S = self.R1 = self.Q1 = False

    def update(self, now: int) -> None:
        self.Q1 = not self.R1 and (self.S or self.Q1)


class SeedTimer:
    """Seed-000 timer object: ``Ini(t)`` (re)starts, ``End()``, ``Reset()``, ``Val()`` (ns)."""

    __slots__ = ("_start", "_preset", "_running")

    def __init__(self) -> None:
        self._start = 0
        self._preset = 0
        self._running = False

    def ini(self, now: int, preset: int) -> None:
        self._start, self._preset, self._running = now, preset, True

    def reset(self) -> None:
        self._running = False

    def end(self, now: int) -> bool:
        return self._running and now - self._start >= self._preset

    def val(self, now: int) -> int:
        return min(now - self._start, self._preset) if self._running else 0


BLOCKS: dict[str, type] = {"TON": TON, "TOF": TOF, "TP": TP, "CTU": CTU, "CTD": CTD,
                           "CTUD": CTUD, "R_TRIG": R_TRIG, "F_TRIG": F_TRIG, "SR": SR, "RS": RS}
