"""Who may connect to the OPC UA server and what each may do (``opcua: security:``).

The rules (docs/opcua.md, "Security"):

- **Endpoints**: the plant's ``policies`` and only those. ``Basic256Sha256_SignAndEncrypt``
  is the default; ``None`` (no signature, no encryption) is offered only when listed. A
  secured policy needs the server's certificate and key: the server refuses to start without
  them, naming the key and ``softplc opcua-cert``.
- **Client certificates**: a client application that opens a signed channel shows its
  certificate; it must be one of the files of ``trusted_clients`` or ``trusted_readers``
  (byte for byte, and within its dates), else the session is refused
  (``BadCertificateUntrusted`` at CreateSession when ``None`` is not offered,
  ``BadUserAccessDenied`` at ActivateSession in any case). The certificate a client
  names in CreateSession on a ``None`` channel (node-opcua and UaExpert do) is not
  checked: nothing proves it, and it grants nothing. The directories are read again at
  each session, so trusting a client needs no restart.
- **Roles**: a session on a signed channel with a certificate of ``trusted_clients`` is a
  *writer* unless ``None`` is listed too (below), one with a certificate of
  ``trusted_readers`` a *reader*; a user
  whose password matches its hash in ``users`` (``softplc hash-pin`` format) is a writer; a
  wrong password or an unknown user is refused; an anonymous session without a certificate
  (only possible on a ``None`` endpoint) is a *reader* with ``anonymous: read`` (the
  default) and refused with ``anonymous: none``. A reader may browse, read, subscribe and
  call ConditionRefresh; its writes and its calls of the methods that change something
  fail with ``BadUserAccessDenied``. Nobody is administrator:
  no client adds or deletes nodes.

Why the certificate is checked in the user manager and not only by asyncua's certificate
validator (asyncua 2.1): the validator sees the certificate the client *names* in
CreateSession, which a hostile client may leave empty (the validator is then skipped) or
set to another's certificate; the user manager sees the one the channel was opened with,
whose signature the channel has verified. And why a session without a certificate is
refused unless ``None`` is listed: asyncua starts every connection on a ``None`` channel
with no permission checks and lets a client ask for ``None`` even when no ``None``
endpoint is offered (``SecureConnection.select_policy`` keeps the current policy when its
URI matches); such a channel carries no certificate, so the user manager closes it. When
``None`` *is* listed, a client may name any certificate on its unsigned channel (the
certificates are public) and asyncua does not tell the user manager which channel a
session came by: so with ``None`` listed a certificate alone makes nobody a writer (a user
with a password still does).

A password check costs one scrypt hash (about 0.2 s: ``runtime/controller/pin.py``) and
asyncua calls the user manager synchronously in its event loop: after a failed check,
checks of that user are refused without hashing for :data:`FAIL_HOLD_S` (other users are
checked as usual), so a client guessing one user's password stalls the server's
publishing at most that share of the time (one hash per user and per second when it
guesses at every user name of the plant); a successful check is
remembered (as an HMAC under a key drawn at start, never the password) so a client that
reconnects does not pay it again.
"""

from __future__ import annotations

import datetime
import ipaddress
import logging
import os
import socket
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto import cert_gen
from asyncua.crypto.permission_rules import USER_TYPES, SimpleRoleRuleset, User, UserRole
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes
from cryptography import x509
from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from runtime.controller.pin import FAIL_HOLD_S, Passwords  # noqa: F401 - FAIL_HOLD_S: its rule
from runtime.errors import Loc, SourceError
from runtime.language.model import OpcuaSecurity
from runtime.language.opcuaconf import credential_problem
from runtime.language.safefile import UnfitFile, read_bounded
from runtime.opcua.methods import peer_text

log = logging.getLogger(__name__)

