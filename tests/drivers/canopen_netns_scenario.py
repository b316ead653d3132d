"""Run inside a private network namespace by test_canopen.py: the CiA 401 node in another
process, the driver here, both on python-can's udp_multicast bus. Prints one JSON line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from drivers.base import Direction, Health
from drivers.canopen_io import CanopenDriver

HERE = os.path.dirname(os.path.abspath(__file__))
GROUP = "239.74.163.2"
#: the longest any step may take, seconds
STEP_TIMEOUT_S = 10.0


def start_slave() -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, os.path.join(HERE, "canopen_slave.py"),
                             "--interface", "udp_multicast", "--channel", GROUP, "--node", "5",
                             "--echo"], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "ready":
        raise RuntimeError("slave did not start")
    return proc


def scan_until(d: CanopenDriver, cond: object) -> bool:
    deadline = time.monotonic() + STEP_TIMEOUT_S
    while time.monotonic() < deadline:
        d.read()
        d.write()
        if callable(cond) and cond():
            return True
        time.sleep(0.01)  # a 10 ms cycle
    return False


def main() -> None:
    result: dict[str, object] = {}
    slave = start_slave()
    d = CanopenDriver("rio", {"interface": "udp_multicast", "channel": GROUP, "node": 5,
                              "heartbeat": "300ms"})
    d.add_point("I0", Direction.IN)
    d.add_point("Q0", Direction.OUT)
    try:
        d.open()
        result["opened"] = d.health.value if d.health is not Health.FAULT else d.fault_reason
        d.outputs["Q0"] = 1
        result["round_trip"] = scan_until(d, lambda: d.inputs["I0"] == 1)
        slave.kill()
        slave.wait()
        scan_until(d, lambda: d.health is Health.FAULT)
        result["lost"] = d.health.value
        result["lost_reason"] = d.fault_reason
        slave = start_slave()
        scan_until(d, lambda: d.health is Health.OK and d.inputs["I0"] == 1)
        result["back"] = d.health.value
    finally:
        d.close()
        slave.terminate()
        slave.wait(10)
        if slave.stdout is not None:
            slave.stdout.close()
    sys.stdout.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
