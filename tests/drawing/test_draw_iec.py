"""``softplc draw`` against IEC 60848 on the course exercises of tests/drawing/charts/ and the
charts of configs/: a straight main line, no link crossing another, one double bar per AND
convergence, and everything the file says (pre/post, min/max, action conditions) drawn in
the seed notation."""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from runtime.drawing import chart as draw
from runtime.language.model import Grafcet
from tests.drawing.test_draw_layout import CHARTS, LAYOUTS, ROOT, SVG

HERE = Path(__file__).resolve().parent / "charts"
EXERCISES = sorted(HERE.glob("*.yaml"))

Point = tuple[float, float]
Segment = tuple[Point, Point]


def _draw(chart: Path, tmp: Path, layout: str, notation: str = "written") -> ET.Element:
    out = tmp / f"{chart.stem}_{layout}_{notation}.svg"
    draw.draw(str(chart), str(out), layout=layout, notation=notation)
    return ET.parse(out).getroot()


def _classes(e: ET.Element) -> set[str]:
    return set((e.get("class") or "").split())


def _segments(root: ET.Element, skip: set[str]) -> list[Segment]:
    """The segments of every polyline whose classes are not in ``skip``."""
    out: list[Segment] = []
    for pl in root.iter(f"{SVG}polyline"):
        if _classes(pl) & skip:
            continue
        pts = [(float(a), float(b)) for a, b in
               (xy.split(",") for xy in (pl.get("points") or "").split())]
        out += list(itertools.pairwise(pts))
    return out


def _crossings(root: ET.Element) -> list[Point]:
    """Points where a vertical link passes right through a horizontal one (neither ends
    there): two links crossing, which IEC 60848 asks to avoid."""
    segs = _segments(root, {"transition", "and"})
    hs = [s for s in segs if abs(s[0][1] - s[1][1]) < 0.01 and abs(s[0][0] - s[1][0]) > 0.01]
    vs = [s for s in segs if abs(s[0][0] - s[1][0]) < 0.01 and abs(s[0][1] - s[1][1]) > 0.01]
    out = []
    for (a, b), (p, q) in itertools.product(hs, vs):
        y, x = a[1], p[0]
        if (min(a[0], b[0]) + 0.5 < x < max(a[0], b[0]) - 0.5
                and min(p[1], q[1]) + 0.5 < y < max(p[1], q[1]) - 0.5):
            out.append((x, y))
    return out


def _step_x(root: ET.Element) -> dict[str, float]:
    return {"".join(t.itertext()): float(t.get("x", "0")) for t in root.iter(f"{SVG}text")
            if "step-name" in _classes(t)}


def _texts(root: ET.Element, cls: str) -> list[str]:
    return ["".join(t.itertext()) for t in root.iter(f"{SVG}text") if cls in _classes(t)]


@pytest.mark.parametrize("layout", LAYOUTS)
def test_main_line_is_straight_when_every_step_has_a_stop_link(layout: str,
                                                                tmp_path: Path) -> None:
    root = _draw(HERE / "taladro.yaml", tmp_path, layout)
    xs = _step_x(root)
    line = [xs[n] for n in ("gsReposo", "gsBajar", "gsTaladrar", "gsSubir")]
    assert max(line) - min(line) < 0.5, line


NO_CROSSING = [*EXERCISES, *CHARTS]


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("chart", NO_CROSSING, ids=[p.stem for p in NO_CROSSING])
def test_no_link_crosses_another(chart: Path, layout: str, tmp_path: Path) -> None:
    """A loop lane goes round a branch, never across it. Steps shared by several AND
    convergences or divergences are the exception: the press's two steps each feed both
    double bars of the transitions leaving them, so one crossing cannot be avoided; the
    three modes' transitions each reach both steps of the parallel tasks, so two cannot
    (one per transition after the first; plain crossings, no bar crossed)."""
    root = _draw(chart, tmp_path, layout)
    allowed = {"prensa": 1, "modos": 2}.get(chart.stem, 0)
    assert len(_crossings(root)) <= allowed, _crossings(root)


