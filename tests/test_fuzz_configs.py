"""Fuzzing every file of configs/: random mutations of its bytes, of its YAML structure, of
its expression text, and of the drivers' config keys. The property: ``softplc compile``
and ``softplc check`` give a clean result or one clean ``FILE:LINE:COL: error:`` line,
never a traceback nor a hang (each case has a deadline).

The commands run in-process (``runtime.cli.main``) for speed, and a few in a subprocess.
The default run tries ``FUZZ_EXAMPLES`` cases per strategy (about 10 s in all on an idle
machine); the slow test tries ten times as many.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.config import ConfigKey, Kind
from drivers.registry import DRIVER_KEYS
from runtime.cli import main

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
#: every YAML file of configs/, relative to it
FILES = sorted(str(p.relative_to(CONFIGS)) for p in CONFIGS.glob("*/*.yaml"))
#: the plant files (they have drivers)
PLANTS = [f for f in FILES if "plant" in Path(f).name]
#: cases per strategy in the default run
FUZZ_EXAMPLES = int(os.environ.get("SOFTPLC_FUZZ_EXAMPLES", "100"))
#: the longest one case may take, s (compile and check of one file, on a busy machine)
DEADLINE_S = 20.0
#: a diagnostic line of check, or the error line of a refusal
LINE = re.compile(r"^(\S.*:\d+:\d+: (error|warning|note)( G\d{3})?: .+|softplc: error: .+)$")
#: what the tests tried, by strategy (the report's counts)
TRIED: dict[str, int] = {}


class Hang(Exception):
    """A case ran past DEADLINE_S."""


@contextlib.contextmanager
def deadline(seconds: float) -> Iterator[None]:
    def expire(signum: int, frame: Any) -> None:
        raise Hang(f"no answer within {seconds} s")
    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of configs/: a mutated file is written beside its original."""
    root = tmp_path_factory.mktemp("fuzz") / "configs"
    shutil.copytree(CONFIGS, root)
    return root


def softplc(*argv: str) -> tuple[int, list[str]]:
    """``softplc ARGV`` in this process: exit status and the lines written. An exception
    out of main() is a traceback for the user: it fails the test."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    return rc, [ln for ln in (out.getvalue() + err.getvalue()).splitlines() if ln.strip()]


def assert_clean(tree: Path, original: str, data: bytes, strategy: str) -> None:
    """``data`` as a mutation of configs/``original``: compile and check say it cleanly."""
    TRIED[strategy] = TRIED.get(strategy, 0) + 1
    src = tree / original
    path = src.with_name("_fuzz_" + src.name)
    path.write_bytes(data)
    with deadline(DEADLINE_S):
        rc, lines = softplc("compile", str(path))
        assert rc in (0, 2), lines
        if rc == 0:
            assert len(lines) == 1 and lines[0].startswith(f"{path}: ok: "), lines
        else:
            assert len(lines) == 1 and LINE.match(lines[0]), lines
            assert ": error" in lines[0], lines
        rc, lines = softplc("check", "--quiet", str(path))
        assert rc in (0, 2), lines
        for line in lines:
            assert LINE.match(line) or line.startswith(("  ", "\t")), (line, lines)
        if rc == 2:  # an error: a loading error (': error:') or a rule's (': error G...')
            assert sum(": error" in ln for ln in lines) >= 1, lines


# -- strategies -------------------------------------------------------------------------
def _text(f: str) -> bytes:
    return (CONFIGS / f).read_bytes()


@st.composite
def byte_mutation(draw: st.DrawFn) -> tuple[str, bytes]:
    """A file with a few bytes replaced, inserted or deleted (NUL, bad UTF-8, controls)."""
    f = draw(st.sampled_from(FILES))
    data = bytearray(_text(f))
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(data)))
        op = draw(st.sampled_from(["replace", "insert", "delete"]))
        chunk = draw(st.one_of(st.binary(min_size=1, max_size=4),
                               st.sampled_from([b"\x00", b"\xff\xfe", b"\t", b":", b"- ",
                                                b"\n  ", b"{", b"]", b"&a", b"*a", b"!!python/"
                                                b"object:os.system", b"\x1b[2J"])))
        if op == "insert":
            data[at:at] = chunk
        elif op == "replace":
            data[at:at + len(chunk)] = chunk
        else:
            del data[at:at + draw(st.integers(1, 40))]
    return f, bytes(data)


SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True),
    st.text(max_size=12), st.sampled_from(["10ms", "0s", "-5ms", "1" * 400 + "s", "T#5s",
                                           "5 s", ".inf", "0x20", "can0", "/dev/ttyUSB0"]))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=6)


def _paths(node: Any, at: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every place in a YAML tree, as the keys/indices leading to it."""
    out = [at]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*at, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*at, i))
    return out


