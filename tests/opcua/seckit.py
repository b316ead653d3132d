"""Test kit for OPC UA security: certificates made once, a real asyncua server in a thread
set up by runtime/opcua/security.py, and asyncua client sessions of each kind."""

from __future__ import annotations

import asyncio
import shutil
import socket
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Client, Server, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from runtime.language.model import OpcuaSecurity
from runtime.opcua import security

#: how long a test waits for a server to start or a session to open, s (a loaded machine)
DEADLINE_S = 60.0


@dataclass(frozen=True)
class Certs:
    """Paths of the server's certificate and key, a trusted client's, an untrusted
    client's, and the trusted directory (holding the trusted client's certificate)."""

    server_cert: str
    server_key: str
    client_cert: str
    client_key: str
    stranger_cert: str
    stranger_key: str
    trusted_dir: str


def make_certs(root: Path) -> Certs:
    """Certificates made with the code `softplc opcua-cert` runs."""
    server_cert, server_key = security.make_certificate(str(root / "server"), days=30,
                                                        hosts=["127.0.0.1", "localhost"])
    client_cert, client_key = security.make_certificate(str(root / "client"), days=30,
                                                        hosts=["localhost"], client=True)
    stranger_cert, stranger_key = security.make_certificate(str(root / "stranger"), days=30,
                                                            hosts=["localhost"], client=True)
    trusted = root / "trusted"
    trusted.mkdir()
    shutil.copy(client_cert, trusted / "client.der")
    return Certs(server_cert, server_key, client_cert, client_key, stranger_cert, stranger_key,
                 str(trusted))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


#: the variables of the test address space: name -> (value, writable by a writer)
VARIABLES = {"tester1.sParo": (False, True), "tester1.iMarcha": (True, False)}


class ServerThread:
    """An asyncua server on 127.0.0.1 with :data:`VARIABLES` (ns=2;s=NAME), secured by
    ``security.apply(server, sec)``, run by its own event loop in a thread."""

    def __init__(self, sec: OpcuaSecurity) -> None:
        self.sec = sec
        self.url = f"opc.tcp://127.0.0.1:{free_port()}"
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.server: Server | None = None

    def __enter__(self) -> ServerThread:
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self.loop).result(DEADLINE_S)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.server is not None:
            asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(DEADLINE_S)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(DEADLINE_S)
        self.loop.close()

    async def _start(self) -> None:
        server = Server()
        await server.init()
        server.set_endpoint(self.url)
        idx = await server.register_namespace("urn:softplc:test")
        assert idx == 2
        objects = server.nodes.objects
        for name, (value, writable) in VARIABLES.items():
            var = await objects.add_variable(ua.NodeId.from_string(f"ns=2;s={name}"), name, value)
            if writable:
                await var.set_writable()
        await security.apply(server, self.sec)
        await server.start()
        self.server = server


@asynccontextmanager
async def session(url: str, certs: Certs | None = None, *, cert: str = "",
                  key: str = "", mode: str = "SignAndEncrypt", user: str | None = None,
                  password: str | None = None) -> AsyncIterator[Client]:
    """A connected asyncua client: with ``cert``/``key`` on a Basic256Sha256 channel of
    ``mode`` (the server's certificate from ``certs``), else on a None channel; with
    ``user``/``password`` as a user token, else anonymous."""
    client = Client(url, timeout=DEADLINE_S)
    client.application_uri = security.CLIENT_URI
    if cert:
        assert certs is not None
        await client.set_security(SecurityPolicyBasic256Sha256, certificate=cert,
                                  private_key=key, server_certificate=certs.server_cert,
                                  mode=getattr(ua.MessageSecurityMode, mode))
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    await asyncio.wait_for(client.connect(), DEADLINE_S)
    try:
        yield client
    finally:
        await client.disconnect()


async def read(client: Client, name: str) -> Any:
    return await client.get_node(ua.NodeId.from_string(f"ns=2;s={name}")).read_value()


async def write(client: Client, name: str, value: bool) -> None:
    await client.get_node(ua.NodeId.from_string(f"ns=2;s={name}")).write_value(
        ua.DataValue(ua.Variant(value, ua.VariantType.Boolean)))
