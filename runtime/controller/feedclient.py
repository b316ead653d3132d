"""The feed's client for a side process's event loop (``softplc opcua``, ``softplc mqtt``):
follow the controller's feed socket forever, decode it, and carry writes to it.

The protocol is runtime/controller/feed.py's (``FeedState`` decodes it). A side process
gives three hooks and runs ``FeedClient.run``: ``schema`` after each schema (the first one
of a connection, and again after an online change), ``frame`` after each frame (the
state's values are then that scan's), ``lost`` when a connection ends (the controller
stopped or restarts); and optionally ``status`` after each controller status (the
state's ``status``: with the alarm board) and ``alarm`` after each change of an alarm
(the state's ``alarm``: every change, in order, between the statuses; a side process that
gives no such hook ignores them and reads the board from the statuses). It reconnects
forever, with a delay doubling from RECONNECT_MIN_S to RECONNECT_MAX_S. ``set`` sends a
write and waits for the controller's answer; ``ask`` any request (``set``, ``call``,
``alarm``) with the answer's OPC UA status name; an applied request returns once the
image written after its answer is decoded (``_catch_up``), so that a value read after a
write is the written one.

A feed says whose it is (its schema's ``name`` and ``home``: the plant's name and
identity, runtime/language/runtimedir.py ``locate``). A side process follows only its own
plant's: the feed of another plant (two plants given one ``feed:`` path, a ``--feed`` to
the wrong socket) ends ``run`` with ``ForeignFeed``, one line at the plant's ``feed:``
(or naming ``--feed``), before any of its values is shown. ``run_beside`` runs the side
process's own work beside the feed and ends both on it.

The values come from the controller's shared image (runtime/controller/image.py), not
from the socket: after each schema the client maps the image the schema describes, says
so (``{"image": true}``: the controller then sends it no frames and computes no values
for it), and polls the image every sample on its event loop, decoding every name in this
process, at the side process's own sample (``poll_period``); the frame hook is called
when the scan advanced (at the feed's sample, the header is checked POLLS_PER_SAMPLE
times a sample; a sample this loop was too busy to see for longer than a sample is not
seen: the image holds the last one only). The image is also read at once
when a controller status comes, so that the values of that scan go with it. A client
that cannot map the image (permissions, an image left by another controller) says why in
one line and takes the frames the socket carries. ``controller_age_s`` is how long ago
the controller last wrote the image (its own CLOCK_MONOTONIC stamp): the controller's
liveness, whatever this process's event loop was doing.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

from runtime.controller.aio import within
from runtime.controller.feed import FeedState, request_line, why_request
from runtime.controller.image import ImageError, ImageReader
from runtime.errors import Loc, SoftplcError, SourceError
from runtime.language.model import PlantDef
from runtime.language.runtimedir import locate

log = logging.getLogger(__name__)
T = TypeVar("T")

#: reconnection delays to the feed, seconds (doubling)
RECONNECT_MIN_S = 0.2
RECONNECT_MAX_S = 2.0
#: the longest feed line read (a whole frame of a large plant), bytes
LINE_MAX = 64 << 20
#: how often per sample the shared image's header is checked for a new scan
POLLS_PER_SAMPLE = 4
#: how long, in samples of the feed, an applied request waits for the image that shows it
CATCH_UP_SAMPLES = 3


def poll_period(feed_s: float, own_s: float | None) -> float:
    """How often the image is polled, seconds. The controller writes it every ``feed_s``
    (the shortest sample of the plant's side processes); a side process whose own sample
    ``own_s`` is longer polls at its own: every poll then finds a later scan, and its
    names are decoded at its sample, not at another side process's (the web page's 100 ms
    beside MQTT's 10 ms). Otherwise a quarter of the feed's: a sample is seen even when
    this loop is a little late (only the header is read until the scan advances)."""
    if own_s is not None and own_s > feed_s:
        return own_s
    return max(0.001, feed_s / POLLS_PER_SAMPLE)


class ForeignFeed(SourceError):
    """The feed is another plant's (or says not whose it is: a controller older than this
    side process): not followed. At the plant's ``feed:``, or at ``--feed``."""


