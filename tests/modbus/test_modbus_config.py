"""The ``modbus:`` section of a plant file and its map: defaults, the default map from the
I/O list and from IEC located addresses (OpenPLC's map), explicit entries, every key
checked at its position (FILE:LINE:COL), ``softplc modbus --map``, and what ``softplc
diff`` says of an edit."""

from __future__ import annotations

import csv
import io
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.change.diff import diff_plants
from runtime.errors import SourceError
from runtime.language.plantfile import load_plant
from runtime.modbus.tables import Tables, decode, encode
from tests.modbus.kit import ROOT, write_plant


def plant(tmp: Path, modbus: str = "", replace: tuple[str, str] = ("", ""),
          port: int = 5020) -> Path:
    path, _ = write_plant(tmp, modbus, port=port)
    if replace[0]:
        text = path.read_text(encoding="utf-8")
        assert replace[0] in text
        path.write_text(text.replace(replace[0], replace[1]), encoding="utf-8")
    return path


def error_of(tmp: Path, modbus: str = "", replace: tuple[str, str] = ("", "")) -> str:
    with pytest.raises(SourceError) as e:
        load_plant(str(plant(tmp, modbus, replace)))
    return str(e.value)


def points(tmp: Path, modbus: str = "", replace: tuple[str, str] = ("", "")
           ) -> dict[str, tuple[str, int, str, bool, str]]:
    pdef = load_plant(str(plant(tmp, modbus, replace)))
    assert pdef.modbus is not None
    return {p.name: (p.table, p.address, p.type, p.writable, p.origin)
            for p in pdef.modbus.points}


def test_the_default_map_follows_the_io_list(tmp_path: Path) -> None:
    pts = points(tmp_path)
    # bound inputs: discrete inputs in plant order; outputs: coils; then the writable names
    assert [n for n, p in pts.items() if p[0] == "I"] == [
        f"tester{t}.{s}" for t in (1, 2) for s in ("iParo", "iMarcha", "iAbierto", "iCerrado")]
    assert [(n, p[1]) for n, p in pts.items() if p[0] == "Q"][-1] == ("tester1.sParo", 8)
    assert pts["tester1.sCierres"] == ("HR", 0, "INT", True, "writable")
    assert pts["tester2.oTest"] == ("Q", 7, "BOOL", False, "iolist")


def test_located_addresses_follow_openplcs_map(tmp_path: Path) -> None:
    """A binding's at: puts its signal where OpenPLC's map puts that located address
    (%IX1.2 -> discrete input 10, %QX0.5 -> coil 5); the others take the free addresses
    around them; %MW and %MD in map: are holding registers from 1024 and 2048."""
    pts = points(tmp_path, "  map:\n    tester1.sCierres: '%MW3'\n"
                           "    tester2.sCierres: '%MD1'\n",
                 ("iMarcha:  {from: sim.I1,", "iMarcha:  {from: sim.I1, at: '%IX1.2',"))
    assert pts["tester1.iMarcha"] == ("I", 10, "BOOL", False, "at")
    assert pts["tester1.iParo"][:2] == ("I", 0) and pts["tester1.iAbierto"][:2] == ("I", 1)
    assert pts["tester1.sCierres"] == ("HR", 1027, "INT", True, "map")
    assert pts["tester2.sCierres"] == ("HR", 2050, "DINT", False, "map")
    pts = points(tmp_path, "", ("oTest:   {from: sim.Q3,", "oTest:   {from: sim.Q3, at: '%QX0.5',"))
    assert pts["tester1.oTest"] == ("Q", 5, "BOOL", False, "at")
    assert pts["tester2.oParado"][:2] == ("Q", 6)  # coil 5 was taken: the next free ones


