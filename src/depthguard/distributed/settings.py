"""Network settings of the distributed camera subsystem: zenoh configuration and key names.

Every session is a zenoh *peer* with explicit endpoints; multicast scouting is off
unless asked for, and the default endpoints are on 127.0.0.1 (a service binds
another interface only when told to). The link lease is 1 s, so a frozen peer's
liveliness token disappears within about a second (R20, R27).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

__all__ = ["DEFAULT_PORT", "DEFAULT_ENDPOINT", "DEFAULT_PREFIX", "Keys", "zenoh_config", "check_endpoint"]

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

    def alive(self, camera: str = "*") -> str:
        if camera != "*" and not _CHUNK.match(camera):
            raise ValueError(f"camera id {camera!r} cannot name a zenoh key: use letters, digits, '_', '-', '.'")
        return f"{self.prefix}/alive/{camera}"


def zenoh_config(listen=("tcp/127.0.0.1:0",), connect=(), multicast: bool = False,
                 lease_ms: int = DEFAULT_LEASE_MS):
    """A ``zenoh.Config``: peer mode, explicit listen / connect endpoints, scouting off by default."""
    import zenoh

    listen = [check_endpoint(e) for e in listen]
    connect = [check_endpoint(e) for e in connect]
    if not (100 <= int(lease_ms) <= 1000):
        raise ValueError(f"lease must be within 100-1000 ms (got {lease_ms})")
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", "true" if multicast else "false")
    c.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    c.insert_json5("transport/link/tx/keep_alive", "4")
    return c
