"""An independent Sparkplug B host application for the tests (not softplc's code): it runs
in its own virtual environment (requirements.txt) and decodes everything with pysparkplug.

    host.py HOST PORT [--ca FILE] [--user U --password P] [--id HOST_ID] [--primary]
            [--keepalive SECONDS]

It subscribes to what edge nodes publish (``spBv1.0/+/NBIRTH/#`` ..., QoS 1) and writes
one JSON line per message to stdout:
``{"rx": seconds, "topic", "kind", "group", "edge", "device", "timestamp", "seq",
"metrics": [{"name", "alias", "datatype", "value", "timestamp", "historical"}]}``
(in a birth, a metric with properties has ``"properties": {key: value}`` too)
(``"error"`` instead of the payload's fields when pysparkplug cannot decode it). It reads
JSON lines on stdin: ``{"cmd": TOPIC, "metrics": [[name, datatype name, value], ...]}``
publishes a command encoded by pysparkplug; ``{"raw": TOPIC, "hex": HEX}`` publishes those
bytes (``"retain": true`` retained, ``"qos": 1``); ``{"state": true|false}`` publishes
this host's STATE (retained, QoS 1, with ``--id``); ``{"flood": TOPIC, "metrics": [...],
"rate": N, "seconds": S}`` publishes one DCMD (or NCMD) N times a second for S seconds
(``"count": C``: C of them at most). ``{"ready": true}`` is written once subscribed, a row
of kind ``HOST_CONNECTED`` at each (re)connection, ``{"sent": N}`` after each request.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Any

import pysparkplug as spb

OUT = threading.Lock()


def metric_properties(payload: bytes) -> dict[str, dict[str, Any]]:
    """Each named metric's properties (a PropertySet of scalars): name -> {key: value}."""
    from pysparkplug._protobuf import sparkplug_b_pb2 as pb  # noqa: PLC0415

    p = pb.Payload()
    p.ParseFromString(payload)
    out: dict[str, dict[str, Any]] = {}
    for m in p.metrics:
        if m.name and m.HasField("properties"):
            pairs = zip(m.properties.keys, m.properties.values, strict=True)
            out[m.name] = {k: getattr(v, v.WhichOneof("value")) if v.WhichOneof("value")
                           else None for k, v in pairs}
    return out


def emit(obj: dict[str, Any]) -> None:
    with OUT:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


