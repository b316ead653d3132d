"""The console's pure parts, without a daemon: the line framer, the editing keys, the
command table, and the rounding of time literals in engine messages."""

from __future__ import annotations

from runtime.console.commands import COMMANDS, round_times
from runtime.console.protocol import (
    CHANGING,
    HELP,
    MAX_LINE,
    PARTIAL_LINE_TIMEOUT_S,
    READ_ONLY,
    LineEvent,
    LineFramer,
    apply_editing_keys,
)


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def framer() -> tuple[LineFramer, Clock]:
    clock = Clock()
    return LineFramer("test", clock), clock


def test_lines_end_at_cr_lf_or_crlf_even_split_across_chunks() -> None:
    f, _ = framer()
    assert f.feed(b"a\rb\nc\r\nd") == [b"a", b"b", b"c"]
    assert f.pending == b"d"
    assert f.feed(b"\r") == [b"d"]
    assert f.feed(b"\ne\n") == [b"e"]  # the LF of the CR of the chunk before
    assert f.feed(b"\n") == [b""]  # an LF alone is an (empty) line
    assert f.feed(b"") == []


def test_ctrl_c_drops_the_half_line() -> None:
    f, _ = framer()
    assert f.feed(b"force x 1\x03get y\n") == [LineEvent.INTERRUPT, b"get y"]


def test_an_overlong_line_is_dropped_whole_when_it_ends() -> None:
    f, _ = framer()
    assert f.feed(b"x" * MAX_LINE) == []
    assert f.feed(b"y") == []
    assert f.pending == b""
    assert f.feed(b"zz\nok\n") == [LineEvent.OVERLONG, b"ok"]
    assert f.feed(b"x" * MAX_LINE + b"\n") == [b"x" * MAX_LINE]


def test_a_half_line_is_dropped_after_its_timeout() -> None:
    f, clock = framer()
    f.feed(b"force x 1")
    clock.t += PARTIAL_LINE_TIMEOUT_S + 1
    assert f.feed(b"status\n") == [b"status"]
    f.feed(b"get ")
    clock.t += PARTIAL_LINE_TIMEOUT_S - 1
    assert f.feed(b"y\n") == [b"get y"]


def test_editing_keys() -> None:
    assert apply_editing_keys("gex\bt y") == "get y"
    assert apply_editing_keys("\x7fab\x7f\x7f\x7fc") == "c"
    assert apply_editing_keys("junk\x15status") == "status"
    assert apply_editing_keys("plain") == "plain"


def test_every_command_has_a_function_and_a_help_line() -> None:
    assert set(READ_ONLY).isdisjoint(CHANGING)
    assert set(COMMANDS) == set(READ_ONLY) | set(CHANGING) == set(HELP)


def test_time_literals_in_messages_are_rounded_to_ms() -> None:
    assert round_times("1s234ms567us") == "1s235ms"
    assert round_times("waits 2s600us more; 10s left") == "waits 2s1ms more; 10s left"
    assert round_times("499us") == "0s"
    # not literals: units out of order, inside a word, a plain number
    assert round_times("1ms2s x1s 42") == "1ms2s x1s 42"