#: the server's ApplicationUri: the server announces it and its certificate must carry it
#: (SubjectAltName URI); clients such as UaExpert check that the two match
APPLICATION_URI = "urn:softplc:opcua:server"
#: the ApplicationUri of a client certificate made by ``softplc opcua-cert --client``: the
#: client must announce the same (asyncua: ``client.application_uri``)
CLIENT_URI = "urn:softplc:opcua:client"
#: the largest certificate or key file read (a certificate is 1-2 kB), bytes
CERTIFICATE_MAX_BYTES = 64 * 1024
#: plant policy name -> asyncua's endpoint type
POLICIES: dict[str, ua.SecurityPolicyType] = {
    "None": ua.SecurityPolicyType.NoSecurity,
    "Basic256Sha256_Sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "Basic256Sha256_SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
}


def _ids(numbers: Iterable[int]) -> frozenset[ua.NodeId]:
    return frozenset(ua.NodeId(ua.Int32(n)) for n in numbers)


#: services that change something: a reader may not call them (Call is let through:
#: ConditionRefresh is for readers too; the methods that change something answer
#: BadUserAccessDenied themselves, runtime/opcua/methods.py and conditions.py)
_CHANGING = _ids((ObjectIds.WriteRequest_Encoding_DefaultBinary,))
#: every service of a session (asyncua's list for its User role: no node management)
_WRITER_IDS = _ids(USER_TYPES)
_READER_IDS = _WRITER_IDS - _CHANGING
#: the plant file position used when the model has none (a model built by a test)
_NOWHERE = Loc("<plant>", 0, 0)


def secured(sec: OpcuaSecurity) -> bool:
    """True if ``sec`` offers an endpoint that signs (so needs a certificate and key)."""
    return any(p != "None" for p in sec.policies)


class Rules(SimpleRoleRuleset):  # type: ignore[misc]  # asyncua is Any to mypy
    """Which services each role may call: writers every service of a session, readers all
    but Write (a changing method answers them BadUserAccessDenied), anyone else nothing
    (asyncua answers BadUserAccessDenied)."""

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: Any) -> bool:
        if user.role is UserRole.User:
            return action_type_id in _WRITER_IDS
        if user.role is UserRole.Anonymous:
            return action_type_id in _READER_IDS
        return False


class TrustedClients:
    """The client certificates of a directory (DER or PEM files), read again at each look-up
    (a few files: trusting a client needs no restart)."""

    def __init__(self, directory: str | None) -> None:
        self.directory = directory

    def certificates(self) -> list[bytes]:
        """DER of every readable certificate of the directory (an unreadable file is
        logged and skipped: it trusts nobody)."""
        if not self.directory:
            return []
        out: list[bytes] = []
        try:
            names = sorted(os.listdir(self.directory))
        except OSError as exc:
            log.error("opcua trusted_clients %s: %s: no client certificate is trusted",
                      self.directory, exc.strerror)
            return []
        for name in names:
            path = os.path.join(self.directory, name)
            if not os.path.isfile(path):
                continue
            try:  # never blocking, never past the bound (a FIFO or a huge file put there)
                out.append(_der(read_bounded(path, CERTIFICATE_MAX_BYTES, follow_links=True)))
            except (OSError, ValueError, UnfitFile) as exc:
                log.warning("opcua trusted_clients: %s is not a certificate (%s): skipped",
                            path, exc)
        return out

    def trusts(self, der: bytes) -> bool:
        """True if ``der`` is one of the directory's certificates and within its dates."""
        if der not in self.certificates():
            return False
        cert = x509.load_der_x509_certificate(der)
        now = datetime.datetime.now(datetime.UTC)
        return cert.not_valid_before_utc <= now <= cert.not_valid_after_utc


def _der(data: bytes) -> bytes:
    """A certificate file's content (DER or PEM) as DER; ValueError if it is neither."""
    if data.lstrip().startswith(b"-----BEGIN"):
        cert = x509.load_pem_x509_certificate(data)
    else:
        cert = x509.load_der_x509_certificate(data)
    return cert.public_bytes(serialization.Encoding.DER)


