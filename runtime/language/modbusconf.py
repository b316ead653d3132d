"""The ``modbus:`` section of a plant file (docs/modbus.md): where ``softplc modbus`` listens,
who may connect, Modbus/TCP Security, the names a client may write, and the address map,
computed here once so that the server and ``softplc modbus --map`` serve and print the same.

The map: a name of ``map:`` is where the plant puts it (``HR10``, ``'%MW3'``, or ``{at:
HR10, type: DINT}``); every other name of the I/O list (the bound inputs and outputs, in
plant order), then every writable name, gets one by default: its binding's IEC located
address (``at: '%IX0.3'``) by OpenPLC's map (%IX to discrete inputs, %QX to coils, %IW to
input registers, %QW to holding registers 0-1023, %MW to holding registers from 1024,
%MD to pairs from 2048), else the next free address of its table (a bool input a discrete
input, a bool output or writable a coil, a number read only an input register, a number
output or writable a holding register). Checked against the plant, every error at its
``FILE:LINE:COL``."""

from __future__ import annotations

import ipaddress
import re
from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.feedconf import FEED_KEY, WRITABLE, feed_key, sample_key, writable_names
from runtime.language.iolist import IOList
from runtime.language.located import Located, parse_located
from runtime.language.model import (
    ModbusDef,
    ModbusLimits,
    ModbusPoint,
    ModbusTls,
    PlantDef,
    VarKind,
)
from runtime.language.plantpaths import PATH
from runtime.language.shape import (
    Choice,
    Int,
    Key,
    ListOf,
    MapOf,
    Section,
    Text,
    Time,
    expect_type,
    one_of,
    time_value,
)
from runtime.language.tlsconf import SERVER_TLS, pem_files
from runtime.language.webconf import is_loopback
from runtime.language.yamlsrc import YList, YMap

#: the snapshot period when the plant does not say (never below the cycle), ns
DEFAULT_SAMPLE_NS = 100_000_000
#: the wire types, and the language types each may carry
WIRE_TYPES: dict[str, tuple[A.Type, ...]] = {
    "BOOL": (A.Type.BOOL,), "INT": (A.Type.INT,), "UINT": (A.Type.INT,),
    "DINT": (A.Type.INT, A.Type.TIME), "UDINT": (A.Type.INT, A.Type.TIME),
    "REAL": (A.Type.REAL,), "TIME": (A.Type.TIME,)}
#: a language type's wire type by default
DEFAULT_WIRE = {A.Type.BOOL: "BOOL", A.Type.INT: "INT", A.Type.REAL: "REAL",
                A.Type.TIME: "TIME"}
#: the tables' names as a person reads them
TABLE_NAMES = {"Q": "coil", "I": "discrete input", "IR": "input register",
               "HR": "holding register"}
#: OpenPLC's map of located addresses: (area, size) -> (table, first address, numbers, step)
OPENPLC: dict[tuple[str, str], tuple[str, int, int, int]] = {
    ("I", "X"): ("I", 0, 200, 1), ("Q", "X"): ("Q", 0, 200, 1),
    ("I", "W"): ("IR", 0, 1024, 1), ("Q", "W"): ("HR", 0, 1024, 1),
    ("M", "W"): ("HR", 1024, 1024, 1), ("M", "D"): ("HR", 2048, 1024, 2)}
_ADDRESS = re.compile(r"^(I|Q|IR|HR)(\d{1,5})$")
_LISTEN = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")
#: the orders of a 32-bit value's two registers, the first the default
WORDS = ("high_first", "low_first")
#: what a role of ``tls: roles:`` may do
ROLES = ("read", "write")

# -- the shape of ``modbus:`` (runtime/language/shape.py)
_HOST_PORT = r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):[0-9]{1,5}"
TLS = Section((
    Key("listen", Text(f"^{_HOST_PORT}$"), "HOST:PORT (default 127.0.0.1:802)."),
    *SERVER_TLS,
    Key("clients_ca", PATH, "The certificate authority (PEM) of the clients' certificates.",
        required=True),
    Key("roles", MapOf(Choice(ROLES), min_properties=1),
        "ROLE: read or write, for the role in each client's certificate (OID "
        "1.3.6.1.4.1.50316.802.1).", required=True),
), "modbus tls", "Modbus/TCP Security: TLS with client certificates, each client's role read "
                 "from its certificate.")
