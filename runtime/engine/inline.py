"""The plant's usual cycle with every instance's scan inlined: no call per instance.

A compiled chart's scan keeps its state in the cells of its closure (program.State), and
its fast path (``Program.fast``, the body for a scan that starts with ``slow`` false) is
plain Python over those cells. This module writes, for a group of instances, one body
that is, per instance: its input bindings stored into its cells, then its fast path with
every state name made the instance's own (``p3_x_gsAbrir``, a cell) and every temporary
the group's (``t_f0``), or its whole scan (``scan_state``) when its ``slow`` cell is set;
then its outputs copied through their bindings (by position in the drivers' images).

Each group is a generator made of that code with the instances' own cells as its closure
(``types.FunctionType(code, globals, name, defaults, closure)``), started once: it reads
and writes the very cells the instances' scan closures and state views use, so the
console, trace, retain and online change see no difference. A cycle resumes it with
``send((now, up))``: its frame, cells and defaults in it, is made once, where a function
call would copy every cell of its closure into a new frame each time (about 0.8 ns a cell,
some 27 cells per drawer tester). A scan's fault is caught in the generator and handed
back to the cycle, which raises it: the generator lives on for the cycles after the fault.

The instances are grouped (up to ``GROUP`` per generator, as many as keep the names of a
group's code under 256, see ``NAMES``), so each group's source compiles on
its own, and the groups of a plant of like instances (one chart, bindings of one shape:
what differs between instances, a point's position or a scan function, is a default
argument, ``K0``, and another group's cell a numbered name, ``L0``) share one code
object: the plant compiles one group's text, not every instance's (about 10 ms instead of
70 for 100 drawer testers). A fault in an inlined scan is raised in a frame of
``FILENAME``; :meth:`Inliner.owner` gives its instance from the frame's group number
(``_group``) and line.
"""

from __future__ import annotations

import builtins
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeAlias

from runtime.compiler.codebook import CodeBook, compile_code
from runtime.compiler.codegen import FAST_CLOCK, SCAN_GLOBALS
from runtime.compiler.emit import code_names, comment, renamed
from runtime.compiler.program import Program
from runtime.engine.instance import Instance

#: the file name of the groups' code, as tracebacks show it
FILENAME = "<plant scans>"
#: instances per group, at most
GROUP = 16
#: the names a group's members may take in its code (its constants, temporaries and
#: cells), so that with the group's own few every name's index stays under 256: an index
#: over 255 costs an ``EXTENDED_ARG`` instruction at each use (a group of 16 drawer
#: testers had 2678 of them, 30% of its instructions, and ran 15% slower than groups of 4)
NAMES = 240
_BUILTINS = set(dir(builtins))
#: a group's generator (types.GeneratorType: ``gi_frame`` tells whether it has ended)
GroupGen: TypeAlias = "types.GeneratorType[BaseException | None, tuple[int, int], None]"
#: a group's ``send((now, up))``: None, or the exception one of its scans raised
Send = Callable[[tuple[int, int]], "BaseException | None"]


def scan_code(inst: Instance) -> types.CodeType:
    """The code object of the instance's scan closure (its locals are the temporaries)."""
    for c in inst.program.factory.__code__.co_consts:
        if isinstance(c, types.CodeType) and c.co_name == "scan":
            return c
    raise LookupError(f"no scan function in the program of {inst.name}")


@dataclass
class Template:
    """A program's fast path made ready to inline: its text with every name of the
    instance's own marked (:data:`MARK`, replaced by the instance's prefix), and the
    state slots it uses (their cells become free variables of the group). Its
    temporaries are the group's (``t_f0``): each scan writes one before it reads it (its
    own scan function would raise otherwise), so the members share them."""

    text: str
    slots: list[int]  # the state slots the body names, by index
    helpers: set[str]  # the module names it calls (``_idiv``, ``_Unstable``)
    temps: set[str]  # the temporaries it names, as the group names them


#: where an instance's prefix goes in a template (a character no Python source holds)
MARK = "\x00"
#: the chart clock of an inlined fast path (in place of ``codegen.FAST_CLOCK``). A chart
#: never paused since it started with the plant has its clock base ``cb`` equal to the
#: plant's start, ``_base`` (``now - up``, a group's local set at its first cycle), so
#: its clock is ``up``: the instances of a group that share that base share one object,
#: where ``now - cb`` made a new integer per instance and scan (about 30 ns at 100 drawer
#: testers). A base equal to ``_base`` but not the same object (set by a full scan) is
#: made that object, once; any other base (a chart once paused, or started later) counts
#: its own clock, as before. A start moved on a running plant starts the groups again
#: (``Inliner.restart``, from ``Plant.start``).
SHARED_CLOCK = ["if cb is _base: ct = up",
                "else:",
                "    ct = now - cb",
                "    if cb == _base: cb = _base"]


