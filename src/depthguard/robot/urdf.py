"""URDF → chain + link geometry (R16).

``yourdfpy`` parses the XML only; kinematics are ours
(:mod:`depthguard.robot.chain`). The URDF tree is reduced to one serial
chain: the path from the root link to the chosen ``tip`` link, plus every
link rigidly attached (through fixed joints only) to a link on that path —
tool frames such as UR's ``tool0`` or ``ee_link`` stay. Branches behind
other moving joints (e.g. gripper fingers when the tip is the flange) are
left out.

Collision geometry (``<collision>``, else ``<visual>``) becomes one merged
mesh per link in the link frame; mesh files are loaded with
:func:`depthguard.geometry.load_mesh`. ``package://PKG/rest`` resolves to
``<share>/PKG/rest`` for the ROS-style share folders known here
(example-robot-data's ``cmeel.prefix/share`` and ``$ROS_PACKAGE_PATH``), then
to a folder named ``PKG`` above the URDF, then to ``rest`` relative to the
URDF's folder; other relative paths are relative to the URDF's folder.
Joint axes are normalised (as pinocchio does); ``continuous`` joints get
limits ``±inf``; a missing velocity limit is ``inf``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from depthguard.geometry import Box, Cylinder, Mesh, Sphere, load_mesh, merge_meshes
from depthguard.robot.chain import FIXED, PRISMATIC, REVOLUTE, LinkSpec

__all__ = ["UrdfRobot", "parse_urdf", "share_dirs", "resolve_uri", "example_robot_data_dir"]

_JTYPES = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC, "fixed": FIXED}


@dataclass(frozen=True, eq=False)
class UrdfRobot:
    """What :func:`parse_urdf` returns: chain rows (root first), local link meshes, the tip."""
    name: str
    links: list[LinkSpec]
    meshes: dict[str, Mesh]        # link name -> merged mesh in the link frame
    tip: str
    path: Path


def example_robot_data_dir() -> Path | None:
    """``.../cmeel.prefix/share/example-robot-data`` of the installed package, or ``None``."""
    try:
        import importlib.metadata as md
        dist = md.distribution("example-robot-data")
    except Exception:
        return None
    for f in dist.files or ():
        parts = str(f).replace("\\", "/").split("/")
        if "example-robot-data" in parts[:-1] and "share" in parts:
            i = parts.index("example-robot-data")
            p = Path(dist.locate_file(f))
            for _ in range(len(parts) - 1 - i):
                p = p.parent
            if p.is_dir():
                return p
    return None


@lru_cache(maxsize=1)
def share_dirs() -> tuple[Path, ...]:
    """Folders holding ROS-style packages, searched for ``package://`` URIs."""
    out: list[Path] = []
    erd = example_robot_data_dir()
    if erd is not None:
        out.append(erd.parent)
    for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if p and Path(p).is_dir():
            out.append(Path(p))
    return tuple(out)


def resolve_uri(uri: str, urdf_dir: Path) -> Path:
    """File path of a URDF mesh URI (``package://``, ``file://``, absolute or relative)."""
    if uri.startswith("file://"):
        return Path(uri[len("file://"):])
    if uri.startswith("package://"):
        rest = uri[len("package://"):]
        pkg, _, sub = rest.partition("/")
        candidates = [d / pkg / sub for d in share_dirs()]
        candidates += [a / sub for a in [urdf_dir, *urdf_dir.parents] if a.name == pkg]
        candidates.append(urdf_dir / sub)
        for c in candidates:
            if c.is_file():
                return c
        raise FileNotFoundError(f"cannot resolve mesh {uri!r}: tried {[str(c) for c in candidates]}")
    p = Path(uri)
    return p if p.is_absolute() else urdf_dir / p


def _origin(o) -> np.ndarray:
    return np.eye(4) if o is None else np.asarray(o, dtype=np.float64)


def _geometry_mesh(geom, urdf_dir: Path, where: str) -> Mesh | None:
    if geom is None:
        return None
    if geom.mesh is not None:
        scale = 1.0 if geom.mesh.scale is None else geom.mesh.scale
        return load_mesh(resolve_uri(geom.mesh.filename, urdf_dir), scale=scale)
    if geom.box is not None:
        return Box(size=tuple(np.asarray(geom.box.size, float))).local_mesh()
    if geom.cylinder is not None:
        return Cylinder(radius=float(geom.cylinder.radius), length=float(geom.cylinder.length)).local_mesh()
    if geom.sphere is not None:
        return Sphere(radius=float(geom.sphere.radius)).local_mesh()
    raise ValueError(f"{where}: unsupported geometry")


def _link_mesh(link, urdf_dir: Path) -> Mesh | None:
    elems = link.collisions or link.visuals
    parts = []
    for i, e in enumerate(elems):
        m = _geometry_mesh(e.geometry, urdf_dir, f"link {link.name!r} geometry {i}")
        if m is not None:
            parts.append(m.transformed(_origin(e.origin)))
    return _weld(merge_meshes(parts)) if parts else None


def _weld(m: Mesh) -> Mesh:
    """Merge duplicate vertices (STL stores three per triangle) and drop degenerate faces."""
    v, inv = np.unique(np.round(m.vertices, 9), axis=0, return_inverse=True)
    f = inv.reshape(-1)[m.faces]
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return Mesh(np.ascontiguousarray(v), np.ascontiguousarray(f[ok], dtype=np.int32))


