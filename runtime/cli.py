"""The ``softplc`` command line: compile, simulate, run, check, draw, monitor ..."""

from __future__ import annotations

import argparse
import errno
import gc
import importlib
import logging
import os
import stat
import sys
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from typing import IO, Any, NoReturn

from runtime import package_version
from runtime.errors import Loc, SoftplcError, SourceError

log = logging.getLogger("softplc")


def cmd_compile(args: argparse.Namespace) -> int:
    from runtime.compiler.codegen import compile_grafcet
    from runtime.language.filekind import read_document
    from runtime.language.grafcetfile import load_grafcet
    from runtime.language.model import Grafcet
    from runtime.language.plantfile import load_plant

    for path in args.files:
        t0 = time.perf_counter()
        kind, doc = read_document(path)
        if kind not in ("grafcet", "plant"):
            raise SourceError(Loc(path, 1, 1), "expected a grafcet file ('grafcet:' and "
                                               "'steps:') or a plant file ('instances:')")
        if kind == "plant":
            pdef = load_plant(path, doc=doc)
            charts: list[Grafcet] = []  # each chart once: instances of one plant share it
            for idef in pdef.instances.values():
                if not any(g is idef.grafcet for g in charts):
                    charts.append(idef.grafcet)
            programs = [compile_grafcet(g) for g in charts]
        else:
            programs = [compile_grafcet(load_grafcet(path, doc=doc))]
        ms = (time.perf_counter() - t0) * 1000
        if args.show:
            for p in programs:
                sys.stdout.write(p.source)
        names = ", ".join(p.grafcet.name for p in programs)
        sys.stderr.write(f"{path}: ok: {names} compiled in {ms:.1f} ms\n")
    return 0


def cmd_iolist(args: argparse.Namespace) -> int:
    """The plant's I/O list: one line per bound signal, as a table or CSV (docs/language.md,
    "The I/O list")."""
    from runtime.language.iolist import IOList
    from runtime.language.plantfile import load_plant

    iolist = IOList(load_plant(args.plant))
    if args.csv:
        sys.stdout.write(iolist.csv())
    else:
        sys.stdout.write("".join(f"{line}\n" for line in iolist.table()))
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """The plant on a virtual clock; the trace and VCD are written as far as the run went
    (a scan fault: every scan before it and a last record naming it, then exit 2)."""
    from runtime.engine.simulate import Simulation, write_trace, write_vcd

    logging.getLogger("drivers").setLevel(logging.WARNING)  # "driver sim: open" is noise here
    sim = Simulation(args.plant, args.script, args.cycles)
    kept: list[dict[str, Any]] = []  # the rows for the VCD, written at the end

    def rows() -> Iterator[dict[str, Any]]:
        for row in sim.run(trace=True):
            if args.vcd:
                kept.append(row)
            yield row

    t0 = time.perf_counter()
    try:
        if args.trace:
            with _output(args.trace, "--trace") as f:
                write_trace(rows(), f)
        elif args.vcd:
            for _ in rows():
                pass
        else:
            for _ in sim.run(trace=False):
                pass
    finally:
        if args.vcd and kept:
            with _output(args.vcd, "--vcd") as f:
                write_vcd(kept, f)
    dt = time.perf_counter() - t0
    steps = "; ".join(f"{n}: {','.join(i.active_steps())}" for n, i in
                      sim.plant.instances.items())
    sys.stderr.write(f"simulated {sim.cycles} scans ({sim.cycles * sim.plant.cycle_ns / 1e9:g} s "
                     f"of plant time) in {dt:.3f} s; final steps: {steps}\n")
    return 0


def _output(path: str, option: str) -> IO[str]:
    """``path`` opened for writing (``--trace``, ``--vcd``); SourceError naming ``option``
    if it cannot be (a directory, no permission), never a traceback."""
    try:
        return open(path, "w", encoding="utf-8")  # noqa: SIM115 - the caller closes it
    except OSError as exc:
        raise SourceError(Loc(option, 1, 1), f"cannot write {path}: "
                                             f"{exc.strerror or exc}") from None


