"""The check every generated program passes before it is compiled (runtime/compiler/guard.py):
what the compiler does not emit is refused with one line and never runs, whatever an
emitter writes; what it emits (every chart and plant of the suite) passes."""

from __future__ import annotations

import json
import marshal
import subprocess
from pathlib import Path

import pytest

from runtime.cli import main
from runtime.compiler import evolution
from runtime.compiler.codebook import CodeBook, compile_code
from runtime.compiler.codegen import SCAN_GLOBALS, Compiler, compile_grafcet
from runtime.compiler.guard import GeneratedCodeRefused, checked_code, checked_eval
from runtime.engine.instance import Instance
from runtime.engine.plant import Plant
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import load_plant
from tests.engine.test_compile_scale import SHAPES

MS = 1_000_000
ROOT = Path(__file__).resolve().parents[2]

#: sources the compiler never writes, and the words of their refusal
REFUSED = {
    "import": ("def f():\n    import os\n", "the operation IMPORT_NAME"),
    "from import": ("def f():\n    from os import system\n", "the operation IMPORT_NAME"),
    "builtin open": ("def f():\n    open('/tmp/x', 'w')\n", "the name 'open'"),
    "dunder import": ("def f():\n    __import__('os')\n", "the name '__import__'"),
    "dunder attribute": ("def f(x):\n    return x.__class__\n", "the name '__class__'"),
    "unknown attribute": ("def f(x):\n    return x.write\n", "the name 'write'"),
    "getattr": ("def f(x):\n    return getattr\n", "the name 'getattr'"),
    "module statement": ("x = 1\n", "the name 'x'"),
    "f-string": ("def f(x):\n    return f'{x}'\n", "the operation FORMAT_"),
    "class": ("def f():\n    class C:\n        pass\n", "the operation LOAD_BUILD_CLASS"),
    "global": ("def f():\n    global x\n    x = 1\n", "the operation STORE_GLOBAL"),
    "with": ("def f(x):\n    with x:\n        pass\n", "the operation "),
    "for loop": ("def f(x):\n    for y in x:\n        pass\n", "the operation "),
    "comprehension": ("def f(x):\n    return [y for y in x]\n", "the operation "),
    "keyword argument": ("def f(a):\n    return f(a=1)\n", "the operation "),
    "star argument": ("def f(a):\n    return f(*a)\n", "the operation CALL_FUNCTION_EX"),
    "dict": ("def f():\n    return {}\n", "the operation BUILD_MAP"),
    "bytes": ("def f():\n    return b'1'\n", "a constant of type bytes"),
    "dunder parameter": ("def f(__a):\n    pass\n", "the name '__a'"),
    "carriage return": ("def f():  # a\rimport os\n", "the character '\\r' in a line"),
    "line separator": ("def f():  # a\u2028b\n    pass\n", "the character '\\u2028' in a line"),
    "nul": ("def f():  # \x00\n    pass\n", "the character '\\x00' in a line"),
    "syntax error": ("x = (\n", "a syntax error"),
}


@pytest.mark.parametrize("source,words", REFUSED.values(), ids=REFUSED.keys())
def test_what_the_compiler_never_writes_is_refused(source: str, words: str) -> None:
    with pytest.raises(GeneratedCodeRefused) as e:
        checked_code(source, "<test>", names=())
    text = str(e.value)
    assert "\n" not in text and words in text and text.startswith("generated code of <test>")
    assert text.endswith("(a defect of softplc's compiler: nothing of it ran)")


def test_what_the_compiler_writes_passes() -> None:
    """Names bound by the program or given to it, the block attributes, literals."""
    source = ("def make(m, init):\n    a, b, = init\n    def scan(now, up):\n"
              "        nonlocal a\n        a = b.Q and _idiv(now, 2) > int(up / 3)\n"
              "        b.update(now)\n        return (a, 'text', None, 1.5, )\n"
              "    return scan\n")
    code = checked_code(source, "<test>", names=("_idiv",))
    env: dict[str, object] = {"_idiv": lambda a, b: a // b}
    exec(code, env)  # noqa: S102
    assert callable(env["make"])
    with pytest.raises(GeneratedCodeRefused, match="the name '_idiv'"):
        checked_code(source, "<test>", names=())  # not given: refused


def test_an_expression_runs_with_no_builtin_but_its_own() -> None:
    fn = checked_eval("lambda m: int(m[0])", {})
    assert fn([2.5]) == 2
    with pytest.raises(GeneratedCodeRefused, match="the name 'len'"):
        checked_eval("lambda m: len(m)", {})


def test_a_book_checks_what_it_compiles() -> None:
    with pytest.raises(GeneratedCodeRefused):
        CodeBook(record=True).compile("import os\n", "<a>", ())
    with pytest.raises(GeneratedCodeRefused):
        compile_code("import os\n", "<a>", ())


CHART = """\
grafcet: Pasted
inputs: [iA]
outputs: [oB]
steps:
  s1: {{initial: true}}
  s2: {{actions: [oB]}}
transitions:
  - {{from: s1, to: s2, when: {when}}}
  - {{from: s2, to: s1, when: NOT iA}}
"""


def careless_chart(tmp_path: Path) -> tuple[Path, Path]:
    marker = tmp_path / "ran"
    when = f"iA (*\r{' ' * 16}open({str(marker)!r}, 'w').write('ran')\r{' ' * 16}# *)"
    chart = tmp_path / "chart.yaml"
    chart.write_text(CHART.format(when=json.dumps(when)), encoding="utf-8")
    return chart, marker


@pytest.mark.parametrize("emit", [
    lambda text: "# " + text,  # a comment as the compiler wrote it before the check
    lambda text: text.split(" when ", 1)[1].replace("(*", "").replace("*)", ""),  # as code
], ids=["raw comment", "pasted as code"])
def test_a_careless_emitter_is_stopped_before_anything_runs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, emit: object) -> None:
    """Whatever a future emitter pastes (here: the transition's text raw in its comment,
    or the text itself as a line of code), the program is refused and nothing runs."""
    monkeypatch.setattr(evolution, "comment", emit)
    chart, marker = careless_chart(tmp_path)
    with pytest.raises(GeneratedCodeRefused):
        compile_grafcet(load_grafcet(str(chart)))
    assert not marker.exists()