def plain(value: Any) -> Any:
    if isinstance(value, bytes | bytearray):
        return value.hex()
    if isinstance(value, int | float | str | bool) or value is None:
        return value
    return str(value)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("host")
    ap.add_argument("port", type=int)
    ap.add_argument("--ca")
    ap.add_argument("--user")
    ap.add_argument("--password")
    ap.add_argument("--id", default="softplc-test-host")
    ap.add_argument("--primary", action="store_true",
                    help="act as the primary host: STATE online at each connection, "
                         "offline as the Will")
    ap.add_argument("--keepalive", type=int, default=5,
                    help="the MQTT keepalive of this host's connection, seconds")
    a = ap.parse_args()
    tls = spb.TLSConfig(ca_certs=a.ca) if a.ca else None
    client = spb.Client(client_id=f"{a.id}-{time.monotonic_ns()}", username=a.user,
                        password=a.password, transport_config=tls)
    state_topic = spb.Topic(message_type=spb.MessageType.STATE, sparkplug_host_id=a.id)
    if a.primary:
        client.set_will(spb.Message(topic=state_topic, payload=spb.State(
            timestamp=spb.get_current_timestamp(), online=False),
            qos=spb.QoS.AT_LEAST_ONCE, retain=True))

    raw: list[bytes] = []  # the payload being decoded (for the births' properties)

    def on_message(_c: Any, m: Any) -> None:
        t = m.topic
        row: dict[str, Any] = {"rx": time.time(), "topic": str(t), "kind": str(t.message_type),
                               "group": t.group_id, "edge": t.edge_node_id,
                               "device": t.device_id}
        p = m.payload
        row["timestamp"] = getattr(p, "timestamp", None)
        row["seq"] = getattr(p, "seq", None)
        if isinstance(p, spb.State):
            row["online"] = p.online
        row["metrics"] = [{"name": x.name, "alias": x.alias, "datatype": x.datatype.name,
                           "value": plain(x.value), "timestamp": x.timestamp,
                           "historical": x.is_historical, "null": x.is_null}
                          for x in (getattr(p, "metrics", None) or
                                    ([p.bd_seq_metric] if hasattr(p, "bd_seq_metric")
                                     else []))]
        if row["kind"] in ("NBIRTH", "DBIRTH") and raw:
            # pysparkplug's Metric has no properties: its own generated module reads them
            props = metric_properties(raw[0])
            for m in row["metrics"]:
                if m["name"] in props:
                    m["properties"] = props[m["name"]]
        emit(row)

    def on_raw(_c: Any, _u: Any, msg: Any) -> None:
        # what pysparkplug cannot decode still shows up (a payload no host could read)
        emit({"rx": time.time(), "topic": msg.topic, "error": "undecodable",
              "hex": bytes(msg.payload[:64]).hex()})

    done = threading.Event()

    def connected(_c: Any) -> None:
        # every (re)connection: what came before may have gaps (a checker starts afresh)
        emit({"rx": time.time(), "topic": "", "kind": "HOST_CONNECTED"})
        if a.primary:  # after the subscriptions (paho sends them first on a reconnection)
            _c._client.publish(str(state_topic), spb.State(  # noqa: SLF001
                timestamp=spb.get_current_timestamp(), online=True).encode(), qos=1,
                retain=True)
        done.set()
    client.connect(a.host, port=a.port, keepalive=a.keepalive, blocking=False, callback=connected)
    if not done.wait(20):
        emit({"fatal": "no connection"})
        return
    inner = client._client  # noqa: SLF001 - raw publishes (hostile payloads) need paho
    inner.on_message = on_raw  # messages pysparkplug's callbacks did not claim
    inner.suppress_exceptions = True  # a payload it cannot decode never ends the host
    original = client._handle_message  # noqa: SLF001

    def guarded(mqtt_message: Any) -> Any:
        raw[:] = [bytes(mqtt_message.payload)]
        try:
            return original(mqtt_message)
        except Exception as exc:  # noqa: BLE001 - reported, the host goes on
            emit({"rx": time.time(), "topic": mqtt_message.topic, "error": repr(exc)})
            raise
    client._handle_message = guarded  # type: ignore[method-assign]  # noqa: SLF001
    # what edge nodes publish (not the commands: this host sends those)
    for kind in ("NBIRTH", "NDATA", "NDEATH", "DBIRTH", "DDATA", "DDEATH"):
        client.subscribe(spb.Topic(group_id=spb.SINGLE_LEVEL_WILDCARD,
                                   message_type=spb.MessageType[kind],
                                   edge_node_id=spb.MULTI_LEVEL_WILDCARD),
                         spb.QoS.AT_LEAST_ONCE, on_message)
    client.subscribe(spb.Topic(message_type=spb.MessageType.STATE,
                               sparkplug_host_id=spb.SINGLE_LEVEL_WILDCARD),
                     spb.QoS.AT_LEAST_ONCE, on_message)
    time.sleep(0.3)
    emit({"ready": True})
    for line in sys.stdin:
        req = json.loads(line)
        now = spb.get_current_timestamp()
        if "cmd" in req:
            topic = spb.Topic.from_str(req["cmd"])
            metrics = tuple(spb.Metric(timestamp=now, name=n, datatype=spb.DataType[d],
                                       value=v) for n, d, v in req["metrics"])
            payload: Any = (spb.NCmd if topic.message_type == spb.MessageType.NCMD
                            else spb.DCmd)(timestamp=now, metrics=metrics)
            client.publish(spb.Message(topic=topic, payload=payload, qos=spb.QoS.AT_MOST_ONCE,
                                       retain=False), include_dtypes=True)
        elif "raw" in req:
            inner.publish(req["raw"], bytes.fromhex(req["hex"]), qos=req.get("qos", 0),
                          retain=bool(req.get("retain", False)))
        elif "flood" in req:  # {"flood": TOPIC, "metrics": [...], "rate": N, "seconds": S}
            topic = spb.Topic.from_str(req["flood"])
            metrics = tuple(spb.Metric(timestamp=now, name=n, datatype=spb.DataType[d],
                                       value=v) for n, d, v in req["metrics"])
            kind = spb.NCmd if topic.message_type == spb.MessageType.NCMD else spb.DCmd
            data = kind(timestamp=now, metrics=metrics).encode(include_dtypes=True)
            period, end = 1.0 / req["rate"], time.monotonic() + req["seconds"]
            due, sent, count = time.monotonic(), 0, req.get("count")
            while time.monotonic() < end and (count is None or sent < count):
                inner.publish(str(topic), data, qos=0)
                sent += 1
                due += period
                time.sleep(max(0.0, due - time.monotonic()))
            req["n"] = sent
        elif "state" in req:
            inner.publish(str(state_topic), spb.State(timestamp=now, online=req["state"]).encode(),
                          qos=1, retain=True)
        emit({"sent": req.get("n")})
    client.disconnect()


if __name__ == "__main__":
    main()