#: the PEM files of ``tls:``, each needed
PEM_KEYS = tuple(k.name for k in TLS.keys if k.value is PATH)
LIMITS = Section((
    Key("connections", Int(1, 1000), "Connections at once (default 16)."),
    Key("rate", Int(1, 100_000), "Requests a second of one connection; more are paced "
                                 "(default 200)."),
    Key("idle", Time(1_000_000_000, 86_400_000_000_000),
        "A connection without a request this long is closed (default 60s, 1s to 24h)."),
), "modbus limits", "What clients may hold of the server.")
#: an entry of ``map:`` in its mapping form (``{at: HR10, type: DINT}``)
MAP_ENTRY = Section((
    Key("at", Text(), "The address: Q<n>, I<n>, IR<n>, HR<n>, or a located "
                      "%IX/%QX/%IW/%QW/%MW/%MD.", required=True),
    Key("type", Choice(tuple(WIRE_TYPES)), "The type on the wire (default: a bool BOOL, an int "
                                           "INT, a real REAL, a time TIME in ms)."),
), "modbus map")
MODBUS = Section((
    Key("listen", Text(f"^({_HOST_PORT}|off)$"),
        "HOST:PORT of plain Modbus/TCP (default 127.0.0.1:502), or off (only tls); an address "
        "other than a loopback one needs clients."),
    Key("clients", ListOf(Text(), min_items=1),
        "The client addresses or networks let in (192.168.10.20, 192.168.10.0/24); default: "
        "anyone who reaches listen."),
    Key("unit", Int(0, 255), "The unit identifier answered (default: any); another is "
                             "answered with exception 11."),
    Key("map", MapOf(one_of(Text(), MAP_ENTRY)),
        "instance.name: ADDRESS (Q<n> coil, I<n> discrete input, IR<n> input register, HR<n> "
        "holding register, or a located %IX/%QX/%IW/%QW/%MW/%MD address), or {at: ADDRESS, "
        "type: BOOL|INT|UINT|DINT|UDINT|REAL|TIME}; every other name of the I/O list and "
        "every writable name gets a default address."),
    Key("writable", WRITABLE, "instance.name of the memory variables and chart flags a client "
                              "may write (a coil or a holding register), applied between two "
                              "scans."),
    Key("words", Choice(WORDS), "The order of the two registers of a 32-bit value: high_first "
                                "(Modbus' big-endian order, default) or low_first."),
    Key("sample", Time(), "How often the values are refreshed (the feed's sample; default "
                          "100ms, never below the cycle)."),
    FEED_KEY,
    Key("tls", TLS),
    Key("limits", LIMITS),
), "modbus", "The Modbus/TCP server of the plant, `softplc modbus PLANT` (docs/modbus.md): "
             "where it listens, who may connect, Modbus/TCP Security, the address map and the "
             "names panels may write.", null=True)


