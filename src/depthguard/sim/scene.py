"""Simulated scenes: static objects, a robot on a joint trajectory, people and props over time.

A :class:`Scene` answers, for any time ``t`` (seconds):

- ``obstacles_at(t)``: every obstacle but the robot, as exact primitives
  (static objects, people's body parts, props);
- ``robot_q(t)``: the robot's joint values;
- ``meshes_at(t, robot=True)``: triangle meshes and names for rendering;
- ``true_distance(points, t)`` and ``occupancy(lo, hi, voxel_size, t)``:
  the ground truth (:mod:`depthguard.sim.ground_truth`).

The robot is a :class:`depthguard.robot.RobotModel` (its volume for ground
truth is ``robot.collision_capsules(q)``) or any object with ``dof``,
``link_meshes(q)``, ``link_mesh_names`` and ``collision_primitives(q)``,
such as the C-arm of :mod:`depthguard.sim.carm`.
"""

from __future__ import annotations

import bisect
import dataclasses

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from depthguard.geometry.mesh import Mesh
from depthguard.geometry.primitives import Primitive
from depthguard.sim import ground_truth as gt
from depthguard.sim.ground_truth import MeshSolid
from depthguard.sim.people import Person

__all__ = ["Scene", "Prop", "JointPath"]

#: local meshes kept per scene (distinct shapes: a scene's people and props have a few dozen;
#: a shape that varies continuously would otherwise add one per frame)
MESH_CACHE_SIZE = 256


@dataclass
class Prop:
    """A movable object: ``shape`` is a primitive posed in its own frame (usually at the origin);
    ``pose0`` its world pose (4x4) until someone carries it."""
    name: str
    shape: Primitive
    pose0: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass
class JointPath:
    """Joint values over time: keys ``(t, q)``; ``"linear"`` (eased) or ``"step"`` interpolation,
    held before the first and after the last key."""
    keys: Sequence[tuple[float, Sequence[float]]]
    interp: str = "linear"

    def __post_init__(self):
        if not self.keys:
            raise ValueError("JointPath needs at least one key")
        ks = sorted(((float(t), np.asarray(q, dtype=np.float64)) for t, q in self.keys), key=lambda k: k[0])
        if len({q.shape for _, q in ks}) != 1:
            raise ValueError("JointPath: every key must have the same number of joint values")
        if self.interp not in ("linear", "step"):
            raise ValueError(f"JointPath interp must be 'linear' or 'step' (got {self.interp!r})")
        self._t = np.array([t for t, _ in ks])
        self._q = np.stack([q for _, q in ks])
        self._tl = self._t.tolist()         # the times as floats: bisect finds the key (500 Hz joint ticks)
        self._ql = list(self._q)

    @property
    def end(self) -> float:
        """Time of the last key (s): the path holds from there on."""
        return float(self._t[-1])

    def __call__(self, t: float) -> np.ndarray:
        ts, qs = self._tl, self._ql
        if t <= ts[0] or len(ts) == 1:
            return qs[0].copy()
        if t >= ts[-1]:
            return qs[-1].copy()
        i = bisect.bisect_right(ts, t) - 1          # np.searchsorted(side="right") - 1
        if self.interp == "step":
            return qs[i].copy()
        s = (t - ts[i]) / (ts[i + 1] - ts[i])
        s = s * s * (3 - 2 * s)
        return (1 - s) * qs[i] + s * qs[i + 1]


