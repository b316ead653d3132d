"""A compiled grafcet: its scan factory, the layout of its state, and the accessors.

The state ``m`` of an instance holds every variable, each step's ``X``, the times its
``.T`` is made of, every function block and the scan's own memory. It lives in the cells
of the instance's scan closure; :class:`State` is the view of it that outside code reads
and writes by slot index, between scans, like a list. Only the compiler knows the layout;
everything else reads and writes through a Program's methods, by the names a person uses
(``iMarcha``, a step's X and T).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from types import CellType, CodeType, FunctionType
from typing import Any

from runtime.compiler import blocks as B
from runtime.compiler.emit import code_names
from runtime.compiler.guard import checked_eval
from runtime.language import ast as A
from runtime.language.model import Grafcet

#: the first part of the key of a coverage counter's slot (``compile_grafcet(coverage=True)``,
#: layout.coverage_key)
COVERAGE = "#cover:"


class SlotKind(enum.Enum):
    """What one entry of the state list holds."""

    VARIABLE = "variable"  # a chart variable or flag (not the SYSTEM clock bits)
    STEP_X = "step X"  # a step's activity
    STEP_START = "step start"  # chart clock (ns) at the step's activation
    STEP_LAST = "step last T"  # the step's .T (ns) frozen when it was left
    BLOCK = "block"  # a function-block or seed-timer object
    CLOCK = "chart clock"  # chart time (ns): advances unless the chart is paused
    INTERNAL = "internal"  # the scan's own memory (edges, stored actions, flags' history)


@dataclass
class Slot:
    """One entry of an instance's state list."""

    key: str  # the compiler's own key: "iParo", "gsAbrir.X", "#ct" ...
    local: str  # name of the local in the scan function
    init: Any
    block: str | None = None  # function-block kind to instantiate per instance
    kind: SlotKind = SlotKind.INTERNAL
    name: str = ""  # the variable, step or block it belongs to ("" for internal memory)
    type: A.Type | None = None  # a variable's type, BOOL for X, TIME for the step times
    index: int = 0  # position in the state list


def step_time_code(x: str, ct: str, t0: str, tk: str) -> str:
    """The expression of ``step.T`` (ns), given the expressions of the step's X, the chart
    clock, the clock at its activation and the .T kept when it was left: the time since
    activation while active, else the duration of its last activity. The one place this
    formula is written: the scan function inlines it, Program evaluates it."""
    return f"({ct} - {t0} if {x} else {tk})"


@dataclass
class Probe:
    """A sub-term of a transition condition that ``explain`` evaluates on an instance."""

    text: str
    depth: int
    fn: Callable[[Memory, int, int], Any]


#: ``scan(now, up, *inputs)`` -> the outputs (a tuple), or None for a chart without any
Scan = Callable[..., "tuple[Any, ...] | None"]
#: ``scan_state(now, up)``: one scan with the inputs as they are in the state
ScanState = Callable[[int, int], "tuple[Any, ...] | None"]


_WHOLE = slice(None)


class State:
    """An instance's state, as a list of slots: ``m[i]``, ``m[i] = v``, ``len(m)``,
    iteration, ``m[:]`` (a list copy) and ``values()`` (a tuple copy: what the process
    image's captures keep, since a tuple of plain values is left out of the garbage
    collector's work after its first young collection, where a list is examined by every
    full one). The values are the cells of the instance's scan closure, so a read sees the
    last scan's value and a write is seen by the next scan; use it between scans (the scan
    thread's owner decides when)."""

    __slots__ = ("cells", "slow", "values")

    def __init__(self) -> None:
        #: the cell of each slot, in slot order (set by :meth:`Program.instantiate`)
        self.cells: list[Any] = []
        #: the cell of the scan's ``slow`` flag: set by every write, so that the next
        #: scan takes its slow path (the chart flags tested, then the flag recomputed)
        self.slow: Any = None
        #: every slot's value as a new tuple, read by the closure itself
        self.values: Callable[[], tuple[Any, ...]] = tuple

    def __getitem__(self, i: Any) -> Any:
        if i.__class__ is slice:  # the values, as a new list
            values = self.values()
            return list(values if i == _WHOLE else values[i])
        return self.cells[i].cell_contents

    def __setitem__(self, i: int, value: Any) -> None:
        self.cells[i].cell_contents = value
        self.slow.cell_contents = True

    def __len__(self) -> int:
        return len(self.cells)

    def getter(self, slots: Sequence[int]) -> Callable[[], tuple[Any, ...]]:
        """A function of no argument giving the values of ``slots`` as a tuple: what
        ``operator.itemgetter(*slots)`` gave on a state list, at the cost of one cell read
        each (for the scan thread's listeners; valid as long as this state's cells are,
        i.e. the instance's life)."""
        env = {f"c{k}": self.cells[i] for k, i in enumerate(slots)}
        code = "lambda: (" + "".join(f"c{k}.cell_contents, " for k in range(len(env))) + ")"
        fn: Callable[[], tuple[Any, ...]] = checked_eval(code, env, ("cell_contents",))
        return fn

    def __iter__(self) -> Iterator[Any]:
        return iter(self.values())

    def __repr__(self) -> str:
        return f"State({self[:]!r})"


