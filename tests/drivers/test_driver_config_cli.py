"""Driver configuration values and point names, refused when the plant is loaded:
``compile``, ``check`` and ``run`` give the same ``FILE:LINE:COL: error:`` line and exit 2,
never a traceback, whether or not the driver's bus library is installed.

The commands run in-process (``runtime.cli.main``) for the many values, and in a
subprocess for a few, as a user runs them.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.cli import main

ROOT = Path(__file__).resolve().parents[2]
CHART = ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml"

#: (inputs, outputs) points of the drawer tester's 4 inputs and 4 outputs, by driver type
POINTS = {
    "modbus_rtu": (["I0", "I1", "I2", "I3"], ["Q0", "Q1", "Q2", "Q3"]),
    "canopen": (["I0", "I1", "I2", "I3"], ["Q0", "Q1", "Q2", "Q3"]),
    "mcp23017": (["A0", "A1", "A2", "A3"], ["B0", "B1", "B2", "B3"]),
    "pcf8574": (["P0", "P1", "P2", "P3"], ["P4", "P5", "P6", "P7"]),
    "gpio": (["17", "18", "27", "22"], ["23", "24", "25", "5"]),
}
#: a valid config of each type, as YAML text per key
VALID = {
    "modbus_rtu": {"port": "/dev/ttyUSB0", "baudrate": "19200", "parity": "E", "unit": "1",
                   "timeout": "100ms"},
    "canopen": {"interface": "socketcan", "channel": "can0", "bitrate": "250000", "node": "5",
                "heartbeat": "500ms"},
    "mcp23017": {"bus": "1", "address": "0x20"},
    "pcf8574": {"bus": "1", "address": "0x38"},
    "gpio": {"chip": "/dev/gpiochip0", "debounce": "5ms"},
}
INS = ["iParo", "iMarcha", "iAbierto", "iCerrado"]
OUTS = ["oAbrir", "oCerrar", "oParado", "oTest"]


def plant_text(type_name: str, cfg: dict[str, str | None],
               points: tuple[list[str], list[str]] | None = None) -> str:
    """A plant of the drawer tester on one driver ``d``; a key given None is left out."""
    merged = {**VALID[type_name], **cfg}
    ins, outs = points or POINTS[type_name]
    lines = ["plc:", "  cycle: 20ms", "drivers:", "  d:", f"    type: {type_name}"]
    lines += [f"    {k}: {v}" for k, v in merged.items() if v is not None]
    lines += ["instances:", "  t:", "    grafcet: drawer_tester.yaml", "    inputs:"]
    lines += [f"      {s}: d.{p}" for s, p in zip(INS, ins, strict=True)]
    lines += ["    outputs:"]
    lines += [f"      {s}: d.{p}" for s, p in zip(OUTS, outs, strict=True)]
    return "\n".join(lines) + "\n"


@pytest.fixture
def plant(tmp_path: Path) -> Callable[[str], str]:
    shutil.copy(CHART, tmp_path / "drawer_tester.yaml")

    def write(text: str) -> str:
        path = tmp_path / "plant.yaml"
        path.write_text(text, "utf-8")
        return str(path)
    return write


def where(text: str, key: str) -> tuple[int, int]:
    """Line and column of the value of driver key ``key`` in a plant_text (of the text
    inside the quotes of a quoted value)."""
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith(f"    {key}: "):
            value = line[len(f"    {key}: "):]
            quoted = value[0] in "'\"" and len(value) > 2
            return n, len(f"    {key}: ") + 1 + quoted
    raise AssertionError(key)  # pragma: no cover


def run_inproc(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, list[str]]:
    """``softplc ARGV`` in this process: exit status, the lines it wrote (both streams)."""
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, [ln for ln in (out + err).splitlines() if ln.strip()]


def three_commands(capsys: pytest.CaptureFixture[str], path: str) -> list[tuple[int, list[str]]]:
    return [run_inproc(capsys, "compile", path), run_inproc(capsys, "check", path),
            run_inproc(capsys, "run", path, "--for", "1s")]


def assert_same_refusal(results: list[tuple[int, list[str]]], prefix: str) -> str:
    """Each command exits 2 with one line starting ``prefix``, the same line for each."""
    lines = []
    for rc, out in results:
        assert rc == 2, out
        errors = [ln for ln in out if ": error" in ln]
        assert len(errors) == 1, out
        assert errors[0].startswith(prefix), (errors[0], prefix)
        assert not any("Traceback" in ln for ln in out), out
        lines.append(errors[0])
    assert len(set(lines)) == 1, lines
    return lines[0]


# (type, key, bad YAML value, words the refusal says)
BAD_VALUES = [
    ("modbus_rtu", "parity", "X", "expected N, E or O"),
    ("modbus_rtu", "baudrate", "12345", "baud rate"),
    ("modbus_rtu", "baudrate", "0", "baud rate"),
    ("modbus_rtu", "timeout", "0", "positive"),
    ("modbus_rtu", "timeout", "-5ms", "time"),
    ("modbus_rtu", "timeout", "-0.5", "positive"),
    ("modbus_rtu", "timeout", "1" * 400 + "s", "time"),
    ("modbus_rtu", "timeout", ".nan", "time"),
    ("modbus_rtu", "timeout", ".inf", "time"),
    ("modbus_rtu", "unit", "0", "slave address"),
    ("modbus_rtu", "stopbits", "3", "1 or 2"),
    ("modbus_rtu", "port", "''", "serial device"),
    ("modbus_rtu", "port", "ttyUSB0", "serial device"),
    ("canopen", "node", "0", "1-127"),
    ("canopen", "node", "128", "1-127"),
    ("canopen", "bitrate", "300000", "bit rate"),
    ("canopen", "bitrate", "0", "bit rate"),
    ("canopen", "interface", "sockcan", "interface"),
    ("canopen", "channel", "'can 0'", "interface name"),
    ("canopen", "channel", "averyveryverylongname", "interface name"),
    ("canopen", "channel", "can/0", "interface name"),
    ("canopen", "heartbeat", "0ms", "positive"),
    ("canopen", "heartbeat", "300s", "heartbeat"),
    ("canopen", "sync", "-1", "positive"),
    ("canopen", "pdo", "{tpdo9: []}", "tpdo1-tpdo4"),
    ("mcp23017", "address", "0x28", "0x20 to 0x27"),
    ("mcp23017", "address", "0x1f", "0x20 to 0x27"),
    ("mcp23017", "address", "'0x77'", "0x20 to 0x27"),
    ("mcp23017", "bus", "-1", "bus number"),
    ("pcf8574", "address", "0x30", "0x38 to 0x3f"),
    ("pcf8574", "address", "0x40", "0x38 to 0x3f"),
    ("gpio", "chip", "gpiochip0", "/dev/gpiochip"),
    ("gpio", "chip", "''", "/dev/gpiochip"),
    ("gpio", "debounce", "-1", "positive"),
    ("gpio", "debounce", "1" * 400 + "ms", "time"),
    ("gpio", "debounce", "2h", "debounce"),
    ("gpio", "bias", "up", "pull_up"),
]


@pytest.mark.parametrize("type_name, key, value, words", BAD_VALUES)
def test_a_bad_value_is_one_line_at_its_place(plant: Callable[[str], str],
                                              capsys: pytest.CaptureFixture[str],
                                              type_name: str, key: str, value: str,
                                              words: str) -> None:
    text = plant_text(type_name, {key: value})
    path = plant(text)
    line, col = where(text, key)
    got = assert_same_refusal(three_commands(capsys, path), f"{path}:{line}:{col}: error: ")
    assert f"driver d ({type_name}): {key}" in got and words in got, got


# (type, key, value): values just inside the new bounds, accepted by all three commands
GOOD_VALUES = [
    ("modbus_rtu", "baudrate", "9600"), ("modbus_rtu", "baudrate", "115200"),
    ("modbus_rtu", "parity", "even"), ("modbus_rtu", "timeout", "1.5"),
    ("modbus_rtu", "port", "/dev/serial/by-id/usb-FTDI_RS485-if00-port0"),
    ("canopen", "bitrate", "125000"), ("canopen", "bitrate", "1000000"),
    ("canopen", "interface", "virtual"), ("canopen", "channel", "vcan0"),
    ("canopen", "heartbeat", "262s"),
    ("mcp23017", "address", "0x27"), ("mcp23017", "address", "'0x20'"),
    ("pcf8574", "address", "0x20"), ("pcf8574", "address", "0x3f"),
    ("gpio", "chip", "/dev/gpiochip4"), ("gpio", "debounce", "0"),
    ("gpio", "debounce", "1s"),
]


@pytest.mark.parametrize("type_name, key, value", GOOD_VALUES)
def test_a_good_value_compiles(plant: Callable[[str], str], capsys: pytest.CaptureFixture[str],
                               type_name: str, key: str, value: str) -> None:
    path = plant(plant_text(type_name, {key: value}))
    rc, out = run_inproc(capsys, "compile", path)
    assert rc == 0, out


@pytest.mark.parametrize("type_name, key", [("modbus_rtu", "port"), ("canopen", "node"),
                                            ("mcp23017", "address")])
def test_a_required_key_missing_is_one_line_at_the_driver(
        plant: Callable[[str], str], capsys: pytest.CaptureFixture[str], type_name: str,
        key: str) -> None:
    text = plant_text(type_name, {key: None})
    path = plant(text)
    line = text.splitlines().index(f"    type: {type_name}") + 1
    got = assert_same_refusal(three_commands(capsys, path), f"{path}:{line}:5: error: ")
    assert f"driver d ({type_name}): {key}: expected" in got


def cli(*argv: str, block: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    """``softplc ARGV`` in a new interpreter where importing each of ``block`` fails (as
    where that library is not installed)."""
    code = ("import sys\n"
            f"for m in {block!r}:\n"
            "    sys.modules[m] = None\n"
            "from runtime.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    return subprocess.run([sys.executable, "-c", code, *argv], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)


def test_parity_x_as_a_user_runs_it(plant: Callable[[str], str]) -> None:
    text = plant_text("modbus_rtu", {"parity": "X"})
    path = plant(text)
    line, col = where(text, "parity")
    want = (f"{path}:{line}:{col}: error: driver d (modbus_rtu): parity: expected N, E or O, "
            "found 'X'")
    for argv in (("compile", path), ("check", path), ("run", path, "--for", "1s")):
        p = cli(*argv)
        out = [ln for ln in (p.stdout + p.stderr).splitlines() if ": error" in ln]
        assert (p.returncode, out) == (2, [want]), (argv, p.stdout, p.stderr)
        assert "Traceback" not in p.stderr


BAD_POINTS = [
    ("mcp23017", "smbus2", (["A0", "A1", "A2", "C3"], POINTS["mcp23017"][1]),
     "d.C3: an mcp23017 point is A0-A7 or B0-B7"),
    ("mcp23017", "smbus2", (["A0", "A1", "A2", "A8"], POINTS["mcp23017"][1]),
     "d.A8: an mcp23017 point is A0-A7 or B0-B7"),
    ("pcf8574", "smbus2", (["P0", "P1", "P2", "P8"], POINTS["pcf8574"][1]),
     "d.P8: a pcf8574 point is P0-P7"),
    ("canopen", "canopen", (["I0", "I1", "I2", "Q7"], POINTS["canopen"][1]),
     "d.Q7 is an output (0x6200): it cannot be bound as an input"),
    ("canopen", "canopen", (["I0", "I1", "I2", "I64"], POINTS["canopen"][1]),
     "d.I64: a canopen point is I0-I63 (0x6000) or Q0-Q63 (0x6200)"),
    ("modbus_rtu", "serial", (POINTS["modbus_rtu"][0], ["Q0", "Q1", "Q2", "I3"]),
     "d.I3 is a discrete input: read-only, it cannot be bound as an output"),
    ("modbus_rtu", "serial", (POINTS["modbus_rtu"][0], ["Q0", "Q1", "Q2", "X3"]),
     "d.X3: a modbus_rtu point is I<n>"),
    ("gpio", "gpiod", (["17", "18", "27", "022"], POINTS["gpio"][1]),
     "d.022: a gpio point is a line offset such as d.17"),
    ("gpio", "gpiod", (["17", "18", "27", "22"], ["23", "24", "25", "17"]),
     "d.17 is already bound as an input"),
]


@pytest.mark.parametrize("type_name, library, points, words", BAD_POINTS)
def test_a_bad_point_is_refused_without_the_library(
        plant: Callable[[str], str], capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch, type_name: str, library: str,
        points: tuple[list[str], list[str]], words: str) -> None:
    for mod in [m for m in sys.modules if m == library or m.startswith(f"{library}.")
                or m.startswith("drivers.") and m not in ("drivers.base", "drivers.config",
                                                          "drivers.registry",
                                                          "drivers.durations")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, library, None)  # import fails: not installed
    text = plant_text(type_name, {}, points)
    path = plant(text)
    bad = words.split()[0].removesuffix(":")  # d.C3
    line = max(n for n, ln in enumerate(text.splitlines(), 1) if ln.endswith(f" {bad}"))
    col = text.splitlines()[line - 1].index("d.") + 1
    rc, out = run_inproc(capsys, "compile", path)
    assert rc == 2, out
    assert len(out) == 1 and out[0].startswith(f"{path}:{line}:{col}: error: {words}"), out
    rc, out = run_inproc(capsys, "check", path)
    assert rc == 2, out  # a rule error (G303), listed with the others: 2 as compile
    errors = [ln for ln in out if ": error" in ln]
    assert errors == [out[0].replace(": error:", ": error G303:")] or errors[0].startswith(
        f"{path}:{line}:{col}: error G303: {words}"), out


def test_mcp23017_port_c_refused_by_compile_without_smbus2(plant: Callable[[str], str]) -> None:
    """The issue's case, as a user meets it: smbus2 not installed, ``exp1.C3``."""
    text = plant_text("mcp23017", {}, (["A0", "A1", "A2", "C3"], POINTS["mcp23017"][1]))
    path = plant(text)
    p = cli("compile", path, block=("smbus2",))
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "d.C3: an mcp23017 point is A0-A7 or B0-B7" in p.stderr
    assert "Traceback" not in p.stderr