def load_modbus(p: PlantDef, value: Any, loc: Loc) -> ModbusDef:
    """``modbus:`` -> ModbusDef with its whole map; SourceError at the faulty key or value.
    An empty ``modbus:`` (``modbus: {}``) serves the default map on 127.0.0.1:502."""
    m = expect_type(value, loc, YMap, "a mapping (listen, clients, map, writable, ...)")
    MODBUS.check(m)
    d = ModbusDef(loc=loc, sample_ns=max(DEFAULT_SAMPLE_NS, p.cycle_ns), locs=dict(m.val_locs))
    if "listen" in m:
        vloc = m.val_locs["listen"]
        text = str(expect_type(m["listen"], vloc, str, "HOST:PORT or off"))
        if text == "off":
            d.host, d.port = "", 0
        else:
            d.host, d.port = listen_value(text, vloc, "modbus listen")
    if "clients" in m:
        d.clients = _clients(m["clients"], m.val_locs["clients"])
    if "unit" in m:
        vloc = m.val_locs["unit"]
        low, high = MODBUS["unit"].low, MODBUS["unit"].high
        unit = MODBUS.value(m, "unit", f"a unit identifier {low}-{high}")
        if not low <= unit <= high:
            raise SourceError(vloc, f"modbus unit: expected {low}-{high}, found {unit}")
        d.unit = int(unit)
    if "writable" in m:
        d.writable = writable_names(p, m["writable"], m.val_locs["writable"], "modbus")
    if "words" in m:
        vloc = m.val_locs["words"]
        if m["words"] not in WORDS:
            raise SourceError(vloc, f"modbus words: expected high_first (Modbus' big-endian "
                                    f"order) or low_first, found '{m['words']}'")
        d.words = str(m["words"])
    if "sample" in m:
        d.sample_ns = sample_key(p, m, "modbus")
    if "feed" in m:  # the default: runtime/language/feedconf.py, once every section is read
        d.feed = feed_key(m, "modbus")
    if "tls" in m:
        d.tls = _tls(p.path, m["tls"], m.val_locs["tls"])
    if "limits" in m:
        d.limits = _limits(m["limits"], m.val_locs["limits"])
    if not d.host and d.tls is None:
        raise SourceError(m.val_locs["listen"], "modbus listen: off, and no tls: the server "
                                                "would serve nobody")
    if d.host and not is_loopback(d.host) and not d.clients:
        raise SourceError(m.val_locs["listen"], f"modbus listen: {d.host} is reachable from "
                          "other machines and plain Modbus/TCP has no security: name the "
                          "panels that may connect in modbus: clients: [ADDRESS or NETWORK, "
                          "...], or listen on 127.0.0.1")
    explicit = _map(p, m["map"], m.val_locs["map"]) if "map" in m else []
    d.points = build_map(p, explicit, d.writable, loc)
    return d