class Scene:
    """A scene over time (module docstring).

    Parameters
    ----------
    static : static obstacles: primitives, or rig ``StaticObject`` s (``name``, ``mesh``,
        ``primitive`` or None — mesh objects become :class:`MeshSolid`).
    robot : the robot (or None).
    robot_path : ``t -> q`` (a :class:`JointPath` or any callable); default: ``robot_q0`` always.
    robot_q0 : joint values when there is no path (default: ``robot.q_home``).
    people : :class:`~depthguard.sim.people.Person` s.
    props : :class:`Prop` s (people's ``carries`` refer to them by name).
    duration : length of the scripted action, seconds.
    """

    def __init__(self, static: Sequence = (), robot=None, robot_path: Callable[[float], np.ndarray] | None = None,
                 robot_q0=None, people: Sequence[Person] = (), props: Sequence[Prop] = (),
                 duration: float = 0.0, name: str = ""):
        self.name = name
        self.static: list[Primitive] = [_as_primitive(o, i) for i, o in enumerate(static)]
        self.robot = robot
        if robot is not None and robot_q0 is None:
            robot_q0 = getattr(robot, "q_home", np.zeros(robot.dof))
        self.robot_q0 = None if robot_q0 is None else np.asarray(robot_q0, dtype=np.float64)
        self._dof: tuple | None = None       # (robot, its joints): asked once (robot_q runs per joint tick)
        self.robot_path = robot_path
        self.people = list(people)
        self.props = {p.name: p for p in props}
        self.duration = float(duration)
        names = [p.name for p in self.people]
        if len(set(names)) != len(names):
            raise ValueError(f"scene {name!r}: person names must be unique (got {names})")
        for person in self.people:
            for c in person.carries:
                if c.prop not in self.props:
                    raise ValueError(f"scene {name!r}: {person.name} carries unknown prop {c.prop!r}")
        self._mesh_cache: dict[tuple, Mesh] = {}     # shape key -> local mesh, least recently used first
        self._events: dict[str, list] = {}          # per prop its carries in time order (prop_pose)
        self._prop_memo: dict[str, tuple] = {}      # per prop (pose key, solid) of the last props_at
        self._static_meshes = [p.mesh() for p in self.static]
        self._static_names = [p.name for p in self.static]

    # ------------------------------------------------------------- queries
    def robot_q(self, t: float) -> np.ndarray:
        """(dof,) joint values of the robot at time ``t`` (empty when there is no robot)."""
        if self.robot is None:
            return np.zeros(0)
        if self.robot_path is None:
            return self.robot_q0.copy()
        q = self.robot_path(t)
        if type(q) is not np.ndarray or q.dtype != np.float64:
            q = np.asarray(q, dtype=np.float64)
        memo = self._dof
        if memo is None or memo[0] is not self.robot:
            memo = self._dof = (self.robot, self.robot.dof)
        if q.shape != (memo[1],):
            raise ValueError(f"scene {self.name!r}: robot path gives {q.shape} joint values, robot has {self.robot.dof}")
        return q

    def prop_pose(self, name: str, t: float) -> np.ndarray:
        """4x4 world pose of a prop at time ``t``: in the carrying hand, or where it was last put down."""
        return self._prop_pose(name, t)[1]

    def _prop_pose(self, name: str, t: float) -> tuple[tuple | None, np.ndarray]:
        """``(key, pose)`` of :meth:`prop_pose`: the pose is the last carry begun by ``t`` (the hand
        at ``min(t, its end)`` times its offset), else the prop's own; ``key`` names it (equal keys,
        equal poses). The carries of a prop are listed once per scene (a prop is posed at every
        simulated frame, issue 29)."""
        prop = self.props[name]
        events = self._events.get(name)
        if events is None:
            events = self._events[name] = sorted(
                ((c.t0, c, person) for person in self.people for c in person.carries if c.prop == name),
                key=lambda e: e[0])
        last = None
        for k, (t0, c, person) in enumerate(events):
            if t < t0:
                break
            last = k
        if last is None:
            return None, prop.pose0
        _, c, person = events[last]
        tt = min(t, c.t1)
        return (last, tt), person.hand_frame(tt, c.hand) @ c.offset_matrix()

    def props_at(self, t: float) -> list[Primitive]:
        out = []
        for name, prop in self.props.items():
            key, T = None, None
            memo = self._prop_memo.get(name)
            if memo is not None:
                key = self._prop_key(name, t)
                if key == memo[0]:
                    out.append(memo[1])         # the same pose as the last time asked: the same solid
                    continue
            key, T = self._prop_pose(name, t)
            solid = dataclasses.replace(prop.shape, world_from_local=T @ prop.shape.world_from_local, name=name)
            self._prop_memo[name] = (key, solid)
            out.append(solid)
        return out

    def _prop_key(self, name: str, t: float) -> tuple | None:
        """The ``key`` of :meth:`_prop_pose` without the pose (a prop lying still: no posing)."""
        events = self._events[name]
        last = None
        for k, (t0, c, _) in enumerate(events):
            if t < t0:
                break
            last = k
        return None if last is None else (last, min(t, events[last][1].t1))

    def dynamic_at(self, t: float) -> list[Primitive]:
        """People's body parts and props at time ``t``."""
        out: list[Primitive] = []
        for person in self.people:
            out.extend(person.primitives(t))
        out.extend(self.props_at(t))
        return out

    def obstacles_at(self, t: float) -> list[Primitive]:
        """Every obstacle but the robot at time ``t``, as exact primitives (named)."""
        return list(self.static) + self.dynamic_at(t)

    def robot_primitives(self, t: float, padding: float = 0.0, q=None) -> list[Primitive]:
        """The robot's volume at time ``t`` (its collision capsules, or the machine's primitives);
        ``q`` overrides the scripted joint values (e.g. a closed loop driving the robot)."""
        if self.robot is None:
            return []
        q = self._q(t, q)
        if hasattr(self.robot, "collision_primitives"):
            return list(self.robot.collision_primitives(q, padding))
        return list(self.robot.collision_capsules(q, padding=padding))

    def _q(self, t: float, q) -> np.ndarray:
        if q is None:
            return self.robot_q(t)
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.robot.dof,):
            raise ValueError(f"scene {self.name!r}: q must have {self.robot.dof} joint values, got shape {q.shape}")
        return q

    def meshes_at(self, t: float, robot: bool = True, q=None) -> tuple[list[Mesh], list[str]]:
        """World triangle meshes at time ``t`` and their names (robot links last, named ``robot/<link>``:
        its full meshes — the camera simulator renders them clustered to
        :data:`~depthguard.geometry.decimate.SIM_CELL`, ``sources/camera_sim.py``); ``q`` overrides
        the robot's scripted joint values."""
        meshes = list(self._static_meshes)
        names = list(self._static_names)
        moving, moving_names = self.moving_meshes_at(t)
        meshes += moving
        names += moving_names
        if robot and self.robot is not None:
            q = self._q(t, q)
            meshes.extend(self.robot.link_meshes(q))
            names.extend(f"robot/{n}" for n in self.robot.link_mesh_names)
        return meshes, names

    @property
    def static_meshes(self) -> list[Mesh]:
        """World meshes of the static obstacles (made once)."""
        return list(self._static_meshes)

    def moving_meshes_at(self, t: float) -> tuple[list[Mesh], list[str]]:
        """World meshes of the people and props at ``t`` and their names (as :meth:`meshes_at`)."""
        meshes, names = [], []
        for prim in self.dynamic_at(t):
            meshes.append(self._local_mesh(prim).transformed(prim.world_from_local))
            names.append(prim.name)
        return meshes, names

    def _local_mesh(self, prim: Primitive) -> Mesh:
        """The primitive's local mesh, built once per distinct shape (people move, shapes stay)."""
        import dataclasses

        def hashable(v):
            if isinstance(v, Mesh):
                return id(v)
            if isinstance(v, (np.ndarray, list, tuple)):
                return tuple(np.asarray(v, dtype=np.float64).ravel().tolist())
            return v

        key = (type(prim).__name__,) + tuple(
            hashable(getattr(prim, f.name))
            for f in dataclasses.fields(prim) if f.name not in ("world_from_local", "name", "_tm"))
        cache = self._mesh_cache
        m = cache.pop(key, None)
        if m is None:
            m = prim.local_mesh()
            if len(cache) >= MESH_CACHE_SIZE:        # shapes that vary (an arm's length per pose) would
                del cache[next(iter(cache))]        # grow it without end over a long run: least recent out
        cache[key] = m                              # (re)inserted: the most recent last
        return m

    # -------------------------------------------------------- ground truth
    def true_distance(self, points: np.ndarray, t: float) -> np.ndarray:
        """(N,) exact distance (m) from points (N, 3) to the nearest non-robot obstacle surface, 0 inside."""
        return gt.true_distance(self.obstacles_at(t), points)

    def occupancy(self, lo, hi, voxel_size: float, t: float, robot: bool = False, mode: str = "centre",
                  refine: int = 2, q=None) -> np.ndarray:
        """(nx, ny, nz) bool: voxel (i, j, k) spanning ``lo + [i, i+1)·voxel_size`` (likewise j, k)
        is occupied by an obstacle (and by the robot if ``robot``); rule of ``mode`` in
        :mod:`depthguard.sim.ground_truth`."""
        prims = self.obstacles_at(t) + (self.robot_primitives(t, q=q) if robot else [])
        return gt.occupancy(prims, lo, hi, voxel_size, mode=mode, refine=refine)


def _as_primitive(obj, i: int) -> Primitive:
    if isinstance(obj, Primitive):
        return obj
    prim = getattr(obj, "primitive", None)
    name = getattr(obj, "name", f"object{i}")
    if prim is not None:
        return prim if prim.name == name else _renamed(prim, name)
    mesh = getattr(obj, "mesh", None)
    if mesh is None:
        raise ValueError(f"static object {name!r} has neither a primitive nor a mesh")
    return MeshSolid(local=mesh, name=name)  # rig meshes are in world coordinates


def _renamed(prim: Primitive, name: str) -> Primitive:
    import dataclasses
    return dataclasses.replace(prim, name=name)