def cmd_run(args: argparse.Namespace) -> int:
    """The controller: the plant in real time on its drivers (or simulated I/O)."""
    from runtime.controller.daemon import Daemon
    from runtime.controller.paths import LEDGER, PathError, plant_files, prepare
    from runtime.controller.plantlock import PlantLock, PlantLocked
    from runtime.controller.service import serve
    from runtime.language.plantfile import load_plant
    from runtime.language.runtimedir import locate
    from runtime.language.shape import time_value

    for_ns = None
    if args.for_ is not None:
        for_ns = time_value(args.for_, Loc("--for", 1, 1), "--for")
    if args.script is not None and not args.sim:
        sys.stderr.write("softplc run: error: --script plays simulated inputs: add --sim\n")
        return 2
    pdef = load_plant(args.plant)
    where = locate(pdef)
    lock = PlantLock(where)
    feed_def = pdef.feed()  # the side processes' feed (opcua:, mqtt:)
    try:
        lock.check()  # a running controller of this plant is named before anything else
        prepare(plant_files(pdef), where.runtime_dir)  # its own directories, checked
        lock.acquire()  # one controller per plant, until this process ends
    except (PathError, PlantLocked) as exc:
        sys.stderr.write(f"softplc run: error: {exc}\n")
        return 2
    LEDGER.lock = lock  # the sockets it binds are recorded as this plant's
    trace = _output(args.trace, "--trace") if args.trace else None
    try:
        try:
            if not args.sim:
                _check_libraries(pdef)
            daemon = Daemon(pdef, sim=args.sim, trace=trace)
            if args.script is not None:
                from runtime.controller.replay import ScriptPlayer

                daemon.add_listener(ScriptPlayer(daemon.plant, args.script))
            server = _console_server(daemon) if pdef.consoles else None
            feed = _feed_server(daemon, feed_def) if feed_def is not None else None

            def started() -> None:
                _check_opened(daemon)
                if server is not None:
                    server.start()
                if feed is not None:
                    feed.start()

            def stopping() -> None:
                if feed is not None:
                    feed.stop()
                if server is not None:
                    server.stop()
            return serve(daemon, for_ns, started, stopping)
        except PathError as exc:  # a socket path that is not this plant's to take
            sys.stderr.write(f"softplc run: error: {exc}\n")
            return 2
        except (SourceError, KeyboardInterrupt):
            raise
        except Exception as exc:  # noqa: BLE001 - at start: one line, never a traceback
            raise _start_error(pdef, exc) from exc
    finally:
        if trace is not None:
            trace.close()


def _check_libraries(pdef: Any) -> None:
    """Every driver's bus library imports; else an error at that driver's plant line."""
    from drivers.registry import DriverImportError, driver_class

    for name, ddef in pdef.drivers.items():
        try:
            driver_class(ddef.type)
        except DriverImportError as exc:
            raise SourceError(ddef.loc, f"driver {name} ({ddef.type}): {exc}") from None


def _check_opened(daemon: Any) -> None:
    """At start, after the drivers were opened (every output written off): a driver that
    could not open (no such port, permission denied, no such CAN interface) is an error at
    its plant line; ``serve`` then stops the controller in order."""
    from drivers.base import Health

    for name, d in daemon.plant.drivers.items():
        if d.health is Health.FAULT:
            ddef = daemon.pdef.drivers[name]
            raise SourceError(ddef.loc, f"driver {name} ({ddef.type}): cannot start: "
                                        f"{d.fault_reason}")


def _start_error(pdef: Any, exc: BaseException) -> SourceError:
    """An unexpected exception while ``run`` starts, as one line at the plant line of the
    driver it came from (found in its traceback), else at the plant file; the traceback
    is logged at debug level (``-v``)."""
    from drivers.base import Driver

    log.debug("while starting", exc_info=exc)
    name = None
    tb = exc.__traceback__
    while tb is not None:
        owner = tb.tb_frame.f_locals.get("self")
        if isinstance(owner, Driver) and owner.name in pdef.drivers:
            name = owner.name  # the innermost driver frame wins
        tb = tb.tb_next
    cause = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    if name is None:
        return SourceError(Loc(pdef.path, 1, 1), f"cannot start: {cause}")
    ddef = pdef.drivers[name]
    return SourceError(ddef.loc, f"driver {name} ({ddef.type}): cannot start: {cause}")


def _console_server(daemon: Any) -> Any:
    from runtime.console.server import ConsoleServer
    from runtime.console.service import ConsoleService

    pdef = daemon.pdef
    service = ConsoleService(daemon, pdef.pin_hash, pdef.release_forces_on_disconnect)
    return ConsoleServer(service, pdef.consoles)


