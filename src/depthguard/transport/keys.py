"""A cell's own certificate authority and its certificates (R35).

Files (PEM; private keys ``*.key`` are written with mode 0600, never overwritten)::

    CA dir    (depthguard keys init DIR)    ca.pem ca.key server.pem server.key
    node dir  (depthguard keys node CAM)    ca.pem node.pem node.key      CN = CAM,  OU = depthguard-node
    admin dir (depthguard keys admin)       ca.pem admin.pem admin.key    CN = NAME, OU = depthguard-admin

The server's certificate (OU ``depthguard-server``) names the hosts it may be reached
at (``localhost``, ``127.0.0.1`` and ``--host`` values) so a node checks the name it
connects to. All keys are ECDSA P-256 (accepted by Zenoh's TLS, rustls). The same
files serve two layers: Zenoh's mutual TLS (who may connect at all) and the
signatures of :mod:`depthguard.transport.auth` (which camera a message speaks for).

:func:`load_identity` reads one such directory into an :class:`Identity`.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

__all__ = ["ROLE_NODE", "ROLE_ADMIN", "ROLE_SERVER", "Identity", "init_authority", "issue_node",
           "issue_admin", "load_identity", "cert_role_and_name"]

ROLE_NODE = "depthguard-node"
ROLE_ADMIN = "depthguard-admin"
ROLE_SERVER = "depthguard-server"
_FILES = {ROLE_SERVER: "server", ROLE_NODE: "node", ROLE_ADMIN: "admin"}
_DAYS = 3650


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


def _write_private(path: Path, key) -> None:
    """Write a private key, mode 0600 from its creation (``O_EXCL``: never overwrite)."""
    from cryptography.hazmat.primitives import serialization

    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _write_public(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _fresh_dir(out: Path, names: Sequence[str]) -> Path:
    """``out``, created if needed; ``ValueError`` (nothing written) if any of ``names`` exists there."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} exists and is not a directory")
    taken = [n for n in names if (out / n).exists()]
    if taken:
        raise ValueError(f"{out} already holds {', '.join(taken)}; nothing was overwritten "
                         f"(choose another directory or remove them yourself)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _name(cn: str, role: str):
    from cryptography.x509.oid import NameOID
    from cryptography import x509

    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, role),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _load_ca(ca_dir: Path):
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    ca_dir = Path(ca_dir)
    for n in ("ca.pem", "ca.key"):
        if not (ca_dir / n).is_file():
            raise FileNotFoundError(f"{ca_dir / n} not found: --ca must be a directory made by "
                                    f"`depthguard keys init`")
    cert = x509.load_pem_x509_certificate((ca_dir / "ca.pem").read_bytes())
    key = serialization.load_pem_private_key((ca_dir / "ca.key").read_bytes(), None)
    return cert, key


def _issue(ca_cert, ca_key, cn: str, role: str, *, server_hosts: Sequence[str] = ()):
    """(key, certificate) for ``cn`` / ``role`` signed by the CA."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID

    key = ec.generate_private_key(ec.SECP256R1())
    now = _now()
    b = (x509.CertificateBuilder().subject_name(_name(cn, role)).issuer_name(ca_cert.subject)
         .public_key(key.public_key()).serial_number(x509.random_serial_number())
         .not_valid_before(now - datetime.timedelta(minutes=5))
         .not_valid_after(now + datetime.timedelta(days=_DAYS))
         .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
         .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                      data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                      crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
         .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
         .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False))
    if role == ROLE_SERVER:
        sans = []
        for h in server_hosts:
            try:
                sans.append(x509.IPAddress(ipaddress.ip_address(h)))
            except ValueError:
                sans.append(x509.DNSName(h))
        b = b.add_extension(x509.SubjectAlternativeName(sans), critical=False)
        b = b.add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                   ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
    else:
        b = b.add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
    return key, b.sign(ca_key, hashes.SHA256())


def _pem(cert) -> bytes:
    from cryptography.hazmat.primitives import serialization
    return cert.public_bytes(serialization.Encoding.PEM)


def init_authority(out: Path, hosts: Sequence[str] = (), name: str = "depthguard cell") -> Path:
    """Create the cell's CA and the server's certificate in ``out`` (R35). ``hosts``: names or
    addresses the server is reached at besides ``localhost`` / ``127.0.0.1``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec

    all_hosts = list(dict.fromkeys(["localhost", "127.0.0.1", *hosts]))
    for h in all_hosts:
        if not h or any(c in h for c in " /*"):
            raise ValueError(f"--host {h!r} is not a host name or IP address")
    out = _fresh_dir(out, ["ca.pem", "ca.key", "server.pem", "server.key"])
    ca_key = ec.generate_private_key(ec.SECP256R1())
    now = _now()
    subject = _name(f"{name} CA", "depthguard-ca")
    ca = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(minutes=5))
          .not_valid_after(now + datetime.timedelta(days=_DAYS))
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                       crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
          .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
          .sign(ca_key, hashes.SHA256()))
    _write_private(out / "ca.key", ca_key)
    _write_public(out / "ca.pem", _pem(ca))
    key, cert = _issue(ca, ca_key, "server", ROLE_SERVER, server_hosts=all_hosts)
    _write_private(out / "server.key", key)
    _write_public(out / "server.pem", _pem(cert))
    return out


