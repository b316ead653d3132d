"""Typed model of grafcet files and plant files, as the loader builds it."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from runtime.errors import Loc
from runtime.language import ast as A
from runtime.language.units import Unit

#: The file place of character ``i`` of a text read from a user's file (a condition, an
#: action, a statement), whatever its YAML style (quoted, block, folded).
Locator = Callable[[int], Loc]


def _shifted(loc: Loc, columns: int) -> Loc:
    return Loc(loc.file, loc.line, loc.col + columns)


class VarKind(enum.Enum):
    INPUT = "input"
    OUTPUT = "output"
    MEMORY = "memory"
    TEMP = "temporary"  # "t" variables: assigned in the program, typed by use
    FLAG = "chart flag"
    SYSTEM = "system value"  # FirstScan, clock bits: read-only


class ScanModel(enum.Enum):
    IMMEDIATE = "immediate"
    CODESYS = "codesys"
    STABLE = "stable"


class Qualifier(enum.Enum):
    N = "N"
    S = "S"
    R = "R"
    L = "L"
    D = "D"
    P = "P"
    P1 = "P1"
    P0 = "P0"
    DS = "DS"
    SD = "SD"
    SL = "SL"
    EVENT = "EVENT"  # on EVENT do ...


#: the IEC 61131-3 elementary types a variable of each of the language's types may declare
#: (``iec_type:``, kept for a PLCopen export; docs/plcopen.md), the first the one declared
#: when the chart names none. The type changes nothing the runtime computes.
IEC_TYPES: dict[str, tuple[str, ...]] = {
    "bool": ("BOOL",),
    "int": ("LINT", "SINT", "INT", "DINT", "USINT", "UINT", "UDINT", "ULINT", "BYTE", "WORD",
            "DWORD", "LWORD"),
    "real": ("LREAL", "REAL"),
    "time": ("TIME",),
}


@dataclass(slots=True)
class Variable:
    name: str
    kind: VarKind
    type: A.Type
    init: Any
    loc: Loc
    retain: bool = False
    #: the name this variable had before an edit (``renamed_from:``, online change)
    renamed_from: str | None = None
    #: what it means, for a person (``description:``; docs/language.md, "The I/O list")
    description: str = ""
    #: the IEC 61131-3 type a PLCopen export declares (``iec_type:``, one of
    #: IEC_TYPES[type]); "" for the first of them
    iec_type: str = ""


@dataclass(slots=True)
class Action:
    qualifier: Qualifier
    step: str
    text: str
    loc: Loc
    time_ns: int | None = None
    target: str | None = None  # bool variable target
    cond: A.Node | None = None  # `N x if C`
    event: A.Node | None = None  # `on E do`
    body: list[A.Node] | None = None  # statements
    index: int = 0  # order of the statement action in the chart (file order)
    locate: Locator | None = field(default=None, compare=False, repr=False)  # of ``text``

    def at(self, offset: int) -> Loc:
        """File place of character ``offset`` of the action's text."""
        return self.locate(offset) if self.locate else _shifted(self.loc, offset)


@dataclass(slots=True)
class Step:
    name: str
    loc: Loc
    initial: bool = False
    actions: list[Action] = field(default_factory=list)
    min_ns: int | None = None
    max_ns: int | None = None
    macro: Macro | None = None
    entry: bool = False
    exit: bool = False
    parent: str | None = None  # enclosing macro-step
    description: str = ""
    #: the name this step had before an edit (``renamed_from:``, online change)
    renamed_from: str | None = None


@dataclass(slots=True)
class Macro:
    steps: list[str]  # names, in file order (nested expansions in place)
    transitions: list[Transition]
    entry: str
    exit: str


