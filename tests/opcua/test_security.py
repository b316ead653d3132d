"""OPC UA security (runtime/opcua/security.py) against real asyncua clients: which
endpoints are offered, which client certificates are let in, who may write."""

from __future__ import annotations

import asyncio
import logging
import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.ua import uaerrors
from cryptography import x509

from runtime.cli import main
from runtime.controller import pin
from runtime.controller.pin import hash_pin
from runtime.errors import Loc, SourceError
from runtime.language.model import OpcuaSecurity
from runtime.opcua import security
from tests.opcua.seckit import Certs, ServerThread, make_certs, read, session, write

#: cheap hashes: the cost is not what is tested here (tests/console/test_console_pin.py)
USERS = {"operator": hash_pin("right-pass", n=16, r=1, p=1),
         "second": hash_pin("second-pass", n=16, r=1, p=1)}
#: what a refused session raises in the client, whichever step refused it
REFUSED = (uaerrors.BadUserAccessDenied, uaerrors.BadCertificateUntrusted,
           uaerrors.BadIdentityTokenRejected, uaerrors.BadSecurityPolicyRejected)


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Certs:
    return make_certs(tmp_path_factory.mktemp("pki"))


def sec(certs: Certs, policies: list[str], **kw: object) -> OpcuaSecurity:
    s = OpcuaSecurity(policies=policies, certificate=certs.server_cert,
                      private_key=certs.server_key, trusted_clients=certs.trusted_dir,
                      users=dict(USERS))
    for k, v in kw.items():
        setattr(s, k, v)
    return s


@pytest.fixture(scope="module")
def secure_only(certs: Certs) -> Iterator[ServerThread]:
    """The default policies: Basic256Sha256 SignAndEncrypt only."""
    with ServerThread(sec(certs, ["Basic256Sha256_SignAndEncrypt"])) as srv:
        yield srv


@pytest.fixture(scope="module")
def with_none(certs: Certs) -> Iterator[ServerThread]:
    """None listed explicitly beside SignAndEncrypt; anonymous: read."""
    with ServerThread(sec(certs, ["None", "Basic256Sha256_SignAndEncrypt"])) as srv:
        yield srv


def run(coro: object) -> object:
    return asyncio.run(coro)  # type: ignore[arg-type]


# --- endpoints ------------------------------------------------------------------------


