"""Modbus/TCP Security and the allow-list: TLS with client certificates whose role
extension (OID 1.3.6.1.4.1.50316.802.1) says what each may do, pymodbus' TLS client as the
panel; a certificate of another authority, or none, is not let in; a client address not in
``modbus: clients`` is refused with one line."""

from __future__ import annotations

import datetime
import ssl
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from pymodbus.client import ModbusTcpClient, ModbusTlsClient

from runtime.modbus.security import ROLE_OID, role_of
from tests.modbus.kit import free_port, rig
from tests.opcua.feedkit import wait_until


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


class Authority:
    """A certificate authority writing PEM files into ``tmp``."""

    def __init__(self, tmp: Path, name: str) -> None:
        self.tmp = tmp
        self.key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        self.cert = (x509.CertificateBuilder().subject_name(_name(name)).issuer_name(_name(name))
                     .public_key(self.key.public_key()).serial_number(x509.random_serial_number())
                     .not_valid_before(now - datetime.timedelta(days=1))
                     .not_valid_after(now + datetime.timedelta(days=30))
                     .add_extension(x509.BasicConstraints(ca=True, path_length=None), True)
                     .sign(self.key, hashes.SHA256()))
        self.path = tmp / f"{name}.pem"
        self.path.write_bytes(self.cert.public_bytes(serialization.Encoding.PEM))

    def issue(self, name: str, role: str | None = None, server: bool = False
              ) -> tuple[Path, Path, bytes]:
        """(certificate PEM, key PEM, certificate DER) for ``name``, with ``role`` in its
        role extension (an ASN.1 UTF8String, as MB-TCP-Security writes it)."""
        key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        b = (x509.CertificateBuilder().subject_name(_name(name)).issuer_name(self.cert.subject)
             .public_key(key.public_key()).serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(days=1))
             .not_valid_after(now + datetime.timedelta(days=30)))
        if server:
            b = b.add_extension(x509.SubjectAlternativeName(
                [x509.IPAddress(__import__("ipaddress").ip_address("127.0.0.1"))]), False)
        if role is not None:
            raw = role.encode()
            b = b.add_extension(x509.UnrecognizedExtension(
                x509.ObjectIdentifier(ROLE_OID), bytes((0x0C, len(raw))) + raw), False)
        cert = b.sign(self.key, hashes.SHA256())
        cpath, kpath = self.tmp / f"{name}.pem", self.tmp / f"{name}.key"
        cpath.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        kpath.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                            serialization.PrivateFormat.PKCS8,
                                            serialization.NoEncryption()))
        return cpath, kpath, cert.public_bytes(serialization.Encoding.DER)


def test_the_role_is_read_from_the_certificate(tmp_path: Path) -> None:
    ca = Authority(tmp_path, "ca")
    assert role_of(ca.issue("panel1", "operator")[2]) == "operator"
    assert role_of(ca.issue("panel2")[2]) is None
    assert role_of(ca.cert.public_bytes(serialization.Encoding.DER)) is None


def tls_client(ca: Authority, port: int, cert: Path | None, key: Path | None
               ) -> ModbusTlsClient:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False  # pymodbus names no server: the authority is still checked
    ctx.load_verify_locations(cafile=str(ca.path))
    if cert is not None and key is not None:
        ctx.load_cert_chain(str(cert), str(key))
    return ModbusTlsClient("127.0.0.1", port=port, sslctx=ctx, timeout=3, retries=0)


def test_roles_from_client_certificates(tmp_path: Path) -> None:
    ca, stranger = Authority(tmp_path, "ca"), Authority(tmp_path, "stranger")
    scert, skey, _ = ca.issue("server", server=True)
    operator = ca.issue("panel-op", "operator")
    viewer = ca.issue("panel-view", "viewer")
    anonymous = ca.issue("panel-norole")
    foreign = stranger.issue("panel-foreign", "operator")
    port = free_port()
    tls = (f"  tls:\n    listen: 127.0.0.1:{port}\n    certificate: {scert}\n"
           f"    private_key: {skey}\n    clients_ca: {ca.path}\n"
           "    roles: {operator: write, viewer: read}\n")
    with rig(tmp_path, tls) as r:
        c = tls_client(ca, port, operator[0], operator[1])
        assert c.connect()
        try:
            assert not c.read_coils(0, count=9, device_id=1).isError()
            assert not c.write_coil(8, True, device_id=1).isError()  # tester1.sParo
            assert r.get("tester1.sParo") == "1"
        finally:
            c.close()
        c = tls_client(ca, port, viewer[0], viewer[1])
        assert c.connect()
        try:
            assert not c.read_coils(0, count=9, device_id=1).isError()
            rr = c.write_coil(8, False, device_id=1)
            assert rr.isError() and rr.exception_code == 1
            assert r.get("tester1.sParo") == "1"
        finally:
            c.close()
        c = tls_client(ca, port, anonymous[0], anonymous[1])
        assert c.connect()
        try:
            rr = c.read_coils(0, count=1, device_id=1)
            assert rr.isError() and rr.exception_code == 1
        finally:
            c.close()
        for cert, key in ((foreign[0], foreign[1]), (None, None)):
            c = tls_client(ca, port, cert, key)
            try:  # the handshake fails: no connection, or no answer on it
                assert not c.connect() or c.read_coils(0, count=1, device_id=1).isError()
            except Exception:  # noqa: BLE001 - pymodbus says so its own way
                pass
            finally:
                c.close()
        assert r.server.popen.poll() is None
        wait_until(lambda: "role viewer: read" in r.server.log(), 10.0, "the viewer's line")
        assert "role (none): no access" in r.server.log()
        assert "role 'viewer' may not write" in r.server.log()
        # the two refused handshakes: one line each
        wait_until(lambda: r.server.log().count("TLS connection from 127.0.0.1:") >= 2, 10.0,
                   "the refused handshakes' lines")


def test_a_client_not_in_the_allow_list_is_refused(tmp_path: Path) -> None:
    with rig(tmp_path, "  clients: [10.0.0.0/8]\n", wait_served=False) as r:
        c = ModbusTcpClient("127.0.0.1", port=r.port, timeout=3, retries=0)
        try:
            ok = c.connect() and not c.read_coils(0, count=1, device_id=1).isError()
        except Exception:  # noqa: BLE001 - closed under it
            ok = False
        finally:
            c.close()
        assert not ok
        wait_until(lambda: "refused: not in modbus: clients" in r.server.log(), 10.0,
                   "the refusal's line")
