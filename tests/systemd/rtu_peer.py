"""A Modbus RTU I/O module on a pseudo-terminal, for the journeys under a real systemd:
pymodbus' serial server (tests/drivers/modbus_peer.py) on one end of a null-modem pair of
ptys (tests/drivers/pty_bridge.py), the other end linked at ``--link`` (e.g. /dev/ttyRTU)
with the owner and mode of a USB serial adapter (root:dialout 0660), so that the service
opens it as it would /dev/ttyUSB0.

Every write request the module receives is appended to ``--log`` as one JSON line
``{"t": wall seconds, "fc": 15, "address": 0, "values": [1, 0]}``: the outputs as the
module saw them, whoever wrote them (a controller killed and restarted writes its "every
output off" first). The process prints ``ready`` once it listens, and runs until killed.

    python rtu_peer.py --link /dev/ttyRTU --log /root/rtu.jsonl
"""

from __future__ import annotations

import argparse
import grp
import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from tests.drivers.modbus_peer import ModbusPeer, announce_and_serve  # noqa: E402
from tests.drivers.pty_bridge import PtyBridge  # noqa: E402


class RecordingPeer(ModbusPeer):
    """The module, writing down every write request it serves."""

    def __init__(self, port: str, log: Path) -> None:
        super().__init__(port, (1,))
        self.log = log
        self._lock = threading.Lock()

    async def _action(self, unit: int, function_code: int, start_address: int, address: int,
                      count: int, registers: list[int], set_values: Any) -> Any:
        if function_code in (5, 6, 15, 16) and set_values is not None:
            line = json.dumps({"t": time.time(), "fc": function_code, "address": address,
                               "values": [int(v) for v in set_values]})
            with self._lock, open(self.log, "a", encoding="utf-8") as f:
                f.write(line + "\n")
        return await super()._action(unit, function_code, start_address, address, count,
                                      registers, set_values)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--link", required=True, help="the path the plant's driver opens")
    ap.add_argument("--log", required=True, type=Path)
    args = ap.parse_args()
    bridge = PtyBridge()
    os.chown(bridge.driver_port, 0, grp.getgrnam("dialout").gr_gid)
    os.chmod(bridge.driver_port, 0o660)
    if os.path.lexists(args.link):
        os.unlink(args.link)
    os.symlink(bridge.driver_port, args.link)
    announce_and_serve(RecordingPeer(bridge.peer_port, args.log).start())


if __name__ == "__main__":
    main()