def _set(tree: Any, at: tuple[Any, ...], value: Any, delete: bool = False) -> Any:
    if not at:
        return value
    parent = tree
    for k in at[:-1]:
        parent = parent[k]
    if delete:
        del parent[at[-1]]
    else:
        parent[at[-1]] = value
    return tree


def _dump(tree: Any) -> bytes:
    return yaml.safe_dump(tree, sort_keys=False, allow_unicode=True).encode("utf-8")


@st.composite
def structure_mutation(draw: st.DrawFn) -> tuple[str, bytes]:
    """A file whose YAML tree had a node deleted, replaced or moved."""
    f = draw(st.sampled_from(FILES))
    tree = yaml.safe_load(_text(f))
    for _ in range(draw(st.integers(1, 3))):
        places = _paths(tree)
        at = draw(st.sampled_from(places))
        op = draw(st.sampled_from(["delete", "replace", "copy"]))
        if op == "delete" and at:
            tree = _set(tree, at, None, delete=True)
        elif op == "copy":
            src = draw(st.sampled_from(places))
            node = tree
            for k in src:
                node = node[k]
            tree = _set(tree, at, yaml.safe_load(yaml.safe_dump(node)))
        else:
            tree = _set(tree, at, draw(VALUES))
    return f, _dump(tree)


TOKENS = ["AND", "OR", "NOT", "(", ")", ">=", "<>", "=", ":=", "+", "-", "*", "/", "MOD",
          ".X", ".T", ".Ini", ".End()", "T#", "5 s", "1" * 40, "9" * 400 + "ms", "1e999",
          "↑", "↓", "RE ", "TRUE", "'", '"', "#", "[", "]", ",", ";", "@", "\\", "\t", "™"]


@st.composite
def expression_mutation(draw: st.DrawFn) -> tuple[str, bytes]:
    """A chart whose text (conditions, actions, names) had tokens put in or taken out."""
    f = draw(st.sampled_from([f for f in FILES if f not in PLANTS]))
    tree = yaml.safe_load(_text(f))
    strings = [at for at in _paths(tree) if at and isinstance(_get(tree, at), str)]
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.sampled_from(strings))
        text = _get(tree, at)
        pos = draw(st.integers(0, len(text)))
        if draw(st.booleans()):
            new = text[:pos] + draw(st.sampled_from(TOKENS)) + text[pos:]
        else:
            new = text[:pos] + text[pos + draw(st.integers(1, 8)):]
        tree = _set(tree, at, new)
    return f, _dump(tree)


def _get(tree: Any, at: tuple[Any, ...]) -> Any:
    for k in at:
        tree = tree[k]
    return tree


#: plants with bus drivers (the others have sim drivers only)
BUS_PLANTS = [f for f in PLANTS if "sim" not in f]
#: values near the edges of drivers' config keys
EDGES = st.one_of(
    st.sampled_from([0, -1, 1, 2, 3, 7, 8, 63, 64, 127, 128, 247, 248, 0x1F, 0x20, 0x27, 0x28,
                     0x37, 0x38, 0x3F, 0x40, 0x77, 0x78, 255, 300, 1200, 12345, 19200,
                     250000, 300000, 2**63, 1e300, -0.0, float("nan"), float("inf"), True,
                     "0x20", "0x1g", "", " ", "0", "0ms", "-1ms", "1" * 400 + "s",
                     "9" * 400, "1e999s", "T#5ms", "5 parsecs", "µs", "N", "X", "even",
                     "pull_up", "up", "socketcan", "sockcan", "can 0", "a/b", "x" * 300,
                     "/dev/null", "/dev/ttyUSB0", "ttyUSB0", "gpiochip0", "/", None]),
    st.integers(-2**64, 2**64), st.floats(), st.text(max_size=20))


_TIME_TEXTS = ["1" * 400 + "s", "9" * 30 + "h", "1e999s", "0", "0ms", "-1ms", ".5s", "5 ms",
               "T#5ms", "1h1h", "2h", "263s", "4295s", "1.5", "ms", "5", "-0", "1" * 400]
TIMES = st.one_of(
    st.sampled_from(_TIME_TEXTS[:3]), st.sampled_from(_TIME_TEXTS), st.floats(),
    st.tuples(st.integers(10**300, 10**500), st.sampled_from(["s", "ms", "h", " us", ""])).map(
        lambda t: f"{t[0]}{t[1]}"),
    st.integers(-10, 10**25), st.from_regex(r"\A[0-9.]{1,6} ?(us|ms|s|m|h)\Z"))


