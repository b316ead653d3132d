"""The Modbus server's staleness is the controller's, not its own event loop's
(runtime/modbus/server.py ``fresh``): with the shared image mapped, the controller's own
stamp in the image header says whether it still writes (``FeedClient.controller_age_s``,
as the OPC UA server does). A server whose loop was blocked longer than the bound still
answers values; a controller that stopped writing gets exception 11."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from runtime.language.plantfile import load_plant
from runtime.modbus.server import ModbusServer, serve, stale_after_s
from tests.opcua.feedkit import serving, wait_until
from tests.opcua.kit import plant_head


class ServerThread:
    """``serve`` (the real server) in a thread of its own with its own event loop."""

    def __init__(self, plant: Path) -> None:
        self.pdef = load_plant(str(plant))
        self.ms: ModbusServer | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="modbus-test", daemon=True)

    def __enter__(self) -> ServerThread:
        self._thread.start()
        assert self._ready.wait(30.0), "the Modbus server did not start"
        return self

    def __exit__(self, *exc: object) -> None:
        if self.loop is not None and self._stop is not None:
            self.loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30.0)

    def _run(self) -> None:
        async def main() -> None:
            self.loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()

            def ready(ms: ModbusServer) -> None:
                self.ms = ms
                self._ready.set()
            await serve(self.pdef, listen=("127.0.0.1", 0), ready=ready, stop=self._stop)
        asyncio.run(main())


def _plant(tmp: Path) -> Path:
    path = tmp / "plant.yaml"
    path.write_text(plant_head(tmp) + f"modbus:\n  listen: 127.0.0.1:0\n  sample: 20ms\n"
                    f"  feed: {tmp}/feed.sock\n", encoding="utf-8")
    return path


def test_a_busy_event_loop_is_not_a_stale_controller_a_frozen_one_is(
        tmp_path: Path) -> None:
    plant = _plant(tmp_path)
    pdef = load_plant(str(plant))
    assert pdef.modbus is not None
    bound = stale_after_s(pdef.modbus.sample_ns)
    with serving(pdef) as (d, feed), ServerThread(plant) as srv:
        ms, loop = srv.ms, srv.loop
        assert ms is not None and loop is not None and feed.image is not None
        wait_until(lambda: ms.fresh() and ms.feed.image is not None, 20.0, "values")
        c = ModbusTcpClient("127.0.0.1", port=ms.ports[0], timeout=10, retries=0)
        assert c.connect()
        try:
            assert not c.read_coils(0, count=1, device_id=1).isError()
            # the server's own loop blocked for twice the bound; the controller runs on:
            # at the end of the block (no frame seen meanwhile), still fresh
            fresh_after: list[bool] = []

            def block() -> None:
                time.sleep(2 * bound + 0.5)
                fresh_after.append(ms.fresh())
            loop.call_soon_threadsafe(block)
            wait_until(lambda: bool(fresh_after), 30.0, "the block's end")
            assert fresh_after == [True]
            assert not c.read_coils(0, count=1, device_id=1).isError()
            # the controller stops writing its image (frozen: its feed unhooked from the
            # scans): exception 11 within the bound, and values again once it writes
            d.remove_listener(feed.on_scan)

            def refused() -> bool:
                rr = c.read_coils(0, count=1, device_id=1)
                return bool(rr.isError() and rr.exception_code == 11)
            wait_until(refused, 20.0, "exception 11 once the controller froze")
            d.add_listener(feed.on_scan)
            wait_until(lambda: not c.read_coils(0, count=1, device_id=1).isError(), 20.0,
                       "values again")
        finally:
            c.close()
