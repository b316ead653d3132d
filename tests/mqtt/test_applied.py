"""After the safe reaction, a Sparkplug host application sees the outputs the machine has.

Issue: the controller halted (a console session holding a force ended) and every output
point went to 0, but the displays kept the stopped chart's value. The edge node's metrics
come from the feed, which reads a chart output as applied (its point, through the binding:
runtime/engine/names.py). ``softplc run`` and ``softplc mqtt`` as processes, Debian's
mosquitto, the independent host application (pysparkplug)."""

from __future__ import annotations

import socket
from pathlib import Path

from tests.mqtt.kit import wait_until
from tests.mqtt.test_sparkplug import births_seen, edge


def test_an_output_metric_goes_off_when_the_outputs_are_held_off(tmp_path: Path) -> None:
    sock = tmp_path / "c.sock"
    console = f"monitor:\n  socket: {{path: '{sock}', trusted: true}}\n"
    with edge(tmp_path, opcua=console) as e:
        births_seen(e)
        wait_until(sock.exists, 30, "the console socket")
        held = socket.socket(socket.AF_UNIX)
        held.connect(str(sock))
        f = held.makefile("rw", encoding="utf-8", newline="\n")
        f.write("force t1.oLamp 1\n")
        f.flush()
        while not f.readline().startswith(("ok", "error")):
            pass
        wait_until(lambda: e.host.latest("t1", "Outputs/oLamp") is True, 30, "the lamp on")
        f.close()
        held.close()  # the session holding a force ends: halted, every output off
        wait_until(lambda: e.host.latest(None, "Controller/state") == "halted", 30,
                   "the halt published")
        wait_until(lambda: e.host.latest("t1", "Outputs/oLamp") is False, 15,
                   "Outputs/oLamp off (it kept the stopped chart's 1)")
        e.alive()
        assert not e.problems(), e.problems()