#: an instance's state (its live view) or a copy of it (a list, ``m[:]``; a tuple,
#: ``values()``)
Memory = State | list[Any] | tuple[Any, ...]


@dataclass
class Program:
    """A compiled grafcet: generated source, scan factory, state layout and accessors."""

    grafcet: Grafcet
    source: str
    factory: Callable[[State, list[Any]], tuple[Scan, ScanState, Callable[[], list[Any]]]]
    slots: list[Slot]
    #: builds the sub-terms of every transition's condition for ``explain`` (by transition
    #: index): called on the first read of :attr:`probes`, not at compile time
    make_probes: Callable[[], dict[int, list[Probe]]] = dict
    inputs: list[str] = field(default_factory=list)  # scan's arguments after ``up``
    outputs: list[str] = field(default_factory=list)  # what a scan returns, in order
    #: the scan's fast path (``slow`` false at its start), unindented, after the inputs'
    #: stores and before the return: the body the plant's cycle inlines (plant.py)
    fast: list[str] = field(default_factory=list)
    _by_key: dict[str, int] = field(init=False, repr=False)
    _step_times: dict[str, Callable[[Memory], int]] = field(init=False, repr=False)
    _cells: list[str] = field(init=False, repr=False)
    _probes: dict[int, list[Probe]] | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._by_key = {s.key: s.index for s in self.slots}
        self._step_times = {}
        self._cells = []
        self._probes = None

    @property
    def probes(self) -> dict[int, list[Probe]]:
        """The sub-terms of every transition condition (transition index -> terms, the
        whole condition first), built on first use: only ``explain`` reads them (a
        1000-step chart's 1747 sub-terms take 0.1 s of processor time to compile)."""
        if self._probes is None:
            self._probes = self.make_probes()
        return self._probes

    def instantiate(self, m: State, init: list[Any] | None = None
                    ) -> tuple[Scan, ScanState]:
        """A new scan closure whose state is ``m`` (its cells bound into ``m``), starting
        from ``init`` (default :meth:`new_state`); returns ``(scan, scan_state)``."""
        make = self.factory
        codes = {c.co_name: c for c in make.__code__.co_consts if isinstance(c, CodeType)}
        # the cells ``make`` would make, made here in the order the usual scan first uses
        # them (its inputs, ``slow``, its fast path's names): one after the other in
        # memory, the ones a plant of many instances touches every cycle take the fewest
        # cache lines (at 1000 drawer testers, 18 ns less per scan than make's order)
        cells = {name: CellType() for name in self._cell_order()}
        init = self.new_state() if init is None else init
        for s, value in zip(self.slots, init, strict=True):
            cells[s.local].cell_contents = value
        cells["m"].cell_contents = m
        cells["slow"].cell_contents = True  # a chart flag or an outside write may be pending
        fns = {name: FunctionType(codes[name], make.__globals__, name, None,
                                  tuple(cells[n] for n in codes[name].co_freevars))
               for name in ("scan", "slowscan", "scan_state", "values") if name in codes}
        cells["scan"].cell_contents = scan = fns["scan"]
        if "slowscan" in fns:  # the slow path, a closure of its own (codegen.py)
            cells["slowscan"].cell_contents = fns["slowscan"]
        m.values = fns["values"]
        m.cells = [cells[s.local] for s in self.slots]
        m.slow = cells["slow"]
        return scan, fns["scan_state"]

    def _cell_order(self) -> list[str]:
        """The names of the scan closure's cells (``make``'s), in the order the plant's
        usual cycle first touches them: the chart's inputs, ``slow``, then the names of
        the fast path in text order; the rest after."""
        order = self._cells
        if not order:
            cellvars = self.factory.__code__.co_cellvars
            cells = set(cellvars)  # a set: n names tested, not n² compared
            seen = dict.fromkeys([f"v_{v}" for v in self.inputs] + ["slow"])
            for line in self.fast:  # line by line: no one long call holding the GIL
                seen.update(dict.fromkeys(code_names(line)))
            seen.update(dict.fromkeys(cellvars))
            order = self._cells = [n for n in seen if n in cells]
        return order

    def new_state(self) -> list[Any]:
        """A fresh state list: initial values, one new object per function block."""
        state = []
        for s in self.slots:
            if s.block == "SeedTimer":
                state.append(B.SeedTimer())
            elif s.block is not None:
                state.append(B.BLOCKS[s.block]())
            else:
                state.append(s.init)
        return state

    # -- where things are ------------------------------------------------------------
    def var_index(self, name: str) -> int:
        """Slot of variable ``name``; KeyError if it has none (unknown, a SYSTEM bit)."""
        s = self.slots[self._by_key[name]]
        if s.kind is not SlotKind.VARIABLE:
            raise KeyError(name)
        return s.index

    def x_index(self, step: str) -> int:
        """Slot of ``step.X``; KeyError for an unknown step."""
        return self._by_key[f"{step}.X"]

    def block_index(self, name: str) -> int:
        """Slot of the function block or seed timer ``name``."""
        s = self.slots[self._by_key[name]]
        if s.kind is not SlotKind.BLOCK:
            raise KeyError(name)
        return s.index

    def index_of(self, name: str) -> int:
        """Slot of a readable name as a plant file writes it: a variable or ``step.X``."""
        if name.endswith(".X") and name[:-2] in self.grafcet.steps:
            return self.x_index(name[:-2])
        return self.var_index(name)

    def public_index(self) -> dict[str, int]:
        """Slot of every name outside code may address: variables, ``step.X``, blocks."""
        out = {}
        for s in self.slots:
            if s.kind in (SlotKind.VARIABLE, SlotKind.BLOCK):
                out[s.name] = s.index
            elif s.kind is SlotKind.STEP_X:
                out[f"{s.name}.X"] = s.index
        return out

    # -- reading and writing a state list -------------------------------------------
    def read(self, m: Memory, name: str) -> Any:
        """Value of variable ``name`` in state list ``m``."""
        return m[self.var_index(name)]

    def write(self, m: State | list[Any], name: str, value: Any) -> None:
        """Store ``value`` (already of the variable's type) into variable ``name``."""
        m[self.var_index(name)] = value

    def step_active(self, m: Memory, step: str) -> bool:
        """``step.X`` in ``m``."""
        return bool(m[self.x_index(step)])

    def step_time(self, m: Memory, step: str) -> int:
        """``step.T`` (ns) in ``m``, as the chart sees it (kept after deactivation)."""
        return self.step_time_reader(step)(m)

    def slot_indices(self, step: str) -> tuple[int, int, int, int]:
        """The slots ``step.T`` is computed from (``step_time_code``): its X, the chart
        clock, the clock at its activation, the .T kept when it was left."""
        ix = self._by_key
        return ix[step + ".X"], ix["#ct"], ix[step + ".T0"], ix[step + ".TK"]

    def step_time_reader(self, step: str) -> Callable[[Memory], int]:
        """A function of a state list giving ``step.T`` (ns); built once per step."""
        fn = self._step_times.get(step)
        if fn is None:
            ix = self._by_key
            code = step_time_code(f"m[{ix[step + '.X']}]", f"m[{ix['#ct']}]",
                                  f"m[{ix[step + '.T0']}]", f"m[{ix[step + '.TK']}]")
            fn = checked_eval(f"lambda m: int({code})", {})
            self._step_times[step] = fn
        return fn

    def scan_time(self, m: Memory) -> int:
        """Monotonic time (ns) of the last scan of ``m``: its clock base plus its chart
        clock (the base is set so at every scan)."""
        return int(m[self._by_key["#clockbase"]] + m[self._by_key["#ct"]])

    def coverage(self, m: Memory) -> dict[str, int]:
        """The counters of a program compiled with ``coverage=True``, by what they count:
        ``step:NAME`` (activations), ``transition:INDEX`` (firings), ``action:N`` (runs of
        the N-th action of ``Grafcet.actions()``); empty without coverage."""
        return {s.key[len(COVERAGE):]: int(m[s.index]) for s in self.slots
                if s.key.startswith(COVERAGE)}

    def chart_paused(self, m: Memory) -> bool:
        """Whether the last scan of ``m`` was paused (SFCPause/SFCQuitError)."""
        return bool(m[self._by_key["#paused"]])
