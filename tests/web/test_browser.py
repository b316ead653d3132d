"""The journeys of docs/web.md in a real browser (Debian's chromium, driven by playwright)
against ``softplc run`` and ``softplc web`` as two real processes on the drawer tester: a
step becoming active shows within 2 samples; a force set from the page reaches the output;
closing the page ends in the console's safe reaction; a wrong login is refused. The
screenshots of docs/web.md are taken here: into the test's own directory, or into the
directory ``SOFTPLC_PICTURES`` names (scripts/make-pictures.sh sets docs/img); a test run
never writes into the source tree by itself."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from tests.opcua.feedkit import wait_until
from tests.web.kit import PASSWORD, SAMPLE_MS, USER, Rig, browser, rig


def picture(tmp_path: Path, name: str) -> str:
    """Where the screenshot ``name`` goes: SOFTPLC_PICTURES if set, else ``tmp_path``."""
    where = os.environ.get("SOFTPLC_PICTURES")
    return str((Path(where) if where else tmp_path) / name)


def open_page(b: Any, r: Rig) -> Any:
    page = b.new_page(viewport={"width": 1400, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.errors = errors
    page.goto(r.url)
    page.wait_for_selector("body[data-link=live]", timeout=30_000)
    page.wait_for_selector("#inst-tester1 g.step-group[data-step=gsParado].active",
                           timeout=30_000)
    return page


def log_in(page: Any, password: str = PASSWORD) -> None:
    page.fill("#user", USER)
    page.fill("#password", password)
    page.click("#login button")


def test_a_step_becoming_active_shows_within_two_samples(tmp_path: Path) -> None:
    with rig(tmp_path) as r, browser() as b:
        page = open_page(b, r)
        step = "#inst-tester1 g.step-group[data-step=gsAbrir]"
        assert not page.locator(step).evaluate("e => e.classList.contains('active')")
        r.console("set sim.I0 1", "set sim.I1 1")  # stop released, start pressed
        page.wait_for_selector(step + ".active", timeout=30_000)
        shown = int(page.locator(step).get_attribute("data-shown-scan"))
        # when the step became active in the controller: the first frame that carries
        # it, less the step's own time in it (.T) at that frame
        k = r.feed.state.index["tester1.gsAbrir.X"]
        kt = r.feed.state.index["tester1.gsAbrir.T"]
        first = next(f for f in r.feed.frames if f[2][k])
        cycle_ns = 10_000_000
        activated = first[0] - first[2][kt] // cycle_ns
        sample_scans = SAMPLE_MS // 10
        assert shown - activated <= 2 * sample_scans, (activated, first[0], shown)
        # the console's why of the new step is listed (it follows every WHY_EVERY_NS, in
        # turn per instance: it may come a few samples after the step), and the
        # transition it waits on is marked
        page.wait_for_selector("#inst-tester1 ul.why li:has-text('gsAbrir')", timeout=10_000)
        page.wait_for_selector("#inst-tester1 g.transition-group.blocking", timeout=10_000)
        page.screenshot(path=picture(tmp_path, "web-page.png"), full_page=False)
        assert page.errors == []


#: in the page: the frame says tester1 left gsParado for gsAbrir while the why it holds is
#: still gsParado's (the why follows the frames by up to WHY_EVERY_NS); the page drawn;
#: what it then lists and marks
_WHY_OF_A_LEFT_STEP = """() => {
  S.values[S.index.get("tester1.gsParado.X")] = false;
  S.values[S.index.get("tester1.gsAbrir.X")] = true;
  S.dirty = true;
  render();
  const box = document.getElementById("inst-tester1");
  return [box.querySelector("ul.why").innerText,
          box.querySelectorAll("g.transition-group.blocking, g.transition-group.true").length];
}"""


def test_the_why_of_a_step_no_longer_active_is_not_shown(tmp_path: Path) -> None:
    """The transitions' why comes after the frames (explained every WHY_EVERY_NS, in the
    feed thread): a frame in which the step has gone must not show the why of that step
    beside it (nor mark its transitions), as if the chart still waited there."""
    with rig(tmp_path) as r, browser() as b:
        page = open_page(b, r)
        page.wait_for_selector("#inst-tester1 ul.why li:has-text('gsParado')", timeout=10_000)
        page.wait_for_selector("#inst-tester1 g.transition-group.blocking", timeout=10_000)
        listed, marked = page.evaluate(_WHY_OF_A_LEFT_STEP)
        assert "gsParado" not in listed
        assert marked == 0
        assert page.errors == []


def test_a_wrong_login_is_refused(tmp_path: Path) -> None:
    with rig(tmp_path) as r, browser() as b:
        page = open_page(b, r)
        log_in(page, "not-the-password")
        page.wait_for_selector("#login-error:has-text('wrong user or password')",
                               timeout=10_000)
        assert page.locator("#who").is_hidden()
        assert all(c["name"] != "softplc_session" for c in page.context.cookies())
        # the page's own socket may not act either: the server refuses it
        page.evaluate("() => { S.ws.send(JSON.stringify({act: [1, 'pause']})); }")
        page.wait_for_selector("#events li:has-text('log in to act')", timeout=10_000)
        assert r.status()["state"] == "running"
        assert "login of 'op' from 127.0.0.1 refused" in r.web.log()


def test_a_force_from_the_page_reaches_the_output_and_closing_the_page_is_safe(
        tmp_path: Path) -> None:
    with rig(tmp_path) as r, browser() as b:
        page = open_page(b, r)
        log_in(page)
        page.wait_for_selector("#who:not([hidden])", timeout=30_000)
        page.wait_for_selector("body[data-link=live]", timeout=30_000)
        cookie = next(c for c in page.context.cookies() if c["name"] == "softplc_session")
        assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
        row = '#inst-tester1 tr[data-name="tester1.oTest"]'
        page.click(row + ' button[data-force="1"]')
        wait_until(lambda: r.value("sim.Q3") is True, 30.0, "sim.Q3 forced on")
        page.wait_for_selector(row + ".forced", timeout=10_000)
        assert "tester1.oTest" in r.status()["forced"]
        page.screenshot(path=picture(tmp_path, "web-forced.png"), full_page=False)
        page.close()  # the page closed while it held a force
        wait_until(lambda: r.status().get("state") == "halted", 30.0, "the safe reaction")
        outputs = [f"sim.Q{i}" for i in range(8)]
        try:
            wait_until(lambda: not any(r.value(q) for q in outputs), 10.0, "outputs off")
        except AssertionError:
            raise AssertionError({q: r.value(q) for q in outputs}) from None
        assert r.status()["forced"] == []
        log = r.ctl.log()
        assert "web:op@127.0.0.1" in log and "while it held: force tester1.oTest" in log, log
        time.sleep(0)  # nothing else: the halt waits for a person's ack


#: the boxes (x, y, width, height) of the elements a selector finds, in page pixels
BOXES = """(sel) => [...document.querySelectorAll(sel)].filter((e) => {
  const r = e.getBoundingClientRect(); return r.width > 0 && r.height > 0;
}).map((e) => { const r = e.getBoundingClientRect(); return [r.x, r.y, r.width, r.height,
  e.textContent]; })"""


def _meet(a: list[Any], b: list[Any]) -> bool:
    return (a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3]
            and b[1] < a[1] + a[3])


def test_the_step_time_and_the_io_list_headers_are_legible(tmp_path: Path) -> None:
    """An active step's time stands clear of its action box and of every other text of
    the drawing (it was drawn over the action box); every header cell of the I/O list
    says what its column is (two were empty), one per column shown."""
    with rig(tmp_path) as r, browser() as b:
        page = open_page(b, r)
        r.console("set sim.I0 1", "set sim.I1 1")  # tester1 opens its drawer: gsAbrir
        step = "#inst-tester1 g.step-group[data-step=gsAbrir]"
        page.wait_for_selector(step + ".active", timeout=30_000)
        page.wait_for_function(f"() => document.querySelector('{step} .live-t')"
                               ".textContent.endsWith(' s')", timeout=30_000)
        (label,) = page.evaluate(BOXES, f"{step} .live-t")
        others = page.evaluate(BOXES, "#inst-tester1 svg text, #inst-tester1 svg rect")
        hit = [o for o in others if o[4] != label[4] and _meet(label, o)
               and not (o[0] <= label[0] and o[1] <= label[1]  # the frame holding it
                        and label[0] + label[2] <= o[0] + o[2]
                        and label[1] + label[3] <= o[1] + o[3])]
        assert hit == [], (label, hit)
        for acting in (False, True):
            heads = page.evaluate(BOXES, "#inst-tester1 table.io th")
            cells = page.evaluate(BOXES, '#inst-tester1 table.io tr[data-name="tester1.oTest"] td')
            assert all(h[4].strip() for h in heads), [h[4] for h in heads]
            assert len(heads) == len(cells), ([h[4] for h in heads], len(cells))
            if not acting:
                log_in(page)
                page.wait_for_selector("#who:not([hidden])", timeout=30_000)
                page.wait_for_selector("body[data-link=live]", timeout=30_000)
        assert page.errors == []
