"""The ``mqtt:`` section of a plant file (docs/mqtt.md): the brokers, the Sparkplug B
identity of the edge node, TLS and credentials, what is published and what may be written.
Checked against the plant, every error at its ``FILE:LINE:COL``."""

from __future__ import annotations

import re
import socket
from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language.feedconf import feed_key, sample_key, writable_names
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.model import MQTT_GROUPS, MqttBroker, MqttDef, MqttTls, PlantDef
from runtime.language.plantpaths import plant_path
from runtime.language.yamlsrc import YList, YMap

MQTT_KEYS = ("brokers", "group_id", "edge_node_id", "client_id", "username", "password_file",
             "tls", "primary_host", "publish", "writable", "sample", "statistics",
             "keepalive", "buffer", "feed")
TLS_KEYS = ("ca", "certificate", "private_key")
#: the default report-by-exception period (never below the cycle), ns
DEFAULT_SAMPLE_NS = 100_000_000
#: the most metric values the store-and-forward buffer may be told to keep
BUFFER_MAX = 10_000_000
#: the shortest statistics period, ns
STATISTICS_MIN_NS = 1_000_000_000
_URL = re.compile(r"^(mqtts?)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)(?::(\d{1,5}))?/?$")
#: Sparkplug B ids (group, edge node, host): UTF-8 without the MQTT wildcards and '/'
_ID_FORBIDDEN = re.compile(r"[+#/\s]")


def load_mqtt(p: PlantDef, value: Any, loc: Loc) -> MqttDef:
    """``mqtt:`` -> MqttDef; SourceError at the faulty key or value."""
    m = expect_type(value, loc, YMap, "a mapping (brokers, group_id, edge_node_id, ...)")
    if "password" in m:
        raise SourceError(m.key_locs["password"], "mqtt: a password is never written in the "
                          "plant file: put it on the first line of a file only the service "
                          "may read, and name that file with password_file")
    check_keys(m, MQTT_KEYS, "mqtt")
    q = MqttDef(loc=loc, sample_ns=max(DEFAULT_SAMPLE_NS, p.cycle_ns))
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
        if q.statistics_ns < STATISTICS_MIN_NS:
            raise SourceError(vloc, "mqtt statistics: expected at least 1s (they are "
                                    "refreshed once a second)")
    if "keepalive" in m:
        vloc = m.val_locs["keepalive"]
        q.keepalive_ns = time_value(m["keepalive"], vloc, "mqtt keepalive")
        if q.keepalive_ns % 1_000_000_000 or not 1 <= q.keepalive_ns // 1_000_000_000 <= 65535:
            raise SourceError(vloc, "mqtt keepalive: expected whole seconds from 1s to "
                                    "65535s (MQTT counts it in seconds)")
    if "buffer" in m:
        vloc = m.val_locs["buffer"]
        q.buffer = expect_type(m["buffer"], vloc, int, "a number of metric values")
        if not 0 <= q.buffer <= BUFFER_MAX:
            raise SourceError(vloc, f"mqtt buffer: expected 0 (no store and forward) to "
                                    f"{BUFFER_MAX}, found {q.buffer}")
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
    check_keys(m, TLS_KEYS, "mqtt tls")
    t = MqttTls(loc=loc)
    for key in TLS_KEYS:
        if key in m:
            setattr(t, key, _path(m, key))
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
