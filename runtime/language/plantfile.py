"""Loading plant files: cycle, drivers, instances and their bindings (language.md).

Without a list of diagnostics the loader raises the first error; with one (``PlantLoad``),
it records, in the order it meets them, the errors it can go on after: the binding errors
(G301 unbound signal, G302 physical output bound twice, and the faults of one binding, which
is then left out) and the load errors of its charts (that instance is left out); it raises
the others. The plant it returns is whole only if it recorded nothing.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field
from typing import Any

from drivers.base import Direction, PointError
from drivers.config import ConfigError
from drivers.durations import format_ns
from drivers.registry import BAUDRATES, DRIVER_KEYS, check_config, check_point
from runtime.errors import Diagnostic, Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.alarmconf import ALARMS, load_alarms
from runtime.language.drivershape import DRIVER, ON_FAULT_CHOICES, keys_of, on_fault_words
from runtime.language.feedconf import settle_feed
from runtime.language.grafcetfile import load_grafcet
from runtime.language.iolist import IO_KEYS, check_io_entry, io_entry
from runtime.language.lexer import is_name
from runtime.language.modbusconf import MODBUS, load_modbus
from runtime.language.model import (
    Binding,
    ConsoleEntry,
    ConsoleLimits,
    DriverDef,
    Grafcet,
    InstanceDef,
    PlantDef,
    VarKind,
)
from runtime.language.mqttconf import MQTT, load_mqtt
from runtime.language.opcuaconf import OPCUA, load_opcua
from runtime.language.plantpaths import PATH, SOCKET_PATH, path_value, plant_path, resolve
from runtime.language.shape import (
    DESCRIPTION,
    Bool,
    Choice,
    Const,
    Def,
    Int,
    Key,
    MapOf,
    Null,
    Section,
    Text,
    Time,
    any_of,
    check_keys,
    description_text,
    expect_type,
    one_of,
    time_value,
)
from runtime.language.typecheck import FLAGS_BOOL
from runtime.language.webconf import WEB, load_web
from runtime.language.yamlsrc import SourceFileError, YMap, load_yaml

_MS, _S = 1_000_000, 1_000_000_000
#: values of ``log:`` (plant-wide under ``plc:``, or per instance) -> whether step changes
#: are logged
LOG_VALUES = {"steps": True, "none": False}

# -- the shape of a plant file (runtime/language/shape.py): the loader's key lists, types
# -- and bounds, and configs/schema/plant.schema.json generated from them
PORT = Def("port", Int(1, 65535), "TCP port.")
TRUSTED = Def("trusted", Bool(), "Allow changing commands without a PIN on this console. Only "
                                 "for a console nobody else can reach, on a bench.",
              default=False)
BAUDRATE = Def("baudrate", Choice(BAUDRATES), "A serial line rate Linux sets, bit/s.")
REALTIME = Section((
    Key("priority", Int(1, 99), "SCHED_FIFO priority 1-99 (default 50)."),
    Key("lock_memory", Bool(), "mlockall: no page faults in the scan."),
    Key("cpu", Int(0, 1023), "The processor (0-1023) the controller's process runs on, "
                             "all its threads; the plant's side processes (opcua, mqtt, "
                             "web, modbus) run on the others. Default: any."),
), "plc realtime")
PLC = Section((
    Key("cycle", Time(1 * _MS, 60 * _S), "Scan period, 1ms to 1m (10ms)."),
    Key("watchdog", Time(10 * _MS, 6 * _S), "A scan longer than this is a fault: outputs to "
                                            "the safe state. 10ms to 6s (1s)."),
    Key("retain", any_of(PATH, Null()), "File of the retained memory (absolute, or relative "
                                        "to this file): a regular file or none yet, never a "
                                        "directory."),
    Key("retain_interval", Time(1), "At most one retain write per interval (1s)."),
    Key("retain_required", Bool(), "Refuse to start when the retained data is lost (false: "
                                   "start with init values after an error line)."),
    Key("realtime", one_of(Const(False), REALTIME),
        "Real-time scheduling of the scan thread: by default SCHED_FIFO 50 where permitted "
        "(the installed service); false: normal priority."),
    Key("log", Choice(tuple(LOG_VALUES)), "steps: log every step activation and deactivation "
                                          "of every instance (an instance's own 'log' says "
                                          "otherwise); none: the default."),
), "plc", "Controller settings.")
#: why a time under ``plc:`` beyond its bounds (``PLC``) would harm the plant: key -> (below
#: the least, above the greatest) (docs/language.md, "The plant file")
PLC_TIMES: dict[str, tuple[str, str]] = {
    "cycle": ("below 1 ms every scan overruns in Python (a wake-up and a scan take tens to "
              "hundreds of µs, a stall of the system several ms; 5-10 ms suits a Raspberry "
              "Pi)",
              "a longer cycle leaves the inputs unread that long (an emergency stop, a limit "
              "switch): pace a slow process with the chart's times (a step's time, TON) at a "
              "shorter cycle"),
    "watchdog": ("the stalls of a system without real-time priority reach several ms: a "
                 "shorter watchdog puts a healthy plant in fault",
                 "a stuck scan would hold the outputs that long before they go off, and a "
                 "stop waits up to three watchdogs for it (S7's cycle monitoring stops at "
                 "6 s too)"),
    "retain_interval": ("", ""),
}
#: why a TCP port a console may listen on is not 0
TCP_PORT_HINT = ("such as 5020; 0 would be a port the system picks, which no client could "
                 "know")
#: why the SCHED_FIFO priorities have the default they have
FIFO_PRIORITY_HINT = "50 leaves room above and below for the system's own threads"
CPU_HINT = "as Linux numbers them: 0 is the first; see nproc"
POINT = Def("point", Text(r"^[^.\s]+\.\S+$"),
            "driver.point (gpio.17, exp1.A0, sim.I0), or another instance's signal "
            "(tester1.oParado, tester1.gsParado.X).")
#: a binding's mapping form: ``{from: gpio.17, invert: true, description: ...}``
BINDING_SPEC = Section((
    Key("from", POINT, required=True),
    Key("invert", Bool(), "Invert the bool at the binding (bools only).", default=False),
    *IO_KEYS,
))
BINDING = Def("binding", one_of(POINT, BINDING_SPEC),
              "'driver.point', or {from: 'driver.point', invert: true} for a signal in "
              "negative logic (an NC contact): inversion happens here and only here; the "
              "mapping form may carry the signal's I/O list: description, unit, range, at.")
#: an output's mapping form: its point as ``to:`` (its value goes there) or ``from:`` (as an
#: input's: every plant written before ``to:``), one of the two
OUTPUT_BINDING_SPEC = Section((
    Key("from", POINT),
    Key("to", POINT),
    Key("invert", Bool(), "Invert the bool at the binding (bools only).", default=False),
    *IO_KEYS,
), extra={"oneOf": [{"required": ["to"], "not": {"required": ["from"]}},
                    {"required": ["from"], "not": {"required": ["to"]}}]})
OUTPUT_BINDING = Def("outputBinding", one_of(POINT, OUTPUT_BINDING_SPEC),
                     "'driver.point', or {to: 'driver.point', invert: true} for an output in "
                     "negative logic: inversion happens here and only here; the mapping form "
                     "may carry the signal's I/O list: description, unit, range, at. An output "
                     "names its point with to: (its value goes there) or from: (as an input "
                     "does), one of the two.")
INSTANCE = Section((
    Key("grafcet", PATH, "The grafcet file, relative to this plant file.", required=True),
    Key("inputs", MapOf(BINDING), "Chart input (or chart flag such as SFCPause) -> binding."),
    Key("outputs", MapOf(OUTPUT_BINDING), "Chart output -> driver point (each physical "
                                          "output bound once)."),
    Key("description", DESCRIPTION, "Free text."),
    Key("log", Choice(tuple(LOG_VALUES)), "steps: log every step activation and deactivation "
                                          "of this instance; none: do not (overrides plc "
                                          "log)."),
), doc="An instance of a grafcet (like a Siemens DB): its own state, its own binding. Every "
       "input and output of the chart must be bound.")
SERIAL = Section((
    Key("port", PATH, "/dev/ttyGS0", required=True),
    Key("baudrate", BAUDRATE, "Baud rate.", default=115200),
    Key("trusted", TRUSTED),
), "monitor serial", "Console on a serial port (UART, USB gadget).")
SOCKET = Section((
    Key("path", SOCKET_PATH, "Socket path.", required=True),
    Key("trusted", TRUSTED),
), "monitor socket")
TCP = Section((
    Key("port", PORT, required=True),
    Key("trusted", TRUSTED),
), "monitor tcp")
CONSOLE_LIMITS = Section((
    Key("max_pause", Time(), "A pause ends into a halt (outputs off, ack needed) after this "
                             "long (default 15m)."),
    Key("max_force", Time(), "A force is released after this long (default 15m)."),
    Key("warn_before", Time(), "The owning session is warned this long before (default 30s)."),
    Key("relock_after_idle", Time(), "An unlocked session with no input for this long locks "
                                     "itself again (default 5m)."),
), "monitor limits", "How long console holds may last (docs/console.md).")
MONITOR = Section((
    Key("serial", SERIAL),
    Key("socket", one_of(SOCKET_PATH, SOCKET), "Console on a Unix socket: its path, or {path, "
                                               "trusted}."),
    Key("tcp", one_of(PORT, TCP), "Console on a TCP port bound to 127.0.0.1: the port, or "
                                  "{port, trusted}."),
    Key("pin_hash", Text(), "Hash of the console PIN, as printed by 'softplc hash-pin'."),
    Key("release_forces_on_disconnect", Bool(),
        "When a console session that held only forces ends, release them and let the charts "
        "run on (without it: release them and halt until ack)."),
    Key("limits", CONSOLE_LIMITS),
), "monitor", "Consoles (docs/console.md): serial port, Unix socket, TCP on 127.0.0.1. "
              "Changing commands need the PIN, unless a console is marked trusted.")
PLANT = Section((
    Key("plc", PLC),
    Key("drivers", MapOf(DRIVER), "I/O drivers, by name (the 'driver' of driver.point)."),
    Key("instances", MapOf(Def("instance", INSTANCE), min_properties=1),
        "Instances, scanned in this order.", required=True),
    Key("monitor", MONITOR),
    Key("opcua", OPCUA),
    Key("mqtt", MQTT),
    Key("alarms", ALARMS),
    Key("web", WEB),
    Key("modbus", MODBUS),
), "a plant file", "One controller: cycle, I/O drivers, the instances of grafcet files with "
                   "their bindings, consoles (docs/language.md, 'The plant file').")


@dataclass
class PlantLoad:
    """One load of a plant file: the charts it read and, if collected, its diagnostics.

    Each chart file is read once per load and its Grafcet shared by every instance that
    names it (the engine compiles each distinct Grafcet once); nothing outlives the load.
    """

    diagnostics: list[Diagnostic] | None = None
    charts: dict[str, Grafcet] = field(default_factory=dict)  # real path -> chart
    chart_files: list[str] = field(default_factory=list)  # as named, instance order, once each

    def chart(self, path: str, loc: Loc) -> Grafcet:
        """The chart of file ``path``, read at its first use in this load; a file that
        cannot be read at all (a FIFO, a device, a huge file, an I/O error) is said at
        ``loc``, the plant's line that names it."""
        real = os.path.realpath(path)
        if real not in self.charts:
            try:
                self.charts[real] = load_grafcet(path)
            except SourceFileError as exc:
                raise SourceError(loc, f"grafcet file {path}: {exc.problem}") from None
        return self.charts[real]

    def report(self, error: SourceError) -> None:
        """An error the load can go on after: raised, or recorded if collected."""
        if self.diagnostics is None:
            raise error
        self.diagnostics.append(error.diagnostic)


