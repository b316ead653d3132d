"""A bank of digital lines: the part the GPIO chip and the I2C port expanders share.

A bank is a device whose lines are each bound either as an input or as an output, read all
at once and written all at once: a GPIO chip (one line request, one ioctl each way), an
MCP23017 (a 2-byte block read of GPIOA+GPIOB, a 2-byte write of OLATA+OLATB), a PCF8574
(one byte each way). :class:`DigitalBank` does for all of them, as python-can's ``BusABC``
and gpiozero's pin factories do for theirs, the work that is the same:

* **lines**: a point is one line, bit ``line(point)`` of the bank's word (an int, bit n for
  line n); ``in_mask``/``out_mask`` hold the bound lines, and each bound input's place in the
  image is known once, at open;
* **directions**: a line is an input or an output, never both (``add_point`` refuses the
  other direction); lines bound to nothing stay inputs;
* **inversion**: the bank moves physical levels. A device's own inversion (GPIO
  ``active_low``, MCP23017 ``IPOL``) is kept off by the back-end's set-up: inverting is the
  binding's, in one place (docs/drivers.md);
* **debounce where the hardware has none**: a chip without a debounce of its own
  (``SOFT_DEBOUNCE``) gets the ``debounce`` key here: an input change is taken once every
  read for the period saw it (reads are once a scan, so it is taken at the first read at
  least the period after the first read that saw it); a change back before then is a bounce
  and is dropped. The first read after an open takes the levels as they are. A chip whose
  kernel driver debounces (GPIO) hands the period to it instead;
* **bulk read and write**: one read of every line per scan, the inputs stored in the image;
  the output word written only when it differs from the last one written, with the bits
  that changed; 0 on every output while ``inhibited``, in a set-up after a power loss too
  (``setup_word``); the safe state a full write of zeros;
* an I/O error (``OSError``) is a fault naming the device (``where()``).

A back-end **must** override:
  ``line(point) -> int`` (the bit of a point, already checked by ``_check_point``),
  ``where() -> str`` (the device, for messages: ``mcp23017 at 0x20 on /dev/i2c-1``),
  ``_attach() -> int`` (open the device and set it up: directions from ``in_mask`` and
  ``out_mask``, its own inversion off, the outputs at ``setup_word()``; return the output
  word it left there),
  ``_read_word() -> int`` (every line's level, bit n for line n; it may first check the
  device, and set it up again after a power loss),
  ``_write_word(word, changed)`` (set the output lines to ``word``; ``changed``: the output
  bits that differ from the last write, every output after a set-up or for the safe state),
  ``_detach()`` (release the device; idempotent).
The driver's config keys come from drivers.registry as for any driver; a back-end with
``SOFT_DEBOUNCE`` declares ``debounce`` among them.
"""

from __future__ import annotations

import abc
from typing import ClassVar

from drivers.base import Driver, DriverError