def _bars(root: ET.Element, kind: str) -> list[tuple[float, float, float]]:
    """(y, x0, x1) of each double bar of ``kind`` (convergence or divergence)."""
    lines = [pl for pl in root.iter(f"{SVG}polyline") if {"and", kind} <= _classes(pl)]
    ys = []
    for pl in lines:
        (x0, y), (x1, _) = [(float(a), float(b)) for a, b in
                            (xy.split(",") for xy in (pl.get("points") or "").split())]
        ys.append((y, min(x0, x1), max(x0, x1)))
    pairs: dict[tuple[float, float], list[float]] = {}
    for y, x0, x1 in ys:
        pairs.setdefault((x0, x1), []).append(y)
    bars = []
    for (x0, x1), both in sorted(pairs.items()):  # the two lines of a bar, 4 px apart
        assert len(both) == 2 and abs(max(both) - min(both) - 4) < 0.01, (x0, x1, both)
        bars.append((min(both) + 2, x0, x1))
    return bars


@pytest.mark.parametrize("layout", LAYOUTS)
def test_each_and_convergence_has_its_own_double_bar(layout: str, tmp_path: Path) -> None:
    root = _draw(HERE / "prensa.yaml", tmp_path, layout)
    bars = _bars(root, "convergence")
    assert len(bars) == 2, bars  # gsPrensar's and gsExpulsar's
    (ya, a0, a1), (yb, b0, b1) = bars
    assert a1 < b0 or b1 < a0, bars  # side by side, not one bar for both
    # no link runs through a bar: links end on it (from above) or leave it (below)
    for (p, q), (y, x0, x1) in itertools.product(
            _segments(root, {"transition", "and"}), bars):
        if abs(p[0] - q[0]) < 0.01 and x0 < p[0] < x1:
            assert not min(p[1], q[1]) < y - 2.5 < y + 2.5 < max(p[1], q[1]), (p, q, y)
    assert len(_bars(root, "divergence")) == 1


# three transitions from one step into the same two steps (the course's exercise with the
# three modes has them from three steps)
SAME_SOURCE = """\
grafcet: Tres
inputs: [iA, iB, iC, iD]
outputs: [oX, oY]
steps:
  gs0: {initial: true}
  gsP: {actions: [oX]}
  gsQ: {actions: [oY]}
transitions:
  - {from: gs0, to: [gsP, gsQ], when: iA}
  - {from: gs0, to: [gsP, gsQ], when: iB}
  - {from: gs0, to: [gsP, gsQ], when: iC}
  - {from: [gsP, gsQ], to: gs0, when: iD}
"""

# two transitions into the same two steps from different rows: the upper one's links reach
# them by channels (it had no double bar at all)
TWO_ROWS = """\
grafcet: Dos
inputs: [iA, iB, iC, iD]
outputs: [oX, oY]
steps:
  gs0: {initial: true}
  gsA: {}
  gsP: {actions: [oX]}
  gsQ: {actions: [oY]}
transitions:
  - {from: gs0, to: [gsP, gsQ], when: iA}
  - {from: gs0, to: gsA, when: iB}
  - {from: gsA, to: [gsP, gsQ], when: iC}
  - {from: [gsP, gsQ], to: gs0, when: iD}
"""