def template(prog: Program, code: types.CodeType) -> Template:
    """The template of ``prog``'s fast path; ``code``: its scan function's code (the
    scan's own locals are the temporaries)."""
    state = {s.local: i for i, s in enumerate(prog.slots)}
    temps = set(code.co_varnames[code.co_argcount:])
    used: set[int] = set()
    helpers: set[str] = set()
    named: set[str] = set()

    def rename(name: str) -> str | None:
        if name in state:
            used.add(state[name])
        elif name in temps:
            named.add("t_" + name)
            return "t_" + name
        elif name != "slow":
            if name in SCAN_GLOBALS:
                helpers.add(name)
                return None
            if name in ("now", "up", "_base") or name in _BUILTINS:
                return None
            raise LookupError(f"{name!r} in the scan of chart {prog.grafcet.name}: not a "
                              "state slot, a temporary or a helper")
        return MARK + name

    fast = list(prog.fast)
    if fast[:1] == [FAST_CLOCK]:  # the clock shared: see SHARED_CLOCK
        fast[:1] = SHARED_CLOCK
    text = "\n".join("    " + line for line in renamed(fast, rename))
    return Template(text, sorted(used), helpers, named)


class Inliner:
    """Writes and builds the groups of a plant's usual cycle.

    For every instance in plant order ``begin(inst)``, then its lines written with the
    names :meth:`cell`, :meth:`slow` and :meth:`const` give, then ``add(inst, inputs,
    outputs)``; then ``build()``. A group's text names its instances by their position in
    the group (``p3_``), other instances' cells and every per-instance value (a point's
    key, a scan function) by a number (``L0``, ``K0``): the groups of a plant of like
    instances have one text, compiled once, each group's function made of that code with
    its own cells and values (its closure and its defaults)."""

    def __init__(self, env: dict[str, Any], instances: list[Instance],
                 bindings: dict[str, int]) -> None:
        """``env``: the plant cycle's environment (the groups' globals); ``instances``:
        every instance, in plant order; ``bindings``: each one's number of bound inputs
        and outputs (each takes about a name in its group: a position, or a cell of
        another instance)."""
        self.env = env
        self._templates: dict[int, Template] = {}
        #: per group: its instances in order (at most GROUP, within NAMES)
        self.members: list[list[Instance]] = []
        size, temps = NAMES, set[str]()
        for inst in instances:
            tpl = self._template(inst)
            names = len(tpl.slots) + 2 + bindings.get(inst.name, 0)
            if (size + names + len(temps | tpl.temps) > NAMES
                    or len(self.members[-1]) >= GROUP):
                self.members.append([])
                size, temps = 0, set()
            self.members[-1].append(inst)
            size += names
            temps |= tpl.temps
        #: every instance's group and position in it
        self._pos = {inst.name: (g, j) for g, members in enumerate(self.members)
                     for j, inst in enumerate(members)}
        self._group = -1
        self._texts: list[list[str]] = []  # per group: each member's lines, joined
        self._free: list[dict[str, Any]] = []  # per group: free name -> its cell
        self._consts: list[dict[str, Any]] = []  # per group: default name -> its value
        self._links: list[dict[int, str]] = []  # per group: id(cell) -> its L name
        self._used: list[set[str]] = []  # per group: the words its lines name
        #: per distinct code: the position (in the group) of each line of its source
        self._lines: dict[types.CodeType, list[int]] = {}
        #: the distinct sources compiled (``FILENAME``), for reading
        self.sources: list[str] = []
        #: each group's generator function, and its running generator's ``send`` (the
        #: list the plant's cycle calls through, see :meth:`revive`)
        self.factories: list[Callable[[], GroupGen]] = []
        self.sends: list[Send] = []
        self._gens: list[GroupGen] = []

    def _template(self, inst: Instance) -> Template:
        """The template of ``inst``'s program (made once per program)."""
        tpl = self._templates.get(id(inst.program))
        if tpl is None:
            tpl = self._templates[id(inst.program)] = template(inst.program, scan_code(inst))
        return tpl

    # -- names, for the lines of the current group ---------------------------------------
    def cell(self, inst: Instance, index: int) -> str:
        """The name of ``inst``'s slot ``index`` in the current group (a free variable):
        ``p{position}_{local}`` for a member of the group, ``L{n}`` for another."""
        cell = inst.m.cells[index]
        g, j = self._pos[inst.name]
        if g == self._group:
            name = f"p{j}_{inst.program.slots[index].local}"
        else:
            links = self._links[-1]
            name = links.setdefault(id(cell), f"L{len(links)}")
        self._free[-1][name] = cell
        return name

    def slow(self, inst: Instance) -> str:
        """The name of member ``inst``'s ``slow`` cell in the current group."""
        name = f"p{self._pos[inst.name][1]}_slow"
        self._free[-1][name] = inst.m.slow
        return name

    def const(self, value: Any) -> str:
        """The name of ``value`` (a point's key, a function) in the current group: one of
        its function's defaults, ``K{n}``."""
        consts = self._consts[-1]
        name = f"K{len(consts)}"
        consts[name] = value
        return name

    # -- the groups ------------------------------------------------------------------
    def begin(self, inst: Instance) -> None:
        """Start ``inst``'s lines (in plant order), in a new group if it is the first of
        one."""
        g, _ = self._pos[inst.name]
        if g != self._group:
            self._group = g
            self._texts.append([])
            self._free.append({})
            self._consts.append({"_group": g})
            self._links.append({})
            self._used.append(set())

    def add(self, inst: Instance, inputs: list[str], outputs: list[str]) -> None:
        """Inline ``inst``'s scan into the current group, after its input lines and
        before its output lines (both at column 0)."""
        j = self._pos[inst.name][1]
        tpl = self._template(inst)
        for i in tpl.slots:
            self.cell(inst, i)
        self._used[-1] |= tpl.helpers | {n for line in inputs + outputs
                                          for n in code_names(line)}
        self._texts[-1].append("\n".join([
            comment(f"instance {j} of the group ({inst.grafcet.name})"), *inputs,
            f"if {self.slow(inst)}: {self.const(inst.scan_state)}(now, up)", "else:",
            tpl.text.replace(MARK, f"p{j}_"), *outputs]))

    def build(self, book: CodeBook | None) -> list[Send]:
        """The groups, in plant order, on the instances' own cells: each a generator,
        created and started once, whose ``send((now, up))`` runs the group's scans and
        returns None, or the exception a scan raised (the generator lives on: the cycle
        raises it)."""
        codes: dict[str, types.CodeType] = {}
        out: list[Send] = []
        for texts, free, consts, used in zip(self._texts, self._free, self._consts,
                                             self._used, strict=True):
            params = sorted(consts) + sorted(used & self.env.keys())
            names = sorted(free)
            head = ["def _outer():", *(f"    {n} = None" for n in names),
                    f"    def group({', '.join(f'{n}=None' for n in params)}):"]
            if names:
                head.append(f"        nonlocal {', '.join(names)}")
            head += ["        _box = []", "        now, up = yield", "        _base = now - up",
                     "        while True:", "            try:"]
            lines = [-1] * len(head)
            body = []
            for j, text in enumerate(texts):
                chunk = text.split("\n")
                body += ["                " + line for line in chunk]
                lines += [j] * len(chunk)
            # a scan's fault goes to the cycle, which raises it; the suspended frame does
            # not keep it (it would keep the fault's frames, and the plant, alive)
            tail = ["            except GeneratorExit:",
                    "                raise",
                    "            except BaseException as _fault:",
                    "                _box.append(_fault)",
                    "            if _box:",
                    "                now, up = yield _box.pop()",
                    "            else:",
                    "                now, up = yield",
                    "    return group"]
            source = "\n".join([*head, *body, *tail]) + "\n"
            code = codes.get(source)
            if code is None:
                module = compile_code(source, FILENAME, self.env.keys(), book)
                outer = next(c for c in module.co_consts if isinstance(c, types.CodeType))
                code = codes[source] = next(c for c in outer.co_consts
                                            if isinstance(c, types.CodeType))
                self._lines[code] = [*lines, *[-1] * len(tail)]
                self.sources.append(source)
            values = {**self.env, **consts}
            defaults = tuple(values[n] for n in code.co_varnames[:code.co_argcount])
            fn = types.FunctionType(code, self.env, "group", defaults,
                                    tuple(free[n] for n in code.co_freevars))
            self.factories.append(fn)
            self._gens.append(_start(fn))
            out.append(self._gens[-1].send)
        self.sends = out
        return out

    def revive(self) -> list[int]:
        """Start again every group whose generator has ended (an exception raised where no
        scan catches it: at its resume, e.g. from a signal handler in the main thread);
        their ``send`` is replaced in :attr:`sends`, the list the cycle calls through.
        Returns the groups started again. The instances' state is in their cells: nothing
        of it is lost."""
        dead = [j for j, gen in enumerate(self._gens) if gen.gi_frame is None]
        for j in dead:
            self._gens[j] = _start(self.factories[j])
            self.sends[j] = self._gens[j].send
        return dead

    def restart(self) -> None:
        """Start every group again: each works out its ``_base`` (the plant's start) at its
        first cycle, so a start moved on a running plant needs new groups (the instances'
        state is in their cells: nothing of it is lost)."""
        for j, gen in enumerate(self._gens):
            gen.close()
            self._gens[j] = _start(self.factories[j])
            self.sends[j] = self._gens[j].send

    def close(self) -> None:
        """End every group's generator (the plant is disposed of)."""
        for gen in self._gens:
            gen.close()

    def owner(self, frame: types.FrameType, lineno: int) -> str | None:
        """The instance whose inlined scan is at line ``lineno`` of ``frame`` (a frame of
        a group, in a fault's traceback), None if none."""
        lines = self._lines.get(frame.f_code)
        g = frame.f_locals.get("_group")
        if lines is None or not isinstance(g, int) or not 1 <= lineno <= len(lines):
            return None
        j = lines[lineno - 1]
        return self.members[g][j].name if j >= 0 else None


def _start(fn: Callable[[], GroupGen]) -> GroupGen:
    """A group's generator, run to its first yield (ready for a cycle)."""
    gen = fn()
    next(gen)
    return gen