def _feed_server(daemon: Any, feed_def: Any) -> Any:
    """The side processes' feed (runtime/controller/feed.py), served by the controller."""
    from runtime.controller.feed import FeedServer

    return FeedServer(daemon, feed_def)


def _side_plant(path: str, section: str, doing: str) -> Any:
    """The plant of a side process (``softplc opcua``, ``softplc mqtt``): loaded, with its
    section, else an error at the plant file."""
    from runtime.language.plantfile import load_plant

    pdef = load_plant(path)
    if getattr(pdef, section) is None:
        raise SourceError(Loc(pdef.path, 1, 1), f"no '{section}:' section: add one to {doing} "
                                                f"(docs/{section}.md)")
    if pdef.realtime_cpu is not None:  # the controller's processor (docs/daemon.md)
        from runtime.controller.realtime import keep_off

        done, why = keep_off(pdef.realtime_cpu)
        if not done:
            log.warning("%s: not kept off the controller's processor %d: %s", section,
                        pdef.realtime_cpu, why)
    return pdef


def _missing_extra(exc: ImportError, extra: str) -> ImportError:
    from drivers.registry import install_hint

    return ImportError(f"{exc}: install the {extra} extra: {install_hint(extra)}")


def _until_signal(serve: Callable[[Any], Awaitable[None]]) -> None:
    """``serve(stop)`` until SIGTERM, SIGINT or SIGHUP sets ``stop``, then ended within
    a bound (runtime/controller/aio.py)."""
    from runtime.controller.aio import run_until_signal

    run_until_signal(serve)


def cmd_opcua(args: argparse.Namespace) -> int:
    """The OPC UA server of a plant, fed by its running controller (docs/opcua.md)."""
    from runtime.language.runtimedir import locate

    pdef = _side_plant(args.plant, "opcua", "serve this plant over OPC UA")
    feed = args.feed or locate(pdef).feed  # where the controller serves it (one home)
    assert feed is not None
    endpoint = args.endpoint or pdef.opcua.endpoint
    problem = _opcua_cannot_serve(pdef, endpoint, feed, bool(args.endpoint), bool(args.feed))
    if problem is not None:  # at once, before asyncua takes seconds to set up
        sys.stderr.write(f"{problem}\n")
        return 2
    try:
        from runtime.opcua.server import serve
    except ImportError as exc:
        raise _missing_extra(exc, "opcua") from None
    if not logging.getLogger().isEnabledFor(logging.DEBUG):
        # asyncua logs every request at INFO: the journal gets its warnings and errors
        logging.getLogger("asyncua").setLevel(logging.WARNING)
    try:
        _until_signal(lambda stop: serve(pdef, endpoint, feed, stop=stop))
    except OSError as exc:  # the port taken between the check and asyncua's bind
        if exc.errno != errno.EADDRINUSE:
            raise
        sys.stderr.write(f"{_opcua_cannot_serve(pdef, endpoint, feed, False, False) or exc}\n")
        return 2
    return 0


def cmd_mqtt(args: argparse.Namespace) -> int:
    """The plant's MQTT Sparkplug B edge node, fed by its running controller
    (docs/mqtt.md)."""
    import ssl

    from runtime.language.runtimedir import locate

    pdef = _side_plant(args.plant, "mqtt", "publish this plant over MQTT")
    feed = args.feed or locate(pdef).feed  # where the controller serves it (one home)
    assert feed is not None
    problem = _feed_cannot_serve(pdef, "mqtt", feed, bool(args.feed))
    if problem is not None:
        sys.stderr.write(f"{problem}\n")
        return 2
    try:
        from runtime.mqtt.session import serve
    except ImportError as exc:
        raise _missing_extra(exc, "mqtt") from None
    try:
        _until_signal(lambda stop: serve(pdef, feed, stop=stop))
    except (OSError, ssl.SSLError) as exc:  # a certificate, key or password file
        where = getattr(exc, "filename", None)
        sys.stderr.write(f"softplc mqtt: error: {where + ': ' if where else ''}"
                         f"{getattr(exc, 'strerror', None) or exc}\n")
        return 2
    return 0


