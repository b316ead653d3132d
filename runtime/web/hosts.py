"""Which host names are this web view (docs/web.md, "Security": DNS rebinding).

A page of another site whose name its owner points at the controller's address (DNS
rebinding) is, for the browser, of the same origin as the controller: its requests carry
that site's name in ``Host`` and in ``Origin``, so checking that the two agree proves
nothing. The server answers only requests whose ``Host`` names it: the address it listens
on, ``localhost``, ``127.0.0.1``, ``::1``, the names of its TLS certificate (subjectAltName
DNS names and addresses, the subject's common name; a ``*.`` name matches one label), and
the names ``web: hosts`` adds. The port is not compared: behind an SSH tunnel the browser
names the tunnel's local port.
"""

from __future__ import annotations

import ipaddress
import logging
import ssl
from collections.abc import Iterable
from typing import Any

log = logging.getLogger(__name__)

#: the names every web view answers to (this machine)
LOOPBACK = ("localhost", "127.0.0.1", "::1")
#: addresses that stand for every address of the machine (they name nothing)
WILDCARDS = ("0.0.0.0", "::", "")


def host_name(header: str) -> str:
    """The host of a ``Host`` header, without its port, brackets and final dot, in lower
    case (``[::1]:8080`` -> ``::1``, ``Example.COM.:80`` -> ``example.com``)."""
    h = header.strip()
    if h.startswith("["):
        h = h[1:h.find("]")] if "]" in h else h[1:]
    elif h.count(":") == 1:
        h = h.split(":", 1)[0]
    return h.rstrip(".").lower()


def _canonical(name: str) -> str:
    name = name.strip().rstrip(".").lower()
    try:
        return str(ipaddress.ip_address(name.strip("[]")))
    except ValueError:
        return name


class Hosts:
    """The names a request's ``Host`` may give."""

    def __init__(self, names: Iterable[str]) -> None:
        self.exact: set[str] = set()
        self.wild: set[str] = set()  # "*.bench.lan" -> "bench.lan"
        for n in names:
            n = _canonical(n)
            if n.startswith("*."):
                self.wild.add(n[2:])
            elif n not in WILDCARDS:
                self.exact.add(n)

    def __contains__(self, header: object) -> bool:
        if not isinstance(header, str):
            return False
        name = _canonical(host_name(header))
        if name in self.exact:
            return True
        head, _, rest = name.partition(".")
        return bool(head) and rest in self.wild


def certificate_names(path: str) -> list[str]:
    """The names of the PEM certificate ``path``: its subjectAltName DNS names and
    addresses, and its subject's common name; [] (and a warning) if it cannot be read."""
    decode = getattr(getattr(ssl, "_ssl", None), "_test_decode_cert", None)
    if decode is None:  # not in this Python: only the other names are this server's
        log.warning("web: cannot read the names of %s (this Python cannot decode a "
                    "certificate): add them to web: hosts", path)
        return []
    try:
        cert: dict[str, Any] = decode(path)
    except (OSError, ssl.SSLError, ValueError) as exc:
        log.warning("web: cannot read the names of %s: %s", path, exc)
        return []
    names = [str(v) for kind, v in cert.get("subjectAltName", ())
             if kind in ("DNS", "IP Address")]
    for rdn in cert.get("subject", ()):
        names += [str(v) for k, v in rdn if k == "commonName"]
    return names


def this_server(listen_host: str, certificate: str | None, extra: Iterable[str]) -> Hosts:
    """The names of a web view listening on ``listen_host`` with ``certificate`` and the
    names of ``web: hosts``."""
    names = [listen_host, *LOOPBACK, *extra]
    if certificate is not None:
        names += certificate_names(certificate)
    return Hosts(names)