def listen_value(text: str, loc: Loc, what: str) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); port 0 takes a free port (tests)."""
    match = _LISTEN.match(text)
    if match is None or not 0 <= int(match.group(2)) < 65536:
        raise SourceError(loc, f"{what}: expected HOST:PORT (e.g. 127.0.0.1:502, "
                               f"0.0.0.0:502), found '{text}'")
    return match.group(1).strip("[]"), int(match.group(2))


def _clients(value: Any, loc: Loc) -> list[str]:
    items = expect_type(value, loc, list, "a list of client addresses or networks")
    locs = getattr(items, "locs", None) if isinstance(items, YList) else None
    out: list[str] = []
    for k, item in enumerate(items):
        iloc = locs[k] if locs is not None and k < len(locs) else loc
        text = str(expect_type(item, iloc, str, "an address or a network (192.168.10.0/24)"))
        try:
            net = ipaddress.ip_network(text, strict=False)
        except ValueError:
            raise SourceError(iloc, f"modbus clients: '{text}' is no address or network "
                                    "(e.g. 192.168.10.20, 192.168.10.0/24)") from None
        if str(net) not in out:
            out.append(str(net))
    if not out:
        raise SourceError(loc, "modbus clients: an empty list lets nobody in: name the "
                               "panels' addresses, or leave the key out")
    return out


def _tls(base: str, value: Any, loc: Loc) -> ModbusTls:
    """``modbus: tls:`` of the plant file ``base``."""
    m = expect_type(value, loc, YMap, "a mapping (listen, certificate, private_key, "
                                      "clients_ca, roles)")
    TLS.check(m)
    t = ModbusTls(loc=loc)
    if "listen" in m:
        vloc = m.val_locs["listen"]
        t.host, t.port = listen_value(str(expect_type(m["listen"], vloc, str, "HOST:PORT")),
                                      vloc, "modbus tls listen")
    for key, path in pem_files(base, m, PEM_KEYS, "modbus tls", loc, t.locs,
                               ": Modbus/TCP Security authenticates both ends").items():
        setattr(t, key, path)
    if "roles" not in m:
        raise SourceError(loc, "modbus tls: expected roles: {ROLE: read or write, ...}: what "
                               "each role of the clients' certificates may do")
    vloc = m.val_locs["roles"]
    roles = expect_type(m["roles"], vloc, YMap, "a mapping ROLE: read or write")
    for role, may in roles.items():
        rloc = roles.val_locs[role]
        if may not in ROLES:
            raise SourceError(rloc, f"modbus tls roles: {role}: expected read or write, "
                                    f"found '{may}'")
        t.roles[str(role)] = str(may)
    if not t.roles:
        raise SourceError(vloc, "modbus tls roles: no role: no client could do anything")
    return t


def _limits(value: Any, loc: Loc) -> ModbusLimits:
    m = expect_type(value, loc, YMap, "a mapping (connections, rate, idle)")
    LIMITS.check(m)
    lim = ModbusLimits(loc=loc)
    for key in ("connections", "rate"):
        if key in m:
            vloc = m.val_locs[key]
            least, most = LIMITS[key].low, LIMITS[key].high
            n = LIMITS.value(m, key, f"a number {least}-{most}")
            if not least <= n <= most:
                raise SourceError(vloc, f"modbus limits {key}: expected {least} to {most}, "
                                        f"found {n}")
            setattr(lim, key, int(n))
    if "idle" in m:
        vloc = m.val_locs["idle"]
        lim.idle_ns = time_value(m["idle"], vloc, "modbus limits idle")
        if not LIMITS["idle"].low <= lim.idle_ns <= LIMITS["idle"].high:
            raise SourceError(vloc, "modbus limits idle: expected 1s to 24h")
    return lim


# -- the map -----------------------------------------------------------------------------------
def name_type(p: PlantDef, name: str) -> A.Type | str:
    """The language type of plant name ``name`` a Modbus map may hold, or why it may not:
    an instance's variable or chart flag, a step's ``.X`` or ``.T``, a driver's ``.ok``."""
    head, _, rest = name.partition(".")
    if head in p.drivers:
        if rest == "ok":
            return A.Type.BOOL
        return (f"'{name}' is a driver point: map the chart signal bound to it (the I/O "
                "list's name), or the driver's health DRIVER.ok")
    idef = p.instances.get(head)
    if idef is None or not rest:
        return (f"unknown instance in '{name}': expected instance.name"
                f"{suggest(head, [*p.instances, *p.drivers])}")
    g = idef.grafcet
    var = g.variables.get(rest)
    if var is not None:
        if var.type is A.Type.STRING:
            return f"'{name}' is a string: Modbus registers carry numbers and bits"
        if var.kind is VarKind.TEMP:
            return f"'{name}' is a temporary, assigned by the chart every scan and kept nowhere"
        return var.type
    step, _, xt = rest.rpartition(".")
    if step in g.steps and xt in ("X", "T"):
        return A.Type.BOOL if xt == "X" else A.Type.TIME
    return f"'{name}': {head} has no variable or step '{rest}'{suggest(rest, g.variables)}"


def _address(text: str, loc: Loc, name: str) -> tuple[str, int, str]:
    """``HR10``, ``Q3`` or ``'%MW2'`` -> (table, address, the size of a located address:
    "W" one register, "D" two, "" for a table's address)."""
    match = _ADDRESS.match(text.strip().upper())
    if match is not None:
        address = int(match.group(2))
        if address > 0xFFFF:
            raise SourceError(loc, f"modbus map: {name}: {text}: an address is 0-65535")
        return match.group(1), address, ""
    found = parse_located(text) if text.strip().startswith("%") else None
    if found is None:
        raise SourceError(loc, f"modbus map: {name}: '{text}': expected Q<n> (coil), I<n> "
                               "(discrete input), IR<n> (input register), HR<n> (holding "
                               "register), or a located address such as %MW0")
    if isinstance(found, str):
        raise SourceError(loc, f"modbus map: {name}: {found}")
    table, address = openplc_address(found, loc, f"modbus map: {name}")
    return table, address, found.size if found.size != "X" else ""