def _retain_path(base: str, value: Any, loc: Loc) -> str:
    """``plc: retain``: a regular file, or one not yet there, never a directory."""
    text = path_value(value, loc, "plc retain")
    if text.endswith(("/", os.sep)):
        raise SourceError(loc, f"plc retain: '{text}' names a directory, expected a file")
    path = resolve(base, text)
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise SourceError(loc, f"plc retain: {path}: {exc.strerror}") from None
    if mode is not None and stat.S_ISDIR(mode):
        raise SourceError(loc, f"plc retain: {path} is a directory, expected a file")
    if mode is not None and not stat.S_ISREG(mode):
        raise SourceError(loc, f"plc retain: {path} is not a regular file (a symbolic link, "
                               "a device or a FIFO)")
    if os.path.realpath(path) == os.path.realpath(base):
        raise SourceError(loc, "plc retain: that is the plant file itself")
    parent = os.path.dirname(path)
    if os.path.lexists(parent) and not os.path.isdir(parent):
        raise SourceError(loc, f"plc retain: {parent} is not a directory")
    return path


def _binding(signal: str, spec: Any, loc: Loc, output: bool = False) -> Binding:
    """The binding of ``signal`` (an output's when ``output``): ``driver.point`` or a
    mapping naming it (``from:``; an output's also ``to:``)."""
    invert = False
    listed: YMap | None = None
    if isinstance(spec, YMap):
        def misplaced(key: str) -> str | None:
            if key != "to":
                return None
            return (": 'to:' binds an output (its value goes to the point): an input's value "
                    f"comes from its point: write 'from: {spec['to']}'")
        (OUTPUT_BINDING_SPEC if output else BINDING_SPEC).check(
            spec, f"the binding of '{signal}'", misplaced)
        key = "to" if output and "to" in spec else "from"
        if output and "to" in spec and "from" in spec:
            raise SourceError(spec.key_locs["to"], f"the binding of '{signal}' names its point "
                                                   "twice ('from:' and 'to:'): keep one")
        if key not in spec:
            raise SourceError(spec.loc, f"binding of '{signal}' needs "
                                        + ("'to: driver.point' (or 'from:')" if output
                                           else "'from: driver.point'"))
        invert = expect_type(spec.get("invert", False), spec.val_locs.get("invert", loc), bool,
                             "true or false for invert")
        listed = spec
        loc = spec.val_locs[key]
        spec = spec[key]
    source = expect_type(spec, loc, str, f"'driver.point' or {{{'to' if output else 'from'}: "
                                         f"..., invert: true}} for '{signal}'")
    if "." not in source:
        raise SourceError(loc, f"expected 'driver.point' or 'instance.signal' for '{signal}', "
                               f"found '{source}'")
    b = Binding(signal, str(source), loc, invert)
    if listed is not None:
        io_entry(b, listed)
    return b