def test_the_command_line_says_a_refusal_in_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(evolution, "comment", lambda text: "# " + text)
    chart, marker = careless_chart(tmp_path)
    assert main(["compile", str(chart)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("softplc: error: generated code of <grafcet")
    assert not marker.exists()


def test_the_same_chart_with_the_compilers_comments_runs(tmp_path: Path) -> None:
    chart, marker = careless_chart(tmp_path)
    inst = Instance("t", compile_grafcet(load_grafcet(str(chart))))
    for k, a in enumerate([0, 1, 1]):
        inst.set("iA", bool(a))
        inst.scan(k * 10 * MS, k * 10 * MS)
    assert inst.active_steps() == ["s2"] and not marker.exists()


def test_code_from_a_book_is_checked_where_it_runs() -> None:
    """A code object handed over by the reload's child is checked in the process that runs
    it: a book whose entry for an innocent text holds other code is refused."""
    innocent = "def x():\n    pass\n"
    book = CodeBook(record=True)
    book.compile(innocent, "<a>", ())
    (key,) = book.blobs
    evil = compile("def x():\n    import os\n", "<a>", "exec")
    forged = CodeBook({key: marshal.dumps(evil)})
    with pytest.raises(GeneratedCodeRefused, match="the operation IMPORT_NAME"):
        forged.compile(innocent, "<a>", ())


#: other CPython versions of this machine (pyenv's), on which the operations of every
#: generated program of configs/ are checked against guard.OPERATIONS
OTHER_PYTHONS = sorted(p for p in Path("/root/.pyenv/versions").glob("3.1[2-9]*/bin/python3")
                       ) if Path("/root/.pyenv/versions").is_dir() else []


@pytest.mark.skipif(not OTHER_PYTHONS, reason="no other CPython 3.12+ on this machine")
@pytest.mark.parametrize("python", OTHER_PYTHONS, ids=[p.parts[-3] for p in OTHER_PYTHONS])
def test_the_operations_of_other_pythons_are_known(python: Path, tmp_path: Path) -> None:
    """The generated programs of every chart and plant of configs/ and of the scale test's
    shapes (long tuples, stable rounds), compiled by another CPython (3.12, 3.13 ...), pass
    the check run by that CPython."""
    sources, names = [], set(SCAN_GLOBALS)
    for chart in sorted(ROOT.glob("configs/*/*.yaml")):
        text = chart.read_text(encoding="utf-8")
        if text.lstrip("# \n").startswith(("grafcet:", "yaml-language")) and "steps:" in text:
            sources.append(Compiler(load_grafcet(str(chart))).generate())
    for make, n in SHAPES.values():
        (tmp_path / "shape.yaml").write_text(make(n), encoding="utf-8")
        sources.append(Compiler(load_grafcet(str(tmp_path / "shape.yaml"))).generate())
    for plant in sorted(ROOT.glob("configs/*/plant_sim.yaml")):
        built = Plant(load_plant(str(plant)), sim=True)
        sources += [built.source, *built._inliner.sources]
        names |= set(built._env)
    (tmp_path / "sources.json").write_text(json.dumps(sources), encoding="utf-8")
    script = ("import json, sys\nfrom runtime.compiler.guard import checked_code\n"
              "names = json.loads(sys.argv[2])\n"
              "for s in json.load(open(sys.argv[1])):\n"
              "    checked_code(s, '<other>', names)\nprint('ok', sys.version_info[:2])\n")
    out = subprocess.run([str(python), "-I", "-c", f"import sys; sys.path.insert(0, {str(ROOT)!r})"
                          f"\n{script}", str(tmp_path / "sources.json"),
                          json.dumps(sorted(names))],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")
