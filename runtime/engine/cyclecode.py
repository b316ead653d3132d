"""The plant's cycles written as Python source, once, when the plant is built.

``cycle(t)`` is the usual one (nothing forced or pulsed): the drivers' reads, a call of each
group of inlined scans (inline.py: per instance its bindings stored into its cells, its
fast path or, its ``slow`` cell set, its whole scan, its outputs copied), the drivers'
writes. ``cycle_slow(now, up)`` writes the bindings into the instances' state and applies
the forces around each scan; ``copy_outputs()`` copies the chart outputs to their points
while the charts are held. All read and write the drivers' images by position
(``IL_sim[3]``, ``OL_sim[7] = ...``), resolved here and never changed; ``invert`` is applied
here and only here. The names they use are the plant's environment (``Plant._bind_env``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.base import Driver, FaultPolicy, PointKind
from runtime.compiler.codebook import CodeBook
from runtime.compiler.emit import code_names, comment
from runtime.compiler.layout import SLOW_FLAGS
from runtime.engine.inline import Inliner
from runtime.engine.instance import Instance
from runtime.language import ast as A
from runtime.language.model import Binding, PlantDef


class CycleWriter:
    """Writes a plant's cycles: :meth:`source` once, after which :attr:`inliner` holds the
    groups of inlined scans it built (their generators, and each fault's instance)."""

    def __init__(self, pdef: PlantDef, instances: dict[str, Instance],
                 drivers: dict[str, Driver], bits: dict[str, frozenset[int]], virtual: bool,
                 env: dict[str, Any], book: CodeBook | None) -> None:
        """``bits``: per driver, the positions of its input bits (Plant.bits: bools, read
        as they are); ``env``: the cycles' environment (the names they may use; ``GS``,
        the groups' sends, is added to it); ``book``: code compiled in another process,
        or None."""
        self.pdef = pdef
        self.instances = instances
        self.drivers = drivers
        self.bits = bits
        self.virtual = virtual
        self._env = env
        self._book = book
        self.inliner: Inliner

    def _input_expr(self, b: Binding, vtype: A.Type, ref: Callable[[Instance, int], str],
                    const: Callable[[Any], str] = repr) -> str:
        """The value of an input binding in the cycle's code; ``ref(instance, slot)``
        writes another instance's slot (a cell in the usual cycle, else its view),
        ``const(value)`` a key or function (a literal, or a name bound to it)."""
        if b.driver is not None:
            if b.point == "ok":
                val = f"D[{const(b.driver)}].health is OK"
                return f"not ({val})" if b.invert else f"({val})"
            # the point's position in the driver's image (fixed for the image's life)
            drv, point = self.drivers[b.driver], b.point or ""
            pos = drv.inputs.index[point]
            ref_ = f"IL_{b.driver}[{const(pos)}]"
            if vtype is A.Type.BOOL:
                if pos in self.bits[b.driver]:  # a bool already (drivers/image.py)
                    return f"(not {ref_})" if b.invert else ref_
                return f"({ref_} == 0)" if b.invert else f"({ref_} != 0)"
            if vtype in (A.Type.INT, A.Type.REAL) and drv.kinds.get(point) is PointKind.BOOL:
                # a driver's read stores a bool at a BOOL point: a number variable reads
                # it as 0 or 1 (a sim point's number stays as it is)
                return f"({ref_} + 0)"
            return ref_
        other = self.instances[b.instance or ""]
        ref_name = b.ref or ""
        if ref_name.endswith(".T") and ref_name[:-2] in other.grafcet.steps:
            fn = "ST_" + other.name if const is repr else const(other.step_time)
            val = f"{fn}({const(ref_name[:-2])})"
        else:
            val = ref(other, other.program.index_of(ref_name))
        return f"(not {val})" if b.invert else val

    @staticmethod
    def _view(inst: Instance, idx: int) -> str:
        """Slot ``idx`` of ``inst`` read through its state view (the slow cycle)."""
        return f"M_{inst.name}[{idx}]"

    def source(self) -> str:
        """The cycles as Python source: ``cycle`` (the fast one: no force, no pulse),
        ``cycle_slow`` (forces and pulses applied around each scan) and ``copy_outputs``.
        Every name of the environment is bound as a default argument, so a cycle reads
        locals, not globals."""
        fast, slow = self._fast_body(), self._slow_body()
        copy = [f"    if FI: force_instance({name!r}, M_{name})"
                for name in self.instances] + self._output_copy() + ["    if SI: stopped_off()"]
        def defaults(body: list[str]) -> str:  # the names of the environment it uses
            used = {n for line in body for n in code_names(line)}
            used &= self._env.keys()
            return ", ".join(f"{n}={n}" for n in sorted(used))

        return "\n".join([f"def cycle(t, {defaults(fast)}):", *fast, "",
                          f"def cycle_slow(now, up, {defaults(slow)}):", *slow, "",
                          # while the charts are held (console pause), forced chart
                          # outputs still reach their points: the copy after the forces
                          f"def copy_outputs({defaults(copy)}):", *copy]) + "\n"

    def _reads(self) -> list[str]:
        """The drivers' reads and the stop on a fault, first lines of both cycles."""
        lines = []
        if not self.virtual:
            lines += [f"    R_{name}()" for name in self.drivers]
            lines += [f"    if DV_{name}.health is FAULT: return DV_{name}"
                      for name, d in self.drivers.items()
                      if d.on_fault is FaultPolicy.STOP]  # a fault: no scan, no write
        return lines

    def _fast_body(self) -> list[str]:
        """The drivers' reads, a call of each group of inlined scans (inline.py: per
        instance its bindings stored into its cells, its fast path or, its ``slow`` cell
        set, its whole scan, its outputs copied), the drivers' writes."""
        lines = self._reads()
        inl = self.inliner = Inliner(
            self._env, list(self.instances.values()),
            {name: len(i.inputs) + len(i.outputs) for name, i in self.pdef.instances.items()})
        for name, inst in self.instances.items():
            inl.begin(inst)
            idef = self.pdef.instances[name]
            g, prog = inst.grafcet, inst.program
            # the declared inputs first: a chart flag bound to one of them (its own
            # instance's ``A.stop``) reads this cycle's value, whatever the file's order
            declared = set(prog.inputs)
            ins = []
            for sig, b in sorted(idef.inputs.items(), key=lambda kv: kv[0] not in declared):
                val = self._input_expr(b, g.variables[sig].type, inl.cell, inl.const)
                cell = inl.cell(inst, prog.var_index(sig))
                if sig in SLOW_FLAGS:  # a chart flag set: the scan's slow path
                    ins += [f"{cell} = _v = {val}", f"if _v: {inl.slow(inst)} = True"]
                else:
                    ins.append(f"{cell} = {val}")
            outs = []
            for sig, b in idef.outputs.items():
                val = inl.cell(inst, prog.var_index(sig))
                pos = inl.const(self.drivers[b.driver or ""].outputs.index[b.point or ""])
                outs.append(f"OL_{b.driver}[{pos}] = {'not ' if b.invert else ''}{val}")
            inl.add(inst, ins, outs)
        groups = inl.build(self._book)
        self._env["GS"] = groups  # the list revive() updates in place
        for j in range(len(groups)):  # a fault in a scan comes back from its group
            lines += [f"    e = GS[{j}](t)", "    if e is not None: return e"]
        if not self.virtual:
            lines += [f"    W_{name}()" for name in self.drivers]
        lines.append("    return None")
        return lines

    def _slow_body(self) -> list[str]:
        """The cycle with forces and pulses: bindings written into the state, the
        instance's forces applied before and after its scan, the forced points masked;
        an instance in fault (``Plant.instance_faults``) not scanned, its outputs' points off."""
        lines = self._reads()
        add = lines.append
        add("    if FP: force_points(False)")
        for name, inst in self.instances.items():
            idef = self.pdef.instances[name]
            g = inst.grafcet
            add(f"    {comment(f'instance {name} ({g.name})')}")
            add(f"    m = M_{name}")
            # the declared inputs first: a chart flag bound to one of them (its own
            # instance's ``A.stop``) reads this cycle's value, whatever the file's order
            declared = set(inst.program.inputs)
            ordered = sorted(idef.inputs.items(), key=lambda kv: kv[0] not in declared)
            for sig, b in ordered:
                v = g.variables[sig]
                slot = inst.program.var_index(sig)
                add(f"    m[{slot}] = {self._input_expr(b, v.type, self._view)}  "
                    + comment(f"{sig} <- {b.source}{' inverted' if b.invert else ''}"))
            add(f"    if FI: force_instance({name!r}, m)")
            add(f"    if not SI or {name!r} not in SI: SS_{name}(now, up)  # not in fault")
            add(f"    if FI: force_instance({name!r}, m)")
        lines += self._output_copy()
        add("    if FP: force_points(True)")
        add("    if SI: stopped_off()  # the outputs of an instance in fault: off")
        if not self.virtual:
            lines += [f"    W_{name}()" for name in self.drivers]
        add("    if FP: force_points(None)")
        add("    return None")
        return lines

    def _output_copy(self) -> list[str]:
        """Generated lines copying every instance output (read in its state) through its
        binding."""
        lines = []
        for name, inst in self.instances.items():
            idef = self.pdef.instances[name]
            for sig, b in idef.outputs.items():
                val = f"M_{name}[{inst.program.var_index(sig)}]"
                if b.invert:
                    val = f"not {val}"
                pos = self.drivers[b.driver or ""].outputs.index[b.point or ""]
                lines.append(f"    OL_{b.driver}[{pos}] = {val}  "
                             + comment(f"{name}.{sig} -> {b.driver}.{b.point}"))
        return lines
