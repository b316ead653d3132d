"""The files the side processes ``softplc web``, ``modbus`` and ``mqtt`` read at their start
besides the plant: the certificates and keys of ``web: tls:``, ``modbus: tls:`` and ``mqtt:
tls:``, and ``mqtt: password_file``.

A server's certificate and key (``web`` and ``modbus``) are declared once (``SERVER_TLS``)
and read once (``pem_files``: each path from the plant file's directory when relative, its
value's place kept). ``side_file_problems`` says which of all these files is not there or
cannot be read by whoever asks, each at its value: ``softplc check`` reports them as G308
errors (as the OPC UA server's, ``opcuaconf.security_problems``). Loading the plant never
refuses them: a controller must start after a power cut whatever happened to a
certificate; the side process refuses to start on such a file with its own line."""

from __future__ import annotations

import os

from runtime.errors import Loc, SourceError
from runtime.language.model import PlantDef
from runtime.language.plantpaths import PATH, missing, plant_path
from runtime.language.shape import Key
from runtime.language.yamlsrc import YMap

#: a server's certificate and its key, as ``web: tls:`` and ``modbus: tls:`` declare them
SERVER_TLS = (
    Key("certificate", PATH, "The server's certificate (PEM, its chain after it).",
        required=True),
    Key("private_key", PATH, "Its private key (PEM).", required=True),
)


def pem_files(base: str, m: YMap, keys: tuple[str, ...], what: str, loc: Loc,
              locs: dict[str, Loc], why: str = "") -> dict[str, str]:
    """The paths ``keys`` of the ``tls:`` mapping ``m`` (at ``loc``, of the plant file
    ``base``; ``what``: "web tls"), each read from the plant file's directory when
    relative and its value's place put in ``locs``. Each key is needed: a missing one is
    SourceError at ``loc`` ("WHAT: expected KEY (a PEM file), found none" and ``why``)."""
    out: dict[str, str] = {}
    for key in keys:
        if key not in m:
            raise SourceError(loc, f"{what}: expected {key} (a PEM file), found none{why}")
        locs[key] = m.val_locs[key]
        out[key] = plant_path(base, m[key], locs[key], f"{what} {key}")
    return out


def side_files(p: PlantDef) -> list[tuple[str, str, str, Loc]]:
    """(side process, what, path, the value's place) of each file ``p``'s web view, Modbus
    server and MQTT edge node read at their start."""
    out: list[tuple[str, str, str, Loc]] = []
    if p.web is not None and p.web.certificate is not None:
        out += [("web", f"web tls {key}", getattr(p.web, key), p.web.tls_locs[key])
                for key in ("certificate", "private_key")]
    if p.modbus is not None and p.modbus.tls is not None:
        t = p.modbus.tls
        out += [("modbus", f"modbus tls {key}", getattr(t, key), t.locs[key])
                for key in ("certificate", "private_key", "clients_ca")]
    if p.mqtt is not None:
        q = p.mqtt
        if q.tls is not None:
            out += [("mqtt", f"mqtt tls {key}", getattr(q.tls, key), q.tls.locs[key])
                    for key in ("ca", "certificate", "private_key")
                    if getattr(q.tls, key) is not None]
        if q.password_file is not None:
            out.append(("mqtt", "mqtt password_file", q.password_file,
                        q.locs["password_file"]))
    return out


def side_file_problems(p: PlantDef) -> list[SourceError]:
    """Each file of ``side_files`` that is not there, not a file, or that this user may not
    read, as one SourceError at its value."""
    out: list[SourceError] = []
    for side, what, path, loc in side_files(p):
        why = missing(path)
        if why is None and not os.access(path, os.R_OK):
            why = f"{path} cannot be read (permission denied)"
        if why is not None:
            out.append(SourceError(loc, f"{what}: {why}: 'softplc {side}' would refuse to "
                                        f"start (docs/{side}.md)"))
    return out
