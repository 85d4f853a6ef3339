"""Reactions as policies: one class per reaction, registered by name, the most restrictive wins (R13, R14, R33).

As nav2's collision_monitor has one class per action, the monitor
(:class:`depthguard.runtime.Monitor`) composes the reaction policies its
configuration names (``monitor: reactions: [repulsion, ssm]``; the older
``reaction: repulsion | ssm | both`` is a shorthand for the same lists). A
policy is made once per monitor with a :class:`PolicySetup` and is given each
control cycle's inputs as a :class:`Cycle`; it answers with a :class:`Part`:

* ``scale`` in [0, 1] for the commanded motion and ``stop`` (a protective stop,
  scale 0): the cycle's speed scale is the supervision's override (stale data,
  unobserved points, R26, R27) times the smallest policy scale;
* ``reasons`` (key → sentence) while it holds the robot, merged into the cycle's;
* optionally a repulsive end-effector velocity ``repulsion`` (3,) m/s (summed)
  and a joint-velocity box ``qd_min``/``qd_max`` (dof,) rad/s (intersected;
  without any the box is the joint position and speed limits alone, times the
  override);
* its own logged terms: ``terms`` (m_cp, K) per control point with
  ``term_names``, and ``record`` (a JSON-able dict written to the cycle's log
  under ``policies.<name>``).

Adding a reaction is one module with one class and one :func:`register_reaction`
call (in the module itself for a plug-in, or a line of :data:`_BUILTIN` here);
``Monitor.step``, the configuration and the result do not change::

    from depthguard.control.policy import Part, register_reaction

    class SlowNearDoor:
        name = "slow_near_door"
        def __init__(self, setup): self.rho = setup.config.rho
        def update(self, cycle):
            near = bool((cycle.observed & (cycle.distance < 0.2)).any())
            return Part(scale=0.5 if near else 1.0, record={"near": near})

    register_reaction("slow_near_door", SlowNearDoor)

A policy may define ``reach(config) -> float`` (a static method, metres): the
radius it needs the distances looked for in (default ``config.rho``);
:attr:`depthguard.config.MonitorConfig.query_rho` is the largest.

This module imports nothing heavy: the configuration checks names against the
registry when a rig loads; a built-in policy's module is imported when first made.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np

__all__ = ["Cycle", "Part", "PolicySetup", "ReactionPolicy", "register_reaction", "reaction_names",
           "policy_class", "policy_reach", "make_policies", "LEGACY_MODES", "mode_name"]


@dataclass(frozen=True)
class PolicySetup:
    """What a policy is made with, once per monitor.

    config : the monitor's :class:`~depthguard.config.MonitorConfig` at start.
    robot : the :class:`~depthguard.robot.model.RobotModel` (``dof``, limits, control points).
    cameras : the monitored :class:`~depthguard.camera.Camera` objects, principal first.
    cp_names : the control points' names (point 0: the end effector).
    ssm_obstacles : with ``ssm.known_scene: muted`` (issue 31), the cameras' unknown objects as
        voxels (:class:`~depthguard.runtime.voxel_input.VoxelObstacles`, the known scene and the
        robot removed): SSM measures its separation from them instead of the cycle's distances.
    """
    config: Any
    robot: Any
    cameras: tuple
    cp_names: tuple[str, ...]
    ssm_obstacles: Any = None


@dataclass
class Cycle:
    """One control cycle's inputs to every policy (the monitor's buffers: read, do not keep).

    t, dt : s, the cycle's time and the time since the previous cycle.
    q : (dof,) rad, the joints the distances are computed at.
    qd : (dof,) rad/s, the commanded joint velocity before any scaling, or None (not given).
    distance : (m_cp,) m per control point, ``inf`` = nothing within ``config.query_rho``;
        meaningful only where ``observed``.
    direction : (m_cp, 3) world unit vectors towards the nearest obstacle.
    observed : (m_cp,) bool, False = no camera can judge the point (R26).
    positions : (m_cp, 3) m world; jacobians : (m_cp, 3, dof) of the control points at ``q``.
    frame_age : s, the age of the oldest camera frame in use.
    override : the supervision's override in [0, 1] (R26, R27) this cycle.
    reasons : the supervision's stop reasons this cycle (read only).
    config : the running :class:`~depthguard.config.MonitorConfig` (it may change between cycles).
    """
    t: float
    dt: float
    q: np.ndarray
    qd: np.ndarray | None
    distance: np.ndarray
    direction: np.ndarray
    observed: np.ndarray
    positions: np.ndarray
    jacobians: np.ndarray
    frame_age: float
    override: float
    reasons: dict
    config: Any


@dataclass
class Part:
    """One policy's answer for one cycle (module docstring); arrays are kept by the result: fresh."""
    scale: float = 1.0
    stop: bool = False
    reasons: dict = field(default_factory=dict)
    repulsion: np.ndarray | None = None
    qd_min: np.ndarray | None = None
    qd_max: np.ndarray | None = None
    terms: np.ndarray | None = None
    term_names: tuple[str, ...] = ()
    record: dict = field(default_factory=dict)