def cmd_web(args: argparse.Namespace) -> int:
    """The plant's live view in the browser, fed by its running controller (docs/web.md)."""
    from runtime.language.runtimedir import locate

    pdef = _side_plant(args.plant, "web", "serve this plant's page")
    feed = args.feed or locate(pdef).feed  # where the controller serves it (one home)
    assert feed is not None
    problem = _feed_cannot_serve(pdef, "web", feed, bool(args.feed))
    if problem is not None:
        sys.stderr.write(f"{problem}\n")
        return 2
    try:
        from runtime.web.server import serve
    except ImportError as exc:
        raise _missing_extra(exc, "web") from None
    w = pdef.web
    if args.listen:  # the same checks as the plant's key
        from runtime.language.webconf import listen_value

        w.host, w.port = listen_value(args.listen, w.certificate is not None,
                                      Loc("--listen", 1, 1))
    coverage = None
    if args.coverage:  # read before serving: a bad file is one line, exit 2
        from runtime.language.coverage import load

        coverage = load(args.coverage)
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)
    try:
        _until_signal(lambda stop: serve(pdef, feed, stop=stop, coverage=coverage))
    except OSError as exc:  # the port is taken, a certificate cannot be read
        where = getattr(exc, "filename", None)
        sys.stderr.write(f"softplc web: error: {where + ': ' if where else ''}"
                         f"{w.host}:{w.port}: {getattr(exc, 'strerror', None) or exc}\n")
        return 2
    return 0


def cmd_modbus(args: argparse.Namespace) -> int:
    """The plant's Modbus/TCP server, fed by its running controller; with ``--map``, its
    address map (docs/modbus.md)."""
    from runtime.language.runtimedir import locate

    if args.map:
        return _modbus_map(args.plant, args.csv)
    pdef = _side_plant(args.plant, "modbus", "serve this plant over Modbus/TCP")
    feed = args.feed or locate(pdef).feed  # where the controller serves it (one home)
    assert feed is not None
    problem = _feed_cannot_serve(pdef, "modbus", feed, bool(args.feed))
    if problem is not None:
        sys.stderr.write(f"{problem}\n")
        return 2
    from runtime.modbus.server import serve

    conf = pdef.modbus
    listen = None
    if args.listen:
        from runtime.language.modbusconf import listen_value

        listen = listen_value(args.listen, Loc("--listen", 1, 1), "--listen")
    host, port = listen or (conf.host, conf.port)
    try:
        _until_signal(lambda stop: serve(pdef, feed, listen, stop=stop))
    except OSError as exc:  # the port is taken or privileged, a certificate unreadable
        where = getattr(exc, "filename", None)
        hint = (": ports below 1024 need root or CAP_NET_BIND_SERVICE (the unit has it); "
                "give modbus: listen a port above 1023 to run it by hand"
                if exc.errno == errno.EACCES and where is None else "")
        sys.stderr.write(f"softplc modbus: error: {where + ': ' if where else ''}"
                         f"{host}:{port}: {getattr(exc, 'strerror', None) or exc}{hint}\n")
        return 2
    return 0


def _modbus_map(path: str, as_csv: bool) -> int:
    """``softplc modbus --map``: the plant's map (its modbus: section's, or the default
    one of a plant without it)."""
    from runtime.language.modbusconf import build_map
    from runtime.language.model import ModbusDef
    from runtime.language.plantfile import load_plant
    from runtime.modbus.mapview import csv_text, table

    pdef = load_plant(path)
    conf = pdef.modbus or ModbusDef(points=build_map(pdef, [], []))
    if as_csv:
        sys.stdout.write(csv_text(pdef, conf))
    else:
        sys.stdout.write("".join(f"{line}\n" for line in table(pdef, conf)))
    return 0


def _feed_cannot_serve(pdef: Any, side: str, feed: str, feed_given: bool) -> str | None:
    """Why the side process ``side`` (opcua, mqtt, web) cannot follow its controller's
    feed at ``feed``, as its one line (at the plant's ``feed:``, or naming the option): the
    path is something other than a socket, where the controller refuses to serve. A
    missing one is fine: the controller is not running yet. None when it can."""
    from runtime.controller.paths import file_kind

    try:
        st = os.lstat(feed)
    except OSError:
        return None
    if stat.S_ISSOCK(st.st_mode):
        return None
    text = (f"{feed} is not a socket ({file_kind(st.st_mode)}): the controller serves its "
            f"feed there; give {side}: feed another path")
    if feed_given:
        return f"softplc {side}: error: --feed: {text}"
    section = getattr(pdef, side)
    return str(SourceError(section.feed_loc or section.loc or Loc(pdef.path, 1, 1),
                           f"{side} feed: {text}"))


