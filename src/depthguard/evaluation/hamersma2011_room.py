"""Hamersma 2011 on ``c-arm-room`` (R21-R24): the room, its setups' frames, the reconstructions
and the C-arm's motions — the pieces that :mod:`depthguard.evaluation.hamersma2011` runs (its
docstring gives the choices)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from depthguard.camera import Camera
from depthguard.control.motion_check import Motion, braking_distance
from depthguard.evaluation.hamersma2011_paper import (AXES, AXIS_LABEL, FRAME_PERIOD, MARGIN, REACTION_TIME,
                                                      SHELL_TOLERANCE)
from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.free_space_product import STILL_FRAMES, FreeSpaceProduct, fuse_still
from depthguard.fusion.free_space_product import product_margins as _fused_margins
from depthguard.fusion.free_space_product import shell_backgrounds as _shell_depths
from depthguard.transforms import pose, rot_x, rot_y, rot_z


def braking_distances() -> dict[str, float]:
    """S per C-arm axis (rad or m): top speed, reaction 0.2 s, stop from top speed in 1 s."""
    from depthguard.sim.carm import CARM_SPEEDS
    return {a: braking_distance(CARM_SPEEDS[a], CARM_SPEEDS[a], REACTION_TIME) for a in AXES}


@dataclass
class Room:
    cell: object
    cameras: list[Camera]
    lo: np.ndarray
    hi: np.ndarray
    scene: object
    carm: object
    setups: list[str]
    times: dict[str, float]
    margin: float = MARGIN
    _sims: dict = field(default_factory=dict)


def _situation_time(v) -> float:
    if isinstance(v, (int, float)):
        return float(v)
    for attr in ("t", "time"):
        if hasattr(v, attr):
            return float(getattr(v, attr))
    raise ValueError(f"c-arm-room situation {v!r} has no time")


def load_room() -> Room:
    """The ``c-arm-room`` cell as used here: cameras, box, scene, C-arm, setups (in order)."""
    from depthguard.sim import load_cell

    cell = load_cell("c-arm-room")
    rig, scene = cell.rig, cell.scene
    times = {name: _situation_time(v) for name, v in cell.situations.items()}
    setups = list(times)
    carm = scene.robot
    if carm is None or not hasattr(carm, "primitives"):
        raise ValueError("c-arm-room: the scene's machine is not a C-arm")
    return Room(cell, list(rig.cameras), np.asarray(rig.workspace.lo, float),
                np.asarray(rig.workspace.hi, float), scene, carm, setups, times)


def carm_pose(room: Room, setup: str):
    from depthguard.sim.carm import CArmPose
    return CArmPose.from_array(room.scene.robot_q(room.times[setup]))


def _sim(room: Room, cam: Camera, seed: int, noiseless: bool):
    from depthguard.sources import SimulatedCamera
    key = (cam.id, seed, noiseless)
    if key not in room._sims:
        room._sims[key] = SimulatedCamera(cam, seed=seed, noiseless=noiseless)
    return room._sims[key]


def scene_meshes(room: Room, setup: str, carm_q=None) -> list:
    """World meshes of a setup with the C-arm at ``carm_q`` (default: the setup's pose)."""
    t = room.times[setup]
    meshes, _ = room.scene.meshes_at(t, robot=False)
    q = carm_pose(room, setup) if carm_q is None else carm_q
    return list(meshes) + list(room.carm.link_meshes(q))


def ideal_frames(room: Room, setup: str, carm_q=None, cameras=None) -> dict[str, np.ndarray]:
    """Noiseless rendered depth per camera (float32, 0 = nothing); default: the cell's cameras."""
    meshes = scene_meshes(room, setup, carm_q)
    out = {}
    for cam in (room.cameras if cameras is None else cameras):
        depth, _ = _sim(room, cam, 0, True).renderer.render(meshes)
        out[cam.id] = np.array(depth, copy=True)
    return out


def measured_frames(room: Room, setup: str, ideal: dict, seed: int = 0, noiseless: bool = False, cameras=None,
                    frame: int = 0):
    """Measured frames from ideal ones through each camera's sensor model (deterministic);
    ``frame`` k is the camera's k-th frame of the still setup (its own noise)."""
    t = room.times[setup]
    by_id = {c.id: c for c in (room.cameras if cameras is None else cameras)}
    out = {}
    for cid, img in ideal.items():
        sim = _sim(room, by_id[cid], seed, noiseless)
        out[cid] = np.array(sim.measure(img, stamp=t + frame * FRAME_PERIOD), copy=True)
    return out


def still_fusion(room: Room, cameras=None):
    """The product's fusion of ``STILL_FRAMES`` frames per camera (one sensor model for all)."""
    from depthguard.fusion.temporal import StillFusion
    models = {_sim(room, c, 0, False).model for c in (room.cameras if cameras is None else cameras)}
    if len(models) != 1:
        raise ValueError("the still fusion needs one sensor model for all cameras")
    return StillFusion.for_sensor(models.pop(), STILL_FRAMES)


def still_frame_list(room: Room, setup: str, ideal: dict, seed: int = 0, cameras=None,
                     first: dict | None = None) -> list[dict[str, np.ndarray]]:
    """``STILL_FRAMES`` consecutive measured frames (dicts id -> (H, W) float32) of the still
    setup, frame 0 first, as :meth:`FreeSpaceProduct.update` takes them; ``first``: frame 0 if
    already measured."""
    frames = [first if first is not None else measured_frames(room, setup, ideal, seed, cameras=cameras)]
    frames += [measured_frames(room, setup, ideal, seed, cameras=cameras, frame=k) for k in range(1, STILL_FRAMES)]
    return frames


def still_frames(room: Room, setup: str, ideal: dict, seed: int = 0, cameras=None,
                 first: dict | None = None) -> dict[str, np.ndarray]:
    """``STILL_FRAMES`` consecutive measured frames per camera of the still setup, fused
    (:class:`~depthguard.fusion.temporal.StillFusion`); ``first``: frame 0 if already measured."""
    return fuse_still(still_fusion(room, cameras), still_frame_list(room, setup, ideal, seed, cameras, first),
                      ids=list(ideal))


def setup_frames(room: Room, setup: str, seed: int = 0, carm_q=None, noiseless: bool = False, cameras=None):
    """Measured depth images (dict id -> (H, W) float32) of a setup."""
    return measured_frames(room, setup, ideal_frames(room, setup, carm_q, cameras), seed, noiseless, cameras)


def perturbed_cameras(cameras, rng: np.random.Generator, rot_deg: float = 0.0, trans_m: float = 0.0):
    """Cameras whose poses are disturbed: each of three rotation angles (about the camera's
    own axes) uniform in ±``rot_deg``, each translation component uniform in ±``trans_m``."""
    out = []
    for c in cameras:
        a, b, g = np.deg2rad(rng.uniform(-rot_deg, rot_deg, 3)) if rot_deg else (0.0, 0.0, 0.0)
        T = c.world_from_camera @ pose(rot_z(g) @ rot_y(b) @ rot_x(a))
        if trans_m:
            T = T.copy()
            T[:3, 3] += rng.uniform(-trans_m, trans_m, 3)
        out.append(c.with_pose(T))
    return out


def shell_primitives(room: Room) -> list:
    """The room's fixed shell (floor, ceiling, walls): static primitives outside the box."""
    return [p for p in room.scene.static if outside_box(p, room.lo, room.hi)]


def shell_meshes(room: Room) -> list:
    """World meshes of the room's fixed shell (:func:`shell_primitives`)."""
    return [p.mesh() for p in shell_primitives(room)]


def shell_backgrounds(room: Room, cameras) -> dict[str, np.ndarray]:
    """Expected depth (float32, 0 = nothing) of the room's shell per camera, as the map's
    cameras believe they are placed (:func:`depthguard.fusion.free_space_product.shell_backgrounds`)."""
    return _shell_depths(cameras, shell_meshes(room))


def shell_map(room: Room, cams, vs) -> FreeSpaceMap:
    """The ``single`` variant: the product's rule on one frame (margin ``room.margin`` = 2 sigma
    of one frame, the shell as background with tolerance ``SHELL_TOLERANCE``)."""
    fs = FreeSpaceMap(cams, (room.lo, room.hi), vs, margin=room.margin)
    fs.set_background(shell_backgrounds(room, cams), tolerance=SHELL_TOLERANCE)
    return fs


def product_margins(room: Room, cams=None) -> tuple[float, float]:
    """``(margin, shell tolerance)`` of the product: 2 and 2 + 3 sigma of the fused depth
    (:func:`depthguard.fusion.free_space_product.product_margins`)."""
    return _fused_margins(still_fusion(room, cams))


def product_map(room: Room, cams, vs) -> FreeSpaceProduct:
    """The product's map (:class:`~depthguard.fusion.free_space_product.FreeSpaceProduct`) of
    the room with cameras ``cams`` at voxel size ``vs``."""
    return FreeSpaceProduct(cams, (room.lo, room.hi), vs, still_fusion(room, cams), shell_meshes(room))


# ------------------------------------------------------------------- pieces
def reconstruct(fs, depths, machine, self_padding):
    """``fs``: a FreeSpaceMap (``depths`` one dict id -> image) or a FreeSpaceProduct
    (``depths`` its list of still frames)."""
    fs.update(depths)
    fs.add_free_volume(machine, padding=self_padding)
    return fs.occupied.copy(), fs.machine.copy()


def object_masks(room: Room, setup: str, lo, hi, s):
    from depthguard.sim.ground_truth import occupancy
    t = room.times[setup]
    out = {}
    for prim in room.scene.obstacles_at(t):
        m = occupancy([prim], lo, hi, s, mode="centre")
        if m.any():
            ext = np.asarray(prim.bounds())
            out[prim.name or type(prim).__name__] = (m, float(np.min(ext[1] - ext[0])))
    return out


def clamped_motion(room: Room, q0, axes: dict[str, float], S: dict[str, float], name: str, offset: float = 0.0):
    """A C-arm motion clamped at the axis limits; ``offset`` (in S) advances the start pose."""
    from depthguard.sim.carm import CARM_LIMITS

    def q_at(u):
        kw = {}
        for f, m in axes.items():
            lo, hi = CARM_LIMITS[f]
            kw[f] = float(np.clip(getattr(q0, f) + (u + offset) * m * S[f], lo, hi))
        return dataclasses.replace(q0, **kw)

    return Motion(name, lambda u: room.carm.primitives(q_at(u)),
                  ", ".join(f"{f} {m:+g} x S={S[f]:.4g}" for f, m in axes.items())), q_at


def motion_specs():
    specs = []
    for a in AXES:
        for sgn in (+1, -1):
            specs.append((f"{AXIS_LABEL[a]} {'+' if sgn > 0 else '-'}", {a: float(sgn)}))
    for sl in (+1, -1):
        for b in ("propeller", "larm"):
            specs.append((f"Long{'+' if sl > 0 else '-'} & {AXIS_LABEL[b]}+", {"longitudinal": float(sl), b: 1.0}))
    return specs


def outside_box(prim, lo, hi, tol=0.01) -> bool:
    b = np.asarray(prim.bounds())
    return bool(np.any(b[1] <= lo + tol) or np.any(b[0] >= hi - tol))