@dataclass(slots=True)
class Transition:
    sources: list[str]  # as written (may name macro-steps)
    targets: list[str]
    cond: A.Node
    text: str
    loc: Loc
    index: int = 0  # priority: file order
    name: str = ""
    # resolved by the loader: macro-steps replaced by their exit/entry steps
    src_steps: list[str] = field(default_factory=list)
    dst_steps: list[str] = field(default_factory=list)
    # where each name of ``sources``/``targets`` is written, and where the condition is
    source_locs: list[Loc] = field(default_factory=list, compare=False, repr=False)
    target_locs: list[Loc] = field(default_factory=list, compare=False, repr=False)
    locate: Locator | None = field(default=None, compare=False, repr=False)  # of ``text``

    def at(self, offset: int) -> Loc:
        """File place of character ``offset`` of the condition (the transition's place if
        the condition is not a text of the file)."""
        return self.locate(offset) if self.locate else self.loc


@dataclass(slots=True)
class Block:
    name: str
    kind: str  # TON TOF TP CTU CTD CTUD R_TRIG F_TRIG SR RS
    loc: Loc


@dataclass(slots=True)
class Statement:
    """A top-level statement of pre/post with its source text."""

    node: A.Node
    text: str
    loc: Loc
    # of the whole text the statement was written in (offsets as in ``node``)
    locate: Locator | None = field(default=None, compare=False, repr=False)

    def at(self, offset: int) -> Loc:
        """File place of character ``offset`` of the text holding the statement."""
        if self.locate:
            return self.locate(offset)
        return _shifted(self.loc, offset - self.node.start)


@dataclass(slots=True)
class Grafcet:
    name: str
    path: str
    loc: Loc
    description: str = ""
    scan: ScanModel = ScanModel.IMMEDIATE
    variables: dict[str, Variable] = field(default_factory=dict)
    steps: dict[str, Step] = field(default_factory=dict)  # every step, file order
    transitions: list[Transition] = field(default_factory=list)  # all, priority order
    timers: dict[str, Loc] = field(default_factory=dict)
    blocks: dict[str, Block] = field(default_factory=dict)
    pre: list[Statement] = field(default_factory=list)
    post: list[Statement] = field(default_factory=list)

    @property
    def inputs(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.kind is VarKind.INPUT]

    @property
    def outputs(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.kind is VarKind.OUTPUT]

    @property
    def memory(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.kind is VarKind.MEMORY]

    def leaf_steps(self) -> list[Step]:
        """Steps that can be active themselves (not macro-steps), file order."""
        return [s for s in self.steps.values() if s.macro is None]

    def actions(self) -> list[Action]:
        return [a for s in self.steps.values() for a in s.actions]


@dataclass(slots=True)
class Binding:
    """One instance signal bound to a driver point, another instance's signal, or a flag."""

    signal: str  # the instance's input/output/flag name
    source: str  # as written: "driver.point" or "instance.name[.X]"
    loc: Loc
    invert: bool = False
    driver: str | None = None  # set for a driver point
    point: str | None = None
    instance: str | None = None  # set for a link to another instance
    ref: str | None = None  # that instance's name: "oX", "gsA.X", "SFCError"
    #: the I/O list (docs/language.md, "The I/O list"): what the signal is, its unit of
    #: measure and, for a number, its engineering range (low, high)
    description: str = ""
    unit: Unit | None = None
    range: tuple[float, float] | None = None
    #: its IEC 61131-3 located address (``at: '%IX0.3'``), "" if none; the Modbus server's
    #: default map follows it (docs/modbus.md)
    at: str = ""
    at_loc: Loc | None = None


@dataclass(slots=True)
class InstanceDef:
    name: str
    grafcet: Grafcet
    loc: Loc
    inputs: dict[str, Binding] = field(default_factory=dict)  # inputs and chart flags
    outputs: dict[str, Binding] = field(default_factory=dict)
    #: what this machine is (``description:``), for a person
    description: str = ""
    #: log every step activation and deactivation (``log: steps``, of the instance or the
    #: plant's ``plc:``; docs/daemon.md, "Logging")
    log_steps: bool = False


@dataclass(slots=True)
class DriverDef:
    name: str
    type: str
    config: dict[str, Any]
    loc: Loc


@dataclass(slots=True)
class ConsoleEntry:
    kind: str  # serial | socket | tcp
    address: str  # port path, socket path, or "127.0.0.1:PORT"
    baudrate: int = 115200
    trusted: bool = False


