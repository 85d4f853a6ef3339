"""Signed messages: which camera (or administrator, or server) a message speaks for (R35).

Zenoh's mutual TLS decides who may connect at all, but it does not tell the
application which certificate a query came through. So every request to the
fusion server, and every reply of the server, is wrapped in a signed envelope::

    "DGA" | version u8 | t_sign f64 (s, wall clock) | nonce 16 B | cert_len u16 | sig_len u16 |
    msg_len u32 | certificate (DER) | message (wire.py bytes) | signature (ECDSA P-256, SHA-256)

The signature covers a domain string, the Zenoh key the envelope was sent on, the
request nonce a reply answers (16 zero bytes for a request), ``t_sign``, the nonce,
SHA-256 of the certificate and the message. :meth:`Verifier.open` accepts an envelope
only when the certificate was issued by the cell's CA (:mod:`depthguard.transport.keys`),
is within its validity, the signature verifies with its key, ``t_sign`` is within
``window_s`` of the verifier's clock and (for requests) the nonce was not seen before
within that window — a recorded message cannot be replayed, moved to another key,
or reused as the answer to another request. The caller then checks the role and the
name (camera id) the certificate carries.

Costs: ~0.5 kB per message (certificate + signature), one ECDSA signature per
message at the sender and one verification at the receiver (~0.1 ms each); a
certificate's chain is checked once and cached.
"""

from __future__ import annotations

import hashlib
import os
import struct
import threading
import time
import warnings
from collections import OrderedDict, deque
from dataclasses import dataclass

__all__ = ["AuthError", "Signer", "Verifier", "Signed", "NO_NONCE"]

MAGIC = b"DGA"
VERSION = 1
_HEAD = struct.Struct("<3sBd16sHHI")
_DOMAIN = b"depthguard-auth-v1\x00"
NO_NONCE = bytes(16)
MAX_CERT = 4096
MAX_SIG = 256


class AuthError(ValueError):
    """An envelope that is not signed, not signed by the cell's authority, tampered, stale or replayed."""


@dataclass(frozen=True)
class Signed:
    """An opened envelope: the inner message, the signer's role and name, and the nonce."""
    message: bytes
    role: str
    name: str
    nonce: bytes
    t_sign: float


def _to_sign(key: str, reply_to: bytes, t_sign: float, nonce: bytes, cert_der: bytes, msg: bytes) -> bytes:
    return b"".join([_DOMAIN, key.encode("utf-8"), b"\x00", reply_to, struct.pack("<d", t_sign), nonce,
                     hashlib.sha256(cert_der).digest(), msg])


class Signer:
    """Seals messages with an :class:`~depthguard.transport.keys.Identity`'s key."""

    def __init__(self, identity):
        self.identity = identity
        self._cert = identity.cert_der

    def seal(self, msg: bytes, key: str, reply_to: bytes = NO_NONCE) -> tuple[bytes, bytes]:
        """``(envelope, nonce)`` for ``msg`` sent on Zenoh key ``key`` (a reply: ``reply_to`` = the
        request's nonce)."""
        from cryptography.hazmat.primitives import hashes
        from cryptography.hazmat.primitives.asymmetric import ec

        t = time.time()
        nonce = os.urandom(16)
        sig = self.identity.key.sign(_to_sign(key, reply_to, t, nonce, self._cert, msg), ec.ECDSA(hashes.SHA256()))
        head = _HEAD.pack(MAGIC, VERSION, t, nonce, len(self._cert), len(sig), len(msg))
        return head + self._cert + msg + sig, nonce


