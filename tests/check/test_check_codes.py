"""``softplc check``: one small chart per diagnostic code that triggers it, and a near miss
that must not."""

from __future__ import annotations

import textwrap
from collections.abc import Callable

import pytest

from runtime.checker.check import check_files, exit_status
from runtime.checker.diag import Diag

HEAD = """\
grafcet: T
inputs: [iA, iB, iC, iD, iW]
outputs: [oX, oY]
memory: {sN: 0, sFlag: false}
"""


def chart(body: str, head: str = HEAD) -> str:
    return head + textwrap.dedent(body)


def run(write: Callable[[str, str], str], text: str, name: str = "chart.yaml") -> list[Diag]:
    path = write(name, text)
    (res,) = check_files([path])[:1]
    assert res.failure is None, res.failure
    return res.diags


def codes(diags: list[Diag]) -> list[str]:
    return [d.code for d in diags]


# (code, chart that triggers it, line of the first diagnostic, near miss)
CASES: dict[str, tuple[str, int, str]] = {
    "G101": (
        """\
        steps:
          gsA: {}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """, 5,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G102": (
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsC, to: gsA, when: iC}
        """, 8,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsC, when: iB}
          - {from: gsC, to: gsA, when: iC}
        """),
    "G103": (
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsB, when: iC}
          - {from: gsB, to: gsA, when: iB}
        """, 10,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G104": (  # AND divergence closed by an OR convergence
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
          gsD: {}
        transitions:
          - {from: gsA, to: [gsB, gsC], when: iA}
          - {from: gsB, to: gsD, when: iB}
          - {from: gsC, to: gsD, when: iC}
          - {from: gsD, to: gsA, when: iD}
        """, 12,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
          gsD: {}
        transitions:
          - {from: gsA, to: [gsB, gsC], when: iA}
          - {from: [gsB, gsC], to: gsD, when: "1"}
          - {from: gsD, to: gsA, when: iD}
        """),
    "G105": (
        """\
        steps:
          gsA: {initial: true, actions: ["P1 oX"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """, 6,
        """\
        steps:
          gsA: {initial: true, actions: ["P1 sFlag := 1", "P oX", "on ↑iC do sN := sN + 1"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G106": (
        """\
        steps:
          gsA: {initial: true, actions: ["N oX if ↑iC"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """, 6,
        """\
        steps:
          gsA: {initial: true, actions: ["N oX if iC"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G201": (
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsA, to: gsC, when: iB}
          - {from: gsB, to: gsA, when: iC}
          - {from: gsC, to: gsA, when: iC}
        """, 11,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsA, to: gsC, when: "iA'·iB"}
          - {from: gsB, to: gsA, when: iC}
          - {from: gsC, to: gsA, when: iC}
        """),
    "G202": (
        """\
        steps:
          gsA: {initial: true, actions: ["L 0s oX"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """, 6,
        """\
        steps:
          gsA: {initial: true, actions: ["L 2s oX"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G203": (  # the two branches loop on their own and never meet
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsB2: {}
          gsC: {}
          gsC2: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsA, to: gsC, when: "iA'"}
          - {from: gsB, to: gsB2, when: iB}
          - {from: gsB2, to: gsB, when: "iB'"}
          - {from: gsC, to: gsC2, when: iC}
          - {from: gsC2, to: gsC, when: "iC'"}
        """, 6,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsA, to: gsC, when: "iA'"}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsC, to: gsA, when: iC}
        """),
    "G204": (
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsC, when: iA}
          - {from: gsC, to: gsA, when: iB}
        """, 11,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: ↑iA}
          - {from: gsB, to: gsC, when: ↑iA}
          - {from: gsC, to: gsA, when: iB}
        """),
    "G205": (
        """\
        steps:
          gsA: {initial: true, actions: ["N sN := sN + 1"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """, 6,
        """\
        steps:
          gsA: {initial: true, actions: ["P1 sN := sN + 1", "N sN := sN + ↑iC",
                                         "N IF ↑iD THEN sN := sN + 1; END_IF"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G206": (
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsStop: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsA, to: gsStop, when: "iA'·iW"}
        """, 12,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsStop: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsA, to: gsStop, when: "iA'·iW"}
          - {from: gsStop, to: gsA, when: iD}
        """),
    "G207": (
        """\
        pre:
          - tFin := iA + sN >= 10
        steps:
          gsA: {initial: true, actions: ["P1 sN := sN + 1"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: tFin}
          - {from: gsB, to: gsA, when: iB}
        """, 6,
        """\
        pre:
          - tFin := iA + (sN >= 10)
          - tDos := (iA + iB + iC) >= 2
        steps:
          gsA: {initial: true, actions: ["P1 sN := sN + 1"]}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: tFin + tDos}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G208": (
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsB, to: gsA, when: "iC·iC'"}
        """, 11,
        """\
        steps:
          gsA: {initial: true}
          gsB: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: "iB·iC'"}
        """),
    "G210": (  # S with no R anywhere: latched for good
        """\
        steps:
          gsA: {initial: true}
          gsB: {actions: ["S oX"]}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """, 7,
        """\
        steps:
          gsA: {initial: true, actions: ["R oX"]}
          gsB: {actions: ["S oX"]}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """),
    "G211": (  # the star-delta start: the star step's own timer, read under scan: stable
        """\
        scan: stable
        timers: [timeStar]
        steps:
          gsOff: {initial: true}
          gsStar: {actions: [oX, "P1 timeStar.Ini(3s)"]}
          gsDelta: {actions: [oY]}
        transitions:
          - {from: gsOff, to: gsStar, when: ↑iA}
          - {from: gsStar, to: gsDelta, when: timeStar.End()}
          - {from: gsDelta, to: gsOff, when: iB}
        """, 13,
        """\
        scan: stable
        steps:
          gsOff: {initial: true}
          gsStar: {actions: [oX]}
          gsDelta: {actions: [oY]}
        transitions:
          - {from: gsOff, to: gsStar, when: ↑iA}
          - {from: gsStar, to: gsDelta, when: gsStar.T >= 3s}
          - {from: gsDelta, to: gsOff, when: iB}
        """),
}

ERRORS = {"G101", "G102", "G103", "G104", "G105", "G106"}


@pytest.mark.parametrize("code", sorted(CASES))
def test_triggers(write: Callable[[str, str], str], code: str) -> None:
    text, line, _ = CASES[code]
    diags = run(write, chart(text))
    mine = [d for d in diags if d.code == code]
    assert mine, f"{code} not reported; got {[str(d) for d in diags]}"
    assert mine[0].line == line, str(mine[0])
    assert mine[0].severity == ("error" if code in ERRORS else "warning")
    assert str(mine[0]).startswith(f"{mine[0].file}:{line}:")
    assert f": {mine[0].severity} {code}: " in str(mine[0])


@pytest.mark.parametrize("code", sorted(CASES))
def test_near_miss(write: Callable[[str, str], str], code: str) -> None:
    _, _, text = CASES[code]
    diags = run(write, chart(text))
    assert code not in codes(diags), [str(d) for d in diags]
    assert not [d for d in diags if d.severity == "error"], [str(d) for d in diags]


# -- details of some codes --------------------------------------------------------------
def test_g101_g105_g106_all_reported_and_checks_go_on(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {actions: ["P1 oX", "on ↑iA do oY", "N oX if ↑iB", "N sN := sN + 1"]}
          gsB: {actions: ["P0 oY"]}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
        """))
    assert codes(diags).count("G105") == 3
    assert codes(diags).count("G106") == 1
    assert codes(diags).count("G101") == 1
    assert "G205" in codes(diags)  # the rest of the chart was still checked
    assert "G102" not in codes(diags)  # no reachability without an initial step


