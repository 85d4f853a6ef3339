"""Rig files: cameras, workspace, robot and static CAD of a cell (R2).

A rig is YAML (format in ``docs/ARCHITECTURE.md``). It is validated once, on
load, with pydantic; every problem becomes a :class:`RigError` whose message
names the file, the field (``cameras[1].fx``) and what is wrong. After
loading, a :class:`Rig` holds only validated, immutable objects.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
import yaml
from pydantic import ValidationError

from depthguard.camera import Camera, CameraError
from depthguard.config import MonitorConfig
from depthguard.geometry.mesh import Mesh, load_mesh
from depthguard.rig_checks import mesh_extent_problem, robot_inside_objects
from depthguard.geometry.primitives import Box, Capsule, Cylinder, Primitive, Sphere
from depthguard.transforms import pose
from depthguard.rig_schema import (RIG_SCHEMA_VERSION, BoxShape, CameraSpec, ControlPointSpec,  # noqa: F401
                                   CylinderShape, LookAtSpec, ObjectSpec, PoseSpec, RigSpec, RobotSpec,
                                   SphereShape, WorkspaceSpec)

__all__ = ["Rig", "RigError", "Workspace", "StaticObject", "RIG_SCHEMA_VERSION", "joint_limits_problem"]


def _yaml_problem(exc: Exception) -> str:
    """A YAML parser's error on one line (the user's one clear line): the problem where it was
    found (1-based line and column) and what it was parsing since where, without the echoed
    source lines PyYAML prints."""
    problem = getattr(exc, "problem", None)
    if not problem:
        return " ".join(str(exc).split())
    mark = getattr(exc, "problem_mark", None)
    text = problem if mark is None else f"{problem} at line {mark.line + 1}, column {mark.column + 1}"
    context, cmark = getattr(exc, "context", None), getattr(exc, "context_mark", None)
    if context:
        text += f" ({context}" + ("" if cmark is None else f" at line {cmark.line + 1}, column {cmark.column + 1}") + ")"
    return text


class RigError(ValueError):
    """A rig file is missing, unreadable or invalid; the message names file and field."""


# ------------------------------------------------------------------ the rig
def _vec(v) -> str:
    return "(" + ", ".join(f"{float(a):.3g}" for a in np.asarray(v).ravel()) + ")"


@dataclass(frozen=True)
class Workspace:
    """Axis-aligned box of interest, world frame, metres."""
    lo: np.ndarray
    hi: np.ndarray

    def __repr__(self) -> str:
        return f"Workspace({_vec(self.lo)}..{_vec(self.hi)} m)"

    def contains(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        return np.all((p >= self.lo) & (p <= self.hi), axis=1)

    def depth_span(self, cam: Camera) -> tuple[float, float]:
        """``(d_min, d_max)`` m: the box's depth range in ``cam``, clipped to the camera's range
        (the depth grid's span, R10); ``ValueError`` when the box lies outside that range."""
        corners = np.array([[x, y, z] for x in (self.lo[0], self.hi[0]) for y in (self.lo[1], self.hi[1])
                            for z in (self.lo[2], self.hi[2])])
        d = corners @ np.asarray(cam.R).T[:, 2] + cam.t[2]
        d_min = max(float(cam.min_range), float(d.min()))
        d_max = min(float(cam.max_range), float(d.max()))
        if d_max <= d_min:
            raise ValueError(f"camera {cam.id}: the workspace lies outside its depth range")
        return d_min, d_max


@dataclass(frozen=True, eq=False)
class StaticObject:
    """A piece of known CAD: its world mesh, and its primitive when it is one (exact ground truth)."""
    name: str
    mesh: Mesh
    primitive: Optional[Primitive] = None

    def __repr__(self) -> str:
        kind = type(self.primitive).__name__.lower() if self.primitive is not None else "mesh"
        lo, hi = self.mesh.bounds
        return (f"StaticObject({self.name!r}, {kind}, {len(self.mesh.vertices)} vertices, "
                f"{len(self.mesh.faces)} faces, bounds {_vec(lo)}..{_vec(hi)} m)")


@dataclass(frozen=True, eq=False)
class Rig:
    """A validated cell description (R2). Build with :meth:`load` or :meth:`from_dict`."""

    name: str
    cameras: list[Camera]
    workspace: Workspace
    robot: Any = None                  # depthguard.robot.RobotModel or None
    robot_q0: Optional[np.ndarray] = None
    objects: list[StaticObject] = field(default_factory=list)
    path: Optional[Path] = None
    description: str = ""
    monitor: MonitorConfig = field(default_factory=MonitorConfig)   # the rig's ``monitor:`` section
    topics: dict = field(default_factory=dict)   # camera id -> depth Image topic (``topic:``, R31)
    depth_scales: dict = field(default_factory=dict)   # camera id -> m per 16-bit unit (``depth_scale:``, R31)
    learned: dict = field(default_factory=dict)   # camera id -> LearnedScene (``scene: {learned: DIR}``, issue 31)
    learned_dir: Optional[Path] = None            # that DIR, resolved
    principal_bin_why: str = ""                   # how monitor.principal_bin was chosen (grid_budget.py)

    def __repr__(self) -> str:
        """One line: the name, file, camera ids, workspace, robot and object names (no mesh arrays)."""
        robot = "none" if self.robot is None else getattr(self.robot, "name", type(self.robot).__name__)
        names = [o.name for o in self.objects]
        shown = ", ".join(names[:8]) + (f", ... ({len(names)} in all)" if len(names) > 8 else "")
        where = f", path={str(self.path)!r}" if self.path is not None else ""
        return (f"Rig({self.name!r}{where}, cameras=[{', '.join(self.camera_ids)}], "
                f"workspace={_vec(self.workspace.lo)}..{_vec(self.workspace.hi)} m, robot={robot}, "
                f"objects=[{shown}])")

    def camera(self, camera_id: str) -> Camera:
        for c in self.cameras:
            if c.id == camera_id:
                return c
        raise ValueError(f"rig {self.name!r} has no camera {camera_id!r}; cameras: "
                         f"{', '.join(c.id for c in self.cameras)}")

    @property
    def camera_ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def static_meshes(self) -> list[Mesh]:
        return [o.mesh for o in self.objects]

    def learned_depth(self, camera_id: str) -> Optional[np.ndarray]:
        """(H, W) float32 m: camera ``camera_id``'s learned static scene (0 = unknown), or None
        when the rig has none for it (:mod:`depthguard.learned_scene`)."""
        sc = self.learned.get(camera_id)
        return None if sc is None else sc.depth

    def without_cad(self) -> "Rig":
        """This rig with its static CAD objects taken out (the learned scene, if any, stays): what a
        cell without CAD sees, for comparing the two."""
        import dataclasses
        return dataclasses.replace(self, objects=[])

    def with_learned(self, folder) -> "Rig":
        """This rig with the learned scene in ``folder`` (:func:`depthguard.learned_scene.load`;
        a scene learned at another camera pose or size raises its one-sentence error)."""
        import dataclasses

        from depthguard.learned_scene import load
        return dataclasses.replace(self, learned=load(folder, self.cameras), learned_dir=Path(folder))

    def key(self) -> str:
        """Hash of every camera (for caches keyed by the rig's geometry)."""
        import hashlib
        return hashlib.sha256("".join(c.key() for c in self.cameras).encode()).hexdigest()[:16]

    # ---------------------------------------------------------------- load
    @classmethod
    def load(cls, path: str | Path) -> "Rig":
        """Load and validate a rig YAML file; :class:`RigError` names the file, field and problem."""
        p = Path(path)
        if not p.is_file():
            raise RigError(f"{p}: rig file not found")
        try:
            data = yaml.safe_load(p.read_text())
        except yaml.YAMLError as exc:
            raise RigError(f"{p}: not valid YAML: {_yaml_problem(exc)}") from None
        except UnicodeDecodeError:
            raise RigError(f"{p}: not a text file") from None
        return cls.from_dict(data, source=p)

    @classmethod
    def from_dict(cls, data: Any, source: str | Path = "<rig>") -> "Rig":
        src = str(source)
        base_dir = Path(source).parent if isinstance(source, Path) else Path.cwd()
        if not isinstance(data, dict):
            raise RigError(f"{src}: a rig must be a mapping with workspace and cameras (got {type(data).__name__})")
        try:
            spec = RigSpec.model_validate(data)
        except ValidationError as exc:
            raise RigError(_format_errors(src, exc)) from None

        cameras = []
        for i, cs in enumerate(spec.cameras):
            try:
                cameras.append(cs.to_camera())
            except (CameraError, ValueError) as exc:
                raise RigError(f"{src}: cameras[{i}] ({cs.id}): {exc}") from None
        ws = Workspace(np.asarray(spec.workspace.min, float), np.asarray(spec.workspace.max, float))

        objects = []
        for i, o in enumerate(spec.objects):
            try:
                objects.append(_make_object(o, base_dir))
            except (FileNotFoundError, ValueError) as exc:
                field_name = "mesh" if o.mesh is not None else "pose"
                raise RigError(f"{src}: objects[{i}].{field_name} ({o.name}): {exc}") from None

        learned, learned_dir = {}, None
        if spec.scene is not None and spec.scene.learned:
            from depthguard.learned_scene import LearnedSceneError, load
            learned_dir = (base_dir / spec.scene.learned).resolve()
            try:
                learned = load(learned_dir, cameras)
            except LearnedSceneError as exc:
                raise RigError(f"{src}: scene.learned: {exc}") from None

        robot, q0 = None, None
        if spec.robot is not None:
            robot, q0 = _make_robot(spec.robot, base_dir, src)
            inside = robot_inside_objects(robot, q0, objects)     # mounted 20 cm inside its table
            if inside:
                raise RigError(f"{src}: robot: {inside}")
        monitor, why = _budgeted_monitor(spec.monitor or MonitorConfig(), cameras, robot, q0)
        return cls(name=spec.name, cameras=cameras, workspace=ws, robot=robot, robot_q0=q0,
                   objects=objects, path=Path(source) if isinstance(source, Path) else None,
                   description=spec.description, monitor=monitor, principal_bin_why=why,
                   topics={c.id: c.topic for c in spec.cameras if c.topic},
                   depth_scales={c.id: c.depth_scale for c in spec.cameras if c.depth_scale is not None},
                   learned=learned, learned_dir=learned_dir)


def _budgeted_monitor(monitor: MonitorConfig, cameras: list, robot, q0) -> tuple[MonitorConfig, str]:
    """``monitor`` with ``principal_bin`` chosen from the grid's column budget
    (:func:`depthguard.grid_budget.auto_principal_bin`, issue 29) when the rig does not set it
    and has a robot, and the sentence saying why (empty when the rig sets it or has no robot)."""
    if "principal_bin" in monitor.model_fields_set or robot is None or q0 is None:
        return monitor, ""
    from depthguard.grid_budget import auto_principal_bin

    ids = list(monitor.cameras) if monitor.cameras else [c.id for c in cameras]
    pid = monitor.principal if monitor.principal is not None else (ids[0] if ids else None)
    cam = next((c for c in cameras if c.id == pid), None)
    if cam is None:                     # a wrong principal is said where the monitor starts
        return monitor, ""
    b, why = auto_principal_bin(cam, robot, q0, monitor.query_rho)
    return MonitorConfig.model_validate({**monitor.model_dump(exclude_unset=True), "principal_bin": b}), why


def _make_object(o: ObjectSpec, base_dir: Path) -> StaticObject:
    T = o.pose.matrix4() if o.pose is not None else np.eye(4)
    prim: Optional[Primitive] = None
    if o.box is not None:
        prim = Box(size=o.box.size, world_from_local=T, name=o.name)
    elif o.sphere is not None:
        prim = Sphere(radius=o.sphere.radius, world_from_local=T, name=o.name)
    elif o.cylinder is not None:
        prim = Cylinder(radius=o.cylinder.radius, length=o.cylinder.length, world_from_local=T, name=o.name)
    elif o.capsule is not None:
        prim = Capsule(radius=o.capsule.radius, length=o.capsule.length, world_from_local=T, name=o.name)
    if prim is not None:
        return StaticObject(o.name, prim.mesh(), prim)
    mpath = Path(o.mesh)
    if not mpath.is_absolute():
        mpath = base_dir / mpath
    if not mpath.is_file():
        raise FileNotFoundError(f"mesh file not found: {mpath}")
    mesh = load_mesh(mpath, scale=o.scale)
    problem = mesh_extent_problem(*mesh.bounds, o.scale)     # millimetres without scale: 1000 x too large
    if problem:
        raise ValueError(f"{mpath.name}: {problem}")
    return StaticObject(o.name, mesh.transformed(T), None)


def _make_robot(rs: RobotSpec, base_dir: Path, src: str):
    from depthguard.robot import load_robot

    base = rs.base.matrix4() if rs.base is not None else np.eye(4)
    target = rs.name
    if rs.urdf is not None and rs.urdf.startswith("package://"):
        from depthguard.robot.urdf import resolve_uri
        try:                                     # a ROS package's URDF (example-robot-data, ROS_PACKAGE_PATH)
            target = str(resolve_uri(rs.urdf, base_dir))
        except FileNotFoundError as exc:
            raise RigError(f"{src}: robot.urdf: {str(exc).replace('cannot resolve mesh', 'cannot find')} (package:// "
                           f"looks in example-robot-data's share folder, then $ROS_PACKAGE_PATH)") from None
    elif rs.urdf is not None:
        up = Path(rs.urdf)
        target = str(up if up.is_absolute() else base_dir / up)
        if not Path(target).is_file():
            raise RigError(f"{src}: robot.urdf: file not found: {target}")
    try:
        robot = load_robot(target, base=base)
    except (ValueError, FileNotFoundError) as exc:
        fld = "robot.name" if rs.name is not None else "robot.urdf"
        raise RigError(f"{src}: {fld}: {exc}") from None
    if rs.control_points is not None:
        from depthguard.robot import ControlPoint
        cps = []
        for i, c in enumerate(rs.control_points):
            link = c.link
            if isinstance(link, str) and link not in robot.link_names:
                raise RigError(f"{src}: robot.control_points[{i}].link: unknown link {link!r}; "
                               f"links: {', '.join(robot.link_names)}")
            if isinstance(link, int) and not (0 <= link < len(robot.link_names)):
                raise RigError(f"{src}: robot.control_points[{i}].link: index {link} out of range "
                               f"[0, {len(robot.link_names)})")
            cps.append(ControlPoint(c.name, link, np.asarray(c.offset, float), c.radius))
        robot = robot.with_control_points(cps)
    q0 = np.asarray(robot.q_home, dtype=float).copy()
    if rs.joints is not None:
        q = np.asarray(rs.joints, dtype=float)
        if q.shape != (robot.dof,):
            raise RigError(f"{src}: robot.joints: expected {robot.dof} joint values for {robot.name}, got {q.size}")
        problem = joint_limits_problem(robot, q)
        if problem:
            raise RigError(f"{src}: robot.joints{problem}")
        q0 = q
    return robot, q0


def joint_limits_problem(robot, q: np.ndarray) -> Optional[str]:
    """``"[j]: v rad is outside the joint limits [lo, hi]"`` for the first joint of ``q`` (dof,)
    rad outside ``robot.q_min``/``q_max``, else None; callers prefix the field (``robot.joints``)."""
    q = np.asarray(q, dtype=float)
    bad = np.nonzero((q < robot.q_min - 1e-9) | (q > robot.q_max + 1e-9))[0]
    if not bad.size:
        return None
    j = int(bad[0])
    return (f"[{j}]: {q[j]:.4f} rad is outside the joint limits [{robot.q_min[j]:.4f}, {robot.q_max[j]:.4f}]"
            f" of {robot.name}")


def _format_errors(src: str, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        loc = ""
        for part in err["loc"]:
            if isinstance(part, int):
                loc += f"[{part}]"
            else:
                loc += ("." if loc else "") + str(part)
        msg = err["msg"]
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling)"
        if err["type"] == "missing":
            msg = "required field is missing"
        lines.append(f"{src}: {loc or '<top>'}: {msg}")
    return "\n".join(lines)
