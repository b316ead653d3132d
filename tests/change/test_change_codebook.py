"""An online change compiles its code in a child process: the controller's process only
unmarshals it (``compile()`` of the plant cycle holds the GIL, 16 ms at 100 testers)."""

from __future__ import annotations

import marshal

import pytest

from runtime.change.plan import apply, prepare
from runtime.compiler.codebook import CodeBook
from runtime.controller.reload import compile_apart, load_apart
from runtime.engine.plant import Plant
from runtime.language.filekind import file_kind
from runtime.language.plantfile import load_plant
from tests.change.changekit import DRAWER_PLANT, ROOT, data_plant


def running(path: str) -> Plant:
    """A plant as ``softplc run --sim`` builds it (not a simulation's virtual plant)."""
    plant = Plant(load_plant(path), sim=True)
    plant.open()
    return plant


def test_the_child_compiles_every_source_the_controller_needs() -> None:
    old = running(DRAWER_PLANT)
    loaded = load_apart(data_plant("timeout"), DRAWER_PLANT)  # a version of the running plant
    assert not isinstance(loaded, str)
    pdef, book = loaded
    assert book is not None and book.blobs
    prep = prepare(old, pdef, book)
    # the chart, the plant's inlined scans and its cycle: found in the book, nothing
    # compiled here
    assert (book.hits, book.misses) == (3, 0)
    assert apply(old, prep).refusals == []


def test_going_back_compiles_the_previous_program_apart_too() -> None:
    old = running(data_plant("timeout"))
    loaded = compile_apart(load_plant(DRAWER_PLANT))
    assert not isinstance(loaded, str)
    pdef, book = loaded
    assert book is not None
    prepare(old, pdef, book)
    assert (book.hits, book.misses) == (3, 0)


def test_a_load_error_comes_back_as_its_line() -> None:
    assert load_apart("/nonexistent/plant.yaml") == load_apart("/nonexistent/plant.yaml")
    out = load_apart("/nonexistent/plant.yaml")
    assert isinstance(out, str) and out.startswith("load error:") and "nonexistent" in out


def test_a_book_never_changes_what_is_compiled() -> None:
    """A source the book does not hold, or a blob that is not code, is compiled here."""
    book = CodeBook(record=True)
    code = book.compile("def x():\n    pass\n", "<a>", ())
    assert (book.hits, book.misses) == (0, 1)
    other = CodeBook(book.blobs)
    assert other.compile("def x():\n    pass\n", "<a>", ()).co_consts == code.co_consts
    assert (other.hits, other.misses) == (1, 0)
    other.compile("def x():\n    return 2\n", "<a>", ())  # another text: compiled
    other.compile("def x():\n    pass\n", "<b>", ())  # another file name: compiled
    assert (other.hits, other.misses) == (1, 2)
    junk = CodeBook({k: marshal.dumps(42) for k in book.blobs})
    env: dict[str, object] = {}
    exec(junk.compile("def x():\n    pass\n", "<a>", ()), env)  # noqa: S102
    assert callable(env["x"]) and (junk.hits, junk.misses) == (0, 1)


def test_a_plant_built_from_a_book_runs_as_one_compiled_here() -> None:
    pdef = load_plant(DRAWER_PLANT)
    book = CodeBook(record=True)
    Plant(pdef, sim=True, book=book)
    reused = CodeBook(book.blobs)
    a, b = Plant(pdef, sim=True, virtual=True), Plant(pdef, sim=True, virtual=True,
                                                         book=reused)
    for n in range(50):
        a.cycle(n * 10_000_000)
        b.cycle(n * 10_000_000)
    assert [i.m[:] for i in a.instances.values()] == [i.m[:] for i in b.instances.values()]


PLANTS = sorted(str(p) for p in (ROOT / "configs").glob("*/*.yaml")
                if file_kind(str(p)) == "plant")


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: p.split("configs/")[1])
def test_the_child_builds_on_sim_io_the_sources_of_the_real_plant(path: str) -> None:
    """The child compiles on simulated I/O (it opens no bus): the sources must be the ones
    the controller generates with its real drivers, or the book would never be used."""
    pdef = load_plant(path)
    real, sim = Plant(pdef), Plant(pdef, sim=True)
    assert real.source == sim.source
    assert [p.source for p in real.programs] == [p.source for p in sim.programs]