def test_g102_and_convergence_never_enabled(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
          gsD: {}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsA, to: gsC, when: "iA'"}
          - {from: [gsB, gsC], to: gsD, when: "1"}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsC, to: gsA, when: iB}
          - {from: gsD, to: gsA, when: iB}
        """))
    g102 = [d for d in diags if d.code == "G102"]
    assert len(g102) == 1 and "'gsD'" in g102[0].message
    assert "never active together" in g102[0].message


def test_g102_macro_step(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsM:
            macro:
              steps:
                eIn: {entry: true}
                eOut: {exit: true}
              transitions:
                - {from: eIn, to: eOut, when: iC}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
          - {from: gsM, to: gsA, when: iD}
        """))
    g102 = [d for d in diags if d.code == "G102"]
    assert [d.message.split("'")[1] for d in g102] == ["gsM"]


def test_g104_reports_firing_sequence(write: Callable[[str, str], str]) -> None:
    text, _, _ = CASES["G104"]
    diags = run(write, chart(text))
    (d,) = [d for d in diags if d.code == "G104"]
    assert "{gsA} -[" in d.message and "{gsB, gsC}" in d.message and "gsD" in d.message


def test_g104_already_active_and_simple_sequence(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true}
          gsB: {initial: true}
          gsC: {}
        transitions:
          - {from: gsA, to: gsC, when: iA}
          - {from: gsC, to: gsB, when: iB}
          - {from: gsB, to: gsA, when: iC}
        """))
    assert "G104" in codes(diags)
    msg = " ".join(d.message for d in diags if d.code == "G104")
    assert "one simple sequence" in msg


def test_g104_source_transition_reactivating_is_fine(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsAlarma: {actions: [oY]}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: iB}
          - {from: [], to: gsAlarma, when: ↑iW}
          - {from: gsAlarma, to: [], when: iD}
        """))
    assert not [d for d in diags if d.severity == "error"], [str(d) for d in diags]


