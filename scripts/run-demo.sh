#!/usr/bin/env bash
# Set up a virtual environment and run the two drawer testers of
# configs/drawer_tester/plant_sim.yaml on simulated I/O, in real time, with the story of
# configs/drawer_tester/story.yaml playing their buttons and limit switches, and the
# console on a Unix socket in the plant's own runtime directory, ${RUNTIME_DIR} of the plant
# file: $XDG_RUNTIME_DIR/softplc/drawer_tester-HASH, else /tmp/softplc-$UID/drawer_tester-HASH
# (HASH: of this clone's configs/drawer_tester, so the demos of two clones run side by side;
# created 0700; docs/daemon.md). Beside it, `softplc web` serves the live page of the plant
# (docs/web.md) on 127.0.0.1:8080, or the next free port up to 8099 when another demo has
# it (WEB_LISTEN=HOST:PORT to choose; log in as demo, password demo, to act). The script
# prints the socket's path, the command for a second terminal, e.g.
#     .venv/bin/softplc monitor /run/user/1000/softplc/drawer_tester-4be1c2d0/drawer.sock
# and the page's address once softplc web listens. Stop with Ctrl-C (every output is
# written off; the page's process stops with it). Extra arguments go to `softplc run` (e.g. --for 30s).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh web
plant=configs/drawer_tester/plant_sim.yaml
listen=${WEB_LISTEN:-$(.venv/bin/python -c 'import socket
for port in range(8080, 8100):
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            continue
    print(f"127.0.0.1:{port}")
    break
else:
    print("127.0.0.1:0")')}
sock=$(.venv/bin/python -c 'import sys
from runtime.language.plantfile import load_plant
from runtime.language.runtimedir import locate
print(locate(load_plant(sys.argv[1])).console)' "$plant")
echo "run-demo: console on $sock; in a second terminal: .venv/bin/softplc monitor $sock" >&2
# softplc web's log passed on, and the page's address said once it listens: the line it
# logs then names the port it has (a browser opened at once is not refused)
announce() {
  local line
  while IFS= read -r line; do
    printf '%s\n' "$line" >&2
    if [[ $line =~ is\ at\ (https?://[^[:space:]]+/) ]]; then
      echo "run-demo: the live page on ${BASH_REMATCH[1]} (softplc web; user demo," \
           "password demo)" >&2
    fi
  done
}
.venv/bin/softplc web "$plant" --listen "$listen" 2> >(announce) &
web=$!
trap 'kill -TERM $web 2>/dev/null; wait $web 2>/dev/null || true' EXIT
.venv/bin/softplc run "$plant" --sim --script configs/drawer_tester/story.yaml "$@"
