"""``softplc compile`` and ``softplc check`` run with the cyclic garbage collector off (a
batch process; cli.BATCH_COMMANDS), other commands with it on; a caller that runs ``main``
in its own process gets its collector back as it was."""

from __future__ import annotations

import gc
from collections.abc import Sequence

import pytest

from runtime import cli


@pytest.fixture
def seen(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Whether the collector was on while each command ran."""
    out: list[bool] = []

    def run(argv: Sequence[str]) -> int:
        out.append(gc.isenabled())
        return 0

    monkeypatch.setattr(cli, "_main", run)
    return out


@pytest.mark.parametrize("argv", [["compile", "a.yaml"], ["-v", "check", "a.yaml", "b.yaml"]])
def test_a_batch_command_runs_without_the_collector(argv: list[str], seen: list[bool]) -> None:
    assert gc.isenabled()
    assert cli.main(argv) == 0
    assert seen == [False]
    assert gc.isenabled()  # the caller's collector as it was


@pytest.mark.parametrize("argv", [["simulate", "p.yaml", "s.yaml"], ["iolist", "p.yaml"]])
def test_other_commands_keep_the_collector(argv: list[str], seen: list[bool]) -> None:
    assert cli.main(argv) == 0
    assert seen == [True]


def test_a_collector_off_before_stays_off(seen: list[bool]) -> None:
    gc.disable()
    try:
        cli.main(["compile", "a.yaml"])
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_the_real_compile_command_gives_the_collector_back(
        drawer: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["compile", drawer]) == 0
    assert "compiled in" in capsys.readouterr().err
    assert gc.isenabled()
