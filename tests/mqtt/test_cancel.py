"""A cancelled task of the edge node ends, even when what it waited for comes in the same
instant (runtime/controller/aio.py, ``within``).

Python 3.11's ``asyncio.wait_for`` returns the result instead of raising when its task is
cancelled in the loop iteration where the awaited thing completes: the cancellation is
lost. The session's broker watch (an UNSUBSCRIBE probe, bounded) lost the cancel of its
task group that way when the probe's UNSUBACK came with it, and went on looping: the task
group, then the process, waited for it forever (a ``softplc mqtt`` that did not end on
SIGTERM in the suite)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import aiomqtt
import pytest

from runtime.controller.aio import within
from runtime.language.plantfile import load_plant
from runtime.mqtt import session as mqtt_session
from runtime.mqtt.session import EdgeSession
from tests.mqtt.kit import Broker, write_plant

#: a failure deadline for a task that must end, seconds (never a speed assertion)
END_S = 10.0


def test_the_broker_watch_ends_when_cancelled_as_its_probe_is_answered(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A real client on a real broker: the watch's task is cancelled from the paho
    callback that takes the probe's UNSUBACK (the answer and the cancel in one loop
    iteration). Before: the watch returned from its probe, confirmed, and looped on
    forever (still running after 10 s); now it ends cancelled."""
    monkeypatch.setattr(mqtt_session, "PROBE_S", 0.01)
    broker = Broker(tmp_path).start()
    try:
        es = EdgeSession(load_plant(str(write_plant(tmp_path, [broker.url]))))

        async def main() -> tuple[bool, bool, int]:
            async with aiomqtt.Client("127.0.0.1", broker.port, identifier="t-cancel") as c:
                es._handed = 1  # a data message handed and not yet confirmed: it probes
                watch = asyncio.ensure_future(es._watch(c))
                answered: list[int] = []
                taken = c._client.on_unsubscribe
                assert taken is not None  # aiomqtt's own: it sets the confirmation

                def on_unsubscribe(*args: Any) -> None:
                    taken(*args)  # the probe's confirmation set...
                    if not answered:
                        answered.append(1)
                        watch.cancel()  # ...and the task cancelled in the same instant
                c._client.on_unsubscribe = on_unsubscribe
                done, _ = await asyncio.wait({watch}, timeout=END_S)
                if not done:
                    watch.cancel()  # (a second cancel: the test's own clean-up)
                    await asyncio.wait({watch}, timeout=END_S)
                return bool(done), watch.cancelled(), len(answered)

        ended, cancelled, answers = asyncio.run(main())
        assert answers == 1, "the probe was never answered"
        assert ended and cancelled, (
            f"the watch went on {END_S:g} s after its cancel (the cancel was lost)")
    finally:
        broker.kill()


def test_within_keeps_a_cancel_that_comes_with_the_result() -> None:
    """The same instant without a broker: an event set and the waiting task cancelled in
    one loop iteration; ``within`` raises CancelledError, a loop around it ends."""

    async def main() -> tuple[bool, int]:
        event = asyncio.Event()
        rounds = [0]

        async def loop_forever() -> None:
            while True:
                rounds[0] += 1
                await within(event.wait(), 5.0)
                event.clear()

        t = asyncio.ensure_future(loop_forever())
        await asyncio.sleep(0)  # it waits for the event
        event.set()
        t.cancel()
        done, _ = await asyncio.wait({t}, timeout=END_S)
        if not done:
            t.cancel()
        return t.cancelled(), rounds[0]

    cancelled, rounds = asyncio.run(main())
    assert cancelled and rounds == 1, rounds


def test_within_bounds_the_wait() -> None:
    async def main() -> None:
        with pytest.raises(TimeoutError):
            await within(asyncio.Event().wait(), 0.01)
        assert await within(asyncio.sleep(0, "done"), None) == "done"
        assert await within(asyncio.sleep(0, "done"), 5.0) == "done"

    asyncio.run(main())