class DigitalBank(Driver):
    """Digital lines of one device, read and written all at once. See the module
    docstring for what the base does and what a back-end overrides."""

    ONE_DIRECTION_PER_POINT = True
    #: True where the device has no debounce of its own: the base filters the inputs
    SOFT_DEBOUNCE: ClassVar[bool] = False

    def _init(self) -> None:
        #: debounce period of the inputs, seconds (0: none)
        self.debounce_s: float = self.params.get("debounce", 0.0)
        #: the bound input lines, and the bound output lines, as bits of the bank's word
        self.in_mask = self.out_mask = 0
        #: the bound input lines, ascending
        self.in_lines: list[int] = []
        #: the bound output lines, ascending
        self.out_lines: list[int] = []
        self._in_bits: list[tuple[int, int]] = []  # (image position, bit) per input
        self._out_bits: list[tuple[int, int]] = []  # (image position, bit) per output
        self._written: int | None = None  # the output word last written; None: unknown
        self._attached = False
        self._accepted: int | None = None  # debounced input word; None: take the next read
        self._since: dict[int, int] = {}  # bit -> clock() when its change was first read

    # -- back-end hooks -----------------------------------------------------------------
    @abc.abstractmethod
    def line(self, point: str) -> int:
        """The line of ``point``: its bit in the bank's word."""

    @abc.abstractmethod
    def where(self) -> str:
        """The device, for messages."""

    @abc.abstractmethod
    def _attach(self) -> int:
        """Open and set up the device; return the output word it holds now."""

    @abc.abstractmethod
    def _read_word(self) -> int:
        """Every line's level, bit n for line n. Raise OSError/DriverError on a fault."""

    @abc.abstractmethod
    def _write_word(self, word: int, changed: int) -> None:
        """Set the output lines to ``word`` (``changed``: the bits to write)."""

    @abc.abstractmethod
    def _detach(self) -> None:
        """Release the device (idempotent)."""

    # -- for back-ends ------------------------------------------------------------------
    def output_word(self) -> int:
        """The outputs of the image as the bank's word: 0 while inhibited."""
        if self.inhibited:
            return 0
        vals = self.outputs.vals
        word = 0
        for pos, bit in self._out_bits:
            if vals[pos]:
                word |= bit
        return word

    @property
    def written(self) -> int | None:
        """The output word last written to the device; None when unknown."""
        return self._written

    def setup_word(self) -> int:
        """The output word a set-up writes (at open, after a power loss): ``output_word``,
        taken as written (0 while inhibited: a set-up never energises an inhibited bank)."""
        self._written = word = self.output_word()
        return word

    # -- Driver hooks -------------------------------------------------------------------
    def _open(self) -> None:
        self.in_lines = sorted(self.line(p) for p in self.inputs)
        self.out_lines = sorted(self.line(p) for p in self.outputs)
        self.in_mask = sum(1 << n for n in self.in_lines)
        self.out_mask = sum(1 << n for n in self.out_lines)
        self._in_bits = [(i, 1 << self.line(p)) for p, i in self.inputs.index.items()]
        self._out_bits = [(i, 1 << self.line(p)) for p, i in self.outputs.index.items()]
        self._accepted, self._written = None, None
        self._since.clear()
        try:
            self._written = self._attach()
        except OSError as exc:
            self._close()
            raise DriverError(f"{self.where()}: {exc}") from exc
        except DriverError:
            self._close()
            raise
        self._attached = True

    def _read(self) -> None:
        try:
            word = self._read_word()
        except OSError as exc:
            raise DriverError(f"{self.where()}: {exc}") from exc
        if self.debounce_s > 0 and self.SOFT_DEBOUNCE:
            word = self._debounced(word)
        vals = self.inputs.vals
        for pos, bit in self._in_bits:
            vals[pos] = word & bit != 0

    def _write(self) -> None:
        if not self._attached or not self.out_mask:
            return
        word = self.output_word()
        written = self._written
        if word == written:
            return
        changed = self.out_mask if written is None else word ^ written
        try:
            self._write_word(word, changed)
        except OSError as exc:
            raise DriverError(f"{self.where()}: {exc}") from exc
        self._written = word

    def _safe_state(self) -> None:
        if not self._attached:  # never opened, or lost: nothing to write to
            return
        self._written = None  # write every output, whatever the last write was
        self._write()

    def _close(self) -> None:
        self._attached = False
        self._written = None
        self._detach()

    def _debounced(self, raw: int) -> int:
        """The input word with every change younger than ``debounce_s`` held back."""
        now = self.clock()
        accepted = self._accepted
        if accepted is None:  # the first read after an open: the levels as they are
            self._accepted = raw & self.in_mask
            return raw
        diff = (raw ^ accepted) & self.in_mask
        since = self._since
        for bit in [b for b in since if not diff & b]:  # back before the period: a bounce
            del since[bit]
        period_ns = int(self.debounce_s * 1e9)
        while diff:
            bit = diff & -diff
            diff ^= bit
            first = since.setdefault(bit, now)
            if now - first >= period_ns:
                accepted ^= bit
                del since[bit]
        self._accepted = accepted
        return accepted
