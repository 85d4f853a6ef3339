"""Request-reply to the fusion server over zenoh (used by nodes and ``depthguard status``)."""

from __future__ import annotations

import time
from typing import Sequence

from depthguard.distributed import wire as W
from depthguard.distributed.settings import DEFAULT_ENDPOINT, DEFAULT_LEASE_MS, Keys, zenoh_config

__all__ = ["ServerClient", "ServerUnavailable", "ServerRefused"]


class ServerUnavailable(ConnectionError):
    """No reply from the fusion server within the timeout."""


class ServerRefused(ValueError):
    """The server answered with an error (refused camera, malformed message ...)."""

    def __init__(self, code: int, text: str):
        super().__init__(f"server refused (code {code}): {text}")
        self.code = code
        self.text = text


class ServerClient:
    """A zenoh peer session connected to the server's endpoint(s)."""

    def __init__(self, connect: Sequence[str] = (DEFAULT_ENDPOINT,), listen: Sequence[str] = ("tcp/127.0.0.1:0",),
                 prefix: str = "depthguard", multicast: bool = False, lease_ms: int = DEFAULT_LEASE_MS,
                 session=None):
        import zenoh

        self.keys = Keys(prefix)
        self._own = session is None
        self.session = session if session is not None else zenoh.open(zenoh_config(listen, connect, multicast, lease_ms))

    def close(self) -> None:
        if self._own and self.session is not None:
            self.session.close()
        self.session = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def request(self, key: str, payload: bytes, timeout: float = 1.0,
                expect: W.MsgType | tuple[W.MsgType, ...] | None = None) -> W.Message:
        """Send one query, decode the first reply; ``ServerRefused`` on ERROR_REP,
        ``ServerUnavailable`` when nobody answers in ``timeout`` seconds."""
        replies = self.session.get(key, payload=payload, timeout=timeout)
        for r in replies:
            if r.ok is None:
                continue
            m = W.decode(r.ok.payload.to_bytes())
            if m.type == W.MsgType.ERROR_REP:
                raise ServerRefused(m.code, m.text)
            if expect is not None:
                ok = (expect,) if isinstance(expect, W.MsgType) else expect
                if m.type not in ok:
                    raise W.WireError(f"unexpected reply {m.type.name} on {key}")
            return m
        raise ServerUnavailable(f"no reply on {key} within {timeout:g} s")

    def wait_for_server(self, timeout: float = 10.0) -> dict:
        """Poll ``status`` until the server answers; its status dict."""
        t_end = time.monotonic() + timeout
        while True:
            try:
                return self.status(timeout=0.5)
            except ServerUnavailable:
                if time.monotonic() > t_end:
                    raise
                time.sleep(0.05)

    def status(self, timeout: float = 1.0) -> dict:
        import json

        m = self.request(self.keys.status, W.status_request(), timeout, W.MsgType.STATUS_REP)
        return json.loads(m.text)

    def set_settings(self, timeout: float = 1.0, **changes) -> dict:
        import json

        m = self.request(self.keys.settings, W.settings_request(**changes), timeout, W.MsgType.STATUS_REP)
        return json.loads(m.text)
