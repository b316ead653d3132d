"""``softplc check`` grows linearly with the size of a chart: counted, not timed.

The charts are bench/compile.py's (a main line of blocks with OR and AND divergences, each
closed, loops back). The work of the rules is counted as the transitions of the chart they
read (every item taken from ``g.transitions``, by iteration or by index) and, for the
reachability, as the (situation, transition) pairs it tests: doubling the chart must about
double the work (a quadratic rule would quadruple it, G203's old rescan grew eightfold).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

from bench.compile import chart_text, parallel_text
from runtime.checker import reach
from runtime.checker.rules import check_grafcet
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet, Transition

SIZES = (60, 120, 240, 480)


class CountingList(list[Transition]):
    """A list of transitions that counts the items read from it."""

    reads = 0

    def __iter__(self) -> Iterator[Transition]:
        for t in super().__iter__():
            self.reads += 1
            yield t

    def __getitem__(self, i: Any) -> Any:
        self.reads += 1
        return super().__getitem__(i)


def load(write: Callable[[str, str], str], steps: int) -> Grafcet:
    return load_grafcet(write(f"big{steps}.yaml", chart_text(steps)))


def assert_linear(work: dict[int, int]) -> None:
    sizes = sorted(work)
    for a, b in zip(sizes, sizes[1:], strict=False):
        ratio = work[b] / work[a]
        assert ratio <= 1.25 * b / a, (
            f"work grows faster than the chart: {a} steps {work[a]}, {b} steps {work[b]} "
            f"(x{ratio:.2f} for x{b / a:.0f}); all: {work}")


def test_the_rules_read_each_transition_a_bounded_number_of_times(
        write: Callable[[str, str], str]) -> None:
    work = {}
    for n in SIZES:
        g = load(write, n)
        counted = CountingList(g.transitions)
        g.transitions = counted
        diags = check_grafcet(g)
        assert not [d for d in diags if d.code in ("G203", "G209")], diags
        work[n] = counted.reads
    assert_linear(work)


def test_the_reachability_tests_a_bounded_number_of_transitions_per_situation(
        write: Callable[[str, str], str]) -> None:
    """The situations of these charts grow linearly (one AND divergence per block), so the
    (situation, transition) pairs tested (``Reach.tested``) must too: a situation tests only
    the transitions of its active steps, not every transition of the chart."""
    work = {}
    for n in SIZES:
        r = reach.explore(load(write, n))
        assert r.complete and not r.unsafe
        work[n] = r.tested
    assert_linear(work)


def test_parallel_branches_are_explored_without_their_product(
        write: Callable[[str, str], str]) -> None:
    """Three parallel branches of 50 steps: 50^3 situations if every interleaving is
    enumerated, over the default bound; the reduced exploration decides the chart."""
    g = load_grafcet(write("parallel.yaml", parallel_text(3, 50)))
    diags = check_grafcet(g)
    assert not [d for d in diags if d.code in ("G102", "G104", "G206", "G209")], diags
    r = reach.reachable(g)
    assert r.complete and r.reduced and len(r.parent) < 10_000
    assert r.reachable_steps == {s.name for s in g.leaf_steps()}


LOOPS = """\
grafcet: Loops
inputs: [iA]
outputs: [oX]
steps:
  a0: {initial: true}
  a1: {}
  b0: {initial: true}
  b1: {}
  c0: {}
  c1: {}
transitions:
  - {from: a0, to: a1, when: iA}
  - {from: a1, to: a0, when: iA'}
  - {from: b0, to: b1, when: iA}
  - {from: b0, to: c0, when: iA'}
  - {from: b1, to: b0, when: iA'}
  - {from: c0, to: c1, when: iA}
"""


def test_the_reduction_neither_starves_a_branch_nor_drops_a_choice(
        write: Callable[[str, str], str]) -> None:
    """Branch a loops alone on links of a simple sequence: it must not be the only one to
    move. b0 -> b1 is not fired alone: b0 has a second way out, to c0."""
    g = load_grafcet(write("loops.yaml", LOOPS))
    full = reach.explore(g)
    red = reach.explore(g, reduce=True)
    assert full.reachable_steps == {"a0", "a1", "b0", "b1", "c0", "c1"}
    assert red.reachable_steps == full.reachable_steps
    assert bool(red.dead) == bool(full.dead)


def test_a_reduced_exploration_that_never_saw_the_way_back_says_g206_is_undecided(
        write: Callable[[str, str], str]) -> None:
    """Past 10 000 situations the reduced exploration may miss the way back to the initial
    situation; G206 needs that way back, so dead situations found without it are a note
    (G212), never silence. Here the three branches have no way back at all."""
    text = parallel_text(3, 50).rsplit("  - {from: [", 1)[0]
    g = load_grafcet(write("oneway.yaml", text))
    r = reach.reachable(g)
    assert r.complete and r.reduced and r.dead and not r.back_to_initial
    notes = [d for d in check_grafcet(g) if d.code == "G212"]
    assert len(notes) == 1 and notes[0].severity == "note", notes
    assert "b0_49, b1_49, b2_49" in notes[0].message or "b0_49" in notes[0].message
