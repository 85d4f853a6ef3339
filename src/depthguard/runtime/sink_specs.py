"""Sinks named by a spec ``SCHEME:ARGUMENT``, registered by scheme like the sources (R31).

``depthguard monitor --sink SPEC`` (repeatable) opens any of them; the older flags are
shorthands (``--zenoh`` is ``zenoh:``, ``--ros2`` is ``ros2:``, ``--view`` is ``view:``),
and every run writes ``jsonl:`` and ``mcap:`` into its folder. Built-in schemes:

==============  ==============================================================  =======================================
``jsonl:[FILE]``  one JSON line per control cycle (default ``OUT/log.jsonl``)   :mod:`depthguard.runtime.sinks`
``mcap:[FILE]``   the results as MCAP for Foxglove (default ``OUT/results.mcap``)   :mod:`depthguard.runtime.mcap_results`
``zenoh:[CELL]``  reaction, distances, health under ``depthguard/<cell>/``; settings in  :mod:`depthguard.runtime.sink_zenoh`
``ros2:[NS]``     ``NS/override``, ``reaction``, ``markers``, ``obstacles``, ``check_path/*`` over rmw_zenoh (default ``/depthguard``)  :mod:`depthguard.runtime.ros2_sink`
``view:[[HOST:]PORT]``  the live 3-D view in the browser (default 127.0.0.1:8080)  :mod:`depthguard.viz.sinks`
``ur-rtde:HOST``  a Universal Robots arm's speed slider (needs ``depthguard[ur]``)  :mod:`depthguard.runtime.ur_sink`
``franky:HOST,path=FILE``  a Franka FR3 runs a joint path, slowed and stopped by the reaction  :mod:`depthguard.runtime.franky_sink`
==============  ==============================================================  =======================================

A sink is a callable ``sink(reaction)`` (:class:`~depthguard.runtime.result.Reaction`) with
optional members that the runner reads:

* ``close()`` — called once at the end;
* ``direct = True`` — called on the control thread itself (it must only keep the newest
  reaction and return at once: a robot's speed, the view); otherwise it is called from the
  fan-out thread (:class:`~depthguard.runtime.sinks.SinkFanout`), which may drop under load;
* ``live = True`` — it drives a real robot: a run as fast as possible is refused;
* ``attach(monitor)`` — called once the monitor exists (the view reads its frames, the Zenoh
  sink listens for settings);
* ``describe`` — a line for the run's log.

A factory is ``factory(argument, rig, context) -> sink``; ``context`` is the run's dict
shared with the sources (``out``: the run's folder, ``fast``, the Zenoh and ROS 2 settings).
A new sink is one module with a factory and one :func:`register_sink` call (in the module
itself for a plug-in, or a line of :data:`SINK_SCHEMES` here); a scheme's module is imported
only when asked for. Every argument is checked (``ValueError``, one sentence) before a run
starts. The table below names modules of this room and below only (``tests/test_layers.py``
checks its strings as imports); a room above registers its own schemes when imported, as
``view:`` does (:mod:`depthguard.viz.sinks`, imported by the CLI that composes a run).
"""

from __future__ import annotations

import importlib
from typing import Callable

__all__ = ["SINK_SCHEMES", "register_sink", "open_sink", "sink_schemes", "shorthand_specs", "check_sink_spec"]

#: scheme -> factory or "module:factory"
SINK_SCHEMES: dict[str, str | Callable] = {
    "jsonl": "depthguard.runtime.sinks:open_jsonl",
    "mcap": "depthguard.runtime.mcap_results:open_mcap",
    "zenoh": "depthguard.runtime.sink_zenoh:open_zenoh",
    "ros2": "depthguard.runtime.ros2_sink:open_ros2",
    "ur-rtde": "depthguard.runtime.ur_sink:open_ur_sink",
    "franky": "depthguard.runtime.franky_sink:open_franky_sink",
}


#: scheme -> ``check(argument)`` run before anything opens (ValueError in one sentence)
SINK_CHECKS: dict[str, Callable[[str], object]] = {}


def register_sink(scheme: str, factory: str | Callable, check: Callable[[str], object] | None = None) -> None:
    """Register ``factory(argument, rig, context) -> sink`` (or ``"module:attr"``) as ``scheme``;
    ``check(argument)``, if given, refuses a bad argument before any source or sink opens."""
    if not isinstance(scheme, str) or not scheme or not scheme.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"sink scheme {scheme!r}: use letters, digits, '-' or '_'")
    SINK_SCHEMES[scheme] = factory
    if check is not None:
        SINK_CHECKS[scheme] = check


def sink_schemes() -> tuple[str, ...]:
    return tuple(sorted(SINK_SCHEMES))


def check_sink_spec(spec: str) -> tuple[str, str]:
    """``(scheme, argument)`` of ``spec``; ``ValueError`` naming the known schemes for an unknown one."""
    scheme, _, argument = (spec or "").partition(":")
    scheme = scheme.strip()
    if scheme not in SINK_SCHEMES:
        raise ValueError(f"--sink {spec!r}: unknown scheme {scheme!r}; the scheme must be one of "
                         f"{', '.join(sink_schemes())}")
    check = SINK_CHECKS.get(scheme)
    if check is not None:
        check(argument)
    return scheme, argument


def open_sink(spec: str, rig=None, context: dict | None = None):
    """The sink of ``spec`` (module docstring)."""
    scheme, argument = check_sink_spec(spec)
    factory = SINK_SCHEMES[scheme]
    if isinstance(factory, str):
        module, _, attr = factory.partition(":")
        factory = getattr(importlib.import_module(module), attr)
    return factory(argument, rig, {} if context is None else context)


def shorthand_specs(*, zenoh: bool = False, ros2: bool = False, view: bool = False) -> list[str]:
    """The specs the older flags stand for: ``--zenoh`` ``zenoh:``, ``--ros2`` ``ros2:``, ``--view`` ``view:``."""
    return [s for on, s in ((zenoh, "zenoh:"), (ros2, "ros2:"), (view, "view:")) if on]