def _load(path: Path):
    import logging

    import yourdfpy

    log = logging.getLogger("yourdfpy")
    level = log.level
    log.setLevel(logging.CRITICAL)  # it logs XML errors itself; ours is the one message
    try:
        return yourdfpy.URDF.load(str(path), build_scene_graph=False, build_collision_scene_graph=False,
                                  load_meshes=False, load_collision_meshes=False)
    except Exception as exc:
        raise ValueError(f"cannot parse URDF {path} (not valid URDF XML): {exc}") from None
    finally:
        log.setLevel(level)


def parse_urdf(path: str | Path, tip: str | None = None, load_geometry: bool = True) -> UrdfRobot:
    """Read a URDF into chain rows and link meshes.

    ``tip``: the last link of the serial chain; by default the leaf reached
    through the most moving joints (ties between different moving chains
    raise ``ValueError`` listing the candidates). Raises ``FileNotFoundError``
    for a missing file or mesh, ``ValueError`` for a malformed URDF, a tree
    with several roots, a loop, or an unsupported joint (floating, planar,
    mimic) on the chain.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"URDF file not found: {path}")
    u = _load(path)
    robot = u.robot
    if robot is None or not robot.links:
        raise ValueError(f"URDF {path}: no <link> elements")
    links = {l.name: l for l in robot.links}
    by_child: dict[str, object] = {}
    children: dict[str, list] = {n: [] for n in links}
    for j in robot.joints:
        for role, nm in (("parent", j.parent), ("child", j.child)):
            if nm not in links:
                raise ValueError(f"URDF {path}: joint {j.name!r} names unknown {role} link {nm!r}")
        if j.child in by_child:
            raise ValueError(f"URDF {path}: link {j.child!r} has two parent joints")
        by_child[j.child] = j
        children[j.parent].append(j)
    roots = [n for n in links if n not in by_child]
    if len(roots) != 1:
        raise ValueError(f"URDF {path}: expected one root link, found {roots or 'none (a loop)'}")
    root = roots[0]

    # depth-first walk: order, moving-joint count per link
    order, moving, seen = [], {root: 0}, set()
    stack = [root]
    while stack:
        n = stack.pop()
        if n in seen:
            raise ValueError(f"URDF {path}: the joint graph has a loop at {n!r}")
        seen.add(n)
        order.append(n)
        for j in reversed(children[n]):
            moving[j.child] = moving[n] + (0 if j.type == "fixed" else 1)
            stack.append(j.child)
    if len(seen) != len(links):
        raise ValueError(f"URDF {path}: links not connected to the root: {sorted(set(links) - seen)}")

    def path_to(n):
        out = [n]
        while n in by_child:
            n = by_child[n].parent
            out.append(n)
        return out[::-1]

    if tip is None:
        leaves = [n for n in order if not children[n]]
        best = max(moving[n] for n in leaves)
        cands = [n for n in leaves if moving[n] == best]
        chains = {tuple(x for x in path_to(n) if x == root or by_child[x].type != "fixed") for n in cands}
        if len(chains) > 1:
            raise ValueError(f"URDF {path}: several chains with {best} moving joints; choose tip= one of {cands}")
        tip = cands[-1]
    elif tip not in links:
        raise ValueError(f"URDF {path}: unknown tip link {tip!r}; links are {sorted(links)}")

    on_path = path_to(tip)
    keep = set(on_path)
    for n in order:  # fixed attachments of kept links (order is parent-first)
        if n in by_child and by_child[n].parent in keep and by_child[n].type == "fixed":
            keep.add(n)
    urdf_dir = path.parent
    specs: list[LinkSpec] = []
    meshes: dict[str, Mesh] = {}
    for n in order:
        if n not in keep:
            continue
        if n == root:
            specs.append(LinkSpec(n))
        else:
            j = by_child[n]
            if j.type not in _JTYPES:
                raise ValueError(f"URDF {path}: joint {j.name!r} of type {j.type!r} is not supported "
                                 f"(revolute, continuous, prismatic, fixed)")
            if j.mimic is not None:
                raise ValueError(f"URDF {path}: joint {j.name!r} mimics {j.mimic.joint!r}; mimic joints are not supported")
            lo, hi, vmax = -np.inf, np.inf, np.inf
            if j.type in ("revolute", "prismatic") and j.limit is not None:
                lo = -np.inf if j.limit.lower is None else float(j.limit.lower)
                hi = np.inf if j.limit.upper is None else float(j.limit.upper)
            if j.type != "fixed" and j.limit is not None and j.limit.velocity:
                vmax = float(j.limit.velocity)
            axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=np.float64)
            try:
                specs.append(LinkSpec(n, parent=j.parent, joint=j.name, jtype=_JTYPES[j.type],
                                      pre=_origin(j.origin), axis=axis, lower=lo, upper=hi, vmax=vmax))
            except ValueError as exc:
                raise ValueError(f"URDF {path}: {exc}") from None
        if load_geometry:
            m = _link_mesh(links[n], urdf_dir)
            if m is not None:
                meshes[n] = m
    return UrdfRobot(name=robot.name or path.stem, links=specs, meshes=meshes, tip=tip, path=path)