@pytest.mark.parametrize(("modbus", "replace", "words"), [
    ("  clients: []\n", ("", ""), "an empty list lets nobody in"),
    ("  clients: [plc7]\n", ("", ""), "'plc7' is no address or network"),
    ("  unit: 300\n", ("", ""), "modbus unit: expected 0-255, found 300"),
    ("  words: big\n", ("", ""), "expected high_first"),
    ("  colour: red\n", ("", ""), "unknown key 'colour' in modbus"),
    ("  map:\n    tester1.iParo: HR0\n", ("", ""),
     "tester1.iParo is a bool: it goes to a coil (Q) or a discrete input (I), not to HR0"),
    ("  map:\n    tester1.sCierres: I3\n", ("", ""), "is a number"),
    ("  map:\n    tester1.sParo: I40\n", ("", ""),
     "tester1.sParo is writable but I40 is read-only over Modbus: put it at a coil (Q)"),
    ("  map:\n    tester1.gsAbrir.X: Q0\n    tester1.gsCerrar.X: Q0\n", ("", ""),
     "tester1.gsCerrar.X at Q0 overlaps tester1.gsAbrir.X at Q0 (map)"),
    ("  map:\n    tester1.gsAbrir.X: Q5\n",
     ("oTest:   {from: sim.Q3,", "oTest:   {from: sim.Q3, at: '%QX0.5',"),
     "tester1.oTest at Q5 overlaps tester1.gsAbrir.X at Q5 (map)"),
    ("  map:\n    tester1.sCierres: {at: HR0, type: DINT}\n    tester2.sCierres: HR1\n",
     ("", ""), "tester2.sCierres at HR1 overlaps tester1.sCierres at HR0 (map)"),
    ("  map:\n    tester1.sCierres: {at: HR0, type: REAL}\n", ("", ""),
     "tester1.sCierres is a int: it cannot be sent as REAL"),
    ("  map:\n    tester1.sCierres: {at: HR0, type: LREAL}\n", ("", ""),
     "type 'LREAL': expected one of BOOL, INT"),
    ("  map:\n    tester1.gsAbrir.T: '%MW0'\n", ("", ""),
     "a TIME takes two registers: a %..W holds one"),
    ("  map:\n    tester1.sCierres: '%IX0.9'\n", ("", ""), "a bit address needs its bit"),
    ("  map:\n    tester1.sCierres: '%MW1024'\n", ("", ""), "go up to %MW1023"),
    ("  map:\n    tester1.sCierres: HR70000\n", ("", ""), "an address is 0-65535"),
    ("  map:\n    sim.I0: I20\n", ("", ""), "is a driver point"),
    ("  map:\n    tester1.SFCCurrentStep: HR5\n", ("", ""), "is a string"),
    ("  map:\n    tester1.gsNada.X: Q20\n", ("", ""), "no variable or step 'gsNada.X'"),
    ("  map:\n    tester1.tParo: Q20\n", ("", ""), "is a temporary"),
    ("", ("listen: 127.0.0.1:", "listen: 0.0.0.0:"),
     "0.0.0.0 is reachable from other machines and plain Modbus/TCP has no security"),
    ("", ("listen: 127.0.0.1:", "listen: 127.0.0.1:x"), "expected HOST:PORT"),
    ("  tls: {certificate: /c.pem, private_key: /k.pem}\n", ("", ""),
     "modbus tls: expected clients_ca"),
    ("  tls: {certificate: /c.pem, private_key: /k.pem, clients_ca: /ca.pem}\n", ("", ""),
     "expected roles"),
    ("  tls: {certificate: /c.pem, private_key: /k.pem, clients_ca: /ca.pem, "
     "roles: {op: all}}\n", ("", ""), "modbus tls roles: op: expected read or write"),
    ("  limits: {rate: 0}\n", ("", ""), "modbus limits rate: expected 1 to 100000"),
    ("  limits: {idle: 10ms}\n", ("", ""), "expected 1s to 24h"),
    ("", ("writable: [tester1.sParo, tester1.sCierres]", "writable: [tester1.oAbrir]"),
     "tester1.oAbrir' is an output"),
    ("", ("iMarcha:  {from: sim.I1,", "iMarcha:  {from: sim.I1, at: '%QX0.1',"),
     "at: %QX0.1 cannot locate the bool input 'iMarcha': expected %IX<byte>.<bit>"),
    ("", ("iMarcha:  {from: sim.I1,", "iMarcha:  {from: sim.I1, at: IX0.1,"),
     "'IX0.1' is no located address"),
])
def test_every_refusal_at_its_place(tmp_path: Path, modbus: str, replace: tuple[str, str],
                                    words: str) -> None:
    text = error_of(tmp_path, modbus, replace)
    assert words in text, text
    assert text.startswith(str(tmp_path / "p" / "plant.yaml") + ":"), text
    line, col = (int(x) for x in text.split(":")[1:3])
    assert line > 1 and col >= 1


def test_listen_off_with_tls_and_clients(tmp_path: Path) -> None:
    pdef = load_plant(str(plant(tmp_path, (
        "  clients: [192.168.10.0/24, 10.0.0.7]\n"
        "  tls: {listen: 0.0.0.0:802, certificate: /c.pem, private_key: /k.pem, "
        "clients_ca: /ca.pem, roles: {operator: write, viewer: read}}\n"),
        ("listen: 127.0.0.1:", "listen: 'off'\n  #"))))
    m = pdef.modbus
    assert m is not None and m.host == "" and m.tls is not None
    assert m.clients == ["192.168.10.0/24", "10.0.0.7/32"]
    assert (m.tls.host, m.tls.port, m.tls.roles) == ("0.0.0.0", 802,
                                                     {"operator": "write", "viewer": "read"})