def load_plant(path: str, load: PlantLoad | None = None, *, doc: Any = None) -> PlantDef:
    """Load a plant file and every grafcet it names; bindings fully checked.

    ``load``: a ``PlantLoad`` with a list of diagnostics to collect them (see the module's
    docstring); by default, a load of its own that raises the first error. ``doc``: the
    plant file's document as ``load_yaml(path)`` returned it, when the caller read it."""
    load = PlantLoad() if load is None else load
    if doc is None:
        doc = load_yaml(path)
    if not isinstance(doc, YMap):
        raise SourceError(Loc(path, 1, 1), "expected a YAML mapping with 'instances:'")
    PLANT.check(doc)
    p = PlantDef(path=path)
    log_steps = False  # plant-wide ``plc: log``, each instance may say otherwise
    if "plc" in doc:
        plc = expect_type(doc["plc"], doc.val_locs["plc"], YMap, "a mapping")
        PLC.check(plc)
        for key in PLC_TIMES:
            if key in plc:
                setattr(p, f"{key}_ns", _plc_time(key, plc[key], plc.val_locs[key]))
        if "retain" in plc and plc["retain"] is not None:
            p.retain_path = _retain_path(path, plc["retain"], plc.val_locs["retain"])
            p.retain_loc = plc.val_locs["retain"]
        if "retain_required" in plc:
            loc = plc.val_locs["retain_required"]
            p.retain_required = expect_type(plc["retain_required"], loc, bool, "true or false")
            p.retain_required_loc = loc
            if p.retain_required and p.retain_path is None:
                raise SourceError(loc, "plc retain_required needs a retain file (plc retain)")
        if plc.get("realtime") is False:  # the scan thread at normal priority
            p.realtime_priority = 0
        elif "realtime" in plc:
            rt = expect_type(plc["realtime"], plc.val_locs["realtime"], YMap,
                             "a mapping ({priority: 1-99, lock_memory: true, cpu: N}) or "
                             "false")
            REALTIME.check(rt)
            if "priority" in rt:
                p.realtime_priority = _int_in(rt["priority"], rt.val_locs["priority"],
                                              REALTIME["priority"], FIFO_PRIORITY_HINT,
                                              "a SCHED_FIFO priority")
            p.lock_memory = _flag(rt, "lock_memory")
            if "cpu" in rt:
                p.realtime_cpu = _int_in(rt["cpu"], rt.val_locs["cpu"], REALTIME["cpu"],
                                         CPU_HINT, "a processor number")
        if "log" in plc:
            log_steps = _log_steps(plc["log"], plc.val_locs["log"])
    drivers = doc.get("drivers") or YMap()
    if drivers:
        expect_type(drivers, doc.val_locs["drivers"], YMap, "a mapping of drivers")
    for name, spec in drivers.items():
        loc = drivers.key_locs[name]
        if not isinstance(name, str) or not is_name(name):
            raise SourceError(loc, f"expected a driver name (letters, digits and _, as in "
                                   f"'exp1', in canonical form), found {name!r}")
        spec = expect_type(spec, drivers.val_locs[name], YMap, f"the driver '{name}' "
                                                                "({type: ...})")
        if "type" not in spec:
            raise SourceError(spec.loc, f"driver '{name}' needs 'type'")
        typ = spec["type"]
        if not isinstance(typ, str) or typ not in DRIVER_KEYS:
            raise SourceError(spec.val_locs["type"], f"unknown driver type '{typ}': expected one "
                              f"of {', '.join(DRIVER_KEYS)}{suggest(str(typ), DRIVER_KEYS)}")
        check_keys(spec, keys_of(typ), f"driver '{name}' ({typ})")
        if spec.get("on_fault", ON_FAULT_CHOICES[0]) not in ON_FAULT_CHOICES:
            raise SourceError(spec.val_locs["on_fault"], f"unknown on_fault {spec['on_fault']!r}"
                                                         f": expected {on_fault_words()}")
        config = {k: (str(v) if isinstance(v, str) else v) for k, v in spec.items()
                  if k != "type"}
        try:  # the values, as the driver will check them, with no bus library imported
            check_config(typ, str(name), config)
        except ConfigError as exc:
            raise SourceError(spec.val_locs.get(exc.key, spec.loc) if exc.key else spec.loc,
                              str(exc)) from None
        p.drivers[name] = DriverDef(name, typ, config, loc)
    if "instances" not in doc:
        raise SourceError(doc.loc, "missing key 'instances': a plant runs at least one instance")
    instances = expect_type(doc["instances"], doc.val_locs["instances"], YMap,
                            "a mapping of instances")
    for name, spec in instances.items():
        loc = instances.key_locs[name]
        if not is_name(str(name)):
            # a name Python would normalise (NFKC: 'nº1' is 'no1') would collide with
            # another once compiled into the plant cycle
            load.report(SourceError(loc, f"expected an instance name (letters, digits and "
                                         f"_, in canonical form), found '{name}'"))
        try:  # an error here leaves the instance out (when collected)
            spec = expect_type(spec, instances.val_locs[name], YMap, f"instance '{name}'")
            try:  # an unknown key does not
                INSTANCE.check(spec, f"instance '{name}'")
            except SourceError as exc:
                load.report(exc)
            if "grafcet" not in spec:
                raise SourceError(spec.loc, f"instance '{name}' needs 'grafcet: FILE'")
            gloc = spec.val_locs["grafcet"]
            gpath = plant_path(path, spec["grafcet"], gloc, "grafcet")
            if not os.path.exists(gpath):
                raise SourceError(gloc, f"grafcet file not found: {gpath}")
            if gpath not in load.chart_files:
                load.chart_files.append(gpath)
            g = load.chart(gpath, gloc)
        except SourceError as exc:
            load.report(exc)
            continue  # the instance is left out
        inst = InstanceDef(name, g, loc, log_steps=log_steps)
        if "description" in spec:
            try:
                inst.description = description_text(spec["description"],
                                                    spec.val_locs["description"])
            except SourceError as exc:
                load.report(exc)
        if "log" in spec:
            try:
                inst.log_steps = _log_steps(spec["log"], spec.val_locs["log"])
            except SourceError as exc:
                load.report(exc)
        written: dict[str, YMap] = {}
        for key in ("inputs", "outputs"):
            section = spec.get(key) or YMap()
            if section:
                try:
                    expect_type(section, spec.val_locs[key], YMap, f"a mapping of {key}")
                except SourceError as exc:
                    load.report(exc)
                    section = YMap()  # its signals are then unbound
            written[key] = section
            for sig, bspec in section.items():
                try:
                    b = _binding(sig, bspec, section.val_locs[sig], key == "outputs")
                except SourceError as exc:
                    load.report(exc)
                    continue  # the binding is left out
                v = g.variables.get(sig)
                if key == "inputs":
                    ok = v is not None and (v.kind is VarKind.INPUT or sig in FLAGS_BOOL)
                    wanted = [x.name for x in g.inputs] + list(FLAGS_BOOL)
                else:
                    ok = v is not None and v.kind is VarKind.OUTPUT
                    wanted = [x.name for x in g.outputs]
                if not ok:
                    load.report(SourceError(section.key_locs[sig], f"'{sig}' is not an "
                                            f"{key[:-1]} of grafcet {g.name}"
                                            f"{suggest(sig, wanted)}"))
                    continue
                if b.invert and v is not None and v.type is not A.Type.BOOL:
                    load.report(SourceError(b.loc, f"invert applies to bools only; '{sig}' is "
                                                   f"{v.type}"))
                if v is not None and isinstance(bspec, YMap):
                    try:
                        check_io_entry(b, bspec, v.type, key[:-1])
                    except SourceError as exc:
                        load.report(exc)
                getattr(inst, key)[sig] = b
        for key, signals in (("inputs", g.inputs), ("outputs", g.outputs)):
            for var in signals:
                if var.name not in written[key]:  # a binding left out is not unbound
                    load.report(SourceError(spec.key_locs.get(key, loc), f"instance '{name}' "
                                f"leaves {key[:-1]} '{var.name}' of grafcet {g.name} unbound: "
                                f"expected a binding '{var.name}: driver.point' in '{key}', "
                                "found none", "G301"))
        p.instances[name] = inst
    _resolve_bindings(p, load)
    if "monitor" in doc and doc["monitor"] is not None:
        _monitor(p, doc["monitor"], doc.val_locs["monitor"])
    named: dict[str, Loc] = {}  # side process section -> its feed: value's place
    for key, load_side in (("opcua", load_opcua), ("mqtt", load_mqtt), ("web", load_web),
                           ("modbus", load_modbus)):
        if key in doc and doc[key] is not None:
            setattr(p, key, load_side(p, doc[key], doc.val_locs[key]))
            section = doc[key]
            if isinstance(section, YMap) and "feed" in section:
                named[key] = section.val_locs["feed"]
    settle_feed(p, named)
    if "alarms" in doc and doc["alarms"] is not None:
        p.alarms = load_alarms(doc["alarms"], doc.val_locs["alarms"])
    return p


