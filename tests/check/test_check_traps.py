"""G210 (a stored action nothing resets) and G211 (a timer read stale under ``scan:
stable``): each warning is shown to be a real trap by running the chart it warns about on
the engine (virtual clock), and its near misses to be sound the same way."""

from __future__ import annotations

import textwrap
from collections.abc import Callable

import pytest

from runtime.checker.check import check_files
from runtime.checker.diag import Diag
from runtime.compiler.codegen import compile_grafcet
from runtime.engine.instance import Instance
from runtime.language.grafcetfile import load_grafcet
from tests.engine.enginekit import Chart

Write = Callable[[str, str], str]


def diags(write: Write, text: str, code: str) -> list[Diag]:
    (res,) = check_files([write("chart.yaml", text)])
    assert res.failure is None, res.failure
    return [d for d in res.diags if d.code == code]


def engine(write: Write, text: str) -> Chart:
    path = write("engine.yaml", text)
    return Chart(Instance("u", compile_grafcet(load_grafcet(path))), cycle_ms=10)


# -- G210 --------------------------------------------------------------------------------
LATCH = """\
grafcet: Latch
inputs: [iA, iB]
outputs: [oX]
memory: {{sN: 0}}
steps:
  gsA: {{initial: true{a}}}
  gsB: {{actions: ["{q} oX"]}}
transitions:
  - {{from: gsA, to: gsB, when: iA}}
  - {{from: gsB, to: gsA, when: iB}}
"""


def latch(q: str = "S", a: str = "") -> str:
    return LATCH.format(q=q, a=a)


def test_g210_an_assignment_does_not_reset_a_stored_target(write: Write) -> None:
    """The decision documented in check.md: ``oX := FALSE`` is no reset, the engine shows
    why (the target is set again in the next scan); an R is."""
    text = latch(a=', actions: ["P1 oX := FALSE"]')
    (d,) = diags(write, text, "G210")
    assert (d.line, d.severity) == (7, "warning")
    assert "no 'R oX' resets it" in d.message
    assert "the assignment to 'oX' in a statement does not reset it" in d.message
    c = engine(write, text).scan()
    c.scan(iA=1).scan(iA=0)
    assert c.steps == ["gsB"] and c["oX"]
    c.scan(iB=1)  # back in gsA: its P1 writes oX := FALSE ...
    assert c.steps == ["gsA"] and not c["oX"]
    c.scan(iB=0)  # ... and the stored S writes it true again in the next scan
    assert c["oX"], "the trap G210 warns about is gone: revisit the rule"
    fixed = latch(a=', actions: ["R oX"]')
    assert not diags(write, fixed, "G210")
    c = engine(write, fixed).scan()
    c.scan(iA=1).scan(iA=0, iB=1).run(3, iB=0)
    assert c.steps == ["gsA"] and not c["oX"]


@pytest.mark.parametrize("q, what", [("S", "stays true for good"),
                                     ("SD 1s", "stays true for good"),
                                     ("DS 1s", "stays true for good"),
                                     ("SL 1s", "only the first activation drives")])
def test_g210_every_stored_qualifier(write: Write, q: str, what: str) -> None:
    (d,) = diags(write, latch(q), "G210")
    assert what in d.message and q.split()[0] in d.message
    assert not diags(write, latch(q, ', actions: ["R oX"]'), "G210")


def test_g210_sl_without_r_drives_its_target_only_once(write: Write) -> None:
    """Why SL is in G210: without R its flip-flop stays set, a second activation does not
    restart it."""
    c = engine(write, latch("SL 50ms")).scan()
    c.scan(iA=1)
    assert c["oX"]
    c.run(10, iA=0).scan(iB=1).scan(iB=0, iA=1)  # left, then entered again
    assert c.steps == ["gsB"] and not c["oX"]


def test_g210_the_chart_resetting_itself_counts(write: Write) -> None:
    """SFCInit/SFCReset written by the chart clear every stored action: no warning."""
    text = latch().replace("outputs: [oX]", "outputs: [oX]\npost: ['SFCReset := iB']")
    assert not diags(write, text, "G210")
    c = engine(write, text).scan()
    c.scan(iA=1).scan(iA=0).scan(iB=1).scan(iB=0)
    assert not c["oX"]


