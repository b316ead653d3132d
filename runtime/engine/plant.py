"""The plant: instances + drivers + bindings, forming the process image of each cycle.

One cycle (semantics.md, "The cycle of the controller"): every driver's ``read()``; for
each instance in plant order, copy its inputs through the bindings (``invert`` applied
here and only here), scan it; copy every output through the bindings into the drivers'
output images; every driver's ``write()``. The cycle is generated as Python code once
(cyclecode.py), so it is one function call with no interpretation of the bindings: the
usual one (nothing forced or pulsed) makes no call per instance, every instance's scan
inlined with its bindings in groups (inline.py); the slow one (forces, pulses) writes the
bindings into the instances' state and applies the forces around each scan.

The charts are scanned on the program's time, not the raw clock: it stands still while
they are not scanned (console pause, iocheck) and each stepped cycle counts exactly one
plant cycle (semantics.md, "Program time").
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType
from typing import Any

from drivers.base import Direction, Driver, FaultPolicy, Health, PointKind
from drivers.registry import driver_class
from drivers.sim import SimDriver
from runtime.compiler.codebook import CodeBook, compile_code
from runtime.compiler.codegen import SCAN_GLOBALS, compile_grafcet
from runtime.compiler.program import Program
from runtime.engine.cyclecode import CycleWriter
from runtime.engine.inline import FILENAME as INLINE_FILE
from runtime.engine.instance import Instance, StepWhy, coerce
from runtime.engine.names import Owner, PlantNames, UnknownName
from runtime.errors import SoftplcError
from runtime.language import ast as A
from runtime.language.model import Grafcet, PlantDef, VarKind

log = logging.getLogger(__name__)


class BindingError(SoftplcError, ValueError):
    """A name given to force/set does not exist in the plant."""


@dataclass(frozen=True, slots=True)
class ForcedVariable:
    """A chart variable held at ``value`` (of its type) until unforced."""

    instance: str
    slot: int  # its index in the instance's state list
    value: Any


#: fewer cycles than this in a row go through ``Plant.cycle`` one by one in ``Plant.cycles``
#: (a run of them in one loop costs about five calls of ``cycle`` to set up)
SHORT = 8
#: the usual cycle: called with ``(now, up)`` (ns), returns None, the driver whose fault
#: stopped it (before any scan), or the exception a scan raised (the caller raises it)
FastCycle = Callable[[tuple[int, int]], "Driver | BaseException | None"]


@dataclass(frozen=True, slots=True)
class ForcedPoint:
    """A physical point held at ``value`` (a raw number) until unforced."""

    driver: Driver
    point: str
    is_output: bool
    value: Any


class Plant:
    """Runs a PlantDef: ``open()``, ``cycle(now)`` every period, ``safe_state()``, ``close()``."""

    # slots: ``cycle`` reads and writes its attributes every cycle; past 30 attributes an
    # instance dict stops sharing its keys and each read is a dict lookup (CPython 3.11)
    __slots__ = ("virtual", "pdef", "_book", "cycle_ns", "watchdog_ns", "retain_interval_ns",
                 "_coverage", "_start", "last_up", "offset_ns", "_last_scan", "_stood_still",
                 "programs", "instances", "drivers", "_handed", "forced", "forced_points",
                 "_forced_by_inst", "_stash", "_pulses", "_hold", "steps_left", "_iocheck",
                 "scans", "names", "_env", "source", "_cycle_fast", "_cycle", "_usual",
                 "_copy_outputs", "_inliner", "bits", "instance_faults", "__weakref__")

    def __init__(self, pdef: PlantDef, *, sim: bool = False,
                 drivers: dict[str, Driver] | None = None, virtual: bool = False,
                 book: CodeBook | None = None, handover: bool = False,
                 coverage: bool = False) -> None:
        """``sim``: every driver replaced by simulated I/O. ``drivers``: driver objects to
        use in place of new ones (by name). ``virtual`` (simulate, on a virtual clock): the
        simulated drivers' images are the whole process image, so the cycle makes no driver
        call (a sim driver never faults and nothing watches its bus). ``book``: code
        objects compiled in another process (an online change), used for the sources it
        holds (runtime/compiler/codebook.py). ``handover``: ``drivers`` are a running
        plant's (an online change): this plant declares its input bits on their images in
        :meth:`take_over`, not before. ``coverage``: the charts compiled to count what
        they do (``Program.coverage``: ``softplc test``).
        """
        if virtual and not sim:
            raise ValueError("a virtual plant runs on simulated I/O only")
        self.virtual = virtual
        self.pdef = pdef
        self._book = book
        self._coverage = coverage
        self.cycle_ns = pdef.cycle_ns
        self.watchdog_ns = pdef.watchdog_ns
        self.retain_interval_ns = pdef.retain_interval_ns
        self._start: int | None = None  # see the property
        #: program time since the start (ns) of the last cycle that scanned the charts
        self.last_up = 0
        #: the program's time is the monotonic clock less this offset (ns): it grows by
        #: the time the charts stood still (console pause, iocheck)
        self.offset_ns = 0
        #: program time (ns) of the last scan of the charts, None before the first
        self._last_scan: int | None = None
        #: whether a cycle since the last scan did not scan the charts
        self._stood_still = False
        #: whether the next cycle is a usual one (``_is_usual``, kept by ``_settle``): the
        #: one test of ``cycle``, where seven were (about 25 ns a cycle)
        self._usual = False
        #: one program per distinct chart (the plant file's loader shares the Grafcet of a
        #: file between its instances): the instances of a chart share its code
        self.programs: list[Program] = []
        self.instances: dict[str, Instance] = {
            name: Instance(name, self._program(idef.grafcet))
            for name, idef in pdef.instances.items()}
        self.drivers: dict[str, Driver] = {}
        #: drivers handed over open (online change): their declared points are kept
        self._handed = set(drivers or ())
        for name, ddef in pdef.drivers.items():
            if drivers and name in drivers:
                self.drivers[name] = drivers[name]
            elif sim:
                cfg = {"on_fault": ddef.config.get("on_fault", "stop")}
                self.drivers[name] = SimDriver(name, cfg)
            else:
                self.drivers[name] = driver_class(ddef.type)(name, ddef.config)
        #: forced variables by name ("instance.var"); change them with force/unforce
        self.forced: dict[str, ForcedVariable] = {}
        #: forced physical points by name ("driver.point"); change them with force/unforce
        self.forced_points: dict[str, ForcedPoint] = {}
        self._forced_by_inst: dict[str, list[tuple[int, Any]]] = {}
        self._stash: list[tuple[Driver, str, Any]] = []
        self._pulses: list[tuple[str, int]] = []
        self._hold = False  # see the property
        self.steps_left = 0  # while held: full cycles still let through
        self._iocheck = False  # see the property
        #: instances in fault, with why (an instance left without an active step by a
        #: forced online change): not scanned, the points of their outputs off, until
        #: :meth:`restart_instance` or :meth:`restart` (``ack``)
        self.instance_faults: dict[str, str] = {}
        self.scans = 0
        self._declare_points(handover)
        #: the plant's names, resolved on the drivers' own point tables
        self.names = PlantNames(pdef, {n: (d.inputs, d.outputs)
                                       for n, d in self.drivers.items()})
        env: dict[str, Any] = {}
        self._env = env
        self._bind_env(env)
        writer = CycleWriter(pdef, self.instances, self.drivers, self.bits, virtual, env,
                             book)
        self.source = writer.source()
        self._inliner = writer.inliner
        exec(compile_code(self.source, "<plant cycle>", env.keys(), book), env)  # noqa: S102 - generated
        #: the cycle with no force and no pulse (semantics unchanged, less to do)
        self._cycle_fast: FastCycle = self._fast_cycle()
        #: the cycle with forces and pulses applied around each scan
        self._cycle: Callable[[int, int], Driver | None] = env["cycle_slow"]
        self._copy_outputs: Callable[[], None] = env["copy_outputs"]
        self._settle()

    # -- construction ----------------------------------------------------------------
    def _program(self, g: Grafcet) -> Program:
        """The program of chart ``g``, compiled the first time it is asked for."""
        for p in self.programs:
            if p.grafcet is g:
                return p
        p = compile_grafcet(g, self._book, self._coverage)
        self.programs.append(p)
        return p

    def _declare_points(self, handover: bool) -> None:
        """Every bound point declared to its driver; and :attr:`bits`, each driver's
        input bits: the BOOL points that only BOOL variables read (their values bools,
        read by the cycle as they are: drivers/image.py), declared to the drivers' images
        (with ``handover``, a running plant's drivers take them in :meth:`take_over`,
        between two cycles: until then the plant they serve reads them)."""
        bits: dict[str, set[str]] = {name: set() for name in self.drivers}
        not_bits: set[tuple[str, str]] = set()
        for name, idef in self.pdef.instances.items():
            chart = self.instances[name].grafcet
            for sig, b in idef.inputs.items():
                if b.driver is None or b.point == "ok":
                    continue
                var = chart.variables.get(sig)
                if var is not None and var.type is A.Type.BOOL:
                    bits[b.driver].add(b.point or "")
                else:
                    not_bits.add((b.driver, b.point or ""))
        for idef in self.pdef.instances.values():
            for direction, section in ((Direction.IN, idef.inputs), (Direction.OUT,
                                                                     idef.outputs)):
                for b in section.values():
                    if b.driver is None or b.point == "ok":
                        continue
                    d = self.drivers[b.driver]
                    if b.driver in self._handed and (b.point or "") in (
                            d.inputs if direction is Direction.IN else d.outputs):
                        continue
                    d.add_point(b.point or "", direction)
        #: per driver: its input bits, by position
        self.bits = {dname: frozenset(d.inputs.index[p] for p in bits[dname]
                                      if d.kinds.get(p) is PointKind.BOOL
                                      and (dname, p) not in not_bits)
                     for dname, d in self.drivers.items()}
        for dname, d in self.drivers.items():
            if not (handover and dname in self._handed):
                d.inputs.declare_bits(self.bits[dname])

    def instance_at(self, frame: FrameType, lineno: int) -> str | None:
        """The instance whose inlined scan is at line ``lineno`` of ``frame`` (a frame of
        a fault's traceback), None if it is not an inlined scan."""
        if frame.f_code.co_filename != INLINE_FILE:
            return None
        return self._inliner.owner(frame, lineno)

    def _bind_env(self, env: dict[str, Any]) -> None:
        env["OK"] = Health.OK
        env["FAULT"] = Health.FAULT
        env["D"] = self.drivers
        env["FP"] = self.forced_points
        env["FI"] = self._forced_by_inst
        env["force_points"] = self._apply_point_forces
        env["force_instance"] = self._apply_instance_forces
        env["SI"] = self.instance_faults
        env["stopped_off"] = self._stopped_off
        env.update(SCAN_GLOBALS)  # what the inlined scans call (inline.py)
        for name, d in self.drivers.items():
            env[f"R_{name}"] = d.read
            env[f"W_{name}"] = d.write
            # the images' value lists, indexed by the points' positions
            env[f"IL_{name}"] = d.inputs.vals
            env[f"OL_{name}"] = d.outputs.vals
            env[f"DV_{name}"] = d
        for name, inst in self.instances.items():
            env[f"M_{name}"] = inst.m
            env[f"S_{name}"] = inst.scan_in
            env[f"SS_{name}"] = inst.scan
            env[f"ST_{name}"] = inst.step_time

    # -- the cycle -----------------------------------------------------------------
    def open(self) -> None:
        """Open every driver and write every output off before the first scan."""
        for d in self.drivers.values():
            d.open()
        self.safe_state()

    def cycle(self, now: int) -> str | None:
        """One controller cycle at monotonic time ``now`` (ns).

        Returns None, or the reason why the cycle stopped short: a driver whose policy is
        ``on_fault: stop`` is faulted after the reads; then no chart is scanned and no
        output written (the caller puts the plant in its safe state).

        While ``hold`` is set (console ``pause``) the charts are not scanned but the I/O
        is: inputs are read and the held outputs written; ``step(n)`` lets exactly n full
        cycles through. In ``iocheck`` mode the charts are stopped and the drivers'
        output images are left to the technician (every output off on entry). The
        charts see the program's time (``_program_time``), which stands still while
        they are not scanned."""
        if self._usual:
            # the usual cycle: running, nothing forced (what follows, made short; no new
            # integer for a zero offset or start, as in a simulation)
            off, start = self.offset_ns, self._start
            pnow = now - off if off else now
            self.last_up = up = pnow - start if start else pnow
            self._last_scan = pnow
        else:
            if self._iocheck or (self._hold and self.steps_left <= 0):
                if self._last_scan is not None:
                    self._stood_still = True
                    self._settle()
                if not self._iocheck and self.forced:
                    self._copy_outputs()
                self.exchange(zero_outputs=False)
                return self.faulted()
            if self._hold:
                self.steps_left -= 1
            pnow = self._program_time(now)
            if self._start is None:
                self._start = pnow
            up = pnow - self._start
            self.last_up = up
            self._last_scan = pnow
            self._settle()
            if (self._pulses or self._forced_by_inst or self.forced_points
                    or self.instance_faults):
                return self._cycle_forced(pnow, up)
        try:
            got = self._cycle_fast((pnow, up))
        except BaseException:
            self._revive()
            raise
        if got is not None:
            if isinstance(got, Driver):
                return f"driver {got.name}: {got.fault_reason}"
            try:  # a scan's fault, raised with the local cleared: the fault's frames must
                raise got  # not hold it (a cycle that would keep the plant alive)
            finally:
                got = None
        self.scans += 1
        return None

    def cycles(self, times: range) -> str | None:
        """One cycle at each of ``times`` (monotonic ns, in order), exactly as :meth:`cycle`
        runs them one by one, for a caller with nothing to do between them (a simulation
        without a trace): a stretch of usual cycles runs in one loop with no call of
        :meth:`cycle` each, so a long run costs its scans. Returns None, or the reason why
        a cycle stopped short (the later ones are not run). A scan's fault is raised as
        from :meth:`cycle`, :attr:`last_now` the time of the cycle that raised it."""
        i = 0
        while i < len(times):
            if self._usual and len(times) - i >= SHORT:
                ran, why = self._usual_cycles(times[i:])
                i += ran
            else:
                why = self.cycle(times[i])
                i += 1
            if why is not None:
                return why
        return None

    @property
    def last_now(self) -> int:
        """The monotonic time (ns) of the last cycle that was not held: its scans ran,
        raised, or a driver fault stopped them (``last_up`` from the start, plus the start
        and the offset)."""
        return self.last_up + (self._start or 0) + self.offset_ns

    def _usual_cycles(self, times: range) -> tuple[int, str | None]:
        """The usual cycles at ``times``, all of them unless one stops short: how many ran
        (that one included), and its reason. The bookkeeping of :meth:`cycle` (``scans``,
        ``last_up``, the last scan's time) is done once, at the end, also when an
        exception ends the loop (a Ctrl-C between two cycles: the cycles before it count)."""
        off, start = self.offset_ns, self._start or 0
        program = range(times.start - off, times.stop - off, times.step)
        fast = self._cycle_fast
        got: Driver | BaseException | None = None
        pnow: int | None = None  # the program time of the last cycle begun
        done: int | None = None  # ... and of the last one that scanned
        try:  # two loops: no new integer for a zero start (a simulation)
            if start:
                for pnow in program:
                    got = fast((pnow, pnow - start))
                    if got is not None:
                        break
                    done = pnow
            else:
                for pnow in program:
                    got = fast((pnow, pnow))
                    if got is not None:
                        break
                    done = pnow
        except BaseException:  # outside the scans (the generator ended): as in cycle
            self._revive()
            raise
        finally:
            ran = 0
            if pnow is not None:
                ran = program.index(pnow) + 1
                self._last_scan = pnow
                self.last_up = pnow - start
            if done is not None:
                self.scans += program.index(done) + 1
        if got is None:
            return ran, None
        if isinstance(got, Driver):
            return ran, f"driver {got.name}: {got.fault_reason}"
        try:  # a scan's fault, raised with the local cleared (see cycle)
            raise got
        finally:
            got = None

    # -- what makes a cycle unusual: set through these, so that ``_usual`` follows ------
    @property
    def start(self) -> int | None:
        """Program time (ns) of the first cycle: the clock bits count from it."""
        return self._start

    @start.setter
    def start(self, value: int | None) -> None:
        moved = value != self._start and self._last_scan is not None
        self._start = value
        if moved:  # the groups' shared chart clock counts from the start (inline.py)
            self._inliner.restart()
            self._cycle_fast = self._fast_cycle()
        self._settle()

    @property
    def hold(self) -> bool:
        """Console pause: charts not scanned, I/O still exchanged (pause/resume/step)."""
        return self._hold

    @hold.setter
    def hold(self, value: bool) -> None:
        self._hold = value
        self._settle()

    @property
    def iocheck(self) -> bool:
        """Commissioning mode (``set_iocheck``): charts stopped, outputs left to the
        technician."""
        return self._iocheck

    @iocheck.setter
    def iocheck(self, value: bool) -> None:
        self._iocheck = value
        self._settle()

    def _settle(self) -> None:
        """Set ``_usual`` again: to be called after any change of what it sums up (the
        attributes :meth:`_is_usual` reads, all changed in this class only)."""
        self._usual = self._is_usual()

    def _is_usual(self) -> bool:
        """Whether the next cycle is a usual one: running (started, not held, not in
        iocheck, the last cycle scanned), no force and no pulse."""
        return not (self._iocheck or self._hold or self._stood_still or self._pulses
                    or self._forced_by_inst or self.forced_points or self.instance_faults
                    ) and self._start is not None

    def _cycle_forced(self, pnow: int, up: int) -> str | None:
        """The cycle with forces and pulses applied around each scan (``cycle``)."""
        if self._pulses:
            self._rebuild_instance_forces()
            for inst, idx in self._pulses:
                self._forced_by_inst.setdefault(inst, []).append((idx, True))
            stopped = self._cycle(pnow, up)
            for inst, idx in self._pulses:
                self.instances[inst].m[idx] = False
            self._pulses.clear()
            self._rebuild_instance_forces()
        else:
            stopped = self._cycle(pnow, up)
        if stopped is not None:
            return f"driver {stopped.name}: {stopped.fault_reason}"
        self.scans += 1
        return None

    def _fast_cycle(self) -> FastCycle:
        """The usual cycle, called with ``(now, up)``: the generated ``cycle`` or, for a
        virtual plant of one group of inlined scans (no driver to read or write), that
        group's own ``send`` (one call less per cycle)."""
        if self.virtual and len(self._inliner.sends) == 1:
            return self._inliner.sends[0]
        fn: FastCycle = self._env["cycle"]
        return fn

    def _revive(self) -> None:
        """After a cycle that raised: a group of inlined scans whose generator ended
        (inline.py, ``revive``) is started again, said in the log."""
        for j in self._inliner.revive():
            log.warning("inlined scans of group %d started again after an exception "
                        "outside its scans", j)
            self._cycle_fast = self._fast_cycle()

    def _program_time(self, now: int) -> int:
        """The program's time (ns) for a scan at monotonic time ``now``.

        Running, it is the clock less ``offset_ns``: real intervals, overruns included.
        A scan that follows cycles in which the charts stood still (console pause,
        iocheck), and every scan let through by ``step``, comes exactly one plant cycle
        after the previous scan, whatever the clock says; the offset takes up the rest,
        so ``resume`` goes on from there with no jump."""
        last = self._last_scan
        if last is not None and (self._stood_still or self._hold):
            self._stood_still = False
            self.offset_ns = now - (last + self.cycle_ns)
        return now - self.offset_ns

    def exchange(self, zero_outputs: bool) -> None:
        """A cycle without scans: read every driver (so inputs stay visible and a lost
        driver can recover) and write the output images, all zero if ``zero_outputs``
        (a faulted controller), else as they are with forced points applied (pause,
        iocheck)."""
        for d in self.drivers.values():
            d.read()
        if zero_outputs:
            for d in self.drivers.values():
                d.outputs.fill(0)
                d.write()
            return
        if self.forced_points:
            self._apply_point_forces(False)
            self._apply_point_forces(True)
        for d in self.drivers.values():
            d.write()
        if self.forced_points:
            self._apply_point_forces(None)

    def step(self, n: int) -> None:
        """While held: let exactly ``n`` full cycles through (0 cancels)."""
        self.steps_left = n

    def pause(self) -> bool:
        """Hold the charts (I/O still exchanged), cancelling any steps; returns whether
        they were held already."""
        was = self._hold
        self._hold = True
        self.steps_left = 0
        self._settle()
        return was

    def resume(self) -> bool:
        """Let the charts run again; returns whether they were held."""
        was = self._hold
        self._hold = False
        self.steps_left = 0
        self._settle()
        return was

    @property
    def held(self) -> bool:
        """Whether the charts are held (console pause), stepping or not."""
        return self._hold

    @property
    def stepping(self) -> bool:
        """Whether cycles asked for by ``step`` are still to run."""
        return self.steps_left > 0

    def explain(self, instance: str) -> list[StepWhy]:
        """``Instance.explain`` of one instance, at the time of the plant's last cycle."""
        inst = self.instances[instance]
        inst.last_up = self.last_up  # the plant scans without Instance.scan
        return inst.explain()

    def pulse(self, instance: str, flag: str) -> None:
        """Hold a chart flag (SFCInit/SFCReset) true for the next scan only."""
        inst = self.instances[instance]
        self._pulses.append((instance, inst.program.var_index(flag)))
        self._settle()

    def set_iocheck(self, on: bool) -> None:
        """Commissioning mode: charts stopped, every output off; leaving it turns every
        output off again (the caller restarts the charts after an acknowledge)."""
        self._iocheck = on
        self._settle()
        self.safe_state()

    def safe_state(self) -> None:
        """Every output of every driver off (de-energised), driver by driver: a bug in
        one driver must not keep another's outputs on."""
        for d in self.drivers.values():
            try:
                d.safe_state()
            except Exception:  # noqa: BLE001 - logged; the others still go off
                log.exception("driver %s: safe state failed", d.name)

    def close(self) -> None:
        for d in reversed(list(self.drivers.values())):
            d.close()

    def faulted(self) -> str | None:
        """Reason of the first driver fault the plant does not tolerate (on_fault: stop)."""
        for name, d in self.drivers.items():
            if d.on_fault is FaultPolicy.STOP and d.health is Health.FAULT:
                return f"driver {name}: {d.fault_reason}"
        return None

    def retain_snapshot(self) -> dict[str, dict[str, Any]]:
        """Retained values by instance (instances with none left out), read once each."""
        snaps = {name: inst.retain_snapshot() for name, inst in self.instances.items()}
        return {name: snap for name, snap in snaps.items() if snap}

    def restore_retain(self, data: dict[str, Any]) -> None:
        for name, values in data.items():
            inst = self.instances.get(name)
            if inst is None or not isinstance(values, dict):
                log.warning("retained data for unknown instance '%s' ignored", name)
                continue
            ignored = inst.restore_retain(values)
            if ignored:
                log.warning("retained values ignored for %s: %s", name, ", ".join(ignored))

    def restart(self) -> None:
        """Every chart back to its initial situation (retained memory kept); an instance
        in fault too."""
        for inst in self.instances.values():
            inst.restart()
        self.instance_faults.clear()
        self._settle()

    # -- an instance in fault --------------------------------------------------------
    def fault_instance(self, name: str, why: str) -> None:
        """Put instance ``name`` in fault: from the next cycle on it is not scanned and
        the points of its outputs are off (its output variables too, for the instances
        that read them), whatever else runs. Between two cycles only."""
        inst = self.instances[name]
        for v in inst.grafcet.outputs:
            off = "" if v.type is A.Type.STRING else coerce(v.type, 0)
            inst.m[inst.program.var_index(v.name)] = off
        self.instance_faults[name] = why
        self._settle()

    def restart_instance(self, name: str) -> None:
        """Instance ``name`` back to its initial situation (retained memory kept), out of
        fault if it was in one. Between two cycles only."""
        self.instances[name].restart()
        self.instance_faults.pop(name, None)
        self._settle()

    def _stopped_off(self) -> None:
        """The points of the outputs of every instance in fault written off (the cycle,
        after its outputs and the forced points)."""
        for name in self.instance_faults:
            for b in self.pdef.instances[name].outputs.values():
                if b.driver is not None:
                    self.drivers[b.driver].outputs[b.point or ""] = 0

    # -- names, set and force --------------------------------------------------------
    def _owner(self, name: str) -> tuple[Owner, str, str]:
        """``instance.var`` or ``driver.point`` -> (owner, head, rest); BindingError if the
        plant has no such name."""
        try:
            return self.names.owner(name)
        except UnknownName as exc:
            raise BindingError(str(exc)) from None

    def get(self, name: str) -> Any:
        owner, head, rest = self._owner(name)
        if owner is Owner.INSTANCE:
            try:
                return self.instances[head].get(rest)
            except KeyError:
                raise BindingError(f"unknown name '{name}'") from None
        d = self.drivers[head]
        if rest == "ok":
            return d.ok
        return d.inputs[rest] if rest in d.inputs else d.outputs[rest]

    def set(self, name: str, value: Any) -> None:
        """Write once (between cycles): a variable, or a physical input of a sim driver."""
        owner, head, rest = self._owner(name)
        if owner is Owner.INSTANCE:
            try:
                self.instances[head].set(rest, value)
            except KeyError:
                raise BindingError(f"'{name}' cannot be written") from None
            return
        d = self.drivers[head]
        image = d.inputs if rest in d.inputs else d.outputs
        image[rest] = int(coerce(A.Type.INT, value))

    def force(self, name: str, value: Any) -> None:
        """Hold a variable or a physical point at ``value`` until unforced."""
        owner, head, rest = self._owner(name)
        if owner is Owner.INSTANCE:
            inst = self.instances[head]
            v = inst.grafcet.variables.get(rest)
            if v is None or v.kind is VarKind.SYSTEM or v.type is A.Type.STRING:
                raise BindingError(f"'{name}' cannot be forced")
            self.forced[name] = ForcedVariable(head, inst.program.var_index(rest),
                                               coerce(v.type, value))
            self._rebuild_instance_forces()
        else:
            if rest == "ok":
                raise BindingError(f"'{name}' cannot be forced")
            d = self.drivers[head]
            self.forced_points[name] = ForcedPoint(d, rest, rest in d.outputs,
                                                   int(coerce(A.Type.INT, value)))
            self._settle()

    def unforce(self, name: str | None = None) -> None:
        """Release one forced name, or every force when ``name`` is None."""
        if name is None:
            self.forced.clear()
            self.forced_points.clear()
        else:
            if name not in self.forced and name not in self.forced_points:
                raise BindingError(f"'{name}' is not forced")
            self.forced.pop(name, None)
            self.forced_points.pop(name, None)
        self._rebuild_instance_forces()

    def is_forced(self, name: str) -> bool:
        """Whether ``name`` (a variable or a point) is forced."""
        return name in self.forced or name in self.forced_points

    def forced_names(self) -> list[str]:
        """Every forced name: variables, then points."""
        return [*self.forced, *self.forced_points]

    def forced_values(self) -> dict[str, Any]:
        """Every forced name with its forced value (a variable's of its type, a point's
        raw), variables first."""
        return {**{k: f.value for k, f in self.forced.items()},
                **{k: f.value for k, f in self.forced_points.items()}}

    def _rebuild_instance_forces(self) -> None:
        self._forced_by_inst.clear()
        for f in self.forced.values():
            self._forced_by_inst.setdefault(f.instance, []).append((f.slot, f.value))
        self._settle()

    def _apply_instance_forces(self, inst: str, m: list[Any]) -> None:
        for idx, value in self._forced_by_inst.get(inst, ()):
            m[idx] = value

    def _apply_point_forces(self, outputs: bool | None) -> None:
        """Forced inputs mask the driver's values during the cycle only (``outputs`` False),
        and are restored after it (None), so a driver or a script keeps its own value;
        forced outputs are written to the driver (True)."""
        if outputs is None:
            for d, point, value in self._stash:
                d.inputs[point] = value
            self._stash.clear()
            return
        for f in self.forced_points.values():
            if f.is_output != outputs:
                continue
            d = f.driver
            if f.is_output:
                d.outputs[f.point] = f.value
            else:
                self._stash.append((d, f.point, d.inputs[f.point]))
                d.inputs[f.point] = f.value

    # -- online change (runtime/change) ---------------------------------------------
    def dispose(self) -> None:
        """Break the one cycle a plant is made of (its generated functions' environment
        holds the plant's own bound methods) and end its groups of inlined scans, so that
        once dropped it is freed at once by
        reference counting: the controller's collector, which runs in the scan's idle
        time, never has to examine a dead plant (an online change drops one each time; a
        collection of a 100-tester plant's objects takes tens of ms). The plant cannot
        cycle any more afterwards; its instances, names and drivers stay readable."""
        self._inliner.close()
        self._env.clear()
        del self._cycle_fast, self._cycle, self._copy_outputs

    def take_over(self, old: Plant, rename: Callable[[str], str | None]) -> list[str]:
        """Go on from ``old``'s plant-level state: program time and start, scans, pause,
        stepping, iocheck, forces, a flag pulse not yet run. ``rename`` gives the new name
        of an old forced name (None: it is gone). Returns one line per force released (name
        gone, value no longer of its type). Between two cycles only."""
        for dname in self._handed:  # read as this plant's cycle reads them, from now on
            self.drivers[dname].inputs.declare_bits(self.bits[dname])
        self.start = old.start  # (the property: groups that ran start again)
        self.last_up, self.offset_ns = old.last_up, old.offset_ns
        self._last_scan, self._stood_still = old._last_scan, old._stood_still
        self._hold, self.steps_left, self._iocheck = old.hold, old.steps_left, old.iocheck
        self.scans = old.scans
        self.forced.clear()
        self.forced_points.clear()
        released = []
        for name, value in old.forced_values().items():
            new = rename(name)
            try:
                if new is None:
                    raise BindingError("no longer in the plant")
                self.force(new, value)
            except (BindingError, ValueError, TypeError) as exc:
                released.append(f"force {name} released: {exc}")
        self._rebuild_instance_forces()
        for inst, idx in old._pulses:  # a flag pulse asked for since the last cycle
            if inst in self.instances:
                flag = old.instances[inst].program.slots[idx].name
                self._pulses.append((inst, self.instances[inst].program.var_index(flag)))
        self._settle()
        return released
