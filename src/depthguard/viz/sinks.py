"""The viz room's sinks, registered by this room itself when it is imported (R31).

The runtime's sink registry (:mod:`depthguard.runtime.sink_specs`) names only modules of its
own room and below; a room above it adds its schemes here, as a plug-in does, so that no
import — and no module path given as a string — runs back up the layers (``tests/test_layers.py``).
Whoever composes a run (the CLI) imports this module; ``import depthguard.viz`` does too.

``view:[[HOST:]PORT]``: the live 3-D view in the browser (:mod:`depthguard.viz.live`, default
127.0.0.1:8080); :mod:`depthguard.viz.live` itself is imported only when a run asks for it.
"""

from __future__ import annotations

from depthguard.runtime.sink_specs import register_sink

__all__ = ["view_address"]


def view_address(argument: str) -> tuple[str, int]:
    """``(host, port)`` of ``view:[[HOST:]PORT]`` (default 127.0.0.1:8080); ``ValueError`` in one sentence."""
    host, _, port = argument.rpartition(":") if ":" in argument else ("", "", argument)
    try:
        port_n = 8080 if not port else int(port)
    except ValueError:
        raise ValueError(f"--sink view:{argument}: the port must be a number, 0 to 65535 (got {port!r})") from None
    if not 0 <= port_n <= 65535:
        raise ValueError(f"--sink view:{argument}: the port must be 0 to 65535 (got {port_n})")
    return host or "127.0.0.1", port_n


register_sink("view", "depthguard.viz.live:open_view", check=view_address)