def _resolve_bindings(p: PlantDef, load: PlantLoad) -> None:
    driven: dict[str, tuple[str, Binding]] = {}
    bound: dict[str, dict[str, Direction]] = {}  # driver -> point -> direction
    for inst in p.instances.values():
        for key in ("inputs", "outputs"):
            for b in getattr(inst, key).values():
                head, rest = b.source.split(".", 1)
                want = inst.grafcet.variables[b.signal].type
                if head in p.drivers:
                    b.driver, b.point = head, rest
                    direction = Direction.IN if key == "inputs" else Direction.OUT
                    try:  # the point, from the driver type's description (G303)
                        if rest != "ok":
                            check_point(p.drivers[head].type, head, rest, direction,
                                        bound.setdefault(head, {}))
                        elif direction is Direction.OUT:
                            raise PointError(f"'{b.source}' is the driver's health, a "
                                             "read-only input: it cannot be bound as an "
                                             "output")
                    except PointError as exc:
                        load.report(SourceError(b.loc, f"{exc} (instance '{inst.name}', "
                                                f"{key[:-1]} '{b.signal}')", "G303"))
                        continue
                    if rest == "ok" and want is not A.Type.BOOL:
                        load.report(SourceError(b.loc, f"type error: expected a {want} source "
                                                f"for '{inst.name}.{b.signal}', found the bool "
                                                f"'{b.source}' (driver health)"))
                    if key == "outputs":
                        if b.source in driven:
                            other_inst, other = driven[b.source]
                            load.report(SourceError(b.loc, f"physical output '{b.source}' is "
                                                    "bound twice: expected one output per "
                                                    f"point, found '{inst.name}.{b.signal}' "
                                                    f"and '{other_inst}.{other.signal}' (line "
                                                    f"{other.loc.line})", "G302"))
                        else:
                            driven[b.source] = (inst.name, b)
                elif head in p.instances and key == "inputs":
                    chart = p.instances[head].grafcet
                    found: A.Type | None = None
                    if rest in chart.variables and chart.variables[rest].kind is not (
                            VarKind.SYSTEM):
                        found = chart.variables[rest].type
                    elif rest.endswith((".X", ".T")) and rest[:-2] in chart.steps:
                        found = A.Type.BOOL if rest.endswith(".X") else A.Type.TIME
                    if found is None:
                        names = [*chart.variables, *(f"{s}.X" for s in chart.steps)]
                        load.report(SourceError(b.loc, f"instance '{head}' has no signal "
                                                f"'{rest}'{suggest(rest, names)}"))
                    elif found is not want:
                        load.report(SourceError(b.loc, f"type error: expected a {want} signal "
                                                f"for '{inst.name}.{b.signal}', found {found} "
                                                f"'{b.source}'"))
                    else:
                        b.instance, b.ref = head, rest
                elif head in p.instances:
                    load.report(SourceError(b.loc, f"expected a driver point for output "
                                                   f"'{b.signal}', found instance '{head}' (an "
                                                   "instance's signal can feed an input only)"))
                else:
                    where = list(p.drivers) + (list(p.instances) if key == "inputs" else [])
                    load.report(SourceError(b.loc, f"unknown driver or instance '{head}' in "
                                                   f"'{b.source}'{suggest(head, where)}"))


