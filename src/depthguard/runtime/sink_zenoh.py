"""The ``zenoh:[CELL]`` sink: reactions, distances and health published under ``depthguard/<cell>/``,
and the running monitor's settings taken from ``depthguard/<cell>/settings`` (R29, R31).

Its own Zenoh session listens where the run's ``context["zenoh_listen"]`` says (loopback unless
told otherwise) and connects to ``context["zenoh_connect"]``; ``CELL`` defaults to the rig's
``monitor: cell`` or its name. Publishing: :class:`depthguard.runtime.sinks.ZenohPublisher`;
settings: :class:`depthguard.runtime.remote.SettingsListener`, started by :meth:`ZenohSink.attach`.
"""

from __future__ import annotations

from depthguard.runtime.sinks import ZenohPublisher, reaction_keys

__all__ = ["ZenohSink", "open_zenoh"]


class ZenohSink:
    """Publisher and settings listener on one session (module docstring)."""
    name = "zenoh"

    def __init__(self, cell: str, listen: str, connect=()):
        import zenoh

        from depthguard.transport.settings import zenoh_config

        reaction_keys(cell)                           # a bad cell name before a session opens
        self.cell = cell
        self.session = zenoh.open(zenoh_config([listen], list(connect)))
        self.publisher = ZenohPublisher(cell, session=self.session)
        self.listener = None
        self.describe = (f"publishing under depthguard/{cell}/ (reaction, distances, health); "
                         f"settings on depthguard/{cell}/settings")

    def attach(self, monitor) -> None:
        from depthguard.runtime.remote import SettingsListener

        self.listener = SettingsListener(monitor, self.session, self.cell)

    def __call__(self, reaction) -> None:
        self.publisher(reaction)

    def close(self) -> None:
        if self.listener is not None:
            self.listener.close()
            self.listener = None
        if self.publisher is not None:
            self.publisher.close()
            self.publisher = None
            self.session.close()


def open_zenoh(argument: str, rig, context: dict) -> ZenohSink:
    """``zenoh:[CELL]`` (module docstring)."""
    cell = argument or rig.monitor.cell or rig.name
    listen = (context.get("zenoh_listen") or (rig.monitor.zenoh_listen,))[0]
    return ZenohSink(cell, listen, tuple(context.get("zenoh_connect", ())))