class ReactionPolicy(Protocol):
    """A reaction: ``Policy(setup)`` once, ``update(cycle) -> Part`` every control cycle."""
    name: str

    def update(self, cycle: Cycle) -> Part: ...


@dataclass
class _Entry:
    target: Any                    # the class, or "module:attr" loaded when first needed


#: the built-in reactions: name -> "module:class" (a new built-in reaction: one line here)
_BUILTIN: dict[str, str] = {
    "repulsion": "depthguard.control.policy_repulsion:Repulsion",    # R13, R14
    "ssm": "depthguard.control.policy_ssm:SpeedSeparationPolicy",    # R33
    "path_watch": "depthguard.control.path_watch:PathWatchPolicy",   # R37: stop short of a blocked segment
}

_REGISTRY: dict[str, _Entry] = {n: _Entry(t) for n, t in _BUILTIN.items()}

#: the shorthand ``reaction:`` modes and the policies they name
LEGACY_MODES: dict[str, tuple[str, ...]] = {"repulsion": ("repulsion",), "ssm": ("ssm",),
                                            "both": ("repulsion", "ssm")}


def register_reaction(name: str, policy: type | str | Callable) -> None:
    """Register a reaction policy under ``name`` (a class, a factory ``f(setup)``, or
    ``"module:attr"``); registering a name again replaces it."""
    if not isinstance(name, str) or not name.replace("_", "").replace("-", "").isalnum():
        raise ValueError(f"reaction name {name!r}: use letters, digits, '_' or '-'")
    _REGISTRY[name] = _Entry(policy)


def reaction_names() -> tuple[str, ...]:
    """The registered reaction names, sorted."""
    return tuple(sorted(_REGISTRY))


def policy_class(name: str):
    """The class (or factory) registered as ``name``; ``ValueError`` naming the known ones."""
    entry = _REGISTRY.get(name)
    if entry is None:
        raise ValueError(f"unknown reaction {name!r}; known: {', '.join(reaction_names())}")
    if isinstance(entry.target, str):
        mod, _, attr = entry.target.partition(":")
        entry.target = getattr(importlib.import_module(mod), attr)
    return entry.target


def policy_reach(name: str, config) -> float:
    """Metres within which policy ``name`` needs the distances (its ``reach(config)``; else ``config.rho``)."""
    reach = getattr(policy_class(name), "reach", None)
    return float(config.rho if reach is None else reach(config))


def make_policies(names, setup: PolicySetup) -> list[tuple[str, ReactionPolicy]]:
    """``[(name, policy)]`` for ``names`` made with ``setup``, in that order."""
    return [(n, policy_class(n)(setup)) for n in names]


def mode_name(names: tuple[str, ...]) -> str:
    """The result's ``reaction`` field: the shorthand mode for its lists, else the names joined by '+'."""
    for mode, ns in LEGACY_MODES.items():
        if tuple(names) == ns:
            return mode
    return "+".join(names)
