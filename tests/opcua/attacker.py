"""A hostile OPC UA client, run as its own process by tests/opcua/test_limits.py:
``python -m tests.opcua.attacker CONFIG_JSON``.

It opens an anonymous session (asyncua's client, on a None channel), then creates
subscriptions at a publishing interval of 0 ms, the first one monitoring every node of
``nodes`` (a JSON file of NodeId strings) at a sampling interval of 0 with the largest
queue (0: "as many as the server allows"), every other one a single node, until the
server refuses a subscription or ``subscriptions`` exist. It prints one JSON line:
``{"subscriptions": N, "items": M, "refusals": ["BadTooMany...", ...], "intervals":
[the revised publishing interval of each subscription, ms]}`` and then
keeps its session open (publishing) until it is killed: the test kills it with SIGKILL,
so nothing ever closes the session cleanly.

It prints ``{"session": "Good", "timeout_ms": T}`` (the session timeout the server
granted) first, or ``{"session": "Bad..."}`` when the server refuses the session.
"""

from __future__ import annotations

import asyncio
import json
import sys
from typing import Any

from asyncua import Client, ua
from asyncua.common.subscription import Subscription


class _Quiet:
    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        pass

    def status_change_notification(self, status: Any) -> None:
        pass


def _say(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


async def attack(cfg: dict[str, Any]) -> None:
    client = Client(cfg["url"], timeout=60, watchdog_intervall=600.0)
    client.session_timeout = 3_600_000  # ask for an hour, as many clients do
    try:
        await client.connect()
    except ua.UaStatusCodeError as exc:
        _say({"session": type(exc).__name__})
        return
    except (OSError, TimeoutError) as exc:
        _say({"session": f"{type(exc).__name__}: {exc}"})
        return
    _say({"session": "Good", "timeout_ms": client.session_timeout})
    with open(cfg["nodes"], encoding="utf-8") as f:
        ids = [ua.NodeId.from_string(i) for i in json.load(f)]
    subs = items = 0
    refusals: list[str] = []
    intervals: list[float] = []
    while subs < cfg["subscriptions"]:
        params = ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=0, RequestedLifetimeCount=100_000,
            RequestedMaxKeepAliveCount=30_000, MaxNotificationsPerPublish=0,
            PublishingEnabled=True, Priority=0)
        sub = Subscription(client.uaclient.session, params, _Quiet())
        try:
            res = await sub.init()
            intervals.append(float(res.RevisedPublishingInterval))
        except ua.UaStatusCodeError as exc:
            refusals.append(type(exc).__name__)
            break
        subs += 1
        nodes = ids if subs == 1 else ids[:1]
        for k in range(0, len(nodes), 250):
            handles = await sub.subscribe_data_change(
                [client.get_node(n) for n in nodes[k:k + 250]], queuesize=0,
                sampling_interval=0)
            assert isinstance(handles, list)
            bad = [h for h in handles if isinstance(h, ua.StatusCode)]
            items += len(handles) - len(bad)
            refusals += sorted({h.name for h in bad} - set(refusals))
    _say({"subscriptions": subs, "items": items, "refusals": refusals,
          "intervals": intervals})
    await asyncio.sleep(3600)


if __name__ == "__main__":
    asyncio.run(attack(json.loads(sys.argv[1])))