#: OPC UA security policies a plant may list (``opcua: security: policies:``)
OPCUA_POLICIES = ("None", "Basic256Sha256_Sign", "Basic256Sha256_SignAndEncrypt")


@dataclass(slots=True)
class OpcuaSecurity:
    """``opcua: security:`` (docs/opcua.md): what the server offers and whom it lets in."""

    policies: list[str] = field(default_factory=lambda: ["Basic256Sha256_SignAndEncrypt"])
    #: the server's certificate and its key (absolute: a relative path in the plant file
    #: is read from the plant file's directory)
    certificate: str | None = None
    private_key: str | None = None
    #: a directory of trusted client certificates (DER or PEM): their sessions may write
    trusted_clients: str | None = None
    #: a directory of client certificates let in to read only (an HMI, a historian)
    trusted_readers: str | None = None
    #: what a client without a user may do: "read" or "none"
    anonymous: str = "read"
    #: user -> password hash (``softplc hash-pin`` format)
    users: dict[str, str] = field(default_factory=dict)
    loc: Loc | None = None
    #: where each key given (certificate, private_key ...) has its value, for the errors
    #: of the server's start
    locs: dict[str, Loc] = field(default_factory=dict)


#: the kinds of alarm (docs/daemon.md, "Alarms") and their default severities (1-1000)
ALARM_SEVERITY = {"fault": 900, "driver": 800, "sfcerror": 700, "maxtime": 700,
                  "overruns": 500}


@dataclass(slots=True)
class AlarmsDef:
    """``alarms:`` of a plant file: each kind's severity, and when overruns are an alarm."""

    severity: dict[str, int] = field(default_factory=lambda: dict(ALARM_SEVERITY))
    #: more overruns than this in ``overrun_window_ns`` make the overruns alarm active
    overrun_count: int = 10
    overrun_window_ns: int = 60_000_000_000
    loc: Loc | None = None


@dataclass(slots=True)
class OpcuaLimits:
    """``opcua: limits:`` (docs/opcua.md, "Limits"): what OPC UA clients may hold of the
    server, so that no client, nor all of them, can wedge it or take the controller's CPU."""

    #: sessions open at once (a connection gone counts until its session is closed)
    sessions: int = 10
    #: subscriptions per session (each publishes at most once per ``sample``)
    subscriptions: int = 5
    #: publishes per second a session's subscriptions may add up to, and all sessions'
    publish_rate: float = 50.0
    publish_rate_total: float = 200.0
    #: monitored items per session, and in all sessions together
    items: int = 5000
    items_total: int = 20000
    #: the longest session timeout granted to a client that asks for more, ns
    session_timeout_ns: int = 60_000_000_000
    #: a session whose connection is gone is closed after this long without a request, ns
    abandoned_ns: int = 10_000_000_000
    loc: Loc | None = None


@dataclass(slots=True)
class OpcuaDef:
    """``opcua:`` of a plant file: the OPC UA server (``softplc opcua``) and its feed."""

    endpoint: str = "opc.tcp://127.0.0.1:4840"
    #: how often the controller sends a snapshot of its image to the feed, ns
    sample_ns: int = 50_000_000
    #: the feed's local socket (the controller serves it, the server connects)
    feed: str = ""
    #: where the plant gives ``feed:`` (the section's own line when the path is the
    #: default), for the side process's start check
    feed_loc: Loc | None = None
    #: ``instance.name`` of the variables and chart flags OPC UA clients may write
    writable: list[str] = field(default_factory=list)
    security: OpcuaSecurity = field(default_factory=OpcuaSecurity)
    limits: OpcuaLimits = field(default_factory=OpcuaLimits)
    loc: Loc | None = None
    #: where each key given (endpoint, feed ...) has its value, for errors at run time
    locs: dict[str, Loc] = field(default_factory=dict)


#: what ``mqtt: publish:`` may list besides names: groups of a plant's values (docs/mqtt.md)
MQTT_GROUPS = ("inputs", "outputs", "memory", "flags", "steps", "step_times", "temporaries",
               "points", "controller", "drivers")