def _plc_time(key: str, value: Any, loc: Loc) -> int:
    """``plc: KEY``, a time within PLC_TIMES[key], in ns."""
    ns = time_value(value, loc, f"plc {key}")
    low, high = PLC[key].low, PLC[key].high
    below, above = PLC_TIMES[key]
    if ns < low or (high is not None and ns > high):
        span = (f"from {format_ns(low)} to {format_ns(high)}" if high is not None
                else "more than 0")
        why = below if ns < low else above
        raise SourceError(loc, f"plc {key}: expected a time {span}, found '{value}'"
                               + (f": {why}" if why else ""))
    return ns


def _int_in(value: Any, loc: Loc, key: Key, hint: str, what: str) -> int:
    """An integer within ``key``'s declared bounds (``hint``: why they are so)."""
    low, high = key.low, key.high
    expected = f"{what} from {low} to {high} ({hint})"
    n = _int(value, loc, expected)
    if not low <= n <= high:
        raise SourceError(loc, f"expected {expected}, found {n}")
    return n


def _log_steps(value: Any, loc: Loc) -> bool:
    """``log: steps`` (every step change logged) or ``log: none``."""
    if not isinstance(value, str) or value not in LOG_VALUES:
        raise SourceError(loc, f"log: expected steps or none, found '{value}'")
    return LOG_VALUES[value]


