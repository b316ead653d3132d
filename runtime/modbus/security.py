"""Modbus/TCP Security (the Modbus Organization's MB-TCP-Security specification v21, 2018):
TLS 1.2 or later with a certificate on both ends, and the client's **role** read from its
certificate's role extension (OID 1.3.6.1.4.1.50316.802.1, an ASN.1 UTF8String), which
the server's authorization rules turn into what the client may do. Here the rules are the
plant's ``modbus: tls: roles:`` (``ROLE: read`` or ``write``); a certificate without the
extension, or with a role not listed, may do nothing: every request is answered with
exception 1 (illegal function), as the specification answers an unauthorized one.

The role is read from the certificate's DER with a small reader of the X.509 structure
(``role_of``): the standard library's ``ssl`` does not decode extensions it does not know,
and no other dependency is needed for one field."""

from __future__ import annotations

import ssl

from runtime.errors import SoftplcError
from runtime.language.model import ModbusTls

#: the role extension's OID (MB-TCP-Security, "RoleOID")
ROLE_OID = "1.3.6.1.4.1.50316.802.1"
#: the ASN.1 string tags a role may be written in: UTF8String (the specification's),
#: PrintableString, IA5String (tolerated)
_STRING_TAGS = (0x0C, 0x13, 0x16)
#: the longest role read, characters
ROLE_MAX = 128


def server_context(tls: ModbusTls) -> ssl.SSLContext:
    """The TLS context of the secure listener: TLS 1.2 or later, the server's certificate,
    client certificates required and checked against ``clients_ca``. OSError or
    ssl.SSLError naming the file that cannot be used."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_cert_chain(tls.certificate, tls.private_key)
    ctx.load_verify_locations(cafile=tls.clients_ca)
    ctx.verify_mode = ssl.CERT_REQUIRED
    return ctx


def encode_oid(oid: str) -> bytes:
    """The DER content octets of an OBJECT IDENTIFIER."""
    arcs = [int(a) for a in oid.split(".")]
    out = bytearray([40 * arcs[0] + arcs[1]])
    for arc in arcs[2:]:
        chunk = [arc & 0x7F]
        arc >>= 7
        while arc:
            chunk.append(0x80 | (arc & 0x7F))
            arc >>= 7
        out += bytes(reversed(chunk))
    return bytes(out)


_ROLE_OID_DER = encode_oid(ROLE_OID)


class DerError(SoftplcError, ValueError):
    """Bytes that are not the DER this reader expects (a ValueError too, as before)."""


def _tlv(data: bytes, pos: int, end: int) -> tuple[int, int, int]:
    """(tag, start of the content, end of the content) of the element at ``pos``."""
    if pos + 2 > end:
        raise DerError("truncated")
    tag, first = data[pos], data[pos + 1]
    pos += 2
    if first < 0x80:
        length = first
    else:
        n = first & 0x7F
        if not 1 <= n <= 4 or pos + n > end:
            raise DerError("bad length")
        length = int.from_bytes(data[pos:pos + n], "big")
        pos += n
    if pos + length > end:
        raise DerError("truncated")
    return tag, pos, pos + length


def _children(data: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    out = []
    pos = start
    while pos < end:
        tag, s, e = _tlv(data, pos, end)
        out.append((tag, s, e))
        pos = e
    return out


def role_of(der: bytes) -> str | None:
    """The role in certificate ``der``'s role extension, None if it has none; DerError for
    bytes that are no certificate."""
    tag, s, e = _tlv(der, 0, len(der))
    if tag != 0x30:
        raise DerError("not a certificate")
    parts = _children(der, s, e)
    if not parts or parts[0][0] != 0x30:
        raise DerError("not a certificate")
    _, ts, te = parts[0]  # tbsCertificate
    for tag, s, e in _children(der, ts, te):
        if tag != 0xA3:  # [3] extensions, EXPLICIT
            continue
        inner = _children(der, s, e)
        if len(inner) != 1 or inner[0][0] != 0x30:
            raise DerError("bad extensions")
        for etag, es, ee in _children(der, inner[0][1], inner[0][2]):
            if etag != 0x30:
                continue
            fields = _children(der, es, ee)
            if not fields or fields[0][0] != 0x06:
                continue
            if der[fields[0][1]:fields[0][2]] != _ROLE_OID_DER:
                continue
            value = fields[-1]
            if value[0] != 0x04:  # extnValue OCTET STRING
                raise DerError("bad role extension")
            stag, ss, se = _tlv(der, value[1], value[2])
            if stag not in _STRING_TAGS or se - ss > 4 * ROLE_MAX:
                raise DerError("the role is no string")
            return der[ss:se].decode("utf-8", errors="replace")[:ROLE_MAX]
    return None
