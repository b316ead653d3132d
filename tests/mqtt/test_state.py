"""The primary host's STATE as the edge node reads it (runtime/mqtt/session.py), on a
virtual clock: the newest STATE of a session rules, a STATE stamped more than
STATE_AHEAD_MAX_MS ahead of the node's clock is refused with one line and taken once the
clock has caught up. (A new session reading its broker's STATE afresh is tested with two
brokers in test_attacks.py.)"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from runtime.controller.logsetup import RateLimit
from runtime.language.plantfile import load_plant
from runtime.mqtt.session import STATE_AHEAD_MAX_MS, EdgeSession, SessionEnded
from tests.mqtt.kit import write_plant

NOW_MS = 1_800_000_000_000


def state(online: bool, ts: object) -> bytes:
    return json.dumps({"online": online, "timestamp": ts}).encode()


def session(tmp_path: Path) -> tuple[EdgeSession, list[float]]:
    """An edge session whose primary host is SCADA and whose node's clock is ``clock[0]``
    (seconds), connected and waiting for the host (no network here)."""
    plant = write_plant(tmp_path, ["mqtt://127.0.0.1:1883"], mqtt="  primary_host: SCADA\n")
    es = EdgeSession(load_plant(str(plant)))
    clock = [NOW_MS / 1000]
    es.node.clock = lambda: clock[0]
    es.host_online = False
    return es, clock


def test_a_state_from_the_far_future_is_refused_until_the_clock_catches_up(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    es, clock = session(tmp_path)
    caplog.set_level(logging.WARNING, "runtime.mqtt.session")
    es._state(state(True, 1 << 62))
    assert not es.host_online
    assert [r.getMessage() for r in caplog.records] == [
        "mqtt: STATE of SCADA ignored: its timestamp 4611686018427387904 is 1.46e+08 "
        "years ahead of this machine's clock (at most 60 s; are both clocks set?)"]
    # the host's own STATE is taken: the forged one did not make it look older
    es._state(state(True, NOW_MS))
    assert es.host_online
    with pytest.raises(SessionEnded, match="went offline"):
        es._state(state(False, NOW_MS + 1))
    # within the bound: taken
    es._state(state(True, NOW_MS + STATE_AHEAD_MAX_MS))
    assert es.host_online


def test_a_refused_state_is_taken_once_this_clock_is_set(tmp_path: Path,
                                                         caplog: pytest.LogCaptureFixture
                                                         ) -> None:
    """A node whose clock is behind (a Raspberry Pi before NTP) refuses the host's STATE,
    then takes it when its clock is set (the session looks at it again, ``again``)."""
    es, clock = session(tmp_path)
    caplog.set_level(logging.WARNING, "runtime.mqtt.session")
    clock[0] -= 3600  # an hour behind
    es._state(state(True, NOW_MS))
    assert not es.host_online and es._state_ahead is not None
    es._state(es._state_ahead, again=True)  # still behind: no second line
    assert len(caplog.records) == 1 and not es.host_online
    clock[0] += 3600  # set by NTP
    es._state(es._state_ahead, again=True)
    assert es.host_online and es._state_ahead is None


def test_an_older_state_is_ignored_and_a_timestamp_must_be_an_integer(
        tmp_path: Path) -> None:
    es, _clock = session(tmp_path)
    es._state(state(True, True))  # JSON true is no timestamp (Python's bool is an int)
    assert not es.host_online
    es._state(state(True, NOW_MS))
    es._state(state(False, NOW_MS - 5))  # a Will of an older connection of the host
    assert es.host_online


def test_a_flood_of_forged_states_is_a_few_lines(tmp_path: Path) -> None:
    """Each forged STATE carries its own timestamp: the line's template is fixed, so the
    log's rate limit (5 lines of a template in 10 s) holds back a flood of them."""
    es, _clock = session(tmp_path)
    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())
    keep = Keep()
    keep.addFilter(RateLimit())
    logger = logging.getLogger("runtime.mqtt.session")
    logger.addHandler(keep)
    try:
        for k in range(1000):
            es._state(state(k % 2 == 0, (1 << 62) + k))
    finally:
        logger.removeHandler(keep)
    assert len(lines) == 5 and not es.host_online, lines
