"""Every path a plant file names is read from the plant file's directory when relative,
whatever the working directory of the command that loads it: the MQTT password file and
TLS files, the web view's and the Modbus server's TLS files too (they were read from the
working directory, so ``softplc mqtt``, ``web`` or ``modbus`` started by systemd, whose
working directory is ``/``, looked for ``/secret.txt`` where ``softplc check`` run beside
the plant had found it)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from runtime.language.plantfile import load_plant

ROOT = Path(__file__).resolve().parents[2]
DRAWER = ROOT / "configs" / "drawer_tester"

SECTIONS = """
mqtt:
  brokers: [mqtts://127.0.0.1:8883]
  group_id: Hall
  edge_node_id: press1
  username: node
  password_file: secret.txt
  tls: {ca: pki/ca.pem, certificate: pki/c.pem, private_key: pki/k.pem}
web:
  listen: 127.0.0.1:0
  tls: {certificate: pki/web.pem, private_key: pki/web.key}
modbus:
  listen: off
  tls: {certificate: pki/mb.pem, private_key: pki/mb.key, clients_ca: pki/panels.pem,
        roles: {operator: write}}
"""


def test_mqtt_web_and_modbus_files_are_read_from_the_plant_files_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    site = tmp_path / "site"
    site.mkdir()
    for name in ("drawer_tester.yaml", "plant_sim.yaml"):
        shutil.copy(DRAWER / name, site / name)
    plant = site / "plant_sim.yaml"
    text = plant.read_text(encoding="utf-8")
    plant.write_text(text[:text.index("\nweb:")] + SECTIONS, encoding="utf-8")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    p = load_plant(os.path.relpath(plant))
    assert p.mqtt is not None and p.mqtt.tls is not None and p.web is not None
    assert p.modbus is not None and p.modbus.tls is not None
    got = (p.mqtt.password_file, p.mqtt.tls.ca, p.mqtt.tls.certificate,
           p.mqtt.tls.private_key, p.web.certificate, p.web.private_key,
           p.modbus.tls.certificate, p.modbus.tls.private_key, p.modbus.tls.clients_ca)
    want = tuple(str(site / n) for n in ("secret.txt", "pki/ca.pem", "pki/c.pem",
                                         "pki/k.pem", "pki/web.pem", "pki/web.key",
                                         "pki/mb.pem", "pki/mb.key", "pki/panels.pem"))
    assert got == want
    # an absolute path stays as written
    plant.write_text(plant.read_text(encoding="utf-8").replace(
        "password_file: secret.txt", "password_file: /etc/softplc/secret.txt"),
        encoding="utf-8")
    q = load_plant(str(plant)).mqtt
    assert q is not None and q.password_file == "/etc/softplc/secret.txt"
