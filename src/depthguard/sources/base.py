"""The source protocol and its registry by scheme (R29, R31).

A **frame source** serves some of the rig's cameras. The runtime pulls from
it: ``frames_until(t)`` returns the frames captured at or before ``t`` that
it has not returned yet (each a :class:`~depthguard.sources.Frame`: camera
id, depth (H, W) float32 metres with 0 = no measurement, capture stamp in
seconds on the monitor's clock). A live source returns what has arrived; a
recording or a simulator returns what is due. ``done`` is True once no
frame will ever come again (the end of a recording); ``lost`` holds a
sentence when the source failed (a camera unplugged) and ``None`` otherwise.

A **live** source (``live = True``: Zenoh joint states, camera units, real
cameras) stamps with the wall clock, ``time.time()`` in seconds — synchronise
the machines of a cell (NTP, PTP) — and a real-time run that has one runs on
that clock too; recordings keep their own stamps (``first_stamp``) and the
simulator its run time from 0.

A **joint source** does the same for joint states: ``states_until(t)``
returns ``[(stamp, q (dof,)), ...]`` in stamp order.

Sources are opened by a spec ``SCHEME:ARGUMENT`` (``sim:flacco-cell``,
``images:DIR``, ``csv:FILE``): a new source is one module that decorates its
factory with :func:`register_source` (frames) or :func:`register_joints`
(joint states) and is listed in ``_SOURCE_MODULES``. A factory is called as
``factory(argument, rig, context)``; ``context`` is a dict shared by every
source of one run (the simulator keeps its world there, so that its frames
and its joint states describe the same robot).
"""

from __future__ import annotations

import importlib
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from depthguard.sources.frame import Frame

__all__ = ["FrameSource", "JointSource", "register_source", "register_joints", "open_source",
           "open_joints", "check_source_spec", "source_schemes", "joint_schemes", "split_spec"]


@runtime_checkable
class FrameSource(Protocol):
    """What the runtime needs of a frame source (module docstring)."""
    camera_ids: list[str]

    def frames_until(self, t: float) -> list[Frame]: ...

    @property
    def done(self) -> bool: ...

    @property
    def lost(self) -> str | None: ...

    def close(self) -> None: ...


@runtime_checkable
class JointSource(Protocol):
    """What the runtime needs of a joint source (module docstring)."""

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]: ...

    @property
    def done(self) -> bool: ...

    @property
    def lost(self) -> str | None: ...

    def close(self) -> None: ...


_SOURCES: dict[str, Callable] = {}
_JOINTS: dict[str, Callable] = {}
# modules that register schemes; imported on first use (optional extras stay unimported until asked for)
_SOURCE_MODULES = ["depthguard.sources.sim_source", "depthguard.sources.images", "depthguard.sources.joints",
                   "depthguard.sources.units", "depthguard.sources.bag", "depthguard.sources.realsense",
                   "depthguard.sources.ros2_source", "depthguard.sources.ur_rtde",
                   "depthguard.sources.franky_joints"]
_loaded = False


def register_source(scheme: str):
    """Decorator: ``factory(argument, rig, context) -> FrameSource`` serves ``scheme:argument``."""
    def deco(factory):
        _SOURCES[scheme] = factory
        return factory
    return deco


def register_joints(scheme: str):
    """Decorator: ``factory(argument, rig, context) -> JointSource`` serves ``scheme:argument``."""
    def deco(factory):
        _JOINTS[scheme] = factory
        return factory
    return deco


def _load_modules() -> None:
    global _loaded
    if not _loaded:
        for m in _SOURCE_MODULES:
            importlib.import_module(m)
        _loaded = True


def source_schemes() -> list[str]:
    _load_modules()
    return sorted(_SOURCES)


def joint_schemes() -> list[str]:
    _load_modules()
    return sorted(_JOINTS)


def split_spec(spec: str) -> tuple[str, str]:
    """``"scheme:argument"`` -> ``(scheme, argument)``; a bare ``"sim"`` has an empty argument."""
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"a source spec is SCHEME:ARGUMENT (got {spec!r})")
    scheme, _, arg = spec.partition(":")
    return scheme.strip(), arg.strip()


def check_source_spec(spec: str) -> tuple[str, str]:
    """``(scheme, argument)`` of a frame source spec, opening nothing (``ValueError`` naming the
    known schemes for an unknown one): a command checks all its arguments before any source opens."""
    _load_modules()
    scheme, arg = split_spec(spec)
    if scheme not in _SOURCES:
        raise ValueError(f"unknown source {spec!r}: the scheme must be one of {', '.join(sorted(_SOURCES))}")
    return scheme, arg


def open_source(spec: str, rig, context: dict | None = None):
    """The frame source of ``spec`` (``ValueError`` naming the known schemes for an unknown one)."""
    scheme, arg = check_source_spec(spec)
    return _SOURCES[scheme](arg, rig, {} if context is None else context)


def open_joints(spec: str, rig, context: dict | None = None):
    """The joint source of ``spec`` (``ValueError`` naming the known schemes for an unknown one)."""
    _load_modules()
    scheme, arg = split_spec(spec)
    if scheme not in _JOINTS:
        raise ValueError(f"unknown joint source {spec!r}: the scheme must be one of {', '.join(sorted(_JOINTS))}")
    return _JOINTS[scheme](arg, rig, {} if context is None else context)