def _opcua_cannot_serve(pdef: Any, endpoint: str, feed: str, endpoint_given: bool,
                        feed_given: bool) -> str | None:
    """Why ``softplc opcua`` cannot serve, as its one line (at the plant's line of the
    key, or naming the option): the feed path is something other than a socket (a missing
    one is fine: the controller is not running yet), or the endpoint's port cannot be
    listened on (another process has it). None when it can."""
    import socket
    from urllib.parse import urlsplit

    opc = pdef.opcua
    where = opc.loc or Loc(pdef.path, 1, 1)

    def at(key: str, given: bool, text: str) -> str:
        if given:
            return f"softplc opcua: error: --{key}: {text}"
        return str(SourceError(opc.locs.get(key, where), f"opcua {key}: {text}"))
    problem = _feed_cannot_serve(pdef, "opcua", feed, feed_given)
    if problem is not None:
        return problem
    url = urlsplit(endpoint)
    host, port = url.hostname or "0.0.0.0", url.port or 4840
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        return at("endpoint", endpoint_given, f"{host}: {exc.strerror or exc}: not started")
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncua does
            try:
                probe.bind(addr)
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    return at("endpoint", endpoint_given,
                              f"port {port} of {host} is in use (another OPC UA server, or "
                              "another plant's: give each plant its own port): not started")
                return at("endpoint", endpoint_given,
                          f"cannot listen on {host}:{port}: {exc.strerror}: not started")
    return None


def cmd_hash_pin(args: argparse.Namespace) -> int:
    """Print the hash of a console PIN for the plant file's ``monitor: pin_hash:``."""
    import getpass

    from runtime.controller.pin import hash_pin

    pin = args.pin
    if pin is None:
        pin = getpass.getpass("PIN: ")
        if getpass.getpass("again: ") != pin:
            sys.stderr.write("softplc hash-pin: error: the two PINs differ\n")
            return 2
    if len(pin) < 4:
        sys.stderr.write("softplc hash-pin: error: a PIN needs at least 4 characters\n")
        return 2
    sys.stdout.write(hash_pin(pin) + "\n")
    return 0


def cmd_reload(args: argparse.Namespace) -> int:
    """Online change through the console of a running controller (docs/online-change.md):
    exit 0 applied, 1 refused (each reason on stderr), 2 cannot connect."""
    from runtime.console.client import ConsoleClient
    from runtime.console.links import MonitorError, Target, console_of

    def fail(text: str, status: int) -> int:
        sys.stderr.write(f"softplc reload: {text}\n")
        return status
    try:
        address = console_of(args.target)
    except SourceError as exc:
        if exc.loc.file == "SOCKET|PORT":  # the target's text
            return fail(f"error: {exc.message}", 2)
        return fail(f"refused: {exc}", 1)  # the edited plant does not load: the refusal
    try:
        client = ConsoleClient(Target.parse(address, args.baudrate).open())
    except MonitorError as exc:
        return fail(f"error: {exc}", 2)
    line = "reload" + (" --force" if args.force else "") + (" --back" if args.back else "")
    line += "".join(f" --restart {name}" for name in args.restart)
    try:
        try:
            client.start()
        except MonitorError as exc:
            return fail(f"error: {exc}", 2)
        if args.pin_file:
            try:
                with open(args.pin_file, encoding="utf-8") as f:
                    pin = f.readline().strip()
            except OSError as exc:
                return fail(f"error: --pin-file: {exc.strerror or exc}", 2)
            reply = client.request(f"unlock {pin}")
            if not reply.get("ok"):
                return fail(f"unlock refused: {reply.get('error')}", 1)
        reply = client.request(line, timeout=args.timeout)
    except MonitorError as exc:
        return fail(f"error: {exc}", 2)
    finally:
        client.close()
    if reply.get("ok"):
        sys.stdout.write("".join(f"{x}\n" for x in reply.get("text", [])))
        return 0
    for x in reply.get("lines", []):
        sys.stderr.write(f"  {x}\n")
    refusals = reply.get("refusals") or [reply.get("error", "refused")]
    for x in refusals:
        sys.stderr.write(f"softplc reload: refused: {x}\n")
    return 1


