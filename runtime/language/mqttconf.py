"""The ``mqtt:`` section of a plant file (docs/mqtt.md): the brokers, the Sparkplug B
identity of the edge node, TLS and credentials, what is published and what may be written.
Checked against the plant, every error at its ``FILE:LINE:COL``."""

from __future__ import annotations

import re
import socket
from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language.feedconf import FEED_KEY, WRITABLE, feed_key, sample_key, writable_names
from runtime.language.model import (
    MQTT_DEFAULT_PUBLISH,
    MQTT_GROUPS,
    MqttBroker,
    MqttDef,
    MqttTls,
    PlantDef,
)
from runtime.language.plantpaths import PATH, plant_path
from runtime.language.shape import (
    Int,
    Key,
    ListOf,
    Section,
    Text,
    Time,
    any_of,
    expect_type,
    time_value,
)
from runtime.language.yamlsrc import YList, YMap

#: the default report-by-exception period (never below the cycle), ns
DEFAULT_SAMPLE_NS = 100_000_000
_URL = re.compile(r"^(mqtts?)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)(?::(\d{1,5}))?/?$")
#: Sparkplug B ids (group, edge node, host): UTF-8 without the MQTT wildcards and '/'
_ID_FORBIDDEN = re.compile(r"[+#/\s]")

# -- the shape of ``mqtt:`` (runtime/language/shape.py)
#: a Sparkplug B id, as editors check it (``_ident`` is the loader's check)
_ID = Text(r"^[^+#/\s]+$")
_BROKER = Text(r"^mqtts?://")
TLS = Section((
    Key("ca", PATH, "The certificate authority (PEM) that signed the brokers' certificates "
                    "(default: the system's)."),
    Key("certificate", PATH, "This node's client certificate (PEM), if the broker asks for "
                             "one."),
    Key("private_key", PATH, "Its private key (PEM)."),
), "mqtt tls", "TLS with the mqtts:// brokers (docs/mqtt.md).")
MQTT = Section((
    Key("brokers", any_of(_BROKER, ListOf(_BROKER, min_items=1)),
        "mqtt://HOST:PORT (plain, default port 1883) or mqtts://HOST:PORT (TLS, 8883), in "
        "order of preference: the next one on failure.", required=True),
    Key("group_id", _ID, "The Sparkplug group of this edge node (a line, a hall).",
        required=True),
    Key("edge_node_id", _ID, "The Sparkplug edge node id (default: the host name)."),
    Key("client_id", Text(min_length=1), "The MQTT client identifier (default "
                                         "softplc-GROUP-EDGE)."),
    Key("username", Text(min_length=1), "The user the broker knows this node by."),
    Key("password_file", PATH, "A file whose first line is the password (the password itself "
                               "is never in the plant file)."),
    Key("tls", TLS),
    Key("primary_host", _ID, "The primary host application's id: the node births only while "
                             "its STATE says online."),
    Key("publish", ListOf(Text()), f"Groups ({', '.join(MQTT_GROUPS)}) and names published "
                                   f"(default {', '.join(MQTT_DEFAULT_PUBLISH)})."),
    Key("writable", WRITABLE, "instance.name of the memory variables and chart flags a DCMD "
                              "may write; everything else is refused."),
    Key("sample", Time(), "Report by exception at most this often (default 100ms; never below "
                          "the cycle)."),
    Key("statistics", Time(1_000_000_000), "How often the controller's statistics are "
                                           "published (default 10s, at least 1s)."),
    Key("keepalive", Time(1_000_000_000, 65535_000_000_000),
        "MQTT keep-alive in whole seconds (default 30s): the broker announces the node's "
        "death 1.5 times this after it went silent."),
    Key("buffer", Int(0, 10_000_000), "Metric values kept while no broker is reachable, the "
                                      "oldest dropped first (default 100000; 0: none)."),
    FEED_KEY,
), "mqtt", "The MQTT Sparkplug B edge node, `softplc mqtt PLANT` (docs/mqtt.md): brokers, "
           "Sparkplug ids, TLS and credentials, what is published and what may be written.")


