"""The fusion server passes the units' depth grid states on to the monitor (issue 29 point 3, R20, R35).

Every Zenoh session of the distributed subsystem is a peer, and peers do not route for each
other: a camera unit and the monitor both connect to the fusion server (with certificates they
have no listener of their own), so the server is the one party both reach. The relay subscribes
to ``<prefix>/states/*`` on the server's session and publishes each message **unchanged** (a
sealed one stays sealed: the monitor checks the unit's signature against the original key) on
``<prefix>/relay/states/<camera>``, which the monitor's ``units:`` source reads. Only the newest
message per camera waits (a newer one replaces it, counted in ``replaced``); a camera that is
not in the server's rig is not passed on (counted in ``refused``). The put runs on the relay's
own thread, never in Zenoh's callback, with congestion control *block*.

Cost: the server receives and sends each state once (1.5 MB per 640x480 frame, codec f32) and
does no decoding.
"""

from __future__ import annotations

import threading

__all__ = ["StateRelay"]


class StateRelay:
    """Passes states on (module docstring). ``server``: a started
    :class:`~depthguard.distributed.server.FusionServer`."""

    def __init__(self, server, log=None):
        self.server = server
        self.keys = server.keys
        self._log = log or (lambda m: None)
        self._cond = threading.Condition()
        self._pending: dict[str, object] = {}
        self._stop = False
        self.relayed = 0
        self.replaced = 0
        self.refused = 0
        self._sub = None
        self._thread = threading.Thread(target=self._run, name="depthguard-state-relay", daemon=True)

    def start(self) -> "StateRelay":
        self._sub = self.server.session.declare_subscriber(self.keys.states("*"), self._on_state)
        self._thread.start()
        return self

    def _on_state(self, sample) -> None:
        cam = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._cond:
            if cam not in self.server.cameras:
                self.refused += 1
                first = self.refused == 1
            else:
                first = False
                if cam in self._pending:
                    self.replaced += 1
                self._pending[cam] = sample.payload
                self._cond.notify()
        if first:
            self._log(f"state relay: a state of camera {cam!r}, which is not in the rig, is not passed on "
                      f"(counted, logged once)")

    def _run(self) -> None:
        import zenoh

        while True:
            with self._cond:
                while not self._pending and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                cam, payload = self._pending.popitem()
            try:
                self.server.session.put(self.keys.state_relay(cam), payload,
                                        congestion_control=zenoh.CongestionControl.BLOCK)
                self.relayed += 1
            except Exception as exc:  # noqa: BLE001 - the relay keeps running; the camera goes stale
                self._log(f"state relay: camera {cam}: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        if self._thread.is_alive():
            self._thread.join(2.0)
        if self._sub is not None:
            try:
                self._sub.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
            self._sub = None