def _transition_xy(root: ET.Element) -> dict[str, Point]:
    """Transition index -> the middle of its bar."""
    out = {}
    for group in root.iter(f"{SVG}g"):
        if "transition-group" in _classes(group):
            bar = next(p for p in group.iter(f"{SVG}polyline") if "transition" in _classes(p))
            pts = [(float(a), float(b)) for a, b in
                   (xy.split(",") for xy in (bar.get("points") or "").split())]
            out[group.get("data-transition", "")] = ((pts[0][0] + pts[-1][0]) / 2, pts[0][1])
    return out


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("which", ["modos", "same-source", "two-rows"])
def test_each_and_divergence_has_its_own_double_bar(which: str, layout: str,
                                                    tmp_path: Path) -> None:
    """Issue 27: three transitions into the same two steps were drawn on one shared double
    bar, which IEC 60848 has no reading for (a double bar follows one transition). Each
    transition with several targets has its own double bar, which spans its own bar and no
    other transition's, apart from the others (the upper one of two transitions in
    different rows had none)."""
    from runtime.language.grafcetfile import load_grafcet

    if which == "modos":
        path = HERE / "modos.yaml"
    else:
        path = tmp_path / "c.yaml"
        path.write_text(SAME_SOURCE if which == "same-source" else TWO_ROWS, encoding="utf-8")
    g = load_grafcet(str(path))
    split = [str(k) for k, t in enumerate(g.transitions) if len(set(t.dst_steps)) > 1]
    assert len(split) == (2 if which == "two-rows" else 3)
    root = _draw(path, tmp_path, layout)
    lines = []
    for pl in root.iter(f"{SVG}polyline"):
        if {"and", "divergence"} <= _classes(pl):
            (x0, y), (x1, _) = [(float(a), float(b)) for a, b in
                                (xy.split(",") for xy in (pl.get("points") or "").split())]
            lines.append((round(y, 2), min(x0, x1), max(x0, x1)))
    assert len(set(lines)) == len(lines) == 2 * len(split), lines  # no bar drawn twice
    bars = [(y + 2, x0, x1) for y, x0, x1 in lines if (y + 4, x0, x1) in lines]
    assert len(bars) == len(split), bars
    at = _transition_xy(root)
    for k in split:
        x, y = at[k]
        mine = [b for b in bars if b[1] < x < b[2] and 0 < b[0] - y < 30]  # right under it
        assert len(mine) == 1, (k, bars)
        others = [j for j, (xj, yj) in at.items()
                  if j != k and abs(yj - y) < 1 and mine[0][1] <= xj <= mine[0][2]]
        assert not others, (k, others)
    for a, b in itertools.combinations(bars, 2):
        assert abs(a[0] - b[0]) > 6 or a[2] < b[1] or b[2] < a[1], (a, b)
    for (p, q), (y, x0, x1) in itertools.product(  # links end on a bar or leave it
            _segments(root, {"transition", "and"}), bars):
        if abs(p[0] - q[0]) < 0.01 and x0 < p[0] < x1:
            assert not min(p[1], q[1]) < y - 2.5 < y + 2.5 < max(p[1], q[1]), (p, q, y)


def test_conditions_actions_and_equations_are_drawn_as_written(tmp_path: Path) -> None:
    """taladro.yaml is written in ST: the drawing shows its texts as the file wrote them,
    as the page's "why" list does (they were drawn in the seed notation)."""
    root = _draw(HERE / "taladro.yaml", tmp_path, "python")
    assert _texts(root, "equation") == ["tParo := iParo OR iPuerta",
                                        "oPiloto := gsReposo.X AND NOT tParo"]
    assert "oRefrigerar if iPieza AND NOT iPuerta" in _texts(root, "action")
    assert "RE iAbajo" in _texts(root, "qualifier")
    assert _texts(root, "condition")[:3] == ["RE iMarcha AND iPieza AND NOT tParo", "iAbajo",
                                             "gsTaladrar.T >= 5s"]


def test_pre_post_min_max_and_action_conditions_in_the_seed_notation(tmp_path: Path) -> None:
    root = _draw(HERE / "taladro.yaml", tmp_path, "python", notation="seed")
    assert _texts(root, "equation") == ["tParo := iParo + iPuerta",
                                        "oPiloto := gsReposo.X·tParo'"]
    assert _texts(root, "equations-title") == ["pre (every scan, before the chart)",
                                               "post (every scan, after the chart)"]
    assert _texts(root, "step-times") == ["min 2s · max 10s"]
    actions = _texts(root, "action")
    assert "oRefrigerar if iPieza·iPuerta'" in actions
    assert "↑iAbajo" in _texts(root, "qualifier")
    assert "sPiezas := sPiezas + 1" in actions
    # --notation seed: the conditions too (as written they are ST here: the test above)
    assert "↑iMarcha·iPieza·tParo'" in _texts(root, "condition")


def test_drawer_tester_equations_are_drawn(tmp_path: Path) -> None:
    root = _draw(ROOT / "configs/drawer_tester/drawer_tester.yaml", tmp_path, "python")
    eq = _texts(root, "equation")
    assert "tParo := iCerrado·(sParo + (sCierres >= 1000))" in eq
    assert "oParado := gsParado.X + sParo·Clock_1Hz + gsAveria.X·Clock_2Hz" in eq
    assert "sParo.Set(1, iParo)" in eq


