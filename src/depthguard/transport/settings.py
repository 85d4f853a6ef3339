"""Network settings of the cell's Zenoh sessions (camera units, fusion server, ``units:`` and
``zenoh:`` sources, Zenoh sinks): zenoh configuration and key names.

Every session is a zenoh *peer* with explicit endpoints; multicast scouting is off
unless asked for, and the default endpoints are on 127.0.0.1 (a service binds
another interface only when told to). The link lease is 1 s, so a frozen peer's
liveliness token disappears within about a second (R20, R27).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

__all__ = ["DEFAULT_PORT", "DEFAULT_ENDPOINT", "DEFAULT_PREFIX", "Keys", "zenoh_config", "check_endpoint",
           "check_exposure", "is_loopback"]

DEFAULT_PORT = 7447
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
DEFAULT_PREFIX = "depthguard"
DEFAULT_LEASE_MS = 1000

_ENDPOINT = re.compile(r"^(tcp|udp|quic|tls|unixsock-stream)/[^\s]+$")
_CHUNK = re.compile(r"^[A-Za-z0-9_\-.]+$")
_PREFIX = re.compile(r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")


def check_endpoint(ep: str) -> str:
    """A zenoh locator such as ``tcp/127.0.0.1:7447``; ``ValueError`` otherwise."""
    if not isinstance(ep, str) or not _ENDPOINT.match(ep):
        raise ValueError(f"endpoint {ep!r} is not a zenoh locator like 'tcp/127.0.0.1:7447'")
    return ep


@dataclass(frozen=True)
class Keys:
    """Zenoh key expressions under one prefix."""
    prefix: str = DEFAULT_PREFIX

    def __post_init__(self):
        if not _PREFIX.match(self.prefix):
            raise ValueError(f"key prefix {self.prefix!r} must be words separated by '/', no wildcards")

    @property
    def init(self) -> str:
        return f"{self.prefix}/init"

    @property
    def update(self) -> str:
        return f"{self.prefix}/update"

    @property
    def status(self) -> str:
        return f"{self.prefix}/status"

    @property
    def settings(self) -> str:
        return f"{self.prefix}/settings"

    @property
    def trigger(self) -> str:
        return f"{self.prefix}/trigger"

    def units(self, camera: str = "*") -> str:
        """``<prefix>/units/<camera>``: each fresh unit's voxels (the server's queryable on
        ``<prefix>/units/*``; ask ``*`` for all, a camera id for one)."""
        if camera != "*" and not _CHUNK.match(camera):
            raise ValueError(f"camera id {camera!r} cannot name a zenoh key: use letters, digits, '_', '-', '.'")
        return f"{self.prefix}/units/{camera}"

    def states(self, camera: str = "*") -> str:
        """``<prefix>/states/<camera>``: the depth grid state a camera unit publishes per frame
        (issue 29, :mod:`depthguard.transport.state_wire`); ``*`` for all."""
        if camera != "*" and not _CHUNK.match(camera):
            raise ValueError(f"camera id {camera!r} cannot name a zenoh key: use letters, digits, '_', '-', '.'")
        return f"{self.prefix}/states/{camera}"

    def state_relay(self, camera: str = "*") -> str:
        """``<prefix>/relay/states/<camera>``: the same states as the fusion server passes them on to
        the monitor (:mod:`depthguard.distributed.state_relay`; the units and the monitor reach each
        other only through it); ``*`` for all."""
        if camera != "*" and not _CHUNK.match(camera):
            raise ValueError(f"camera id {camera!r} cannot name a zenoh key: use letters, digits, '_', '-', '.'")
        return f"{self.prefix}/relay/states/{camera}"

    def alive(self, camera: str = "*") -> str:
        if camera != "*" and not _CHUNK.match(camera):
            raise ValueError(f"camera id {camera!r} cannot name a zenoh key: use letters, digits, '_', '-', '.'")
        return f"{self.prefix}/alive/{camera}"


def _host(ep: str) -> str:
    """The host part of ``proto/HOST:PORT`` (brackets of an IPv6 address removed)."""
    addr = ep.split("/", 1)[1].split("#", 1)[0].split("?", 1)[0]
    host = addr.rsplit(":", 1)[0] if ":" in addr else addr
    return host.strip("[]")


def is_loopback(ep: str) -> bool:
    """True when endpoint ``ep`` binds / reaches only this machine (127.0.0.0/8, ::1, localhost)."""
    import ipaddress

    if ep.startswith("unixsock-stream/"):
        return True
    host = _host(ep)
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_exposure(listen, connect=(), identity=None, insecure: bool = False) -> None:
    """The rules of R35 for endpoints, one sentence each (``ValueError``):

    * a ``tls/`` endpoint needs certificates (``--keys``);
    * with certificates every endpoint is ``tls/`` (a plain one would let anyone in);
    * without certificates a service listens on loopback only, unless ``insecure``.
    """
    for ep in list(listen) + list(connect):
        check_endpoint(ep)
        if ep.startswith("tls/") and identity is None:
            raise ValueError(f"endpoint {ep} is TLS and needs certificates: give --keys DIR "
                             f"(made by `depthguard keys init|node|admin`, see docs/THREAT_MODEL.md)")
        if identity is not None and not ep.startswith("tls/"):
            raise ValueError(f"with --keys every endpoint must be tls/HOST:PORT (got {ep}): "
                             f"a plain endpoint would accept anyone")
    if identity is None and not insecure:
        for ep in listen:
            if not is_loopback(ep):
                raise ValueError(f"refusing to listen on {ep} without certificates: anyone who reaches it "
                                 f"could feed the safety system. Use --keys DIR with tls/HOST:PORT "
                                 f"(`depthguard keys init`), or --insecure on a network you trust")


def zenoh_config(listen=("tcp/127.0.0.1:0",), connect=(), multicast: bool = False,
                 lease_ms: int = DEFAULT_LEASE_MS, identity=None):
    """A ``zenoh.Config``: peer mode, explicit listen / connect endpoints, scouting off by default.

    ``identity`` (:class:`~depthguard.transport.keys.Identity`): Zenoh's TLS with mutual
    certificates — the cell's CA as the only root, this party's certificate and key for both
    directions, the server's name checked on connect (R35)."""
    import zenoh

    listen = [check_endpoint(e) for e in listen]
    connect = [check_endpoint(e) for e in connect]
    if identity is None and any(e.startswith("tls/") for e in listen + connect):
        raise ValueError("tls/ endpoints need certificates: give --keys DIR (see `depthguard keys init`)")
    if not (100 <= int(lease_ms) <= 1000):
        raise ValueError(f"lease must be within 100-1000 ms (got {lease_ms})")
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", "true" if multicast else "false")
    c.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    c.insert_json5("transport/link/tx/keep_alive", "4")
    if identity is not None:
        tls = {"root_ca_certificate": str(identity.ca_path), "enable_mtls": True,
               "listen_private_key": str(identity.key_path), "listen_certificate": str(identity.cert_path),
               "connect_private_key": str(identity.key_path), "connect_certificate": str(identity.cert_path),
               "verify_name_on_connect": True}
        c.insert_json5("transport/link/tls", json.dumps(tls))
    return c