def load_mqtt(p: PlantDef, value: Any, loc: Loc) -> MqttDef:
    """``mqtt:`` -> MqttDef; SourceError at the faulty key or value."""
    m = expect_type(value, loc, YMap, "a mapping (brokers, group_id, edge_node_id, ...)")
    if "password" in m:
        raise SourceError(m.key_locs["password"], "mqtt: a password is never written in the "
                          "plant file: put it on the first line of a file only the service "
                          "may read, and name that file with password_file")
    MQTT.check(m)
    q = MqttDef(loc=loc, sample_ns=max(DEFAULT_SAMPLE_NS, p.cycle_ns), locs=dict(m.val_locs))
    if "brokers" not in m:
        raise SourceError(loc, "mqtt: expected brokers: [mqtt://HOST:PORT, ...] (the "
                               "plant's broker, then its fail-over brokers), found none")
    q.brokers = _brokers(m["brokers"], m.val_locs["brokers"])
    if "group_id" not in m:
        raise SourceError(loc, "mqtt: expected group_id: the Sparkplug group of this edge "
                               "node (e.g. a line or a hall), found none")
    q.group_id = _ident(m, "group_id")
    q.edge_node_id = (_ident(m, "edge_node_id") if "edge_node_id" in m
                      else _host_id(loc))
    q.client_id = (_text(m, "client_id", "an MQTT client identifier") if "client_id" in m
                   else f"softplc-{q.group_id}-{q.edge_node_id}")
    if "username" in m:
        q.username = _text(m, "username", "a user name")
    if "password_file" in m:
        q.password_file = _path(m, "password_file")
        if q.username is None:
            raise SourceError(m.key_locs["password_file"], "mqtt: password_file without "
                              "username: name the user too")
    if "tls" in m:
        q.tls = _tls(m["tls"], m.val_locs["tls"])
        if not any(b.tls for b in q.brokers):
            raise SourceError(m.key_locs["tls"], "mqtt tls: no broker is mqtts://: write "
                              "the brokers as mqtts://HOST:PORT to use TLS")
    if "primary_host" in m:
        q.primary_host = _ident(m, "primary_host")
    if "publish" in m:
        q.publish = _publish(p, m["publish"], m.val_locs["publish"])
    if "writable" in m:
        q.writable = writable_names(p, m["writable"], m.val_locs["writable"], "mqtt")
    if "sample" in m:
        q.sample_ns = sample_key(p, m, "mqtt")
    if "statistics" in m:
        vloc = m.val_locs["statistics"]
        q.statistics_ns = time_value(m["statistics"], vloc, "mqtt statistics")
        if q.statistics_ns < MQTT["statistics"].low:
            raise SourceError(vloc, "mqtt statistics: expected at least 1s (they are "
                                    "refreshed once a second)")
    if "keepalive" in m:
        vloc = m.val_locs["keepalive"]
        q.keepalive_ns = time_value(m["keepalive"], vloc, "mqtt keepalive")
        low, high = MQTT["keepalive"].low, MQTT["keepalive"].high
        if q.keepalive_ns % 1_000_000_000 or not low <= q.keepalive_ns <= high:
            raise SourceError(vloc, "mqtt keepalive: expected whole seconds from 1s to "
                                    "65535s (MQTT counts it in seconds)")
    if "buffer" in m:
        vloc = m.val_locs["buffer"]
        q.buffer = MQTT.value(m, "buffer", "a number of metric values")
        if not MQTT["buffer"].low <= q.buffer <= MQTT["buffer"].high:
            raise SourceError(vloc, f"mqtt buffer: expected {MQTT['buffer'].low} (no store and "
                                    f"forward) to {MQTT['buffer'].high}, found {q.buffer}")
    if "feed" in m:  # the default: runtime/language/feedconf.py, once every section is read
        q.feed = feed_key(m, "mqtt")
    return q


def _text(m: YMap, key: str, what: str) -> str:
    vloc = m.val_locs[key]
    text = str(expect_type(m[key], vloc, str, what))
    if not text:
        raise SourceError(vloc, f"mqtt {key}: expected {what}, found nothing")
    return text


def _path(m: YMap, key: str) -> str:
    """A file's path (``${RUNTIME_DIR}`` expanded), checked as every path a plant names and
    read from the plant file's directory when relative (``plantpaths.plant_path``)."""
    vloc = m.val_locs[key]
    return plant_path(vloc.file, m[key], vloc, f"mqtt {key}")