def _issue_into(ca_dir: Path, out: Path, cn: str, role: str) -> Path:
    stem = _FILES[role]
    ca_cert, ca_key = _load_ca(ca_dir)
    out = _fresh_dir(out, ["ca.pem", f"{stem}.pem", f"{stem}.key"])
    key, cert = _issue(ca_cert, ca_key, cn, role)
    _write_private(out / f"{stem}.key", key)
    _write_public(out / f"{stem}.pem", _pem(cert))
    _write_public(out / "ca.pem", _pem(ca_cert))
    return out


def issue_node(camera: str, ca_dir: Path, out: Path) -> Path:
    """A node's certificate naming ``camera`` (a rig camera id), signed by the CA in ``ca_dir``."""
    from depthguard.config import check_camera_id

    check_camera_id(camera)
    return _issue_into(ca_dir, out, camera, ROLE_NODE)


def issue_admin(ca_dir: Path, out: Path, name: str = "admin") -> Path:
    """An administrator's certificate (``depthguard status``, settings changes)."""
    from depthguard.config import check_camera_id

    check_camera_id(name)
    return _issue_into(ca_dir, out, name, ROLE_ADMIN)


def cert_role_and_name(cert) -> tuple[str, str]:
    """``(OU role, CN name)`` of an ``x509.Certificate`` (empty strings when absent)."""
    from cryptography.x509.oid import NameOID

    def one(oid):
        v = cert.subject.get_attributes_for_oid(oid)
        return str(v[0].value) if len(v) == 1 else ""
    return one(NameOID.ORGANIZATIONAL_UNIT_NAME), one(NameOID.COMMON_NAME)


@dataclass
class Identity:
    """One party's key material: its role (``ROLE_*``), name (camera id, ``server`` or admin
    name), file paths (for Zenoh's TLS) and loaded objects (for signatures)."""
    directory: Path
    role: str
    name: str
    ca_path: Path
    cert_path: Path
    key_path: Path
    cert: object
    key: object
    ca_cert: object
    cert_der: bytes


def load_identity(directory: Path) -> Identity:
    """The identity in ``directory`` (a CA dir gives the server's; a node or admin dir its own).
    ``FileNotFoundError`` / ``ValueError`` naming the file when something is missing or wrong."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"--keys {d}: no such directory (make one with `depthguard keys init|node|admin`)")
    stems = [s for s in ("server", "node", "admin") if (d / f"{s}.pem").is_file()]
    if len(stems) != 1:
        raise ValueError(f"--keys {d}: expected exactly one of server.pem, node.pem, admin.pem (found "
                         f"{', '.join(s + '.pem' for s in stems) or 'none'})")
    stem = stems[0]
    paths = {"ca": d / "ca.pem", "cert": d / f"{stem}.pem", "key": d / f"{stem}.key"}
    for p in paths.values():
        if not p.is_file():
            raise FileNotFoundError(f"--keys {d}: {p.name} is missing")
    mode = paths["key"].stat().st_mode & 0o077
    if mode:
        raise ValueError(f"{paths['key']} is readable by others (mode {oct(paths['key'].stat().st_mode & 0o777)}); "
                         f"run `chmod 600 {paths['key']}`")
    try:
        ca = x509.load_pem_x509_certificate(paths["ca"].read_bytes())
        cert = x509.load_pem_x509_certificate(paths["cert"].read_bytes())
        key = serialization.load_pem_private_key(paths["key"].read_bytes(), None)
    except ValueError as exc:
        raise ValueError(f"--keys {d}: cannot read a certificate or key ({exc})") from None
    role, name = cert_role_and_name(cert)
    if _FILES.get(role) != stem:
        raise ValueError(f"{paths['cert']}: role {role!r} does not match the file name {stem}.pem")
    from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat
    if (key.public_key().public_bytes(Encoding.DER, PublicFormat.SubjectPublicKeyInfo)
            != cert.public_key().public_bytes(Encoding.DER, PublicFormat.SubjectPublicKeyInfo)):
        raise ValueError(f"{paths['key']} does not belong to {paths['cert']}")
    return Identity(d, role, name, paths["ca"], paths["cert"], paths["key"], cert, key, ca,
                    cert.public_bytes(Encoding.DER))