#: the groups published when the plant does not say (issue 28: outputs, inputs, steps' X,
#: memory, chart flags, the controller's state and statistics, the drivers' health)
MQTT_DEFAULT_PUBLISH = ("outputs", "inputs", "steps", "memory", "flags", "controller",
                        "drivers")


@dataclass(slots=True)
class MqttBroker:
    """One broker of ``mqtt: brokers:`` (tried in order, the next one on failure)."""

    url: str
    host: str
    port: int
    tls: bool


@dataclass(slots=True)
class MqttTls:
    """``mqtt: tls:``: whom the edge node trusts, and its own certificate if the broker
    asks for one. Without ``ca`` the system's certificate authorities are trusted."""

    ca: str | None = None
    certificate: str | None = None
    private_key: str | None = None
    loc: Loc | None = None
    #: where each file given has its value, for ``softplc check`` (no setting: not compared)
    locs: dict[str, Loc] = field(default_factory=dict, compare=False)


@dataclass(slots=True)
class MqttDef:
    """``mqtt:`` of a plant file: the Sparkplug B edge node (``softplc mqtt``, docs/mqtt.md)."""

    brokers: list[MqttBroker] = field(default_factory=list)
    group_id: str = ""
    #: the host name unless the plant names one
    edge_node_id: str = ""
    #: the MQTT client identifier (default ``softplc-GROUP-EDGE``)
    client_id: str = ""
    username: str | None = None
    #: a file whose first line is the password (never the password itself)
    password_file: str | None = None
    tls: MqttTls | None = None
    #: the primary host application whose STATE the node waits for (None: no waiting)
    primary_host: str | None = None
    #: groups (MQTT_GROUPS) and names published
    publish: list[str] = field(default_factory=lambda: list(MQTT_DEFAULT_PUBLISH))
    #: ``instance.name`` of the variables and chart flags a DCMD may write
    writable: list[str] = field(default_factory=list)
    #: report by exception at most this often, ns (a snapshot of the image per sample)
    sample_ns: int = 100_000_000
    #: the controller's statistics (lateness, counters, uptime) are published this often, ns
    statistics_ns: int = 10_000_000_000
    #: MQTT keep-alive, ns: the broker publishes the node's death (its Will) after 1.5 times
    #: this without a word from the node
    keepalive_ns: int = 30_000_000_000
    #: metric values kept while no broker is reachable (store and forward), the oldest
    #: dropped first beyond it
    buffer: int = 100_000
    #: the feed's local socket (the controller serves it, ``softplc mqtt`` connects)
    feed: str = ""
    #: where the plant gives ``feed:`` (the section's own line when the path is the
    #: default), for the side process's start check
    feed_loc: Loc | None = None
    loc: Loc | None = None
    #: where each key given has its value (``password_file``'s for ``softplc check``)
    locs: dict[str, Loc] = field(default_factory=dict)


@dataclass(slots=True)
class WebDef:
    """``web:`` of a plant file: the live view in the browser (``softplc web``, docs/web.md)."""

    #: the address and port it listens on; anything but a loopback address needs HTTPS
    host: str = "127.0.0.1"
    port: int = 8080
    #: how often the controller sends a snapshot of its image to the feed, ns
    sample_ns: int = 100_000_000
    #: the feed's local socket (the controller serves it, the web view connects)
    feed: str = ""
    #: where the plant gives ``feed:`` (the section's own line when the path is the
    #: default), for the side process's start check
    feed_loc: Loc | None = None
    #: HTTPS: the certificate (PEM, its chain after it) and its private key (PEM)
    certificate: str | None = None
    private_key: str | None = None
    #: where ``tls:`` gives each of the two, for ``softplc check``
    tls_locs: dict[str, Loc] = field(default_factory=dict)
    #: who may act from the page: user -> password hash (``softplc hash-pin``)
    users: dict[str, str] = field(default_factory=dict)
    #: who may look: "anyone" who reaches the address, or only logged-in "users"
    read: str = "anyone"
    #: a login ends after this long without an action from its pages, ns
    idle_logout_ns: int = 600_000_000_000
    #: pages open at once (WebSocket connections), in all
    max_pages: int = 20
    #: a page that answers nothing (not even the server's ping) for this long is closed,
    #: and what it held released (a browser frozen, a laptop asleep), ns
    page_timeout_ns: int = 30_000_000_000
    #: names besides its own (listen address, loopback, certificate) the page is reached
    #: by: any other Host is refused (DNS rebinding)
    hosts: list[str] = field(default_factory=list)
    #: the writable names (the feed's; the page acts through the console, docs/web.md)
    writable: list[str] = field(default_factory=list)
    loc: Loc | None = None
    #: where each key given has its value, for errors at run time
    locs: dict[str, Loc] = field(default_factory=dict)