def test_g201_witness_and_exclusive_comparisons(write: Callable[[str, str], str]) -> None:
    text, _, _ = CASES["G201"]
    (d,) = [d for d in run(write, chart(text)) if d.code == "G201"]
    assert "iA=1" in d.message and "iB=1" in d.message
    diags = run(write, chart("""\
        pre:
          - tLleno := sN >= 10
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
          gsD: {}
        transitions:
          - {from: gsA, to: gsB, when: tLleno}
          - {from: gsA, to: gsC, when: "(sN < 10)·↑iA"}
          - {from: gsA, to: gsD, when: "(sN < 10)·iA'"}
          - {from: gsB, to: gsA, when: ↑iB}
          - {from: gsC, to: gsA, when: iB}
          - {from: gsD, to: gsA, when: iB}
        """), "cmp.yaml")
    assert "G201" not in codes(diags), [str(d) for d in diags]


def test_g201_edges_and_step_times(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: gsB, when: "↑iA"}
          - {from: gsA, to: gsC, when: "↓iA + (gsA.T >= 5s)·iB"}
          - {from: gsB, to: gsA, when: iC}
          - {from: gsC, to: gsA, when: iC}
        """))
    (d,) = [d for d in diags if d.code == "G201"]
    assert "gsA.T=5s" in d.message and "previous scan 0" in d.message


def test_g202_variants(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true, max: 10s, actions: ["D 10s oX", "N oY if iA·iA'",
                                                   "on ↑iB·↓iB do sN := 1"]}
          gsB: {actions: ["D 6s oY", "D 4s oX"]}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsA, when: gsB.T >= 5s}
        """))
    g202 = [d.message for d in diags if d.code == "G202"]
    assert len(g202) == 4, g202
    assert any("max time" in m for m in g202)
    assert any("condition is never true" in m for m in g202)
    assert any("event never happens" in m for m in g202)
    assert any("'D 6s oY'" in m and "always left" in m for m in g202)


def test_g203_and_divergence_not_closed(write: Callable[[str, str], str]) -> None:
    diags = run(write, chart("""\
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
        transitions:
          - {from: gsA, to: [gsB, gsC], when: iA}
          - {from: gsB, to: [], when: iB}
          - {from: gsC, to: [], when: iC}
        """))
    assert any(d.code == "G203" and "AND divergence" in d.message for d in diags)


def test_g207_location_points_at_the_bool(write: Callable[[str, str], str]) -> None:
    text, _, _ = CASES["G207"]
    (d,) = [d for d in run(write, chart(text)) if d.code == "G207"]
    assert (d.line, d.col) == (6, 13)  # the 'iA' of '  - tFin := iA + sN >= 10'
    assert "'iA'" in d.message


def test_exit_status(write: Callable[[str, str], str]) -> None:
    ok = write("ok.yaml", chart(CASES["G201"][2]))
    warn = write("warn.yaml", chart(CASES["G201"][0]))
    bad = write("bad.yaml", chart(CASES["G103"][0]))
    broken = write("broken.yaml", chart("""\
        steps:
          gsA: {initial: true}
        transitions:
          - {from: gsA, to: gsZ, when: iA}
        """))
    assert exit_status(check_files([ok])) == 0
    assert exit_status(check_files([ok, warn])) == 0
    assert exit_status(check_files([ok, bad])) == 2  # an error found: 2, as every command's
    res = check_files([bad, broken])
    assert exit_status(res) == 2
    assert "unknown step 'gsZ'" in (res[1].failure or "")