def cmd_diff(args: argparse.Namespace) -> int:
    """What loading NEW into a controller running OLD would do; 1 if it cannot be applied
    online (static refusals), 0 if it can (state checks listed)."""
    from runtime.change.diff import chart_plant, diff_plants
    from runtime.language.filekind import read_document
    from runtime.language.grafcetfile import load_grafcet
    from runtime.language.plantfile import load_plant
    from runtime.language.runtimedir import version_of

    (old_kind, old_doc), (new_kind, new_doc) = read_document(args.old), read_document(args.new)
    kinds = [old_kind, new_kind]
    for path, kind in zip((args.old, args.new), kinds, strict=True):
        if kind not in ("grafcet", "plant"):
            raise SourceError(Loc(path, 1, 1), "expected a grafcet file ('grafcet:' and "
                                               "'steps:') or a plant file ('instances:')")
    if kinds[0] != kinds[1]:
        raise SourceError(Loc(args.new, 1, 1), f"expected a {kinds[0]} file like {args.old}, "
                                               f"found a {kinds[1]} file")
    if kinds[0] == "plant":
        old = load_plant(args.old, doc=old_doc)
        with version_of(args.old):  # ${RUNTIME_DIR} is the running plant's, as in reload
            new = load_plant(args.new, doc=new_doc)
    else:
        g = load_grafcet(args.old, doc=old_doc)
        old, new = chart_plant(g), chart_plant(load_grafcet(args.new, doc=new_doc), g.name)
    cs = diff_plants(old, new)
    out = sys.stdout.write
    for line in cs.lines() or ["no change"]:
        out(line + "\n")
    refusals = cs.static_refusals()
    if refusals:
        out("cannot be applied online:\n")
        for line in refusals:
            out(f"  {line}\n")
        return 1
    out("can be applied online\n")
    for line in cs.state_checks():
        out(f"  {line}\n")
    return 0


def cmd_opcua_cert(args: argparse.Namespace) -> int:
    """Write the OPC UA server's self-signed certificate and key (docs/opcua.md)."""
    from runtime.opcua.security import APPLICATION_URI, CLIENT_URI, make_certificate

    try:
        cert, key = make_certificate(args.dir, args.days, args.host, client=args.client)
    except FileExistsError as exc:
        sys.stderr.write(f"softplc opcua-cert: error: {exc} exists: not overwritten (move "
                         "it away to make a new one)\n")
        return 2
    except OSError as exc:
        sys.stderr.write(f"softplc opcua-cert: error: {args.dir}: {exc.strerror}\n")
        return 2
    sys.stdout.write(f"certificate {cert}\nprivate key {key} (mode 0600)\n"
                     f"application URI {CLIENT_URI if args.client else APPLICATION_URI}\n")
    return 0