def test_a_plant_instance_is_drawn_with_the_legend_of_its_io(tmp_path: Path) -> None:
    """Issue 29: the plant's I/O list as a legend (signal, point, NC, meaning); a chart
    drawn alone has none when its variables carry no description."""
    root = _draw(ROOT / "configs/drawer_tester/plant_sim.yaml", tmp_path, "python")
    legend = [" ".join(t.replace("\u00a0", " ").split()) for t in _texts(root, "legend")]
    assert legend[0] == "iParo <- sim.I0 NC Pulsador de paro SJP (NC)"
    assert legend[4] == "oAbrir -> sim.Q0 Contactor QAA, abrir el cajón"
    assert len(legend) == 8
    assert _texts(root, "legends-title") == [
        "I/O of tester1 (Banco de ensayo de guías de cajón 1)"]
    alone = _draw(ROOT / "configs/drawer_tester/drawer_tester.yaml", tmp_path, "python")
    assert _texts(alone, "legend") == []


@pytest.mark.parametrize("layout", LAYOUTS)
def test_the_token_covers_no_text_of_its_step(layout: str, tmp_path: Path) -> None:
    """Issue 27: the active step's token was drawn on its "max 5s" label. Every step of
    the shared-failure chart active at once: the token's disc is clear of the step's name
    and times, and inside its box (inside the inner box of an initial step)."""
    from runtime.drawing.text import text_w
    from runtime.language.grafcetfile import load_grafcet

    g = load_grafcet(str(HERE / "fallo.yaml"))
    svg, _ = draw.chart_svg(g, active=set(g.steps), layout=layout)
    root = ET.fromstring(svg)
    for group in root.iter(f"{SVG}g"):
        if "step-group" not in _classes(group):
            continue
        token = next(c for c in group.iter(f"{SVG}circle") if "token" in _classes(c))
        cx, cy, r = (float(token.get(k, "0")) for k in ("cx", "cy", "r"))
        box = next(e for e in group.iter(f"{SVG}rect") if "step" in _classes(e))
        inner = next((e for e in group.iter(f"{SVG}rect") if "initial" in _classes(e)), box)
        x0, y0 = float(inner.get("x", "0")), float(inner.get("y", "0"))
        x1 = x0 + float(inner.get("width", "0"))
        y1 = y0 + float(inner.get("height", "0"))
        assert x0 < cx - r and cx + r < x1 and y0 < cy - r and cy + r < y1, group.get("data-step")
        for t in group.iter(f"{SVG}text"):
            size = float(t.get("font-size", "12"))
            w = text_w("".join(t.itertext()), size)
            tx = float(t.get("x", "0"))
            left = {"start": tx, "middle": tx - w / 2, "end": tx - w}[t.get("text-anchor", "start")]
            top, bottom = float(t.get("y", "0")) - size * 0.8, float(t.get("y", "0")) + 2
            clear = (cx + r <= left or cx - r >= left + w or cy + r <= top or cy - r >= bottom)
            assert clear, (group.get("data-step"), "".join(t.itertext()), (cx, cy))