def _parallel_loops(n: int, unreachable: bool = False) -> str:
    """An AND divergence into ``n`` two-step loops: 2**n reachable situations."""
    lines = ["steps:", "  gsA: {initial: true}"]
    for i in range(n):
        lines += [f"  gsB{i}: {{}}", f"  gsC{i}: {{}}"]
    if unreachable:
        lines.append("  gsZ: {}")
    lines.append("transitions:")
    lines.append("  - {from: gsA, to: [" + ", ".join(f"gsB{i}" for i in range(n))
                 + "], when: iA}")
    for i in range(n):
        lines.append(f"  - {{from: gsB{i}, to: gsC{i}, when: \"iB·iC'\"}}")
        lines.append(f"  - {{from: gsC{i}, to: gsB{i}, when: \"iC·iB'\"}}")
    lines.append("  - {from: [" + ", ".join(f"gsC{i}" for i in range(n))
                 + "], to: gsA, when: iD}")
    if unreachable:
        lines.append("  - {from: gsZ, to: gsA, when: iD}")
    return "\n".join(lines) + "\n"


def test_g209_bounded_exploration(write: Callable[[str, str], str],
                                  capsys: pytest.CaptureFixture[str]) -> None:
    path = write("big.yaml", HEAD + _parallel_loops(8, unreachable=True))
    full = check_files([path])[0].diags  # 2**8 + 1 situations: under the default bound
    assert "G209" not in codes(full), [str(d) for d in full]
    assert [d.message.split("'")[1] for d in full if d.code == "G102"] == ["gsZ"]
    cut = check_files([path], limit=50)[0].diags
    (g209,) = [d for d in cut if d.code == "G209"]
    assert g209.severity == "warning" and (g209.line, g209.col) == (1, 1)
    assert "stopped (more than 50 reachable situations; raise it with --limit)" in g209.message
    # what the links alone decide is still reported; nothing else is claimed
    assert [d.message.split("'")[1] for d in cut if d.code == "G102"] == ["gsZ"]
    assert "G206" not in codes(cut)
    # the command line takes --limit
    import argparse

    from runtime.checker.check import register

    p = argparse.ArgumentParser(prog="softplc")
    register(p.add_subparsers(dest="command", required=True))
    args = p.parse_args(["check", "--limit", "50", "-q", path])
    assert args.func(args) == 2  # G102 is an error
    assert "G209" in capsys.readouterr().out


def test_every_code_is_in_the_table_of_docs_check_md() -> None:
    """Each code the checker can print has its row in docs/check.md (severity included)."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    source = "".join(p.read_text(encoding="utf-8")
                     for p in (root / "runtime" / "checker").glob("*.py"))
    found = set(re.findall(r'"(?:warning|note|error)", "(G\d{3})"', source))
    assert {"G210", "G211", "G306", "G307", "G401"} <= found, found
    doc = (root / "docs" / "check.md").read_text(encoding="utf-8")
    rows = set(re.findall(r"^\| (G\d{3}) \| (?:error|warning|note) \|", doc, re.M))
    assert found <= rows, sorted(found - rows)


def test_compile_and_check_exit_alike_on_one_chart(write: Callable[[str, str], str]) -> None:
    """A chart without an initial step: ``softplc compile`` refused it with exit status 2,
    ``softplc check`` said the same error with 1 (README: an error in a file is exit 2)."""
    import subprocess
    import sys

    path = write("noinit.yaml", "grafcet: G\ninputs: [go]\nsteps:\n  a: {}\n  b: {}\n"
                                "transitions:\n  - {from: a, to: b, when: go}\n")
    got = {cmd: subprocess.run([sys.executable, "-m", "runtime.cli", cmd, "-q", path]
                               if cmd == "check" else
                               [sys.executable, "-m", "runtime.cli", cmd, path],
                               capture_output=True, text=True, timeout=120,
                               check=False).returncode
           for cmd in ("compile", "check")}
    assert got == {"compile": 2, "check": 2}