class _VersionAction(argparse.Action):
    """``--version``: the package's version, looked up only when asked for (importing
    importlib.metadata costs every start some 20 ms, 120 ms without cached bytecode)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=default,
                         help=help or "show the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        sys.stdout.write(f"softplc {package_version()}\n")
        parser.exit()


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The command line's parser. With ``argv``, the subcommands that live in their own
    module are registered only if ``argv`` names them (or names no known command: then
    every one, for the help and the 'invalid choice' error), so that ``softplc compile``
    does not import the checker, the drawing and the console."""
    p = argparse.ArgumentParser(prog="softplc", description="GRAFCET/SFC soft-PLC runtime")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    p.add_argument("--version", action=_VersionAction)
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("compile", help="compile and check grafcet or plant files")
    c.add_argument("files", nargs="+")
    c.add_argument("--show", action="store_true", help="print the generated Python source")
    c.set_defaults(func=cmd_compile)

    io = sub.add_parser("iolist", help="print a plant's I/O list (signal, point, NC, "
                                       "description, unit, range)")
    io.add_argument("plant")
    io.add_argument("--csv", action="store_true", help="comma-separated, for a spreadsheet")
    io.set_defaults(func=cmd_iolist)

    s = sub.add_parser("simulate", help="run a plant on a virtual clock with simulated I/O")
    s.add_argument("plant")
    s.add_argument("--script", help="simulation script (YAML)")
    s.add_argument("--trace", help="write one JSON object per scan to this file")
    s.add_argument("--vcd", help="write a Value Change Dump to this file")
    s.add_argument("--cycles", type=int, help="number of scans (overrides the script)")
    s.set_defaults(func=cmd_simulate)

    r = sub.add_parser("run", help="run a plant in real time (the controller)",
                       description="Run the plant on its drivers in real time until "
                                   "SIGTERM/SIGINT/SIGHUP/SIGQUIT; every output off before "
                                   "the first scan "
                                   "and at the end.")
    r.add_argument("plant")
    r.add_argument("--sim", action="store_true",
                   help="replace every driver by simulated I/O (runs on any machine)")
    r.add_argument("--for", dest="for_", metavar="DURATION",
                   help="stop after this long (e.g. 10s), an orderly stop")
    r.add_argument("--trace", metavar="FILE", help="write one JSON line per cycle")
    r.add_argument("--script", metavar="S.yaml",
                   help="with --sim: play this simulation script's input changes in real time")
    r.set_defaults(func=cmd_run)

    rl = sub.add_parser("reload", help="load the changed plant and charts into a running "
                                       "controller (online change)",
                        description="Ask a running controller, through its console, to load "
                                    "its plant file and charts again and swap the programs "
                                    "between two scans, state carried over "
                                    "(docs/online-change.md). Exit 0 applied, 1 refused, 2 "
                                    "cannot connect.")
    rl.add_argument("target", metavar="PLANT|SOCKET|PORT",
                    help="the plant file (its console is found as its side processes find "
                         "it: /etc/softplc/NAME/plant.yaml), or /run/softplc/NAME/console.sock,"
                         " 127.0.0.1:5020, /dev/ttyUSB0")
    rl.add_argument("--force", action="store_true",
                    help="apply what is refused unless forced (docs/online-change.md)")
    rl.add_argument("--restart", action="append", default=[], metavar="INSTANCE",
                    help="restart this instance from its initial situation (repeatable)")
    rl.add_argument("--back", action="store_true",
                    help="return to the program that ran before the last change")
    rl.add_argument("--pin-file", metavar="FILE",
                    help="unlock the console with the PIN on this file's first line")
    rl.add_argument("--baudrate", type=int, default=115200, help="serial speed (115200)")
    rl.add_argument("--timeout", type=float, default=60.0, metavar="S",
                    help="how long to wait for the controller's answer (60)")
    rl.set_defaults(func=cmd_reload)

    h = sub.add_parser("hash-pin", help="print the hash of a console PIN for the plant file")
    h.add_argument("pin", nargs="?", help="the PIN (asked without echo if omitted)")
    h.set_defaults(func=cmd_hash_pin)

    d = sub.add_parser("diff", help="what loading a changed chart or plant into a running "
                                    "controller would do (online change)")
    d.add_argument("old", help="the running chart or plant file")
    d.add_argument("new", help="the changed one")
    d.set_defaults(func=cmd_diff)
    oc = sub.add_parser("opcua-cert", help="make the OPC UA server's certificate and key",
                        description="Write a self-signed certificate (DIR/server-cert.der) "
                                    "and its private key (DIR/server-key.pem, mode 0600) "
                                    "for the OPC UA server; existing files are never "
                                    "overwritten.")
    oc.add_argument("--dir", default="/etc/softplc/opcua", help="where to write them "
                    "(default /etc/softplc/opcua)")
    oc.add_argument("--days", type=int, default=3650, help="validity (default 3650)")
    oc.add_argument("--host", action="append", default=[], metavar="H",
                    help="a DNS name or IP address clients use to reach the server "
                         "(repeatable; default this machine's name, localhost, 127.0.0.1)")
    oc.add_argument("--client", action="store_true",
                    help="make a client certificate (DIR/client-cert.der, client-key.pem) "
                         "instead, e.g. for a Python client")
    oc.set_defaults(func=cmd_opcua_cert)

    o = sub.add_parser("opcua", help="serve a running plant over OPC UA (its own process)")
    o.add_argument("plant")
    o.add_argument("--endpoint", help="override opcua: endpoint (opc.tcp://HOST:PORT)")
    o.add_argument("--feed", help="override opcua: feed (the controller's feed socket)")
    o.set_defaults(func=cmd_opcua)

    mq = sub.add_parser("mqtt", help="publish a running plant over MQTT Sparkplug B (its own "
                                     "process)")
    mq.add_argument("plant")
    mq.add_argument("--feed", help="override mqtt: feed (the controller's feed socket)")
    mq.set_defaults(func=cmd_mqtt)

    wb = sub.add_parser("web", help="serve a running plant's live page in the browser "
                                    "(its own process)")
    wb.add_argument("plant")
    wb.add_argument("--listen", help="override web: listen (HOST:PORT)")
    wb.add_argument("--feed", help="override web: feed (the controller's feed socket)")
    wb.add_argument("--coverage", metavar="COVERAGE.json",
                    help="shade the charts by the coverage softplc test --coverage-file wrote")
    wb.set_defaults(func=cmd_web)

    mb = sub.add_parser("modbus", help="serve a running plant over Modbus/TCP (its own "
                                       "process), or print its address map")
    mb.add_argument("plant")
    mb.add_argument("--map", action="store_true",
                    help="print the address map a panel's tag editor takes, and exit")
    mb.add_argument("--csv", action="store_true", help="with --map: as CSV")
    mb.add_argument("--listen", help="override modbus: listen (HOST:PORT)")
    mb.add_argument("--feed", help="override modbus: feed (the controller's feed socket)")
    mb.set_defaults(func=cmd_modbus)

    command = None if argv is None else next((a for a in argv if not a.startswith("-")), "")
    known = command in sub.choices or command in MODULE_COMMANDS
    wanted = {module for name, module in MODULE_COMMANDS.items()
              if command is None or command == name or not known}
    for module in dict.fromkeys(MODULE_COMMANDS.values()):  # each module once, in order
        if module in wanted:
            importlib.import_module(module).register(sub)
    return p