def _need(m: YMap, key: str, what: str) -> Any:
    if key not in m:
        raise SourceError(m.loc, f"missing key '{key}': expected {what}")
    return m[key]


def _int(value: Any, loc: Loc, what: str) -> int:
    return int(expect_type(value, loc, int, what))


def _flag(m: YMap, key: str) -> bool:
    return bool(expect_type(m.get(key, False), m.val_locs.get(key, m.loc), bool,
                            f"true or false for {key}"))


def _monitor(p: PlantDef, mon: Any, loc: Loc) -> None:
    mon = expect_type(mon, loc, YMap, "a mapping")
    MONITOR.check(mon)
    if "serial" in mon:
        s = expect_type(mon["serial"], mon.val_locs["serial"], YMap, "{port, baudrate}")
        SERIAL.check(s)
        port = path_value(_need(s, "port", "the serial port (e.g. /dev/ttyGS0)"),
                          s.val_locs.get("port", s.loc), "monitor serial port")
        baud = s.get("baudrate", SERIAL["baudrate"].default)
        if isinstance(baud, bool) or baud not in BAUDRATES:
            raise SourceError(s.val_locs.get("baudrate", s.loc), f"monitor serial baudrate: "
                              f"expected a standard baud rate such as 9600 or 115200 (50 to "
                              f"{BAUDRATES[-1]}), found {baud!r}")
        p.consoles.append(ConsoleEntry("serial", port, baud, _flag(s, "trusted")))
    if "socket" in mon:
        s = mon["socket"]
        if isinstance(s, YMap):
            SOCKET.check(s)
            path = path_value(_need(s, "path", "the socket's path"),
                              s.val_locs.get("path", s.loc), "monitor socket", socket=True)
            p.consoles.append(ConsoleEntry("socket", path, trusted=_flag(s, "trusted")))
        else:
            path = path_value(s, mon.val_locs["socket"], "monitor socket", socket=True)
            p.consoles.append(ConsoleEntry("socket", path))
    if "tcp" in mon:
        s = mon["tcp"]
        if isinstance(s, YMap):
            TCP.check(s)
            number = _int_in(_need(s, "port", "a TCP port number"),
                             s.val_locs.get("port", s.loc), TCP["port"], TCP_PORT_HINT,
                             "a TCP port number")
            p.consoles.append(ConsoleEntry("tcp", f"127.0.0.1:{number}",
                                           trusted=_flag(s, "trusted")))
        else:
            number = _int_in(s, mon.val_locs["tcp"], TCP["port"], TCP_PORT_HINT,
                             "a TCP port number")
            p.consoles.append(ConsoleEntry("tcp", f"127.0.0.1:{number}"))
    if "pin_hash" in mon:
        p.pin_hash = str(MONITOR.value(mon, "pin_hash", "the PIN's hash printed by 'softplc "
                                                        "hash-pin'"))
    if "release_forces_on_disconnect" in mon:
        p.release_forces_on_disconnect = _flag(mon, "release_forces_on_disconnect")
    if "limits" in mon:
        p.console_limits = _console_limits(mon["limits"], mon.val_locs["limits"])


def _console_limits(value: Any, loc: Loc) -> ConsoleLimits:
    """``monitor: limits: {max_pause: 15m, max_force: 15m, warn_before: 30s,
    relock_after_idle: 5m}`` (each optional) -> ConsoleLimits."""
    lim = expect_type(value, loc, YMap, "a mapping of times")
    CONSOLE_LIMITS.check(lim)
    given = {f"{k}_s": time_value(lim[k], lim.val_locs[k], f"monitor limits {k}") / 1e9
             for k in CONSOLE_LIMITS.names if k in lim}
    out = ConsoleLimits(**given)
    for k in ("max_pause", "max_force", "relock_after_idle"):
        s = getattr(out, f"{k}_s")
        if s <= 0 or (k != "relock_after_idle" and s <= out.warn_before_s):
            raise SourceError(lim.val_locs.get(k, lim.loc), f"monitor limits: {k} must be "
                              + ("longer than warn_before" if s > 0 else "more than 0"))
    return out
