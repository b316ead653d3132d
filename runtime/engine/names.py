"""The names of a plant: resolved from its definition, read from an image, parsed.

A name is what a person types at the console or a script sets (``tester1.iMarcha``,
``tester1.gsParado.X``, ``tester1.gsParado.T``, ``sim.I0``, ``sim.ok``). PlantNames
resolves a name from the plant definition alone (no driver opened, no Plant built); the
Catalogue resolves every name of a running plant once, each with a reader that takes it
from an Image, a copy of the process image captured between two cycles.

A chart output is read as **applied**: what its driver point holds, through the
binding's inversion, in the output's type. While the plant runs that is the chart's value
(or a forced point's); while the outputs are held off (fault, halted, iocheck, a watchdog
inhibit: every point written off) it is off, whatever the stopped chart last said. Every
display reads the Catalogue (the console's ``get``, ``status`` and streams, the monitor,
the feed of the OPC UA server, the MQTT edge node and the web page), so none shows an
output the machine does not have. The chart's own value stays readable
(``Signal.chart``), and the console says where it differs ("not applied").
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from drivers.base import PointKind
from drivers.durations import format_ns, parse_literal
from runtime.errors import SoftplcError, suggest
from runtime.language import ast as A
from runtime.language.iolist import IOList
from runtime.language.model import Binding, PlantDef, Variable, VarKind

if TYPE_CHECKING:
    from runtime.compiler.program import Memory
    from runtime.engine.plant import Plant


class CommandError(SoftplcError):
    """A command that cannot be carried out; the message is the reply's reason.

    Examples: a bad value (``set tester1.iParo 7``), an unknown name, ``cycle`` while the
    charts run."""


class UnknownName(SoftplcError, LookupError):
    """A name that does not resolve; the message says why, with the closest name."""


class Owner(enum.Enum):
    """What the first part of a plant name designates."""

    INSTANCE = "instance"
    DRIVER = "driver"


@dataclass(frozen=True, slots=True)
class ScriptInput:
    """What a simulation script may set: an unbound chart input or flag (written into the
    instance), a chart input bound to a driver point (written into that point, inverted
    at the binding), or a driver's input point (raw). A chart input bound to another
    instance or to ``driver.ok`` cannot be set: ``bound_to`` names that source."""

    key: str
    instance: str | None = None
    variable: Variable | None = None
    driver: str | None = None
    point: str | None = None
    invert: bool = False
    bound_to: str | None = None


class PlantNames:
    """The names of a plant, from its definition: its instances with their charts, its
    drivers with the points the bindings declare (or, on a built plant, the drivers'
    own point tables)."""

    def __init__(self, pdef: PlantDef,
                 points: Mapping[str, tuple[Collection[str], Collection[str]]] | None = None
                 ) -> None:
        """``points``: driver -> (input points, output points); by default the points the
        bindings declare, in the order a Plant declares them."""
        self.pdef = pdef
        if points is None:
            found: dict[str, tuple[dict[str, None], dict[str, None]]] = {
                d: ({}, {}) for d in pdef.drivers}
            for idef in pdef.instances.values():
                for k, section in enumerate((idef.inputs, idef.outputs)):
                    for b in section.values():
                        if b.driver is not None and b.point != "ok" and b.driver in found:
                            found[b.driver][k][b.point or ""] = None
            points = found
        self.points = points

    def owner(self, name: str) -> tuple[Owner, str, str]:
        """``instance.rest`` or ``driver.point`` (a declared point or ``ok``) ->
        (owner, head, rest); UnknownName otherwise."""
        head, _, rest = name.partition(".")
        if head in self.pdef.instances and rest:
            return Owner.INSTANCE, head, rest
        if head in self.points and rest:
            ins, outs = self.points[head]
            if rest in ins or rest in outs or rest == "ok":
                return Owner.DRIVER, head, rest
        raise UnknownName(f"unknown name '{name}'")

    def script_input(self, key: str) -> ScriptInput:
        """What setting ``key`` in a simulation script writes; UnknownName if it is no
        input (see ``bound_to`` for an input that is bound to what cannot be set)."""
        head, _, rest = key.partition(".")
        if head in self.pdef.instances and rest:
            idef = self.pdef.instances[head]
            g = idef.grafcet
            var = g.variables.get(rest)
            if var is None or (var.kind is not VarKind.INPUT and var.kind is not VarKind.FLAG):
                names = [v.name for v in g.variables.values() if v.kind in (VarKind.INPUT,
                                                                              VarKind.FLAG)]
                raise UnknownName(f"'{key}' is not an input or chart flag of {head}"
                                  f"{suggest(rest, names)}")
            b: Binding | None = idef.inputs.get(rest)
            if b is None:  # an unbound chart flag: written into the instance
                return ScriptInput(key, head, var)
            if b.driver is None or b.point == "ok":
                return ScriptInput(key, head, var, bound_to=b.source)
            return ScriptInput(key, head, var, b.driver, b.point or "", b.invert)
        if head in self.points and rest:
            ins = self.points[head][0]
            if rest not in ins:
                raise UnknownName(f"'{key}' is not an input point of driver {head}"
                                  f"{suggest(rest, ins)}")
            return ScriptInput(key, driver=head, point=rest)
        raise UnknownName(f"unknown name '{key}': expected instance.input, instance.SFCFlag "
                          "or driver.point" + suggest(head, [*self.pdef.instances,
                                                             *self.pdef.drivers]))


@dataclass(slots=True)
class Image:
    """The process image after one cycle: state slots, driver images, driver health.

    A driver's image is its value list (``drivers.image.Image.vals``), read by the point's
    position. A capture is tuples (one C copy each, no lookup per point) of values only,
    which the garbage collector stops examining at their first young collection; lists
    would be examined by every full one (the console's streams hold hundreds of
    captures: tens of ms a full collection at 100 testers)."""

    scan: int
    m: Sequence[Memory]
    inputs: Sequence[Sequence[Any]]
    outputs: Sequence[Sequence[Any]]
    ok: Sequence[bool]


@dataclass(frozen=True, slots=True)
class Signal:
    """A name of the running plant (what the console reads): its type and how to read it
    from an Image."""

    text: str
    type: A.Type
    read: Callable[[Image], Any]
    #: input, output, memory, temporary, chart flag, step, step time, point in/out, health
    role: str
    #: for a physical input: the chart inputs it feeds, (instance.signal, inverted)
    feeds: tuple[tuple[str, bool], ...] = ()
    #: for a chart input/output: its binding, e.g. "sim.I0 inverted"
    binding: str = ""
    #: for a chart output (whose ``read`` is the applied value, its point's): the chart's
    #: own value; None for every other name
    chart: Callable[[Image], Any] | None = None
    #: for a chart output: the point it is bound to ("sim.Q2")
    point: str = ""
    #: how a process beside the controller computes ``read`` from the shared image
    #: (runtime/controller/image.py), as plain data (never code): ("slot", i, idx),
    #: ("steptime", i, x, ct, t0, tk), ("current", i, ((step, x), ...)), ("point", "in" |
    #: "out", j, pos), ("applied", j, pos, invert, type), ("ok", j); i an instance's
    #: position in an Image, j a driver's, idx/x/ct/t0/tk slots of ``img.m[i]``
    spec: tuple[Any, ...] = ()

    def raw(self) -> list[tuple[tuple[str, int], int]] | None:
        """Where ``read`` takes its raw values from in an Image, from ``spec``: each as
        ((part, k), slot), part ``"m"`` (``img.m[k]``), ``"in"`` / ``"out"`` (driver
        ``k``'s input / output values) or ``"ok"`` (``img.ok``, k 0). None when it
        cannot be said by slots: a step time (the chart clock it is computed from
        changes every scan), a name without ``spec``."""
        spec = self.spec
        kind = spec[0] if spec else None
        if kind == "slot":
            return [(("m", spec[1]), spec[2])]
        if kind == "current":
            return [(("m", spec[1]), x) for _, x in spec[2]]
        if kind == "point":
            return [((spec[1], spec[2]), spec[3])]
        if kind == "applied":
            return [(("out", spec[1]), spec[2])]
        if kind == "ok":
            return [(("ok", 0), spec[1])]
        return None

    def show(self, value: Any) -> str:
        """The value as a person reads it: bools 0/1, times rounded to ms."""
        if self.type is A.Type.TIME and isinstance(value, int):
            return format_ns(round(value / 1e6) * 1_000_000)
        if isinstance(value, bool):
            return str(int(value))
        return str(value)

    def plain(self, value: Any) -> Any:
        """The value for JSON: bools 0/1, times in whole ms."""
        if self.type is A.Type.TIME and isinstance(value, int):
            return round(value / 1e6)
        return int(value) if isinstance(value, bool) else value


class Catalogue:
    """Every console name of a plant, resolved once: the plant's structure never changes
    after construction (restart() refills the state lists in place)."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.names: dict[str, Signal] = {}
        #: instance -> the position of its state in an Image (``img.m[k]``)
        self._instances = {n: k for k, n in enumerate(plant.instances)}
        #: instance -> {"inputs": [...], "outputs": [...], "memory": [...]}
        self.groups: dict[str, dict[str, list[str]]] = {}
        #: driver -> its point names
        self.points: dict[str, list[str]] = {}
        #: bound driver output point -> the chart output writing it
        self.written_by: dict[str, str] = {}
        #: the chart names their scan writes at every scan, whatever the situation (bool
        #: action targets, top-level pre/post assignments): a ``set`` is overwritten
        self.rewritten: set[str] = set()
        #: what each name means to a person (the plant file's I/O list)
        self.iolist = IOList(plant.pdef)
        feeds: dict[str, list[tuple[str, bool]]] = {}
        bindings: dict[str, str] = {}
        for name, idef in plant.pdef.instances.items():
            for sig, b in idef.inputs.items():
                bindings[f"{name}.{sig}"] = "<- " + b.source + (" inverted" if b.invert
                                                                else "")
                if b.driver is not None:
                    feeds.setdefault(b.source, []).append((f"{name}.{sig}", b.invert))
            for sig, b in idef.outputs.items():
                bindings[f"{name}.{sig}"] = "-> " + b.source + (" inverted" if b.invert
                                                                else "")
                self.written_by[b.source] = f"{name}.{sig}"
        #: driver output point -> (driver's position in an Image, the point's position)
        self._outputs = {f"{dname}.{p}": (j, pos)
                         for j, (dname, d) in enumerate(plant.drivers.items())
                         for p, pos in d.outputs.index.items()}
        for i, (name, inst) in enumerate(plant.instances.items()):
            self._instance(i, name, inst, bindings)
        for j, (dname, d) in enumerate(plant.drivers.items()):
            pts = []
            for direction, points in (("in", d.inputs), ("out", d.outputs)):
                for p, pos in points.index.items():
                    typ = A.Type.BOOL if d.kinds.get(p) is PointKind.BOOL else A.Type.INT
                    text = f"{dname}.{p}"
                    self.names[text] = Signal(text, typ, _point_reader(direction, j, pos),
                                              f"point {direction}",
                                              tuple(feeds.get(text, ())),
                                              spec=("point", direction, j, pos))
                    pts.append(text)
            text = f"{dname}.ok"
            self.names[text] = Signal(text, A.Type.BOOL, _ok_reader(j), "driver health",
                                      tuple(feeds.get(text, ())), spec=("ok", j))
            pts.append(text)
            self.points[dname] = pts
        #: what ``trace`` and ``cycle`` compare: everything but step times (they change
        #: every scan)
        self.traced = [n for n in self.names.values() if n.role != "step time"]
        #: the chart outputs bound to a point (read as applied, their ``chart`` beside)
        self.outputs = [n for n in self.names.values() if n.chart is not None]

    def _instance(self, i: int, name: str, inst: Any, bindings: dict[str, str]) -> None:
        from runtime.compiler.layout import written  # lazy: the controller's side only

        g, prog = inst.grafcet, inst.program
        self.rewritten.update(f"{name}.{v}" for v in written(g)[0])
        groups: dict[str, list[str]] = {"inputs": [], "outputs": [], "memory": []}
        for key in inst.names():
            text = f"{name}.{key}"
            if key.endswith(".T") and key[:-2] in g.steps:
                s = key[:-2]
                ix = prog.slot_indices(s)
                n = Signal(text, A.Type.TIME, _step_time_reader(i, prog.step_time_reader(s)),
                           "step time", spec=("steptime", i, *ix))
            elif key.endswith(".X") and key[:-2] in g.steps:
                x = prog.x_index(key[:-2])
                n = Signal(text, A.Type.BOOL, _slot_reader(i, x), "step",
                           spec=("slot", i, x))
            elif key == "SFCCurrentStep":
                leaf = tuple((s.name, prog.x_index(s.name)) for s in g.leaf_steps())
                n = Signal(text, A.Type.STRING, _current_step_reader(i, leaf), "chart flag",
                           spec=("current", i, leaf))
            else:
                v = g.variables[key]
                idx = prog.var_index(key)
                own = _slot_reader(i, idx)
                b = self.plant.pdef.instances[name].outputs.get(key)
                if v.kind is VarKind.OUTPUT and b is not None and b.source in self._outputs:
                    j, pos = self._outputs[b.source]
                    n = Signal(text, v.type, _applied_reader(j, pos, b.invert, v.type),
                               v.kind.value, binding=bindings.get(text, ""), chart=own,
                               point=b.source,
                               spec=("applied", j, pos, b.invert, v.type.value))
                else:
                    n = Signal(text, v.type, own, v.kind.value,
                               binding=bindings.get(text, ""), spec=("slot", i, idx))
                if v.kind is VarKind.INPUT:
                    groups["inputs"].append(text)
                elif v.kind is VarKind.OUTPUT:
                    groups["outputs"].append(text)
                elif v.kind is VarKind.MEMORY:
                    groups["memory"].append(text)
            self.names[text] = n
        self.groups[name] = groups

    def not_applied(self, img: Image) -> list[tuple[Signal, Any, Any, Any]]:
        """The chart outputs whose point does not hold what the chart says (the outputs
        held off, a forced point), each as (signal, the chart's value, the applied value,
        what the point holds)."""
        out = []
        for s in self.outputs:
            assert s.chart is not None
            applied, chart = s.read(img), s.chart(img)
            if not same(applied, chart):
                out.append((s, chart, applied, self.names[s.point].read(img)))
        return out

    def resolve(self, text: str) -> Signal:
        """The Signal for ``text``; CommandError naming the closest one if unknown."""
        n = self.names.get(text)
        if n is None:
            raise CommandError(f"unknown name '{printable(text)}'{suggest(text, self.names)}")
        return n

    def expand(self, words: list[str]) -> list[Signal]:
        """Names, where an instance or driver name alone stands for all its signals."""
        out: list[Signal] = []
        for w in words:
            if w in self.groups:
                g = self.groups[w]
                out += [self.names[t] for t in (*g["inputs"], *g["outputs"], *g["memory"])]
            elif w in self.points:
                out += [self.names[t] for t in self.points[w]]
            else:
                out.append(self.resolve(w))
        return out

    def physical_inputs(self) -> list[Signal]:
        return [n for n in self.names.values() if n.role == "point in"]

    def instance_index(self, name: str) -> int:
        """Where instance ``name``'s state is in an Image: ``img.m[k]``."""
        return self._instances[name]

    def release(self) -> None:
        """Let go of every name one at a time (for a Catalogue nobody else holds: it is
        empty afterwards). Dropped whole, a Catalogue of 100 testers frees its ~4000
        names in one cascade, some 2 ms in which no other thread takes the GIL."""
        for table in (self.names, self.groups, self.points, self.written_by,
                      self._outputs, self._instances):
            while table:
                table.popitem()
        while self.rewritten:
            self.rewritten.pop()

    def capture(self, scan: int) -> Image:
        """A copy of the process image (scan thread, between cycles: a tuple copy per
        instance and driver image)."""
        p = self.plant
        return Image(scan, tuple([inst.m.values() for inst in p.instances.values()]),
                     tuple([tuple(d.inputs.vals) for d in p.drivers.values()]),
                     tuple([tuple(d.outputs.vals) for d in p.drivers.values()]),
                     tuple([d.ok for d in p.drivers.values()]))

    def live(self) -> Image:
        """The process image itself, without copies (read it at a scan boundary only)."""
        p = self.plant
        return Image(-1, [inst.m for inst in p.instances.values()],
                     [d.inputs.vals for d in p.drivers.values()],
                     [d.outputs.vals for d in p.drivers.values()],
                     [d.ok for d in p.drivers.values()])


def _slot_reader(i: int, idx: int) -> Callable[[Image], Any]:
    return lambda img: img.m[i][idx]


def _step_time_reader(i: int, step_time: Callable[[Memory], int]
                      ) -> Callable[[Image], Any]:
    return lambda img: step_time(img.m[i])


def _current_step_reader(i: int, leaf: tuple[tuple[str, int], ...]
                         ) -> Callable[[Image], Any]:
    def read(img: Image) -> str:
        m = img.m[i]
        active = [s for s, x in leaf if m[x]]
        return active[-1] if active else ""
    return read


def _point_reader(direction: str, j: int, pos: int) -> Callable[[Image], Any]:
    """Reader of the point at position ``pos`` of driver ``j``'s input or output image."""
    if direction == "in":
        return lambda img: img.inputs[j][pos]
    return lambda img: img.outputs[j][pos]


def _applied_reader(j: int, pos: int, invert: bool, t: A.Type) -> Callable[[Image], Any]:
    """Reader of a chart output as applied: the point at position ``pos`` of driver
    ``j``'s output image, through the binding's inversion, in the output's type ``t`` (a
    point written off holds the int 0)."""
    if t is A.Type.BOOL:
        if invert:
            return lambda img: not img.outputs[j][pos]
        return lambda img: bool(img.outputs[j][pos])
    if t is A.Type.REAL:
        return lambda img: float(img.outputs[j][pos])
    if t in (A.Type.INT, A.Type.TIME):
        return lambda img: int(img.outputs[j][pos])
    return lambda img: img.outputs[j][pos]


def _ok_reader(j: int) -> Callable[[Image], Any]:
    return lambda img: img.ok[j]


def not_applied_lines(not_applied: dict[str, dict[str, Any]],
                      head: str = "not applied: ") -> list[str]:
    """One line per chart output whose point does not hold what the chart says (the
    outputs held off, a forced point), from ``status``'s ``not_applied``: the console's
    ``status`` and the monitor."""
    return [f"{head}{name}: the chart's {d['chart']}, {d['point']} holds {d['holds']}"
            for name, d in not_applied.items()]


def same(a: Any, b: Any) -> bool:
    """Whether two values of a name are the same (a NaN is the same as a NaN)."""
    return bool(a == b or (a != a and b != b))


def parse_value(name: Signal, text: str) -> Any:
    """A value typed at the console -> the name's type; CommandError says what was
    expected."""
    t = name.type
    low = text.lower()
    if t is A.Type.BOOL:
        if low in ("1", "true", "on"):
            return True
        if low in ("0", "false", "off"):
            return False
        expected = "0 or 1 (or true/false, on/off)"
    elif t is A.Type.INT:
        try:
            return int(text, 0) if low.startswith(("0x", "0b", "0o")) else int(text)
        except ValueError:
            expected = "an integer"
    elif t is A.Type.REAL:
        try:
            return float(text)
        except ValueError:
            expected = "a number"
    elif t is A.Type.TIME:
        ns = parse_literal(text.split("#", 1)[1] if "#" in text else text)
        if ns is not None:
            return ns
        expected = "a time like 5s, 250ms or T#1m30s"
    else:
        raise CommandError(f"{name.text} is a {t.value.lower()}: it cannot be written from "
                           "the console")
    raise CommandError(f"bad value '{printable(text)}' for {name.text}: expected "
                       f"{expected}")


def printable(text: str, limit: int = 40) -> str:
    """``text`` cut to ``limit`` characters, control characters escaped (never echo
    terminal escapes back to a person's screen)."""
    cut = text[:limit]
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in cut)
    return shown + ("..." if len(text) > limit else "")
