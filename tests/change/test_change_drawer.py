"""Online change on the drawer story, exact to the scan: a change applied between scans k-1
and k gives, from scan k on, the trace of the new chart started from the carried state
(written by hand, not by ``apply``)."""

from __future__ import annotations

import pytest

from runtime.change.plan import apply, prepare
from tests.change.changekit import (
    DRAWER_PLANT,
    Story,
    data_plant,
    sim_plant,
    state,
    version,
    write_state,
)

#: scans of the drawer story (17.5 s at 10 ms)
END = 1750


def swapped(edit: str, k: int) -> tuple[list[dict], list[dict], list[dict]]:
    """(rows of the changed run from k on, rows of the expected run, rows of the old chart
    going on unchanged), the change applied after scan k-1 of the story."""
    story = Story(sim_plant(DRAWER_PLANT))
    story.run(k)
    old = story.plant
    # the expected run: the new chart, its state written by hand from the old plant
    expected = Story(sim_plant(data_plant(edit)))
    write_state(old, expected.plant)
    expected.k = k
    # the old chart going on, for the proof that the change matters
    same = Story(sim_plant(DRAWER_PLANT))
    write_state(old, same.plant)
    same.k = k
    prep = prepare(old, version(data_plant(edit), old))
    before = state(old)
    res = apply(old, prep)
    assert res.refusals == []
    assert state(old) == before  # the old plant is only read
    assert state(prep.plant) == state(expected.plant)
    story.bind(prep.plant)
    return story.run(END - k), expected.run(END - k), same.run(END - k)


def first_difference(a: list[dict], b: list[dict]) -> tuple[int, str] | None:
    for ra, rb in zip(a, b, strict=True):
        for key in ra:
            if ra[key] != rb[key]:
                return ra["k"], key
    return None


def test_a_timeout_change_applied_while_the_step_runs_keeps_its_time():
    """tester1 is in gsAbrir since 3500 ms (the drawer jams); at 4000 ms the opening
    time-out drops from 10 s to 4 s: gsAveria at 7500 ms, gsAbrir.T counted from 3500 ms."""
    got, want, old = swapped("timeout", 400)
    assert first_difference(got, want) is None
    k = next(r["k"] for r in got if r["tester1.gsAveria.X"])
    assert k == 750
    assert next(r["k"] for r in old if r["tester1.gsAveria.X"]) == 1350
    assert got[0]["tester1.sCierres"] == 4  # the count goes on


def test_an_action_change_lights_the_pilot_from_the_carried_failure():
    """tester2 is in gsAveria (12500-13000 ms); the new action oTest there acts from the
    swap scan on, since the carried situation has gsAveria active."""
    got, want, old = swapped("action", 1270)
    assert first_difference(got, want) is None
    assert got[0]["tester2.gsAveria.X"] and got[0]["tester2.oTest"]
    assert not old[0]["tester2.oTest"]


def test_a_new_step_on_an_inactive_branch():
    got, want, old = swapped("new_step", 400)
    assert first_difference(got, want) is None
    # tester2 acknowledges at 13000 ms and releases at 13100 ms: now through gsRearme
    at = {r["k"]: r for r in got}
    assert at[1300]["tester2.gsRearme.X"] and not at[1300]["tester2.gsParado.X"]
    assert at[1310]["tester2.gsParado.X"]
    assert {r["k"]: r for r in old}[1300]["tester2.gsParado.X"]  # the old chart: no wait


@pytest.mark.parametrize("edit", ["timeout", "action", "new_step"])
def test_the_swap_scan_itself_is_exact(edit):
    """Scan by scan from the very first scan after the swap, at a few points of the story."""
    for k in (1, 255, 1299):
        got, want, _ = swapped(edit, k)
        assert first_difference(got[:60], want[:60]) is None
