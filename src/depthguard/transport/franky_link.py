"""One connection to a Franka FR3 through ``franky`` (PyPI ``franky-control``, extra
``depthguard[franka]``), shared by ``--sink franky:HOST`` and ``--joints franky:HOST`` (R27, R31).

libfranka lets one client command the robot (FCI, TCP port 1337): the sink that moves the
robot and the source that reads its joints of one run must use the same ``franky.Robot``.
:func:`link_for` gives it, one per host and process, counted (:meth:`FrankyLink.release`
closes it with its last user). ``franky`` is imported only here, only when asked for.
"""

from __future__ import annotations

import socket
import threading

__all__ = ["FrankyError", "FRANKA_DOF", "FCI_PORT", "missing_package", "parse_host", "check_reachable",
           "FrankyLink", "link_for"]

FRANKA_DOF = 7
FCI_PORT = 1337                   # libfranka's command port (fixed)


class FrankyError(ValueError):
    """A Franka connection that cannot be used (one sentence why)."""


def missing_package() -> str | None:
    """The sentence to print when ``franky`` cannot be imported, else ``None``."""
    try:
        import franky  # noqa: F401
    except ImportError as exc:
        return (f"franky: the package franky-control is not installed ({exc}); install depthguard[franka] "
                "(pip install 'depthguard[franka]') to use a Franka robot")
    return None


def parse_host(argument: str, what: str) -> str:
    """The robot's address of ``franky:HOST`` (libfranka's port is fixed: no ``:PORT``)."""
    host = (argument or "").strip()
    if not host or any(c in host for c in " /,:;?"):
        raise FrankyError(f"{what}: {argument!r} is not a robot address (franky:HOST, e.g. franky:172.16.0.2)")
    return host


def check_reachable(host: str, what: str, timeout_s: float = 2.0) -> None:
    """:class:`FrankyError` unless something accepts TCP on ``host``:1337 within ``timeout_s``
    (libfranka itself waits much longer for an address that does not answer)."""
    try:
        with socket.create_connection((host, FCI_PORT), timeout=timeout_s):
            pass
    except OSError as exc:
        raise FrankyError(f"{what}: no Franka robot answers at {host}:{FCI_PORT} within {timeout_s:g} s ({exc}); "
                          f"check the address and that FCI is enabled in Desk") from None


class FrankyLink:
    """A ``franky.Robot`` on ``host`` with a user count; ``lock`` serialises commands."""

    def __init__(self, host: str, connect_timeout_s: float = 2.0):
        missing = missing_package()
        if missing:
            raise FrankyError(missing)
        import franky

        check_reachable(host, f"franky {host}", connect_timeout_s)
        self.host = host
        self.franky = franky
        try:
            self.robot = franky.Robot(host, realtime_config=franky.RealtimeConfig.Ignore)
        except Exception as exc:  # noqa: BLE001 - libfranka raises its own types (version mismatch, refused)
            raise FrankyError(f"franky {host}: libfranka could not connect ({type(exc).__name__}: {exc})") from None
        self.lock = threading.RLock()
        self.users = 0
        self.closed = False

    def joint_state(self):
        """``(q (7,) rad, dq (7,) rad/s, robot time s)`` of the newest robot state."""
        import numpy as np

        st = self.robot.state
        return (np.asarray(st.q, dtype=np.float64).reshape(-1), np.asarray(st.dq, dtype=np.float64).reshape(-1),
                float(st.time.to_sec()))

    def release(self) -> None:
        with _LOCK:
            self.users -= 1
            if self.users > 0 or self.closed:
                return
            self.closed = True
            _LINKS.pop(self.host, None)
        del self.robot                                   # franky closes the connection with the object


_LINKS: dict[str, FrankyLink] = {}
_LOCK = threading.Lock()


def link_for(host: str) -> FrankyLink:
    """The process's link to ``host`` (opened on first use); the caller must :meth:`~FrankyLink.release` it."""
    with _LOCK:
        link = _LINKS.get(host)
        if link is None or link.closed:
            link = FrankyLink(host)
            _LINKS[host] = link
        link.users += 1
        return link