def test_registers_to_and_from_values() -> None:
    from runtime.language.model import ModbusPoint

    def pt(t: str) -> ModbusPoint:
        return ModbusPoint("x", "HR", 0, t)
    assert encode(pt("INT"), -2) == ([0xFFFE], False)
    assert encode(pt("INT"), 70000) == ([0x7FFF], True)  # clipped, and said
    assert encode(pt("UINT"), -1) == ([0], True)
    assert encode(pt("DINT"), -2) == ([0xFFFF, 0xFFFE], False)
    assert encode(pt("DINT"), -2, high_first=False) == ([0xFFFE, 0xFFFF], False)
    assert encode(pt("REAL"), 1.5) == ([0x3FC0, 0], False)
    assert encode(pt("TIME"), 1_500_000_000) == ([0, 1500], False)  # ns -> ms
    assert decode(pt("INT"), [0xFFFE]) == -2
    assert decode(pt("DINT"), [0xFFFF, 0xFFFE]) == -2
    assert decode(pt("REAL"), [0x3FC0, 0]) == 1.5
    assert decode(pt("TIME"), [0, 1500]) == 1_500_000_000
    assert decode(pt("BOOL"), [1]) is True
    t = Tables([ModbusPoint("a", "HR", 2, "DINT", True), ModbusPoint("b", "Q", 3, "BOOL")])
    assert t.size == {"Q": 4, "I": 0, "IR": 0, "HR": 4}
    t.refresh(lambda name: {"a": 65537, "b": True}[name])
    assert t.read("HR", 0, 4) == [0, 0, 1, 1] and t.read("Q", 0, 4) == [0, 0, 0, 1]
    assert [w.value for w in t.writes("HR", 2, [0, 9], lambda n: True)] == [9]


def test_map_command_prints_what_a_tag_editor_takes(tmp_path: Path) -> None:
    path = plant(tmp_path, "  map:\n    tester2.sCierres: IR4\n")
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "modbus", "--map", "--csv",
                        str(path)], capture_output=True, text=True, cwd=ROOT, timeout=120,
                       check=False)
    assert r.returncode == 0, r.stderr
    rows = list(csv.reader(io.StringIO(r.stdout)))
    assert rows[0] == ["ref", "address", "type", "name", "description", "unit", "access"]
    by_name = {row[3]: row for row in rows[1:]}
    assert by_name["tester1.iParo"] == ["100001", "DI 0", "BOOL", "tester1.iParo",
                                        "Pulsador de paro SJP (NC)", "", "R"]
    assert by_name["tester1.sParo"][:3] + by_name["tester1.sParo"][-1:] == [
        "000009", "coil 8", "BOOL", "RW"]
    assert by_name["tester1.sCierres"][:3] == ["400001", "HR 0", "INT"]
    assert by_name["tester2.sCierres"][:3] == ["300005", "IR 4", "INT"]
    # a plant without modbus: gets the default map (what modbus: {} would serve)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "modbus", "--map",
                        str(ROOT / "configs/drawer_tester/plant_sim.yaml")],
                       capture_output=True, text=True, cwd=ROOT, timeout=120, check=False)
    assert r.returncode == 0 and "100001  DI 0" in r.stdout, r.stdout + r.stderr


def test_diff_names_what_the_server_reads_at_its_start(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    old = load_plant(str(plant(tmp_path / "a")))
    new = load_plant(str(plant(tmp_path / "b", "  map:\n    tester2.sCierres: IR4\n",
                               ("writable: [tester1.sParo, tester1.sCierres]",
                                "writable: [tester1.sParo]"))))
    lines = diff_plants(old, new).lines()
    assert "plant: modbus writable changed: [tester1.sParo, tester1.sCierres] -> " \
           "[tester1.sParo]" in lines, lines
    assert any(ln.startswith("plant: modbus map changed: applied when the Modbus/TCP server "
                             "restarts") for ln in lines), lines
    assert not any("listen" in ln or "port" in ln for ln in lines), lines


def test_a_port_in_use_is_one_line(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        path = plant(tmp_path, port=port)
        r = subprocess.run([sys.executable, "-m", "runtime.cli", "modbus", str(path)],
                           capture_output=True, text=True, cwd=tmp_path, timeout=120,
                           check=False, env={**os.environ, "PYTHONPATH": str(ROOT),
                                             "XDG_RUNTIME_DIR": str(tmp_path)})
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"softplc modbus: error: 127.0.0.1:{port}: ") and "in use" in lines[0], r.stderr
