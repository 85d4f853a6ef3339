"""Sinks named by a spec ``SCHEME:ARGUMENT`` (``depthguard monitor --sink SPEC``, repeatable) (R31).

Known schemes: ``ur-rtde:HOST`` (a Universal Robots arm's speed slider,
:mod:`depthguard.runtime.ur_sink`), ``franky:HOST,path=FILE`` (a Franka FR3 running a joint path
through franky, :mod:`depthguard.runtime.franky_sink`). A scheme's module is imported only when
asked for.
"""

from __future__ import annotations

import importlib
import inspect

__all__ = ["SINK_SCHEMES", "open_sink"]

#: scheme -> "module:factory"; the factory takes the argument after ``SCHEME:``
SINK_SCHEMES = {"ur-rtde": "depthguard.runtime.ur_sink:open_ur_sink",
                "franky": "depthguard.runtime.franky_sink:open_franky_sink"}


def open_sink(spec: str, rig=None):
    """The sink of ``spec``; ``ValueError`` naming the known schemes for an unknown one. ``rig`` is
    handed to a factory that takes one (to check the robot's joints against it)."""
    scheme, _, argument = (spec or "").partition(":")
    scheme = scheme.strip()
    if scheme not in SINK_SCHEMES:
        raise ValueError(f"--sink {spec!r}: unknown scheme {scheme!r}; the scheme must be one of "
                         f"{', '.join(sorted(SINK_SCHEMES))}")
    module, _, factory = SINK_SCHEMES[scheme].partition(":")
    fn = getattr(importlib.import_module(module), factory)
    if rig is not None and "rig" in inspect.signature(fn).parameters:
        return fn(argument, rig=rig)
    return fn(argument)