def shared_failure_chart(seed: int, back_to: int = 2) -> str:
    """A generated chart as a new user writes one from the course exercises: a line of 3
    to 7 steps closed by a return to the initial step, failure transitions from some of
    its steps into one shared failure step, whose reset goes back to one of the first
    ``back_to`` steps of the line."""
    import random

    rnd = random.Random(seed)
    n = rnd.randint(3, 7)
    steps = [f"s{i}" for i in range(n)]
    fails = set(rnd.sample(steps[1:], rnd.randint(1, n - 1)))
    lines = [f"grafcet: Gen{seed}", "inputs: [a, f, r]", "steps:", "  s0: {initial: true}",
             *[f"  {s}: {{}}" for s in steps[1:]], "  sF: {}", "transitions:"]
    for i, s in enumerate(steps):
        lines.append(f"  - {{from: {s}, to: {steps[(i + 1) % n]}, when: a}}")
        if s in fails:
            lines.append(f"  - {{from: {s}, to: sF, when: f}}")
    lines.append(f"  - {{from: sF, to: {rnd.choice(steps[:back_to])}, when: r}}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("layout", LAYOUTS)
def test_generated_charts_with_a_shared_failure_step_have_no_crossing(
        layout: str, tmp_path: Path) -> None:
    """Issue 27: a failure link across the main line, a return link across another. Over
    60 generated charts, none has a crossing and no failure step sits under the normal
    sequence, on the main line (before the fix, in each layout: 26 had a crossing, 36 the
    failure step on the main line)."""
    from runtime.language.grafcetfile import load_grafcet

    crossed = []
    for seed in range(60):
        path = tmp_path / f"gen{seed}.yaml"
        path.write_text(shared_failure_chart(seed), encoding="utf-8")
        svg, _ = draw.chart_svg(load_grafcet(str(path)), layout=layout)
        root = ET.fromstring(svg)
        if _crossings(root):
            crossed.append(seed)
        xs = _step_x(root)
        assert abs(xs["sF"] - xs["s0"]) > 1, seed
    assert crossed == []


def _forced(g: Grafcet) -> bool:
    """Does the reset of a generated chart go back to a step ``s_k`` with failures both
    from a step above it and from ``s_k`` or one below? Then its link must cross one: it
    enters ``s_k`` from above, on the side of the failure links (the other side has the
    line's own return, whose lane spans ``s_k``), inside the region closed by the line
    from the upper failing step to the lower one, their failure links and the failure
    step's OR convergence line; and it leaves from under that line."""
    line = [s for s in g.steps if s != "sF"]
    fails = [line.index(t.src_steps[0]) for t in g.transitions if t.dst_steps == ["sF"]]
    k = line.index(next(t.dst_steps[0] for t in g.transitions if t.src_steps == ["sF"]))
    return any(i < k for i in fails) and any(j >= k for j in fails)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_reset_into_any_step_crosses_only_where_it_must(layout: str,
                                                          tmp_path: Path) -> None:
    """Issue 27: a reset back to the third step or lower crossed a link though the chart
    allows a drawing without. Over 200 generated charts whose reset goes back to any
    step, the charts with a crossing are exactly those where one cannot be avoided
    (``_forced``), with one crossing each (before the fix, in each layout: 76 crossed,
    67 of them forced)."""
    from runtime.language.grafcetfile import load_grafcet

    crossed, forced = {}, []
    for seed in range(200):
        text = shared_failure_chart(seed, back_to=7)
        path = tmp_path / f"gen{seed}.yaml"
        path.write_text(text, encoding="utf-8")
        g = load_grafcet(str(path))
        svg, _ = draw.chart_svg(g, layout=layout)
        n = len(_crossings(ET.fromstring(svg)))
        if n:
            crossed[seed] = n
        if _forced(g):
            forced.append(seed)
    assert len(forced) == 67  # the generator's
    assert sorted(crossed) == forced
    assert set(crossed.values()) == {1}


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("chart", NO_CROSSING, ids=[p.stem for p in NO_CROSSING])
def test_links_back_up_are_told_apart(chart: Path, layout: str, tmp_path: Path) -> None:
    """Issue 27: two links back up whose horizontals ran 6 px apart looked like one lane.
    Horizontals of links back up that overlap side by side are at least 10 px apart."""
    root = _draw(chart, tmp_path, layout)
    hs = []
    for pl in root.iter(f"{SVG}polyline"):
        if "back" not in _classes(pl):
            continue
        pts = [(float(a), float(b)) for a, b in
               (xy.split(",") for xy in (pl.get("points") or "").split())]
        hs += [(p, q) for p, q in itertools.pairwise(pts)
               if abs(p[1] - q[1]) < 0.01 and abs(p[0] - q[0]) > 0.01]
    for (a, b), (p, q) in itertools.combinations(hs, 2):
        overlap = min(max(a[0], b[0]), max(p[0], q[0])) - max(min(a[0], b[0]),
                                                               min(p[0], q[0]))
        if overlap > 1 and abs(a[1] - p[1]) > 0.01:
            assert abs(a[1] - p[1]) >= 10, ((a, b), (p, q))
