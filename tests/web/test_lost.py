"""What the page shows while it has no controller (docs/web.md, "When the link is
lost"), in a real browser against ``softplc run`` and ``softplc web`` as two real
processes: the controller killed, the page must not go on saying "running" and showing
the last values as if they were the plant's; they stay, greyed, and the state is
"unknown" until a controller says its own. Then the same when the web view itself goes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tests.web.kit import browser, rig, start, stop
from tests.web.test_browser import open_page

#: what the page shows of the controller and of tester1: the state badge's text and
#: class, the body's data-state, the fault, the colour of a value of the I/O list and the
#: fill of the active step
SHOWN = """() => {
  const b = document.getElementById("state");
  const v = document.querySelector('#inst-tester1 tr[data-name="tester1.oParado"] td.value');
  const s = document.querySelector("#inst-tester1 g.step-group.active rect");
  return {state: b.textContent, cls: b.className, data: document.body.dataset.state,
          fault: document.getElementById("fault").textContent,
          value: v.textContent, colour: getComputedStyle(v).color,
          fill: s ? getComputedStyle(s).fill : null};
}"""
#: the colour of what is not current (app.css: the link lost), and of an active step then
STALE = "rgb(158, 158, 158)"
STALE_FILL = "rgb(224, 224, 224)"


def _current(shown: dict[str, Any]) -> bool:
    return shown["colour"] != STALE and shown["fill"] not in (None, STALE_FILL)


def test_a_page_without_its_controller_says_so_and_greys_the_last_values(
        tmp_path: Path) -> None:
    with rig(tmp_path) as r, browser() as b:
        page = open_page(b, r)
        page.wait_for_selector("#state.running", timeout=30_000)
        live = page.evaluate(SHOWN)
        assert live["state"] == "running" and _current(live), live

        r.ctl.popen.kill()  # the controller's process ends at once (a crash, a power cut)
        r.ctl.popen.wait()
        page.wait_for_selector("body[data-link=lost]", timeout=30_000)
        lost = page.evaluate(SHOWN)
        assert lost["state"] == "unknown" and lost["data"] == "unknown", lost
        assert "running" not in lost["cls"] and lost["fault"] == "", lost
        # the last values are still there to read, greyed: not current
        assert lost["value"] == live["value"], (live, lost)
        assert lost["colour"] == STALE and lost["fill"] == STALE_FILL, lost

        again = start(tmp_path, "run", str(r.plant), "--sim")  # a controller again
        try:
            page.wait_for_selector("body[data-link=live]", timeout=60_000)
            page.wait_for_selector("#state.running", timeout=30_000)
            back = page.evaluate(SHOWN)
            assert _current(back), back

            r.web.popen.kill()  # now the web view goes: the page loses its socket
            r.web.popen.wait()
            page.wait_for_selector("body[data-link=lost]", timeout=30_000)
            gone = page.evaluate(SHOWN)
            assert gone["state"] == "unknown" and gone["colour"] == STALE, gone
            assert page.errors == []
        finally:
            stop(again)