#: the Modbus tables, as the driver's points name them: coils, discrete inputs, input
#: registers, holding registers
MODBUS_TABLES = ("Q", "I", "IR", "HR")


@dataclass(frozen=True, slots=True)
class ModbusPoint:
    """One plant name in the Modbus server's map (``modbus: map:``, docs/modbus.md)."""

    name: str
    #: a table of MODBUS_TABLES
    table: str
    #: protocol address, from 0 (of its first register)
    address: int
    #: BOOL (a bit), INT, UINT (one register), DINT, UDINT, REAL, TIME (two registers)
    type: str
    #: a name of ``modbus: writable:``
    writable: bool = False
    #: where its address comes from: map (the plant's modbus: map:), at (the binding's IEC
    #: located address), iolist (the next free address of its table), writable (the same,
    #: for a writable name outside the I/O list)
    origin: str = "iolist"
    loc: Loc | None = None

    @property
    def words(self) -> int:
        """Registers it takes (0 for a bit)."""
        return 0 if self.type == "BOOL" else 2 if self.type in ("DINT", "UDINT", "REAL",
                                                                  "TIME") else 1


@dataclass(slots=True)
class ModbusTls:
    """``modbus: tls:``: Modbus/TCP Security (TLS with client certificates, the role taken
    from each client's certificate)."""

    host: str = "127.0.0.1"
    port: int = 802
    certificate: str = ""
    private_key: str = ""
    #: the certificate authority (PEM) whose client certificates are let in
    clients_ca: str = ""
    #: role (the certificate's role extension) -> "read" or "write"
    roles: dict[str, str] = field(default_factory=dict)
    loc: Loc | None = None
    #: where each file given has its value, for ``softplc check`` (no setting: not compared)
    locs: dict[str, Loc] = field(default_factory=dict, compare=False)


@dataclass(slots=True)
class ModbusLimits:
    """``modbus: limits:``: what clients may hold of the server."""

    #: connections open at once, in all
    connections: int = 16
    #: requests a second one connection may make (more wait: the connection is paced)
    rate: int = 200
    #: a connection without a request for this long is closed, ns
    idle_ns: int = 60_000_000_000
    loc: Loc | None = None


@dataclass(slots=True)
class ModbusDef:
    """``modbus:`` of a plant file: the Modbus/TCP server of the plant (``softplc
    modbus``, docs/modbus.md) and its address map."""

    #: the plain Modbus/TCP listener (host "": none, only ``tls``)
    host: str = "127.0.0.1"
    port: int = 502
    #: the client addresses or networks let in (empty: anyone who reaches ``host``)
    clients: list[str] = field(default_factory=list)
    #: the unit identifier answered (None: any)
    unit: int | None = None
    #: the map: every name served, with its table, address and type
    points: list[ModbusPoint] = field(default_factory=list)
    #: ``instance.name`` of the variables and chart flags a client may write
    writable: list[str] = field(default_factory=list)
    #: a 32-bit value's registers: "high_first" (Modbus' big-endian order) or "low_first"
    words: str = "high_first"
    #: how often the controller sends a snapshot of its image to the feed, ns
    sample_ns: int = 100_000_000
    #: the feed's local socket (the controller serves it, ``softplc modbus`` connects)
    feed: str = ""
    #: where the plant gives ``feed:`` (the section's own line when the path is the
    #: default), for the side process's start check
    feed_loc: Loc | None = None
    tls: ModbusTls | None = None
    limits: ModbusLimits = field(default_factory=ModbusLimits)
    loc: Loc | None = None
    #: where each key given has its value, for errors at run time
    locs: dict[str, Loc] = field(default_factory=dict)