def openplc_address(at: Located, loc: Loc, what: str) -> tuple[str, int]:
    """A located address's table and address in OpenPLC's map."""
    where = OPENPLC.get((at.area, at.size))
    if where is None:
        raise SourceError(loc, f"{what}: {at} has no place in the Modbus map (%IX, %QX, %IW, "
                               "%QW, %MW, %MD have)")
    table, first, numbers, step = where
    if not at.number < numbers:
        raise SourceError(loc, f"{what}: {at}: the map's %{at.area}{at.size} go up to "
                               f"%{at.area}{at.size}{numbers - 1}")
    if at.size == "X":
        return table, 8 * at.number + at.bit
    return table, first + step * at.number


def _map(p: PlantDef, value: Any, loc: Loc) -> list[ModbusPoint]:
    m = expect_type(value, loc, YMap, "a mapping instance.name: ADDRESS")
    out: list[ModbusPoint] = []
    for name, spec in m.items():
        kloc, vloc = m.key_locs[name], m.val_locs[name]
        t = name_type(p, str(name))
        if isinstance(t, str):
            raise SourceError(kloc, f"modbus map: {t}")
        wire = None
        if isinstance(spec, YMap):
            MAP_ENTRY.check(spec, f"modbus map: {name}")
            if "at" not in spec:
                raise SourceError(vloc, f"modbus map: {name}: expected at: ADDRESS")
            if "type" in spec:
                wire = str(expect_type(spec["type"], spec.val_locs["type"], str,
                                       "a type (" + ", ".join(WIRE_TYPES) + ")")).upper()
                if wire not in WIRE_TYPES:
                    raise SourceError(spec.val_locs["type"], f"modbus map: {name}: type "
                                      f"'{spec['type']}': expected one of "
                                      f"{', '.join(WIRE_TYPES)}{suggest(wire, WIRE_TYPES)}")
                if t not in WIRE_TYPES[wire]:
                    raise SourceError(spec.val_locs["type"], f"modbus map: {name} is a "
                                      f"{t.value}: it cannot be sent as {wire}")
            vloc = spec.val_locs["at"]
            spec = spec["at"]
        text = str(expect_type(spec, vloc, str, "an address such as HR10 or '%MW0'"))
        table, address, size = _address(text, vloc, str(name))
        if wire is None:
            wire = "DINT" if size == "D" and t is A.Type.INT else DEFAULT_WIRE[t]
        pt = ModbusPoint(str(name), table, address, wire, origin="map", loc=vloc)
        _check_size(pt, size, f"modbus map: {name}")
        out.append(pt)
    return out


def _check_size(pt: ModbusPoint, size: str, what: str) -> None:
    """A located word (%..W) holds one register, a double word (%..D) two."""
    if size == "W" and pt.words == 2:
        raise SourceError(pt.loc or Loc("", 1, 1), f"{what}: a {pt.type} takes two registers: "
                          "a %..W holds one (locate it at %MD, or at HR<n>)")
    if size == "D" and pt.words == 1:
        raise SourceError(pt.loc or Loc("", 1, 1), f"{what}: a {pt.type} takes one register: "
                          "a %..D holds two (give it type DINT, or locate it at %MW)")


