"""The disk cache of compiled code (runtime/compiler/codecache.py): an unchanged chart is
not compiled again; a changed chart, compiler or Python is; an entry written without the
cache's key, altered, not private to the user or failing the guard is never run."""

from __future__ import annotations

import logging
import marshal
import os
from pathlib import Path
from types import CodeType

import pytest

from bench.compile import chart_text
from runtime.compiler import codecache
from runtime.compiler.codecache import DIGEST, MIN_SOURCE, CodeCache, entry_name
from runtime.compiler.codegen import SCAN_GLOBALS, Compiler, compile_grafcet
from runtime.compiler.guard import GeneratedCodeRefused, checked_code
from runtime.engine.instance import Instance
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet

NAMES = SCAN_GLOBALS.keys()
#: a program the guard accepts, long enough for the cache
SOURCE = "# a line of comment\n" * (MIN_SOURCE // 20 + 1) + "def make(m, init):\n    return 1\n"


def chart(tmp_path: Path, steps: int = 60, name: str = "big.yaml") -> Grafcet:
    path = tmp_path / name
    path.write_text(chart_text(steps), encoding="utf-8")
    return load_grafcet(str(path))


@pytest.fixture
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    d = tmp_path / "cache"
    monkeypatch.setenv(codecache.ENV, str(d))
    return d


@pytest.fixture
def compiles(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The filenames the cache's caller compiled (a miss), in order."""
    done: list[str] = []

    def counting(source: str, filename: str, names: object) -> CodeType:
        done.append(filename)
        return checked_code(source, filename, names)  # type: ignore[arg-type]

    monkeypatch.setattr(codecache, "checked_code", counting)
    return done


def entries(d: Path) -> list[Path]:
    return sorted(p for p in d.iterdir() if p.name.endswith(".code"))


def test_an_unchanged_chart_is_compiled_once(tmp_path: Path, cache_dir: Path,
                                            compiles: list[str]) -> None:
    g = chart(tmp_path)
    assert len(Compiler(g).generate()) >= MIN_SOURCE  # the chart is large enough to cache
    first = compile_grafcet(g)
    assert len(compiles) == 1
    assert oct(cache_dir.stat().st_mode & 0o777) == "0o700"
    assert [oct(p.stat().st_mode & 0o777) for p in entries(cache_dir)] == ["0o600"]
    assert sorted(p.name for p in cache_dir.iterdir() if not p.name.endswith(".code")) \
        == ["key"]  # nothing left of the key's or the entry's writing
    assert oct((cache_dir / "key").stat().st_mode & 0o777) == "0o600"
    second = compile_grafcet(chart(tmp_path))  # another process would load it again
    assert len(compiles) == 1  # loaded from the cache
    assert marshal.dumps(second.factory.__code__) == marshal.dumps(first.factory.__code__)
    # and it runs as the compiled one
    runs = []
    for prog in (first, second):
        inst = Instance("i", prog)
        out = []
        for k in range(40):
            out.append(inst.scan_in(k * 10_000_000, k * 10_000_000,
                                    *((k >> b) & 1 == 1 for b in range(6))))
        runs.append((out, inst.m[:]))
    assert runs[0] == runs[1]
    assert any(o != runs[0][0][0] for o in runs[0][0])  # the chart did move


def test_a_changed_chart_compiler_or_python_is_compiled_again(
        tmp_path: Path, cache_dir: Path, compiles: list[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    compile_grafcet(chart(tmp_path))
    compile_grafcet(chart(tmp_path, 72, "bigger.yaml"))  # another chart: another source
    assert len(compiles) == 2
    assert len(entries(cache_dir)) == 2
    tag = codecache.VERSION_TAG
    monkeypatch.setattr(codecache, "VERSION_TAG", tag.replace(
        f"softplc-code {codecache.COMPILER_VERSION} ",
        f"softplc-code {codecache.COMPILER_VERSION + 1} "))
    compile_grafcet(chart(tmp_path))  # the compiler's version changed
    assert len(compiles) == 3
    monkeypatch.setattr(codecache, "VERSION_TAG", tag.replace(
        codecache.sys.version, "3.99.0 (another Python)"))
    compile_grafcet(chart(tmp_path))  # the Python changed
    assert len(compiles) == 4
    assert len(entries(cache_dir)) == 4
    monkeypatch.setattr(codecache, "VERSION_TAG", tag)
    compile_grafcet(chart(tmp_path))  # back to this one: its entry is still there
    assert len(compiles) == 4


def test_the_tag_names_python_and_the_compiler() -> None:
    import importlib.util
    import sys
    assert sys.version in codecache.VERSION_TAG
    assert importlib.util.MAGIC_NUMBER.hex() in codecache.VERSION_TAG
    assert f"softplc-code {codecache.COMPILER_VERSION} " in codecache.VERSION_TAG


def test_an_altered_entry_is_refused_and_compiled_again(
        tmp_path: Path, cache_dir: Path, compiles: list[str],
        caplog: pytest.LogCaptureFixture) -> None:
    compile_grafcet(chart(tmp_path))
    [entry] = entries(cache_dir)
    data = bytearray(entry.read_bytes())
    data[DIGEST + len(data) // 2] ^= 1  # one bit of the code
    entry.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING, "runtime.compiler.codecache"):
        compile_grafcet(chart(tmp_path))
    assert len(compiles) == 2
    assert "refused (not written with this cache's key)" in caplog.text
    compile_grafcet(chart(tmp_path))  # the entry was written again, right this time
    assert len(compiles) == 2


def test_an_entry_forged_without_the_key_never_runs(tmp_path: Path, cache_dir: Path,
                                                   compiles: list[str]) -> None:
    g = chart(tmp_path)
    source = Compiler(g).generate()
    prog = compile_grafcet(g)
    name = f"<grafcet {g.name} {prog.factory.__code__.co_filename.split()[-1]}"
    [entry] = entries(cache_dir)
    assert entry.name == entry_name(source, name)
    # whoever can write the directory but has not the key: a code object of their own
    # (one the guard would pass: only the key keeps it out), under the right name, with a
    # digest made under another key
    payload = compile("def make(m, init):\n    return 1\n", name, "exec")
    blob = marshal.dumps(payload)
    import hashlib
    import hmac
    entry.write_bytes(hmac.new(b"x" * DIGEST, entry.name.encode() + b"\0" + blob,
                               hashlib.sha256).digest() + blob)
    entry.chmod(0o600)
    again = compile_grafcet(chart(tmp_path))
    assert len(compiles) == 2  # refused, compiled from the chart
    assert marshal.dumps(again.factory.__code__) == marshal.dumps(prog.factory.__code__)


def test_an_entry_with_the_key_is_still_checked_by_the_guard(tmp_path: Path) -> None:
    """Defence in depth: an entry that passes the HMAC (written with the key) holding code
    the guard refuses is refused by the guard, not run."""
    source = SOURCE
    with CodeCache(str(tmp_path / "c")) as cache:
        bad = compile("import os\n" + source, "<grafcet T 0>", "exec")
        cache.store(source, "<grafcet T 0>", bad)  # as if the key had leaked
        with pytest.raises(GeneratedCodeRefused, match="IMPORT_NAME"):
            cache.load(source, "<grafcet T 0>", NAMES)


def test_an_entry_not_private_to_the_user_is_not_read(tmp_path: Path) -> None:
    source = SOURCE
    code = checked_code(source, "<grafcet T 0>", NAMES)
    d = tmp_path / "c"
    with CodeCache(str(d)) as cache:
        cache.store(source, "<grafcet T 0>", code)
    [entry] = entries(d)
    with CodeCache(str(d)) as cache:
        assert cache.load(source, "<grafcet T 0>", NAMES) is not None
    entry.chmod(0o620)  # another can write it
    with CodeCache(str(d)) as cache:
        assert cache.load(source, "<grafcet T 0>", NAMES) is None
    entry.chmod(0o600)
    moved = d / "elsewhere"
    entry.rename(moved)
    entry.symlink_to(moved)  # a link: not followed
    with CodeCache(str(d)) as cache:
        assert cache.load(source, "<grafcet T 0>", NAMES) is None
    entry.unlink()
    os.link(moved, entry)  # two links: refused
    with CodeCache(str(d)) as cache:
        assert cache.load(source, "<grafcet T 0>", NAMES) is None


@pytest.mark.parametrize("how", ["group writable", "others readable", "a link"])
def test_a_directory_not_private_is_not_used(tmp_path: Path, how: str,
                                            caplog: pytest.LogCaptureFixture) -> None:
    d = tmp_path / "c"
    with CodeCache(str(d)) as cache:
        assert cache.usable
    if how == "group writable":
        d.chmod(0o770)
    elif how == "others readable":
        d.chmod(0o704)
    else:
        (tmp_path / "link").symlink_to(d)
        d = tmp_path / "link"
    source = SOURCE
    with CodeCache(str(d)) as cache:
        assert not cache.usable
        cache.store(source, "<grafcet T 0>", checked_code(source, "<grafcet T 0>", NAMES))
        assert cache.load(source, "<grafcet T 0>", NAMES) is None
    assert not entries(tmp_path / "c")


def test_a_key_not_private_disables_the_cache(tmp_path: Path) -> None:
    d = tmp_path / "c"
    with CodeCache(str(d)) as cache:
        assert cache.usable
    (d / "key").chmod(0o644 | 0o002)
    with CodeCache(str(d)) as cache:
        assert not cache.usable


def test_off_and_small_sources_compile_without_the_cache(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compiles: list[str]) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv(codecache.ENV, "off")
    assert codecache.cache_dir() is None
    compile_grafcet(chart(tmp_path))
    compile_grafcet(chart(tmp_path))
    assert len(compiles) == 2  # compiled each time
    assert not (tmp_path / "xdg").exists()
    monkeypatch.delenv(codecache.ENV)
    assert codecache.cache_dir() == str(tmp_path / "xdg" / "softplc" / "code")
    d = tmp_path / "c"
    monkeypatch.setenv(codecache.ENV, str(d))
    compile_grafcet(chart(tmp_path, 12, "small.yaml"))  # below MIN_SOURCE
    compile_grafcet(chart(tmp_path, 12, "small.yaml"))
    assert len(compiles) == 4
    assert not d.exists()


def test_softplc_compile_as_a_process_uses_the_cache(tmp_path: Path) -> None:
    """The real command: the first run writes the chart's entry, the second reads it (an
    entry altered in between is refused with a warning line, then written again)."""
    import subprocess
    import sys
    chart_path = tmp_path / "big.yaml"
    chart_path.write_text(chart_text(60), encoding="utf-8")
    d = tmp_path / "cache"
    env = {**os.environ, codecache.ENV: str(d)}

    def run() -> str:
        proc = subprocess.run([sys.executable, "-m", "runtime.cli", "compile", str(chart_path)],
                              env=env, capture_output=True, text=True, check=False)
        assert proc.returncode == 0, proc.stderr
        return proc.stderr

    run()
    [entry] = entries(d)
    data = bytearray(entry.read_bytes())
    data[-1] ^= 1
    entry.write_bytes(bytes(data))
    err = run()
    assert "refused (not written with this cache's key)" in err
    assert "compiled in" in err
    assert "refused" not in run()  # written again by the second run