class Users(UserManager):  # type: ignore[misc]  # asyncua is Any to mypy
    """asyncua's user manager: the role of a session from its channel certificate, its
    user token and the plant's ``security:`` (module docstring)."""

    def __init__(self, sec: OpcuaSecurity, clock: Callable[[], float] = time.monotonic) -> None:
        self.sec = sec
        self.trusted = TrustedClients(sec.trusted_clients)
        self.readers = TrustedClients(sec.trusted_readers)
        self.allow_none = "None" in sec.policies
        #: the users' passwords (a wrong one holds that user only: guessing one user's
        #: password never locks out another)
        self.passwords = Passwords(sec.users, clock)
        #: why the last session was refused ("" if it was not)
        self.refusal = ""

    def get_user(self, iserver: Any, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        """The session's User, or None to refuse it (BadUserAccessDenied; why in
        ``refusal``, which the session's log line says: ``log_refusals``)."""
        self.refusal = ""
        if not certificate:  # asyncua passes b"" for a channel without a certificate
            certificate = None
            if not self.allow_none:
                self.refusal = ("a channel without security (the plant lists no None "
                                "policy)")
                return None
        writer = bool(certificate) and self.trusted.trusts(bytes(certificate))
        if certificate and not writer and not self.readers.trusts(bytes(certificate)):
            self.refusal = ("a client certificate in neither trusted_clients nor "
                            "trusted_readers (or out of its dates)")
            return None
        if username is not None:
            if self._password_ok(username, password or ""):
                return User(role=UserRole.User, name=username)
            self.refusal = f"user '{username}': wrong password or unknown user"
            return None
        if writer and not self.allow_none:
            return User(role=UserRole.User, name=_subject(certificate))
        if certificate is not None and not self.allow_none:  # a trusted reader
            return User(role=UserRole.Anonymous, name=_subject(certificate))
        if self.sec.anonymous == "read":
            return User(role=UserRole.Anonymous)
        self.refusal = "an anonymous session (anonymous: none)"
        return None

    def _password_ok(self, username: str, password: str) -> bool:
        return self.passwords.check(username, password)


def _subject(der: Any) -> str:
    try:
        return x509.load_der_x509_certificate(bytes(der)).subject.rfc4514_string()
    except ValueError:
        return "an unreadable certificate"


@dataclass(frozen=True, slots=True)
class Credentials:
    """The server's certificate (DER) and private key (PEM), read and parsed."""

    certificate: bytes
    private_key: bytes


def read_credentials(sec: OpcuaSecurity, where: Loc | None = None) -> Credentials | None:
    """The certificate and key of ``sec`` read (bounded, never blocking: asyncua would read
    any file) and parsed, before the server takes seconds to set up; None when no policy
    signs. SourceError at the key's value in the plant file (else at its ``security:``,
    else at ``where``: its ``opcua:``) saying what is wrong: no such key, no such file
    (``opcuaconf.credential_problem``: a new pair is advised only when neither file is
    there), a file that cannot be read (why), or one that holds no certificate or key;
    never advising to make a file that is there."""
    section = sec.loc or where or _NOWHERE
    if not secured(sec):
        return None
    for key in ("certificate", "private_key"):
        if not getattr(sec, key):
            default = "" if sec.loc else " (the default: no 'security:' section)"
            raise SourceError(section, f"opcua security: policies {', '.join(sec.policies)}"
                                       f"{default} need a server certificate: no '{key}' "
                                       "key (make one with 'softplc opcua-cert', or list "
                                       "policies: [None]: docs/opcua.md)")
    problem = credential_problem(sec)
    if problem is not None:
        raise SourceError(sec.locs.get(problem[0], section),
                          f"opcua security {problem[0]}: {problem[1]}")
    data = {key: _read(str(getattr(sec, key)), sec.locs.get(key, section), key)
            for key in ("certificate", "private_key")}
    cert_path, key_path = str(sec.certificate), str(sec.private_key)
    try:
        cert = _der(data["certificate"])
    except ValueError as exc:
        raise SourceError(sec.locs.get("certificate", section),
                          f"opcua security certificate: {cert_path} holds no certificate "
                          f"(DER or PEM): {exc}") from None
    try:
        key = _private_key(data["private_key"])
    except (ValueError, TypeError, UnsupportedAlgorithm) as exc:
        raise SourceError(sec.locs.get("private_key", section),
                          f"opcua security private_key: {key_path} holds no private key "
                          f"without a password (PEM or DER): {exc}") from None
    public = x509.load_der_x509_certificate(cert).public_key()
    if public.public_bytes(*_SPKI) != key.public_key().public_bytes(*_SPKI):
        raise SourceError(sec.locs.get("private_key", section),
                          f"opcua security private_key: {key_path} is not the key of the "
                          f"certificate {cert_path}")
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    return Credentials(cert, pem)


#: how two public keys are compared
_SPKI = (serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)


def _read(path: str, loc: Loc, key: str) -> bytes:
    """A certificate or key file's bytes; SourceError at ``loc`` saying why it cannot be
    read (a file that is there: nothing is advised to be made)."""
    try:
        return read_bounded(path, CERTIFICATE_MAX_BYTES, follow_links=True)
    except UnfitFile as exc:
        why = f"{exc.found}, expected a file of at most {CERTIFICATE_MAX_BYTES} bytes"
    except FileNotFoundError:  # gone since the plant was loaded
        why = "no such file (make one with 'softplc opcua-cert', docs/opcua.md)"
    except OSError as exc:
        why = f"cannot be read: {exc.strerror or exc}"
    raise SourceError(loc, f"opcua security {key}: {path}: {why}")


def _private_key(data: bytes) -> Any:
    """A private key file's content (PEM or DER, no password) as a key object."""
    if data.lstrip().startswith(b"-----BEGIN"):
        return serialization.load_pem_private_key(data, password=None)
    return serialization.load_der_private_key(data, password=None)


async def apply(server: Server, sec: OpcuaSecurity, where: Loc | None = None,
                credentials: Credentials | None = None) -> None:
    """Set up ``server``'s endpoints, certificate, trusted clients and users from ``sec``;
    call after ``await server.init()`` and before ``await server.start()``. The
    certificate and key are ``credentials`` (else read here: ``read_credentials``, whose
    SourceError says what is wrong)."""
    await server.set_application_uri(APPLICATION_URI)
    if secured(sec):
        creds = credentials or read_credentials(sec, where)
        assert creds is not None
        await server.load_certificate(creds.certificate, "der")
        await server.load_private_key(creds.private_key, format="pem")
    rules = Rules()
    server.set_security_policy([POLICIES[p] for p in sec.policies], permission_ruleset=rules)
    # the client certificate is the application's identity; no X509 *user* tokens
    server.set_identity_tokens([ua.AnonymousIdentityToken, ua.UserNameIdentityToken])
    users = Users(sec)
    server.iserver.set_user_manager(users)
    log_refusals(server, users)
    if not users.allow_none:
        # clients name their certificate in CreateSession on None channels too (node-opcua,
        # UaExpert), where it proves nothing: checked there only when None is not offered
        server.set_certificate_validator(_validator(users.trusted, users.readers))
    if sec.users and not any(p == "Basic256Sha256_SignAndEncrypt" for p in sec.policies):
        log.warning("opcua: users are set but no SignAndEncrypt policy is listed: their "
                    "passwords may cross the network readable")


def log_refusals(server: Server, users: Users) -> None:
    """One log line for each session refused at CreateSession or ActivateSession, naming
    the client's address, the subject of the certificate it showed, why and the status:
    ``opcua: refused the client at 10.0.0.7:50122 (certificate CN=panel 3): a client
    certificate in neither trusted_clients nor trusted_readers (BadUserAccessDenied)``."""
    iserver = server.iserver
    plain = iserver.create_session

    def create_session(name: Any, *args: Any, **kwargs: Any) -> Any:
        session = plain(name, *args, **kwargs)
        create, activate = session.create_session, session.activate_session

        def said(exc: Exception, certificate: Any, why: str) -> None:
            code = getattr(exc, "code", StatusCodes.BadUserAccessDenied)
            log.warning("opcua: refused the client at %s (certificate %s): %s (%s)",
                        peer_text(session.name),
                        _subject(certificate) if certificate else "none",
                        why or "refused", ua.StatusCode(code).name)

        async def created(params: Any, *a: Any, **k: Any) -> Any:
            try:
                return await create(params, *a, **k)
            except (ServiceError, ua.UaStatusCodeError) as exc:
                said(exc, params.ClientCertificate, "a client certificate in neither "
                     "trusted_clients nor trusted_readers (or out of its dates)")
                raise

        def activated(params: Any, peer_certificate: Any) -> Any:
            users.refusal = ""
            try:
                return activate(params, peer_certificate)
            except (ServiceError, ua.UaStatusCodeError) as exc:
                said(exc, peer_certificate, users.refusal)
                raise
        session.create_session, session.activate_session = created, activated
        return session
    iserver.create_session = create_session


def _validator(*trusted: TrustedClients) -> Callable[[x509.Certificate, Any], Any]:
    """asyncua's certificate validator: BadCertificateUntrusted at CreateSession for a
    client certificate in none of ``trusted`` (the user manager checks the channel's own)."""

    async def validate(cert: x509.Certificate, app: Any) -> None:
        der = cert.public_bytes(serialization.Encoding.DER)
        if not any(t.trusts(der) for t in trusted):
            raise ServiceError(StatusCodes.BadCertificateUntrusted)

    return validate


def make_certificate(directory: str, days: int = 3650, hosts: Iterable[str] = (),
                     client: bool = False) -> tuple[str, str]:
    """Write a self-signed certificate (``server-cert.der``) and its RSA 2048 key
    (``server-key.pem``, mode 0600) for :data:`APPLICATION_URI` into ``directory``; (cert
    path, key path).
    ``hosts``: DNS names or IP addresses clients reach the server by (default this machine's
    name, localhost and 127.0.0.1). ``client``: a client certificate (``client-...``,
    ClientAuth, :data:`CLIENT_URI`) instead, for tests and scripts. FileExistsError naming
    the path if either file exists: nothing is overwritten."""
    prefix = "client" if client else "server"
    cert_path = os.path.join(directory, f"{prefix}-cert.der")
    key_path = os.path.join(directory, f"{prefix}-key.pem")
    for path in (cert_path, key_path):
        if os.path.lexists(path):
            raise FileExistsError(path)
    names = list(hosts) or [socket.gethostname(), "localhost", "127.0.0.1"]
    uri = CLIENT_URI if client else APPLICATION_URI
    alt: list[x509.GeneralName] = [x509.UniformResourceIdentifier(uri)]
    for name in names:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(name)))
        except ValueError:
            alt.append(x509.DNSName(name))
    key = cert_gen.generate_private_key()
    usage = ExtendedKeyUsageOID.CLIENT_AUTH if client else ExtendedKeyUsageOID.SERVER_AUTH
    cert = cert_gen.generate_self_signed_app_certificate(
        key, f"softplc {prefix} {names[0]}", {}, alt, [usage], days=days)
    os.makedirs(directory, mode=0o755, exist_ok=True)
    # the key first, created 0600 and exclusively: never readable by others, even briefly
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(cert_gen.dump_private_key_as_pem(key))
    fd = os.open(cert_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(cert.public_bytes(serialization.Encoding.DER))
    return cert_path, key_path