class FeedLost(SoftplcError, ConnectionError):
    """The feed is not connected, or its connection ended before a write was answered.

    For example: a write asked while the controller restarts."""


def _why_waiting(exc: OSError) -> str:
    """Why a connection to the feed failed, in the words of the waiting line."""
    if isinstance(exc, FileNotFoundError):
        return "not there: is the controller running?"
    if isinstance(exc, ConnectionRefusedError):
        return "nobody serves it: is the controller running?"
    return exc.strerror or str(exc)


class FeedClient:
    """Follows the feed at ``path`` for the side process ``side`` (``opcua``, ``mqtt``)."""

    def __init__(self, path: str, side: str,
                 schema: Callable[[dict[str, Any]], Awaitable[None]],
                 frame: Callable[[], Awaitable[None]],
                 lost: Callable[[], Awaitable[None]],
                 status: Callable[[], Awaitable[None]] | None = None, *,
                 plant: PlantDef,
                 alarm: Callable[[], Awaitable[None]] | None = None) -> None:
        self.path = path
        self.side = side
        #: the plant this side process serves: only its feed is followed
        self.plant = plant
        self.owner = locate(plant)
        self.state = FeedState()
        self._on_schema, self._on_frame, self._on_lost = schema, frame, lost
        self._on_status = status
        self._on_alarm = alarm
        self._writer: asyncio.StreamWriter | None = None
        self._pending: dict[int, asyncio.Future[tuple[bool, str, str]]] = {}
        self._ids = itertools.count(1)
        self._stop = asyncio.Event()
        #: the instances whose transitions it follows (asked again on each connection)
        self._why: list[str] = []
        #: the controller's shared image, while mapped, and its polling task
        self.image: ImageReader | None = None
        #: the feed's sample (the controller writes the image this often), seconds
        self._sample_s = 0.1
        self._poll: asyncio.Task[None] | None = None

    @property
    def connected(self) -> bool:
        return self._writer is not None

    async def run(self) -> None:
        """Follow the feed until ``stop()``: reconnect forever."""
        delay = RECONNECT_MIN_S
        said = ""  # the last reason for waiting said at INFO: each new one is said once
        while not self._stop.is_set():
            try:
                reader, writer = await asyncio.open_unix_connection(self.path, limit=LINE_MAX)
            except OSError as exc:
                why = _why_waiting(exc)
                if why != said:
                    log.info("waiting for the controller's feed %s (%s)", self.path, why)
                    said = why
                log.debug("feed %s: %s", self.path, exc)
                await self._wait(delay)
                delay = min(RECONNECT_MAX_S, delay * 2)
                continue
            delay = RECONNECT_MIN_S
            said = ""
            log.info("connected to the controller's feed %s", self.path)
            self._writer = writer
            # the status kept is the last connection's until this one's first comes (a
            # controller started again is not shown with the last one's state as its own)
            self.state.status_current = False
            if self._why:
                writer.write(why_request(self._why))
            try:
                await self._follow(reader)
            except (OSError, ValueError, asyncio.IncompleteReadError, KeyError,
                    IndexError, TypeError) as exc:
                log.warning("feed: %s", exc)
            finally:
                self._writer = None
                self._unmap()
                writer.close()
                for fut in self._pending.values():
                    if not fut.done():
                        fut.set_exception(FeedLost("the feed's connection ended"))
                await self._on_lost()
            if not self._stop.is_set():
                log.warning("lost the controller's feed: waiting for it to come back")
                said = _why_waiting(FileNotFoundError())  # that line says it already
                await self._wait(RECONNECT_MIN_S)

    def controller_age_s(self) -> float | None:
        """Seconds since the controller last wrote its shared image (its own monotonic
        stamp, not this process's event loop); None while no image is mapped."""
        image = self.image
        return image.age_s() if image is not None else None

    def _map(self, schema: dict[str, Any]) -> None:
        """Map the image the schema describes and say so to the controller, which then
        sends this client no frames (or say why not: frames then). Before the schema
        hook: a side process building its names for a long time (an OPC UA server's
        thousands of nodes) must not have frames pile up unread meanwhile, until the
        controller drops it for not reading."""
        self._unmap()
        if schema.get("image") is None:
            log.info("feed %s: the controller offers no shared image: values come as "
                     "frames over the socket", self.path)
            return
        try:
            self.image = ImageReader(schema)
        except ImageError as exc:
            log.warning("feed %s: %s: values come as frames over the socket instead",
                        self.path, exc)
            return
        self._sample_s = float(schema.get("sample_ms") or 100) / 1e3
        if self._writer is not None:
            self._writer.write(b'{"image":true}\n')

    def _start_polling(self, schema: dict[str, Any]) -> None:
        """Poll the mapped image (after the schema hook: its names are built)."""
        if self.image is None:
            return
        period = poll_period(float(schema.get("sample_ms") or 100) / 1e3,
                             self.own_sample_s())
        self._poll = asyncio.ensure_future(self._follow_image(self.image, period))

    def own_sample_s(self) -> float | None:
        """This side process's own ``sample`` (its section's), seconds; None if unknown."""
        ns = getattr(getattr(self.plant, self.side, None), "sample_ns", None)
        return ns / 1e9 if isinstance(ns, int) and ns > 0 else None

    def _unmap(self) -> None:
        if self._poll is not None:
            self._poll.cancel()
            self._poll = None
        if self.image is not None:
            self.image.close()
            self.image = None

    async def _follow_image(self, image: ImageReader, period: float) -> None:
        """Every ``period`` s: the image decoded into the state's values, and the frame
        hook called, when the controller wrote a later scan."""
        try:
            while True:
                await self._read_image(image)
                await asyncio.sleep(period)
        except asyncio.CancelledError:
            raise
        except Exception:  # noqa: BLE001 - said; the connection is closed and made again
            log.exception("feed %s: reading the shared image failed", self.path)
            if self._writer is not None:
                self._writer.close()

    async def _read_image(self, image: ImageReader) -> None:
        """The image decoded into the state's values and the frame hook called, if the
        controller wrote a later scan than the state has."""
        st = self.state
        stamp = image.stamp()  # the header only: cheap while the scan has not advanced
        if stamp is None or stamp[0] == st.scan or stamp[0] < 0:
            return
        got = image.read()
        if got is not None and got[0] != st.scan:
            st.scan, st.wall, st.values = got
            await self._on_frame()

    def stop(self) -> None:
        """End ``run()``: the connection is closed (a read waiting on it ends)."""
        self._stop.set()
        if self._writer is not None:
            self._writer.close()

    def follow_why(self, instances: list[str]) -> None:
        """Follow these instances' transitions (``state.whys``), on this connection and
        the next ones; ``[]`` stops."""
        if instances == self._why:
            return
        self._why = list(instances)
        if self._writer is not None:
            self._writer.write(why_request(self._why))

    async def set(self, name: str, value: Any, timeout: float) -> tuple[bool, str]:
        """Write ``name`` through the controller: its (ok, text). FeedLost if there is no
        connection or it ends first; TimeoutError after ``timeout`` seconds."""
        ok, text, _code = await self.ask("set", name, value, self.side, timeout=timeout)
        return ok, text

    async def ask(self, kind: str, *args: Any, timeout: float) -> tuple[bool, str, str]:
        """A request to the controller (``set``, ``call``, ``alarm``: runtime/controller/
        feed.py), waited for: (ok, text, OPC UA status name). FeedLost if there is no
        connection or it ends first; TimeoutError after ``timeout`` seconds."""
        writer = self._writer
        if writer is None:
            raise FeedLost("the controller's feed is not connected")
        ident = next(self._ids)
        fut: asyncio.Future[tuple[bool, str, str]] = (
            asyncio.get_running_loop().create_future())
        self._pending[ident] = fut
        try:
            writer.write(request_line(kind, ident, *args))
            answer = await within(fut, timeout)
        finally:
            self._pending.pop(ident, None)
        image = self.image
        if answer[0] and image is not None:
            await self._catch_up(image)
        return answer

    async def _catch_up(self, image: ImageReader) -> None:
        """After a request the controller applied: the first image written after the
        answer decoded (it holds what the request did), so that a read that follows a
        write shows it, not the sample before (a Modbus client reading a register it has
        just written, an OPC UA client reading back). At most CATCH_UP_SAMPLES samples of
        the feed: a controller that stopped meanwhile is the stale rule's business."""
        loop = asyncio.get_running_loop()
        stamp = image.stamp()
        seen = stamp[0] if stamp is not None else self.state.scan
        end = loop.time() + CATCH_UP_SAMPLES * self._sample_s + 0.05
        while loop.time() < end:
            stamp = image.stamp()
            if stamp is not None and stamp[0] > seen:
                break
            await asyncio.sleep(min(0.002, self._sample_s / POLLS_PER_SAMPLE))
        await self._read_image(image)

    async def run_beside(self, work: Awaitable[T]) -> T:
        """``work`` (the side process's own: its sessions, its serving) while following
        the feed, until ``work`` ends; a feed refused (ForeignFeed) ends both and is
        raised. The feed is stopped on the way out."""
        feed = asyncio.ensure_future(self.run())
        main = asyncio.ensure_future(work)
        try:
            await asyncio.wait({feed, main}, return_when=asyncio.FIRST_COMPLETED)
            if feed.done() and not feed.cancelled():
                refused = feed.exception()
                if refused is not None:
                    raise refused
            return await main
        finally:
            self.stop()
            main.cancel()
            await asyncio.gather(feed, main, return_exceptions=True)

    def _check_owner(self, schema: dict[str, Any]) -> None:
        """ForeignFeed unless the schema's plant is this side process's."""
        name, home = schema.get("name"), schema.get("home")
        me = self.owner
        if (name, home) == (me.name, me.home):
            return
        if name is None or home is None:
            why = ("the feed of a controller that does not say which plant it runs (a "
                   "softplc older than this one): not followed; restart the controller")
        else:
            why = (f"the feed of plant {name} ({home}), not of this plant {me.name} "
                   f"({me.home}): not followed; give {self.side}: feed a path of its own "
                   "(or leave it out: the default is the plant's own)")
        section = getattr(self.plant, self.side, None)
        if section is not None and section.feed == self.path:
            loc = section.feed_loc or section.loc or Loc(self.plant.path, 1, 1)
            raise ForeignFeed(loc, f"{self.side} feed: {self.path} is {why}")
        raise ForeignFeed(Loc("--feed", 1, 1), f"{self.path} is {why}")

    async def _wait(self, seconds: float) -> None:
        try:
            await within(self._stop.wait(), seconds)
        except TimeoutError:
            pass

    async def _follow(self, reader: asyncio.StreamReader) -> None:
        st = self.state
        while not self._stop.is_set():
            line = await reader.readline()
            if not line.endswith(b"\n"):
                # the end: a last line cut short (the controller dropped this client for
                # reading too slowly, or stopped) is not decoded
                return
            kind = st.apply(line)
            if kind == "schema":
                self._unmap()  # the old layout's values must not follow the new names
                self._check_owner(st.schema)
                self._map(st.schema)
                await self._on_schema(st.schema)
                self._start_polling(st.schema)
            elif kind == "frame":
                await self._on_frame()
            elif kind == "status":
                if self._on_status is not None:
                    await self._on_status()
                if self.image is not None:
                    # the image of the scan this status goes with (written before it was
                    # sent): values and status shown together, not a poll period apart
                    await self._read_image(self.image)
            elif kind == "alarm":
                if self._on_alarm is not None:
                    await self._on_alarm()
            elif kind == "reply":
                ident, ok, text, code = json.loads(line)["r"]
                fut = self._pending.get(int(ident))
                if fut is not None and not fut.done():
                    fut.set_result((bool(ok), str(text), str(code)))