#: subcommands that live with their own module, which has a ``register(sub)`` (a module
#: may register several: PLCopen's import and export): name -> module
MODULE_COMMANDS = {
    "check": "runtime.checker.check",
    "draw": "runtime.drawing.chart",
    "chronogram": "runtime.drawing.chronogram",
    "install-service": "runtime.controller.install",
    "monitor": "runtime.console.monitor",
    "import": "runtime.plcopen.commands",
    "export": "runtime.plcopen.commands",
    "test": "runtime.scenario.commands",
}


def _unrecognized(parser: argparse.ArgumentParser, args: argparse.Namespace,
                  rest: list[str]) -> NoReturn:
    """Exit 2 with the usage of the command ``args`` is for and what was left over; a file
    left over by a command that takes ``--script`` is pointed there."""
    command = parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            command = action.choices.get(args.command, parser)
    hint = ""
    if len(rest) == 1 and not rest[0].startswith("-") and getattr(args, "script", 0) is None:
        hint = f" (a script is given with --script: --script {rest[0]})"
    command.error(f"unrecognized arguments: {' '.join(rest)}{hint}")


#: commands that read files, check or compile them and exit: the collector of cyclic
#: garbage is off while they run (a 4000-step chart: 0.4 s of 3.8 s of processor time
#: spent collecting, for 8 % more memory at the peak; docs/check.md)
BATCH_COMMANDS = frozenset({"compile", "check"})


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    collecting = gc.isenabled()
    if next((a for a in argv if not a.startswith("-")), "") in BATCH_COMMANDS:
        gc.disable()  # its garbage ends with the command (on again after it: a caller's)
    try:
        return _main(argv)
    finally:
        if collecting:
            gc.enable()


def _main(argv: Sequence[str]) -> int:
    parser = build_parser(argv)
    args, rest = parser.parse_known_args(argv)
    if rest:  # said by the command's own parser: its usage, not every command's
        _unrecognized(parser, args, rest)
    from runtime.controller.logsetup import setup_logging

    setup_logging(args.verbose)
    try:
        return int(args.func(args) or 0)
    except SourceError as exc:
        sys.stderr.write(f"{exc}\n")
        return 2
    except SoftplcError as exc:
        from runtime.compiler.guard import GeneratedCodeRefused

        if not isinstance(exc, GeneratedCodeRefused):
            raise
        sys.stderr.write(f"softplc: error: {exc}\n")
        return 2
    except ImportError as exc:
        sys.stderr.write(f"softplc: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
