"""The console's ``web USER ADDRESS`` (docs/console.md): only on a plant with ``web:``,
once per session, with words that can go into a log line; the session then acts without
a PIN under the name ``web:USER@ADDRESS``."""

from __future__ import annotations

from pathlib import Path

from tests.console.consolekit import make_rig
from tests.web.kit import rig


def test_web_is_refused_on_a_plant_without_a_web_section() -> None:
    r = make_rig(serial_port=False, trusted=False)
    try:
        c = r.connect()
        assert c.error("web op 127.0.0.1") == "web: the plant has no web: section"
    finally:
        r.close()


def test_web_names_the_session_once_and_lets_it_act(tmp_path: Path) -> None:
    with rig(tmp_path) as r:
        out = r.console("force tester1.oTest 1", "web other x", "unforce tester1.oTest")
        assert out == ["acting for web:test@local", "ok", "tester1.oTest forced to 1", "ok",
                       "error web: this session already acts for web:test@local",
                       "tester1.oTest released", "ok"]
        assert r.console("web a;b x", "force tester1.oTest 1", act=False) == [
            "error usage: web USER ADDRESS", "error changing commands are disabled on this "
            "console: no pin_hash in the plant file and the console is not trusted"]
        log = r.ctl.log()
        assert "acts for web:test@local" in log
        assert "console web:test@local: force tester1.oTest" in log, log