def near(key: ConfigKey) -> st.SearchStrategy[Any]:
    """Values at and around the declared bounds and choices of ``key``."""
    if key.kind is Kind.DURATION:
        return TIMES
    bounds = [b for b in (key.minimum, key.maximum) if b is not None]
    bounds += [n for r in getattr(key, "ranges", ()) for n in r]
    bounds += [c for c in key.choices if isinstance(c, int)]
    ints = [b + d for b in bounds for d in (-1, 0, 1)]
    texts = [str(c) for c in key.choices] + [f"0x{i:02x}" for i in ints if i >= 0]
    return st.one_of(st.sampled_from(ints or [0]), st.sampled_from(texts or [""]),
                     st.integers(-2**64, 2**64), st.text(max_size=20))


@st.composite
def driver_mutation(draw: st.DrawFn) -> tuple[str, bytes]:
    """A plant whose drivers' config keys got other values (or other types, or unknown
    keys, or were taken out)."""
    f = draw(st.sampled_from(BUS_PLANTS if draw(st.integers(0, 3)) else PLANTS))
    tree = yaml.safe_load(_text(f))
    drivers = tree.get("drivers") or {}
    for _ in range(draw(st.integers(1, 3))):
        name = draw(st.sampled_from(sorted(drivers)))
        spec = drivers[name]
        typ = draw(st.sampled_from([spec.get("type"), *DRIVER_KEYS])) if draw(
            st.integers(0, 5)) == 0 else spec.get("type")
        spec["type"] = typ
        keys = [*DRIVER_KEYS.get(str(typ), {}), "on_fault", "colour"]
        key = draw(st.sampled_from(keys))
        declared = DRIVER_KEYS.get(str(typ), {}).get(key)
        if draw(st.integers(0, 4)) == 0:
            spec.pop(key, None)
        elif declared is not None and draw(st.integers(0, 3)):
            spec[key] = draw(near(declared))
        else:
            spec[key] = draw(EDGES if draw(st.integers(0, 3)) else VALUES)
    return f, _dump(tree)


STRATEGIES: dict[str, Callable[[], st.SearchStrategy[tuple[str, bytes]]]] = {
    "bytes": byte_mutation, "structure": structure_mutation,
    "expression": expression_mutation, "drivers": driver_mutation}


def _fuzz(name: str, examples: int) -> Callable[[Path], None]:
    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                     HealthCheck.function_scoped_fixture])
    @given(case=STRATEGIES[name]())
    def run(tree: Path, case: tuple[str, bytes]) -> None:
        assert_clean(tree, case[0], case[1], name)
    return run


@pytest.mark.parametrize("name", list(STRATEGIES))
def test_mutated_configs_give_a_clean_answer(tree: Path, name: str) -> None:
    _fuzz(name, FUZZ_EXAMPLES)(tree)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(STRATEGIES))
def test_mutated_configs_give_a_clean_answer_long(tree: Path, name: str) -> None:
    _fuzz(name, 10 * FUZZ_EXAMPLES)(tree)


def test_every_config_file_is_fuzzed() -> None:
    assert len(FILES) >= 20 and len(PLANTS) >= 9, FILES


# -- a few as the user runs them ---------------------------------------------------------
#: (file, text, its replacement, check's exit status: 2 for an error of either kind)
SUBPROCESS_CASES = [
    ("modbus_module/plant.yaml", b"parity: E", b"parity: X", 2),
    ("modbus_module/plant.yaml", b"timeout: 100ms", b"timeout: " + b"1" * 400 + b"ms", 2),
    ("pi_mcp23017/plant.yaml", b"exp1.A3", b"exp1.C3", 2),
    ("canopen_node/plant.yaml", b"node: 5", b"node: 128", 2),
    ("drawer_tester/drawer_tester.yaml", b"steps:", b"st\x00eps:", 2),
]


@pytest.mark.parametrize("original, old, new, check_status", SUBPROCESS_CASES)
def test_a_few_mutations_as_a_user_runs_them(tree: Path, original: str, old: bytes,
                                             new: bytes, check_status: int) -> None:
    data = _text(original)
    assert old in data
    path = (tree / original).with_name("_user_" + Path(original).name)
    path.write_bytes(data.replace(old, new, 1))
    for command in ("compile", "check"):
        p = subprocess.run([sys.executable, "-m", "runtime.cli", command, str(path)],
                           capture_output=True, text=True, cwd=ROOT, timeout=120)
        lines = [ln for ln in (p.stdout + p.stderr).splitlines() if ": error" in ln]
        assert p.returncode == (2 if command == "compile" else check_status), (
            command, p.stdout, p.stderr)
        assert "Traceback" not in p.stderr
        assert len(lines) == 1 and lines[0].startswith(f"{path}:"), (command, lines)