def build_map(p: PlantDef, explicit: list[ModbusPoint], writable: list[str],
              loc: Loc | None = None) -> list[ModbusPoint]:
    """The whole map: ``explicit`` (the plant's ``map:``), then the I/O list's names and the
    writable names, each at its binding's located address or the next free address of its
    table; every name checked against its table and every address against the others
    (SourceError at the name's place, or at ``loc``, the section's)."""
    here = loc or Loc(p.path, 1, 1)
    taken: dict[str, dict[int, ModbusPoint]] = {t: {} for t in TABLE_NAMES}
    done: dict[str, ModbusPoint] = {}
    out: list[ModbusPoint] = []

    def place(pt: ModbusPoint) -> None:
        if pt.loc is None:
            pt = ModbusPoint(pt.name, pt.table, pt.address, pt.type, pt.writable, pt.origin,
                             here)
        _check_table(pt, pt.name in writable)
        pt = ModbusPoint(pt.name, pt.table, pt.address, pt.type, pt.name in writable,
                         pt.origin, pt.loc)
        for a in range(pt.address, pt.address + max(1, pt.words)):
            other = taken[pt.table].get(a)
            if other is not None:
                raise SourceError(pt.loc or here, f"modbus map: {pt.name} at "
                                  f"{_shown(pt.table, pt.address)} overlaps {other.name} at "
                                  f"{_shown(other.table, other.address)} ({other.origin})")
            if a > 0xFFFF:
                raise SourceError(pt.loc or here, f"modbus map: {pt.name} at "
                                  f"{_shown(pt.table, pt.address)} passes address 65535")
        for a in range(pt.address, pt.address + max(1, pt.words)):
            taken[pt.table][a] = pt
        done[pt.name] = pt
        out.append(pt)

    for pt in explicit:
        if pt.name in done:
            raise SourceError(pt.loc or here, f"modbus map: {pt.name} is given twice")
        place(pt)
    iolist = IOList(p)
    later: list[tuple[str, A.Type, str]] = []  # name, type, direction
    for row in iolist.rows:
        if row.signal in done or row.type is A.Type.STRING:
            continue
        head, _, sig = row.signal.partition(".")
        b = p.instances[head].inputs.get(sig) or p.instances[head].outputs.get(sig)
        if b is not None and b.at:
            found = parse_located(b.at)
            assert not isinstance(found, str)
            loc = b.at_loc or b.loc
            table, address = openplc_address(found, loc, f"{row.signal} at")
            wire = DEFAULT_WIRE[row.type]
            if found.size == "D" and row.type is A.Type.INT:
                wire = "DINT"
            pt = ModbusPoint(row.signal, table, address, wire, origin="at", loc=loc)
            _check_size(pt, found.size if found.size != "X" else "", f"{row.signal} at")
            place(pt)
        else:
            later.append((row.signal, row.type, row.direction))
    for name in writable:
        if name not in done and name not in [n for n, _t, _d in later]:
            t = name_type(p, name)
            assert not isinstance(t, str)  # a writable name is a variable or a flag
            later.append((name, t, "write"))
    for name, t, direction in later:
        wire = DEFAULT_WIRE[t]
        if t is A.Type.BOOL:
            table = "I" if direction == "in" and name not in writable else "Q"
        else:
            table = "IR" if direction == "in" and name not in writable else "HR"
        words = 0 if wire == "BOOL" else 2 if wire in ("REAL", "TIME") else 1
        place(ModbusPoint(name, table, _free(taken[table], words), wire,
                          origin="iolist" if direction != "write" else "writable"))
    return out


def _free(taken: dict[int, ModbusPoint], words: int) -> int:
    """The first address from which ``max(1, words)`` addresses are free."""
    a = 0
    need = max(1, words)
    while any(a + k in taken for k in range(need)):
        a += 1
    return a


def _check_table(pt: ModbusPoint, writable: bool) -> None:
    """A bit in a bit table, a number in a register table, a writable name in a table a
    client writes (coils, holding registers)."""
    loc = pt.loc
    bit_table = pt.table in ("Q", "I")
    if (pt.type == "BOOL") != bit_table:
        want = "a coil (Q) or a discrete input (I)" if pt.type == "BOOL" else \
            "an input register (IR) or a holding register (HR)"
        raise SourceError(loc or Loc("", 1, 1), f"modbus map: {pt.name} is a "
                          f"{'bool' if pt.type == 'BOOL' else 'number'}: it goes to {want}, "
                          f"not to {_shown(pt.table, pt.address)}")
    if writable and pt.table in ("I", "IR"):
        raise SourceError(loc or Loc("", 1, 1), f"modbus map: {pt.name} is writable but "
                          f"{_shown(pt.table, pt.address)} is read-only over Modbus: put it at "
                          f"a {'coil (Q)' if bit_table else 'holding register (HR)'}")


def _shown(table: str, address: int) -> str:
    return f"{table}{address}"


def reference(table: str, address: int) -> str:
    """The 1-based 6-digit reference many panels' tag editors take: 000001 the first coil,
    100001 the first discrete input, 300001 the first input register, 400001 the first
    holding register."""
    digit = {"Q": 0, "I": 1, "IR": 3, "HR": 4}[table]
    return f"{digit}{address + 1:05d}"