def test_none_is_refused_unless_listed(secure_only: ServerThread,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A hostile client asks for a None channel the server does not offer (asyncua's own
    client checks the endpoint list after CreateSession: made to take any endpoint)."""
    monkeypatch.setattr(Client, "find_endpoint", staticmethod(lambda eps, mode, uri: eps[0]))

    async def go() -> None:
        async with session(secure_only.url) as c:
            await read(c, "tester1.iMarcha")
    with pytest.raises(REFUSED):
        run(go())


def test_none_only_offered_when_listed(secure_only: ServerThread,
                                       with_none: ServerThread) -> None:
    async def modes(url: str) -> set[str]:
        eps = await Client(url).connect_and_get_server_endpoints()
        return {f"{ep.SecurityPolicyUri.rsplit('#', 1)[1]}_{ep.SecurityMode.name}"
                for ep in eps}
    assert run(modes(secure_only.url)) == {"Basic256Sha256_SignAndEncrypt"}
    assert run(modes(with_none.url)) == {"None_None_", "Basic256Sha256_SignAndEncrypt"}


def test_none_listed_anonymous_reads(with_none: ServerThread) -> None:
    async def go() -> object:
        async with session(with_none.url) as c:
            return await read(c, "tester1.iMarcha")
    assert run(go()) is True


# --- client certificates --------------------------------------------------------------


def test_trusted_certificate_signandencrypt_is_a_writer(secure_only: ServerThread,
                                                        certs: Certs) -> None:
    async def go() -> object:
        async with session(secure_only.url, certs, cert=certs.client_cert,
                           key=certs.client_key) as c:
            await write(c, "tester1.sParo", True)
            value = await read(c, "tester1.sParo")
            await write(c, "tester1.sParo", False)
            return value
    assert run(go()) is True


def test_a_trusted_reader_certificate_reads_but_may_not_write(certs: Certs,
                                                             tmp_path: Path) -> None:
    """``trusted_readers``: an HMI or a historian on an encrypted channel, read only."""
    readers = tmp_path / "readers"
    readers.mkdir()
    (readers / "hmi.der").write_bytes(Path(certs.stranger_cert).read_bytes())

    async def go() -> object:
        async with session(srv.url, certs, cert=certs.stranger_cert,
                           key=certs.stranger_key) as c:
            value = await read(c, "tester1.iMarcha")
            with pytest.raises(uaerrors.BadUserAccessDenied):
                await write(c, "tester1.sParo", True)
            return value
    with ServerThread(sec(certs, ["Basic256Sha256_SignAndEncrypt"],
                          trusted_readers=str(readers))) as srv:
        assert run(go()) is True


def test_untrusted_certificate_is_refused(secure_only: ServerThread, certs: Certs) -> None:
    async def go() -> None:
        async with session(secure_only.url, certs, cert=certs.stranger_cert,
                           key=certs.stranger_key) as c:
            await read(c, "tester1.iMarcha")
    with pytest.raises(uaerrors.BadCertificateUntrusted):
        run(go())


def test_a_refused_client_is_named_in_the_log(secure_only: ServerThread, certs: Certs,
                                               with_none: ServerThread,
                                               caplog: pytest.LogCaptureFixture) -> None:
    """Issue 29: the log names a refused client: its address, its certificate's subject,
    why and the status (before, the untrusted certificate's line had no address, the
    validator's refusal no line at all)."""
    caplog.set_level(logging.WARNING, "runtime.opcua.security")
    subject = x509.load_der_x509_certificate(
        Path(certs.stranger_cert).read_bytes()).subject.rfc4514_string()

    async def go(url: str, **kw: object) -> None:
        async with session(url, certs, **kw) as c:  # type: ignore[arg-type]
            await read(c, "tester1.iMarcha")
    with pytest.raises(uaerrors.BadCertificateUntrusted):
        run(go(secure_only.url, cert=certs.stranger_cert, key=certs.stranger_key))
    with pytest.raises(REFUSED):
        run(go(with_none.url, user="intruder", password="wrong"))  # no hold on a user
    said = [r.getMessage() for r in caplog.records if "refused the client" in r.getMessage()]
    assert len(said) == 2, said
    assert said[0].startswith("opcua: refused the client at 127.0.0.1:")
    assert said[0].endswith(f"(certificate {subject}): a client certificate in neither "
                            "trusted_clients nor trusted_readers (or out of its dates) "
                            "(BadCertificateUntrusted)")
    assert said[1].endswith("(certificate none): user 'intruder': wrong password or "
                            "unknown user (BadUserAccessDenied)")


def test_trusting_a_client_needs_no_restart(secure_only: ServerThread, certs: Certs) -> None:
    """The directory is read at each session: copy the certificate in, then take it out."""
    path = Path(certs.trusted_dir) / "stranger.der"
    path.write_bytes(Path(certs.stranger_cert).read_bytes())

    async def go() -> object:
        async with session(secure_only.url, certs, cert=certs.stranger_cert,
                           key=certs.stranger_key) as c:
            return await read(c, "tester1.iMarcha")
    try:
        assert run(go()) is True
    finally:
        path.unlink()
    with pytest.raises(uaerrors.BadCertificateUntrusted):
        run(go())


def test_a_certificate_named_on_a_none_channel_makes_no_writer(certs: Certs) -> None:
    """With None listed, a client can name any (public) certificate on its unsigned
    channel, and asyncua hands it to the user manager as the channel's: it must not make
    a writer. The user manager is called as asyncua calls it at ActivateSession."""
    der = Path(certs.client_cert).read_bytes()
    users = security.Users(sec(certs, ["None", "Basic256Sha256_SignAndEncrypt"]))
    user = users.get_user(None, certificate=der)
    assert user is not None and user.role is security.UserRole.Anonymous
    # without None listed the same certificate, proven by a signed channel, is a writer
    users = security.Users(sec(certs, ["Basic256Sha256_SignAndEncrypt"]))
    user = users.get_user(None, certificate=der)
    assert user is not None and user.role is security.UserRole.User


# --- anonymous and users --------------------------------------------------------------


def test_anonymous_reads_but_write_is_denied(with_none: ServerThread) -> None:
    async def go() -> None:
        async with session(with_none.url) as c:
            assert await read(c, "tester1.sParo") is False
            await write(c, "tester1.sParo", True)
    with pytest.raises(uaerrors.BadUserAccessDenied):
        run(go())


def test_user_with_the_right_password_writes(with_none: ServerThread) -> None:
    async def go() -> object:
        async with session(with_none.url, user="operator", password="right-pass") as c:
            await write(c, "tester1.sParo", True)
            value = await read(c, "tester1.sParo")
            await write(c, "tester1.sParo", False)
            return value
    assert run(go()) is True


def test_user_with_the_right_password_writes_on_a_secure_channel(
        secure_only: ServerThread, certs: Certs) -> None:
    async def go() -> object:
        async with session(secure_only.url, certs, cert=certs.client_cert,
                           key=certs.client_key, user="operator",
                           password="right-pass") as c:
            await write(c, "tester1.sParo", True)
            value = await read(c, "tester1.sParo")
            await write(c, "tester1.sParo", False)
            return value
    assert run(go()) is True


@pytest.mark.parametrize("user,password", [("operator", "wrong-pass"), ("nobody", "x")])
def test_wrong_password_or_unknown_user_is_refused(certs: Certs, user: str,
                                                   password: str) -> None:
    # a server of its own: a failed check holds further checks for FAIL_HOLD_S
    with ServerThread(sec(certs, ["None"])) as srv:
        async def go() -> None:
            async with session(srv.url, user=user, password=password) as c:
                await read(c, "tester1.iMarcha")
        with pytest.raises(uaerrors.BadUserAccessDenied):
            run(go())


def test_wrong_password_is_refused_even_with_a_trusted_certificate(
        secure_only: ServerThread, certs: Certs) -> None:
    async def go() -> None:
        async with session(secure_only.url, certs, cert=certs.client_cert,
                           key=certs.client_key, user="operator", password="wrong") as c:
            await read(c, "tester1.iMarcha")
    with pytest.raises(uaerrors.BadUserAccessDenied):
        run(go())


def test_anonymous_none_refuses_anonymous(certs: Certs) -> None:
    with ServerThread(sec(certs, ["None"], anonymous="none")) as srv:
        async def anonymous() -> None:
            async with session(srv.url) as c:
                await read(c, "tester1.iMarcha")
        with pytest.raises(REFUSED):
            run(anonymous())

        async def operator() -> object:
            async with session(srv.url, user="operator", password="right-pass") as c:
                return await read(c, "tester1.iMarcha")
        assert run(operator()) is True


def test_failed_checks_hold_further_checks_without_hashing(certs: Certs) -> None:
    """A client guessing passwords costs one hash per FAIL_HOLD_S, on a virtual clock."""
    now = [100.0]
    calls: list[str] = []
    users = security.Users(sec(certs, ["None"]), clock=lambda: now[0])
    real = pin.check_pin

    def counting(text: str, stored: str) -> bool:
        calls.append(text)
        return real(text, stored)
    pin.check_pin = counting  # type: ignore[assignment]  # the one home of the checks
    try:
        assert users.get_user(None, "operator", "guess1") is None
        assert users.get_user(None, "operator", "right-pass") is None  # held: not hashed
        assert calls == ["guess1"]
        # another user is not held by the guesses at "operator"
        assert users.get_user(None, "second", "second-pass") is not None
        assert calls == ["guess1", "second-pass"]
        del calls[1:]
        now[0] += security.FAIL_HOLD_S
        assert users.get_user(None, "operator", "right-pass") is not None
        assert users.get_user(None, "operator", "right-pass") is not None  # remembered
        assert calls == ["guess1", "right-pass"]
    finally:
        pin.check_pin = real  # type: ignore[assignment]


# --- start-up checks and the certificate command --------------------------------------


@pytest.mark.parametrize("missing", ["certificate", "private_key"])
def test_secured_policy_without_certificate_refuses_to_start(certs: Certs,
                                                             missing: str) -> None:
    from asyncua import Server

    async def go() -> None:
        server = Server()
        await server.init()
        await security.apply(server, sec(certs, ["Basic256Sha256_SignAndEncrypt"],
                                         **{missing: None}), Loc("plant.yaml", 14, 3))
    with pytest.raises(SourceError) as err:
        run(go())
    text = str(err.value)
    # no security: section (no position of its own): the error is at the opcua: section
    assert text.startswith("plant.yaml:14:3: error: ")
    assert f"no '{missing}' key" in text and "softplc opcua-cert" in text


def test_opcua_cert_writes_der_and_a_private_key(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "opcua"
    assert main(["opcua-cert", "--dir", str(d), "--days", "10", "--host", "plc1.local",
                 "--host", "10.0.0.5"]) == 0
    cert = x509.load_der_x509_certificate((d / "server-cert.der").read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.UniformResourceIdentifier) == [security.APPLICATION_URI]
    assert san.get_values_for_type(x509.DNSName) == ["plc1.local"]
    assert [str(a) for a in san.get_values_for_type(x509.IPAddress)] == ["10.0.0.5"]
    assert (cert.not_valid_after_utc - cert.not_valid_before_utc).days == 10
    assert stat.S_IMODE(os.stat(d / "server-key.pem").st_mode) == 0o600
    assert (d / "server-key.pem").read_bytes().startswith(b"-----BEGIN PRIVATE KEY-----")
    assert security.APPLICATION_URI in capsys.readouterr().out


def test_opcua_cert_never_overwrites(tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["opcua-cert", "--dir", str(tmp_path)]) == 0
    before = (tmp_path / "server-key.pem").read_bytes()
    capsys.readouterr()
    assert main(["opcua-cert", "--dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "server-cert.der") in err and "not overwritten" in err
    assert (tmp_path / "server-key.pem").read_bytes() == before


def test_rules_let_readers_read_and_writers_write() -> None:
    rules = security.Rules()
    wr = ua.NodeId(ua.Int32(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary))
    rd = ua.NodeId(ua.Int32(ua.ObjectIds.ReadRequest_Encoding_DefaultBinary))
    add = ua.NodeId(ua.Int32(ua.ObjectIds.AddNodesRequest_Encoding_DefaultBinary))
    reader, writer = security.User(role=security.UserRole.Anonymous), security.User(
        role=security.UserRole.User)
    admin = security.User(role=security.UserRole.Admin)
    assert rules.check_validity(reader, rd, None) and not rules.check_validity(reader, wr, None)
    assert rules.check_validity(writer, wr, None) and not rules.check_validity(writer, add, None)
    assert not rules.check_validity(admin, rd, None)


def test_opcua_cert_client_names_the_client_uri(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 25: it printed urn:softplc:opcua:server for a certificate holding ...:client."""
    assert main(["opcua-cert", "--client", "--dir", str(tmp_path)]) == 0
    cert = x509.load_der_x509_certificate((tmp_path / "client-cert.der").read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.UniformResourceIdentifier) == [security.CLIENT_URI]
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == f"application URI {security.CLIENT_URI}"