def _ident(m: YMap, key: str) -> str:
    """A Sparkplug id: group_id, edge_node_id, primary_host."""
    text = _text(m, key, "a Sparkplug id")
    bad = _ID_FORBIDDEN.search(text)
    if bad is not None:
        raise SourceError(m.val_locs[key], f"mqtt {key}: '{text}' holds '{bad.group()}': a "
                          "Sparkplug id may not hold '+', '#', '/' or spaces")
    return text


def _host_id(loc: Loc) -> str:
    """The host name as the edge node id (its first label if it holds what an id may not)."""
    host = socket.gethostname()
    if not host or _ID_FORBIDDEN.search(host):
        raise SourceError(loc, f"mqtt: the host name '{host}' is no Sparkplug id: set "
                               "edge_node_id")
    return host


def _brokers(value: Any, loc: Loc) -> list[MqttBroker]:
    items = [value] if isinstance(value, str) else expect_type(
        value, loc, list, "a list of broker URLs (mqtt://HOST:PORT or mqtts://HOST:PORT)")
    if not items:
        raise SourceError(loc, "mqtt brokers: expected at least one broker URL")
    locs = getattr(items, "locs", None) if isinstance(items, YList) else None
    out: list[MqttBroker] = []
    for k, item in enumerate(items):
        iloc = locs[k] if locs is not None and k < len(locs) else loc
        url = str(expect_type(item, iloc, str, "mqtt://HOST:PORT or mqtts://HOST:PORT"))
        match = _URL.match(url)
        port = int(match.group(3) or (8883 if match.group(1) == "mqtts" else 1883)
                   ) if match else 0
        if match is None or not 0 < port < 65536:
            raise SourceError(iloc, f"mqtt brokers: expected mqtt://HOST:PORT or "
                                    f"mqtts://HOST:PORT (TLS), found '{url}'")
        host = match.group(2).strip("[]")
        out.append(MqttBroker(url, host, port, match.group(1) == "mqtts"))
    return out


def _tls(value: Any, loc: Loc) -> MqttTls:
    m = expect_type(value, loc, YMap, "a mapping (ca, certificate, private_key)")
    TLS.check(m)
    t = MqttTls(loc=loc)
    for key in TLS.names:
        if key in m:
            setattr(t, key, _path(m, key))
            t.locs[key] = m.val_locs[key]
    if (t.certificate is None) != (t.private_key is None):
        raise SourceError(loc, "mqtt tls: certificate and private_key go together (the "
                               "client certificate the broker asks for, and its key)")
    return t


def _publish(p: PlantDef, value: Any, loc: Loc) -> list[str]:
    items = expect_type(value, loc, list, f"a list of {', '.join(MQTT_GROUPS)} or names")
    locs = getattr(items, "locs", None)
    out: list[str] = []
    for k, item in enumerate(items):
        iloc = locs[k] if locs is not None and k < len(locs) else loc
        word = str(expect_type(item, iloc, str, "a group or a name"))
        if "." in word:
            problem = published_name_problem(p, word)
            if problem is not None:
                raise SourceError(iloc, f"mqtt publish: {problem}")
        elif word not in MQTT_GROUPS:
            raise SourceError(iloc, f"mqtt publish: unknown group '{word}': expected one of "
                                    f"{', '.join(MQTT_GROUPS)}, or a name instance.variable"
                                    f"{suggest(word, MQTT_GROUPS)}")
        if word not in out:
            out.append(word)
    return out


def published_name_problem(p: PlantDef, name: str) -> str | None:
    """Why ``name`` is no name of the plant a publish list may hold, or None."""
    head, _, rest = name.partition(".")
    if head in p.drivers:
        return None  # a point: the driver knows its points (the edge node warns if absent)
    idef = p.instances.get(head)
    if idef is None or not rest:
        return (f"unknown instance or driver in '{name}'"
                f"{suggest(head, [*p.instances, *p.drivers])}")
    g = idef.grafcet
    step, _, xt = rest.rpartition(".")
    if step in g.steps and xt in ("X", "T"):
        return None
    if rest in g.variables or rest == "SFCCurrentStep":
        return None
    return f"'{name}': {head} has no variable or step '{rest}'{suggest(rest, g.variables)}"