class Verifier:
    """Opens envelopes signed by certificates of one CA (module docstring).

    ``ca_cert``: the cell's CA (``x509.Certificate``). ``window_s``: accepted clock
    difference between signer and verifier, and how long nonces are remembered.
    """

    def __init__(self, ca_cert, window_s: float = 30.0):
        self.ca = ca_cert
        self.window_s = float(window_s)
        self._certs: OrderedDict[bytes, tuple] = OrderedDict()     # sha256(der) -> (role, name, key, not_after)
        self._seen: set[bytes] = set()
        self._order: deque[tuple[float, bytes]] = deque()
        self._lock = threading.Lock()

    def _check_cert(self, der: bytes):
        from cryptography import x509

        from depthguard.transport.keys import cert_role_and_name

        h = hashlib.sha256(der).digest()
        with self._lock:
            hit = self._certs.get(h)
        if hit is not None:
            return hit
        try:
            with warnings.catch_warnings():              # e.g. a serial number <= 0: refused below anyway
                warnings.simplefilter("ignore")
                cert = x509.load_der_x509_certificate(der)
                role, name = cert_role_and_name(cert)
        except Exception:  # noqa: BLE001 - ValueError, x509.InvalidVersion ...: all mean "not a certificate"
            raise AuthError("the certificate in the envelope cannot be parsed") from None
        try:
            cert.verify_directly_issued_by(self.ca)
        except Exception:  # noqa: BLE001 - ValueError, TypeError or InvalidSignature: all mean "not ours"
            raise AuthError(f"certificate {role}/{name} was not issued by this cell's authority") from None
        try:
            try:
                is_ca = cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
            except x509.ExtensionNotFound:
                is_ca = False
            entry = (role, name, cert.public_key(), cert.not_valid_before_utc.timestamp(),
                     cert.not_valid_after_utc.timestamp())
        except Exception:  # noqa: BLE001 - any parse failure of an extension or key
            raise AuthError(f"certificate {role}/{name} cannot be parsed") from None
        if is_ca:
            raise AuthError(f"certificate {role}/{name} is a CA certificate, not a party's")
        with self._lock:
            self._certs[h] = entry
            while len(self._certs) > 1024:
                self._certs.popitem(last=False)
        return entry

    def open(self, data: bytes, key: str, reply_to: bytes | None = None) -> Signed:
        """Verify and unwrap an envelope received on ``key``. ``reply_to``: None for a request
        (the nonce must be new), else the nonce of the request this must answer."""
        from cryptography.exceptions import InvalidSignature
        from cryptography.hazmat.primitives import hashes
        from cryptography.hazmat.primitives.asymmetric import ec

        b = bytes(data)
        if len(b) < _HEAD.size or b[:3] != MAGIC:
            raise AuthError("message is not signed (no depthguard envelope): a certificate is required")
        magic, ver, t_sign, nonce, nc, ns, nm = _HEAD.unpack_from(b)
        if ver != VERSION:
            raise AuthError(f"envelope version {ver} not supported (this end speaks {VERSION})")
        if nc > MAX_CERT or ns > MAX_SIG or _HEAD.size + nc + nm + ns != len(b):
            raise AuthError("envelope lengths do not match its size")
        der = b[_HEAD.size:_HEAD.size + nc]
        msg = b[_HEAD.size + nc:_HEAD.size + nc + nm]
        sig = b[_HEAD.size + nc + nm:]
        role, name, pub, t0, t1 = self._check_cert(der)
        now = time.time()
        if not (t0 <= now <= t1):
            raise AuthError(f"certificate {role}/{name} is not valid now")
        try:
            pub.verify(sig, _to_sign(key, reply_to or NO_NONCE, t_sign, nonce, der, msg), ec.ECDSA(hashes.SHA256()))
        except (InvalidSignature, ValueError, TypeError):
            raise AuthError(f"bad signature on a message from {role}/{name} (tampered, or sent on another key)") from None
        if not abs(now - t_sign) <= self.window_s:
            raise AuthError(f"message from {role}/{name} signed {now - t_sign:+.1f} s ago, outside the "
                            f"{self.window_s:g} s window (replayed, or clocks not synchronised)")
        if reply_to is None:
            with self._lock:
                while self._order and now - self._order[0][0] > 2 * self.window_s:
                    self._seen.discard(self._order.popleft()[1])
                if nonce in self._seen:
                    raise AuthError(f"message from {role}/{name} replayed (nonce seen before)")
                self._seen.add(nonce)
                self._order.append((now, nonce))
        return Signed(msg, role, name, nonce, t_sign)
