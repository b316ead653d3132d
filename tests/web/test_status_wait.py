"""The controller's status on the page: a page is never sent a status the controller has
not given on this connection. Frames can come before the first status (from the shared
image, or a status held back from a client behind); a page then showed "state undefined"
(an empty status), and after a reconnection the last controller's state."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from runtime.language.plantfile import load_plant
from runtime.web.server import Page, WebView
from tests.opcua.feedkit import HeldStatusFeed, until
from tests.web.kit import write_plant


def test_a_page_gets_only_this_connections_statuses(tmp_path: Path) -> None:
    """A real controller's lines (its schema without the image: the frames come as
    lines), played again by a feed in this test that holds its statuses, to the web
    view's real feed client; what the view sends its page is kept."""
    pdef = load_plant(str(write_plant(tmp_path)))
    path = str(tmp_path / "played.sock")
    played = HeldStatusFeed(pdef, path)
    view = WebView(pdef, feed=path)
    sent: list[dict[str, Any]] = []
    view._send = lambda page, text, keep=False: sent.append(  # type: ignore[method-assign]
        json.loads(text))

    def statuses() -> list[Any]:
        return [m["status"] for m in sent if m["t"] == "s"]

    async def main() -> None:
        view.pages.add(Page(ws=None, address="test", login=None))  # type: ignore[arg-type]
        follow = asyncio.ensure_future(view.feed.run())
        try:
            await until(lambda: view.frames >= 1, what="the first frame")
            view._hello(next(iter(view.pages)))  # a page opened now
            assert [m["t"] for m in sent if m["t"] in ("f", "s")] == ["f", "f"], sent
            played.steps[0].set()
            await until(lambda: view.frames >= 2, what="the frame after the status")
            assert [s["state"] for s in statuses()] == ["running"], statuses()
            del sent[:]
            played.steps[1].set()  # the connection ends; the view connects again
            await until(lambda: view.frames >= 3, what="the new connection's first frame")
            assert [m["t"] for m in sent] == ["lost", "schema", "w", "f"], sent
            played.steps[2].set()
            await until(lambda: view.frames >= 4, what="the frame after the new status")
            assert [s["state"] for s in statuses()] == ["running"], statuses()
        finally:
            view.feed.stop()
            follow.cancel()
            await asyncio.gather(follow, return_exceptions=True)

    try:
        asyncio.run(main())
    finally:
        played.close()
