"""Request-reply to the fusion server over zenoh (used by nodes and ``depthguard status``).

With an ``identity`` (:mod:`depthguard.transport.keys`, R35) the session uses Zenoh's
mutual TLS, every request is signed (:mod:`depthguard.transport.auth`) and only replies
signed by the cell's server for that very request are accepted; others are skipped and
remembered in :attr:`ServerClient.last_refused_reply`.
"""

from __future__ import annotations

import time
from typing import Sequence

from depthguard.transport import wire
from depthguard.transport.settings import DEFAULT_ENDPOINT, DEFAULT_LEASE_MS, Keys, zenoh_config

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

    def __init__(self, connect: Sequence[str] = (DEFAULT_ENDPOINT,), listen: Sequence[str] | None = None,
                 prefix: str = "depthguard", multicast: bool = False, lease_ms: int = DEFAULT_LEASE_MS,
                 session=None, identity=None):
        import zenoh

        self.keys = Keys(prefix)
        self.connect = list(connect)
        self.identity = identity
        self._signer = self._verifier = None
        if identity is not None:
            from depthguard.transport.auth import Signer, Verifier

            self._signer, self._verifier = Signer(identity), Verifier(identity.ca_cert)
        if listen is None:                 # with certificates: no listener of our own (nothing to attack)
            listen = [] if identity is not None else ["tcp/127.0.0.1:0"]
        self.last_refused_reply: str | None = None
        self._own = session is None
        self.session = session if session is not None else zenoh.open(
            zenoh_config(listen, connect, multicast, lease_ms, identity=identity))

    def close(self) -> None:
        if self._own and self.session is not None:
            self.session.close()
        self.session = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def request(self, key: str, payload: bytes, timeout: float = 1.0,
                expect: wire.MsgType | tuple[wire.MsgType, ...] | None = None) -> wire.Message:
        """Send one query, decode the first reply; ``ServerRefused`` on ERROR_REP,
        ``ServerUnavailable`` when nobody answers in ``timeout`` seconds."""
        nonce = None
        if self._signer is not None:
            payload, nonce = self._signer.seal(payload, key)
        if self._signer is None:
            replies = self.session.get(key, payload=payload, timeout=timeout)
        else:           # every answerer, no merging: a forged reply cannot hide or replace the server's
            import zenoh

            replies = self.session.get(key, payload=payload, timeout=timeout, target=zenoh.QueryTarget.ALL,
                                       consolidation=zenoh.ConsolidationMode.NONE)
        for r in replies:
            if r.ok is None:
                continue
            data = r.ok.payload.to_bytes()
            if self._verifier is not None:
                from depthguard.transport.auth import AuthError
                from depthguard.transport.keys import ROLE_SERVER

                try:
                    signed = self._verifier.open(data, key, reply_to=nonce)
                    if signed.role != ROLE_SERVER:
                        raise AuthError(f"reply signed by {signed.role}/{signed.name}, not by the server")
                except AuthError as exc:
                    self.last_refused_reply = str(exc)
                    continue
                data = signed.message
            m = wire.decode(data)
            if m.type == wire.MsgType.ERROR_REP:
                raise ServerRefused(m.code, m.text)
            if expect is not None:
                ok = (expect,) if isinstance(expect, wire.MsgType) else expect
                if m.type not in ok:
                    raise wire.WireError(f"unexpected reply {m.type.name} on {key}")
            return m
        why = f" (a reply was refused: {self.last_refused_reply})" if self.last_refused_reply else ""
        raise ServerUnavailable(f"no reply on {key} within {timeout:g} s{why}")

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

        m = self.request(self.keys.status, wire.status_request(), timeout, wire.MsgType.STATUS_REP)
        return json.loads(m.text)

    def set_settings(self, timeout: float = 1.0, **changes) -> dict:
        import json

        m = self.request(self.keys.settings, wire.settings_request(**changes), timeout, wire.MsgType.STATUS_REP)
        return json.loads(m.text)