def test_g210_reported_once_per_target_at_its_first_store(write: Write) -> None:
    text = textwrap.dedent("""\
        grafcet: Two
        inputs: [iA, iB]
        outputs: [oX, oY]
        steps:
          gsA: {initial: true, actions: ["S oY", "R oY"]}
          gsB: {actions: ["S oX"]}
          gsC: {actions: ["S oX"]}
        transitions:
          - {from: gsA, to: gsB, when: iA}
          - {from: gsB, to: gsC, when: iB}
          - {from: gsC, to: gsA, when: iA}
        """)
    (d,) = diags(write, text, "G210")
    assert d.line == 6 and "in step 'gsB', 'gsC'" in d.message


# -- G211 --------------------------------------------------------------------------------
STAR_DELTA = """\
grafcet: StarDelta
scan: {scan}
inputs: [iMarcha, iParo]
outputs: [oLinea, oEstrella, oTriangulo]
timers: [timeEstrella]
blocks: {{tonEstrella: TON}}
pre: [{pre}]
steps:
  gsParado: {{initial: true}}
  gsEstrella: {{actions: [oLinea, oEstrella{star}]}}
  gsTriangulo: {{actions: [oLinea, oTriangulo]}}
transitions:
  - {{from: gsParado, to: gsEstrella, when: ↑iMarcha}}
  - {{from: gsEstrella, to: gsTriangulo, when: "{when}"}}
  - {{from: gsTriangulo, to: gsParado, when: iParo}}
"""

#: (actions of gsEstrella, pre, condition of gsEstrella → gsTriangulo)
TRAPS = {
    "seed timer": (', "P1 timeEstrella.Ini(3s)"', "", "timeEstrella.End()"),
    "seed timer value": (', "P1 timeEstrella.Ini(5s)"', "", "timeEstrella.Val() >= 3s"),
    "TON in the step": (', "N tonEstrella(IN := 1, PT := 3s)"', "", "tonEstrella.Q"),
    "through a temporary": (', "N tonEstrella(IN := 1, PT := 3s)"',
                            "'tHecho := tonEstrella.Q'", "tHecho"),
}
SOUND = {
    "the step's time": ("", "", "gsEstrella.T >= 3s"),
    "TON in pre": ("", "'tonEstrella(IN := gsEstrella.X, PT := 3s)'", "tonEstrella.Q"),
}


def star_delta(case: tuple[str, str, str], scan: str = "stable") -> str:
    star, pre, when = case
    return STAR_DELTA.format(scan=scan, star=star, pre=pre, when=when)


def second_start(c: Chart) -> Chart:
    """Start, let the timer end (4 s), stop, start again: the scan of the second start."""
    c.scan().scan(iMarcha=1).run(400, iMarcha=0)
    assert c.steps == ["gsTriangulo"]
    c.scan(iParo=1).scan(iParo=0)
    assert c.steps == ["gsParado"]
    return c.scan(iMarcha=1)


@pytest.mark.parametrize("name", TRAPS)
def test_g211_the_star_step_is_skipped_on_every_start_after_the_first(write: Write,
                                                                    name: str) -> None:
    text = star_delta(TRAPS[name])
    (d,) = diags(write, text, "G211")
    assert d.line == 14 and d.severity == "warning"
    assert "source step 'gsEstrella' starts" in d.message
    assert "'gsEstrella.T >= ...'" in d.message
    c = second_start(engine(write, text))
    assert c.steps == ["gsTriangulo"] and not c["oEstrella"], \
        "the trap G211 warns about is gone: revisit the rule"


@pytest.mark.parametrize("name", SOUND)
def test_g211_near_misses_start_in_star_every_time(write: Write, name: str) -> None:
    text = star_delta(SOUND[name])
    assert not diags(write, text, "G211")
    c = second_start(engine(write, text))
    assert c.steps == ["gsEstrella"] and c["oEstrella"]


def test_g211_only_under_scan_stable(write: Write) -> None:
    text = star_delta(TRAPS["seed timer"], scan="immediate")
    assert not diags(write, text, "G211")
    c = second_start(engine(write, text))
    assert c.steps == ["gsEstrella"] and c["oEstrella"]


def test_g211_points_at_the_timer_in_the_condition(write: Write) -> None:
    (d,) = diags(write, star_delta(TRAPS["seed timer"]), "G211")
    line = star_delta(TRAPS["seed timer"]).splitlines()[d.line - 1]
    assert line[d.col - 1:].startswith("timeEstrella.End()")
    (d,) = diags(write, star_delta(TRAPS["through a temporary"]), "G211")
    assert "tHecho (= ...tonEstrella.Q...)" in d.message