@dataclass(slots=True)
class FeedDef:
    """The controller's feed (runtime/controller/feed.py) as the plant's side processes
    (``opcua:``, ``mqtt:``) need it: one socket, one snapshot period, and the names each
    side process may write."""

    path: str
    #: a snapshot every this long, ns: the shortest period a side process asks for
    sample_ns: int
    #: side process ("opcua", "mqtt") -> the names it may write
    writable: dict[str, list[str]] = field(default_factory=dict)


@dataclass(slots=True)
class ConsoleLimits:
    """How long console holds may last, seconds (``monitor: limits:``, console.md)."""

    #: a pause ends into a halt (outputs off, ``ack`` needed) after this long
    max_pause_s: float = 900.0
    #: a force is released after this long
    max_force_s: float = 900.0
    #: the owning session is warned this long before either ends
    warn_before_s: float = 30.0
    #: an unlocked session with no input for this long locks itself again
    relock_after_idle_s: float = 300.0


#: the scan thread's SCHED_FIFO priority when the plant file does not say (docs/daemon.md,
#: "Real time"): a normal-priority scan waits for the processor behind whatever else runs
DEFAULT_REALTIME_PRIORITY = 50


@dataclass(slots=True)
class PlantDef:
    path: str
    cycle_ns: int = 10_000_000
    #: the default from bench/sidestart.py's figures (docs/daemon.md, "The watchdog's
    #: default"): longer than the worst lateness of a loaded controller starting a side process
    watchdog_ns: int = 1_000_000_000
    retain_path: str | None = None
    #: where ``plc: retain`` is written (errors about the retained data point there)
    retain_loc: Loc | None = None
    retain_interval_ns: int = 1_000_000_000
    #: refuse to start when the retained data is lost (docs/daemon.md)
    retain_required: bool = False
    retain_required_loc: Loc | None = None
    #: SCHED_FIFO priority of the scan thread (``plc: realtime: priority``); None: not
    #: set, DEFAULT_REALTIME_PRIORITY where permitted; 0: ``realtime: false``, none
    realtime_priority: int | None = None
    lock_memory: bool = False
    #: the processor the controller's process runs on, every thread of it (``plc:
    #: realtime: cpu``), and which the plant's side processes keep off; None: any
    realtime_cpu: int | None = None
    alarms: AlarmsDef = field(default_factory=AlarmsDef)
    drivers: dict[str, DriverDef] = field(default_factory=dict)
    instances: dict[str, InstanceDef] = field(default_factory=dict)
    consoles: list[ConsoleEntry] = field(default_factory=list)
    pin_hash: str | None = None
    release_forces_on_disconnect: bool = False
    console_limits: ConsoleLimits = field(default_factory=ConsoleLimits)
    #: the OPC UA server's section (``opcua:``), None without one
    opcua: OpcuaDef | None = None
    #: the MQTT Sparkplug B edge node's section (``mqtt:``), None without one
    mqtt: MqttDef | None = None
    #: the web view's section (``web:``), None without one
    web: WebDef | None = None
    #: the Modbus/TCP server's section (``modbus:``), None without one
    modbus: ModbusDef | None = None

    def side_sections(self) -> list[tuple[str, OpcuaDef | MqttDef | WebDef | ModbusDef | None]]:
        """The sections of the side processes fed by the controller, present or not."""
        return [("opcua", self.opcua), ("mqtt", self.mqtt), ("web", self.web),
                ("modbus", self.modbus)]

    def feed(self) -> FeedDef | None:
        """The feed the controller serves for its side processes, None if it has none."""
        sides = {k: v for k, v in self.side_sections() if v is not None}
        if not sides:
            return None
        first = next(iter(sides.values()))
        return FeedDef(first.feed, min(v.sample_ns for v in sides.values()),
                       {k: list(v.writable) for k, v in sides.items()})
