"""The static scene learned from the cameras: a cell without CAD (issue 31; R16, R17, R34).

Most cells have no CAD of their tables, fences and racks. ``depthguard rig
learn-scene`` (:mod:`depthguard.filtering.scene_learner`) watches the cell with
no person in it — the robot may move: it is removed at each frame's capture
joints (R9, R30) — and keeps, per camera and pixel:

- ``depth`` (H, W) float32 m: the median of the frames where the pixel returned and
  the robot was not in front of it; 0 = **unknown** (never returned, returned in
  fewer than ``min_share`` of the frames it was not hidden, or always hidden by the
  robot). Unknown stays unknown: it is never "nothing there";
- ``sigma`` (H, W) float32 m: its noise, the larger of the sensor model's
  ``sigma(z)`` (:func:`depthguard.sensors.depth_sigma`) and the observed spread
  (1.4826 MAD over the frames); the band a measurement must keep to match the
  scene is ``k sigma + ABS_MARGIN`` (:meth:`LearnedScene.band`);
- ``seen`` (H, W) uint16: the number of frames the median is over.

It is stored in a folder: ``scene.json`` (what was learned, when, from which
source; per camera its intrinsics and pose) and one ``<camera>.npz`` per camera.
A rig refers to it (``scene: {learned: DIR}``); :func:`load` refuses a scene
learned with another image size, other intrinsics or another pose of a camera
(one sentence naming the camera and what differs): a moved camera must be
relearned or recalibrated, never silently matched against a scene it no longer sees.

The per-pixel median is the hot loop (pixels x frames): :func:`robust_depth` is
numba, :func:`robust_depth_numpy` its plain twin (tests compare both).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["LearnedScene", "LearnedSceneError", "robust_depth", "robust_depth_numpy", "save", "load",
           "ABS_MARGIN", "K_SIGMA", "FORMAT"]

#: added to ``k sigma`` (m): the band's floor (mounting vibration, a pixel's footprint on a slanted surface)
ABS_MARGIN = 0.01
#: the band's ``k``
K_SIGMA = 3.0
#: ``scene.json``'s ``format``
FORMAT = "depthguard-learned-scene/1"
#: a camera's pose must match within this (m, degrees) and its intrinsics within this (px)
POSE_TOL_M = 0.002
POSE_TOL_DEG = 0.1
INTRINSICS_TOL_PX = 0.05


class LearnedSceneError(ValueError):
    """A learned scene that cannot be used (one sentence: the folder, the camera, the problem)."""


@dataclass(eq=False)
class LearnedScene:
    """One camera's learned static scene (module docstring); ``camera`` is the
    :class:`~depthguard.camera.Camera` it was learned with (intrinsics and pose)."""
    camera: object
    depth: np.ndarray
    sigma: np.ndarray
    seen: np.ndarray
    frames: int

    def band(self, k: float = K_SIGMA) -> np.ndarray:
        """(H, W) float32 m: how far a measurement may be from ``depth`` and still be the scene
        (``k sigma + ABS_MARGIN``; meaningless where ``depth`` is 0)."""
        return (k * self.sigma + ABS_MARGIN).astype(np.float32)

    @property
    def known(self) -> np.ndarray:
        """(H, W) bool: pixels with a learned surface."""
        return self.depth > 0


# ------------------------------------------------------------------ the per-pixel robust depth
def robust_depth_numpy(stack: np.ndarray, min_share: float = 0.5, min_frames: int = 3):
    """The plain twin of :func:`robust_depth`.

    stack : (N, H, W) float32 m, one frame per layer: > 0 a measurement, 0 no return, NaN
    not observable (the robot in front). A pixel's surface is the median of its returns when
    it returned in at least ``min_share`` of its observable frames and at least ``min_frames``
    times; else 0. Returns ``(depth, spread, seen)``: (H, W) float32 m, float32 m (1.4826 MAD),
    uint16 (returns used)."""
    s = np.asarray(stack, dtype=np.float32)
    observable = np.isfinite(s)
    ret = observable & (s > 0)
    n_obs = observable.sum(axis=0)
    n_ret = ret.sum(axis=0)
    vals = np.where(ret, s, np.nan)
    with np.errstate(invalid="ignore"), __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(vals, axis=0)
        mad = np.nanmedian(np.abs(vals - med[None]), axis=0)
    ok = (n_ret >= min_frames) & (n_ret >= min_share * n_obs)
    depth = np.where(ok, med, 0.0).astype(np.float32)
    spread = np.where(ok, 1.4826 * mad, 0.0).astype(np.float32)
    return depth, spread, np.where(ok, n_ret, 0).astype(np.uint16)


def _kernel():
    import numba

    @numba.njit(cache=True, parallel=True)
    def kernel(stack, min_share, min_frames, depth, spread, seen):
        n, h, w = stack.shape
        for r in numba.prange(h):
            buf = np.empty(n, dtype=np.float32)
            dev = np.empty(n, dtype=np.float32)
            for c in range(w):
                n_obs = 0
                k = 0
                for i in range(n):
                    v = stack[i, r, c]
                    if v == v:                 # not NaN: observable
                        n_obs += 1
                        if v > 0.0:
                            buf[k] = v
                            k += 1
                if k < min_frames or k < min_share * n_obs:
                    depth[r, c] = 0.0
                    spread[r, c] = 0.0
                    seen[r, c] = 0
                    continue
                b = np.sort(buf[:k])
                if k % 2 == 1:
                    m = b[k // 2]
                else:
                    m = np.float32(0.5) * (b[k // 2 - 1] + b[k // 2])
                for i in range(k):
                    dev[i] = abs(b[i] - m)
                d = np.sort(dev[:k])
                if k % 2 == 1:
                    mad = d[k // 2]
                else:
                    mad = np.float32(0.5) * (d[k // 2 - 1] + d[k // 2])
                depth[r, c] = m
                spread[r, c] = np.float32(1.4826) * mad
                seen[r, c] = min(k, 65535)

    return kernel


_KERNEL = None


def robust_depth(stack: np.ndarray, min_share: float = 0.5, min_frames: int = 3):
    """Per-pixel median and spread of a frame stack (numba; :func:`robust_depth_numpy` is the twin
    and says what it computes)."""
    global _KERNEL
    if _KERNEL is None:
        _KERNEL = _kernel()
    s = np.ascontiguousarray(stack, dtype=np.float32)
    _, h, w = s.shape
    depth = np.zeros((h, w), np.float32)
    spread = np.zeros((h, w), np.float32)
    seen = np.zeros((h, w), np.uint16)
    _KERNEL(s, float(min_share), int(min_frames), depth, spread, seen)
    return depth, spread, seen


# ------------------------------------------------------------------ storage
def _camera_record(cam) -> dict:
    return {"width": int(cam.width), "height": int(cam.height), "fx": float(cam.fx), "fy": float(cam.fy),
            "cx": float(cam.cx), "cy": float(cam.cy), "sensor": cam.sensor,
            "world_from_camera": np.asarray(cam.world_from_camera, dtype=float).tolist()}


def save(folder, scenes: dict, info: dict | None = None) -> Path:
    """Write ``scenes`` (camera id -> :class:`LearnedScene`) to ``folder`` (made if needed):
    ``scene.json`` and ``<camera>.npz``; ``info`` (source, duration, ...) goes into the json."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    cams = {}
    for cid, sc in scenes.items():
        np.savez_compressed(out / f"{cid}.npz", depth=sc.depth.astype(np.float32),
                            sigma=sc.sigma.astype(np.float32), seen=sc.seen.astype(np.uint16))
        cams[cid] = dict(_camera_record(sc.camera), file=f"{cid}.npz", frames=int(sc.frames),
                         known_share=float(np.count_nonzero(sc.depth > 0)) / sc.depth.size)
    (out / "scene.json").write_text(json.dumps({"format": FORMAT, **(info or {}), "cameras": cams}, indent=2))
    return out


def pose_difference(a, b) -> tuple[float, float]:
    """``(metres, degrees)`` between two (4, 4) world-from-camera poses."""
    A, B = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    dt = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    Rr = A[:3, :3].T @ B[:3, :3]
    ang = math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(Rr)) - 1.0) / 2.0))))
    return dt, ang


def camera_problem(record: dict, cam) -> str | None:
    """What makes a scene learned with ``record`` (``scene.json``'s camera entry) unusable for
    ``cam``; None when it fits."""
    size = (int(record.get("width", -1)), int(record.get("height", -1)))
    if size != (cam.width, cam.height):
        return (f"it was learned at {size[0]}x{size[1]} and the rig's camera is {cam.width}x{cam.height}")
    for k in ("fx", "fy", "cx", "cy"):
        if abs(float(record[k]) - float(getattr(cam, k))) > INTRINSICS_TOL_PX:
            return f"it was learned with {k} = {float(record[k]):.2f} px and the rig's camera has {getattr(cam, k):.2f} px"
    dt, ang = pose_difference(record["world_from_camera"], cam.world_from_camera)
    if dt > POSE_TOL_M or ang > POSE_TOL_DEG:
        return (f"the rig's camera pose differs from the one it was learned at by {dt * 1000:.1f} mm and "
                f"{ang:.2f} deg (allowed {POSE_TOL_M * 1000:g} mm, {POSE_TOL_DEG:g} deg)")
    return None


def load(folder, cameras) -> dict:
    """The learned scenes of ``cameras`` (list of :class:`~depthguard.camera.Camera`) stored in
    ``folder``: camera id -> :class:`LearnedScene`; a camera the folder does not have gets none
    (the CAD, if any, is its known scene). :class:`LearnedSceneError`, one sentence, for a
    missing or unreadable folder and a camera learned at another size, intrinsics or pose."""
    p = Path(folder)
    meta_file = p / "scene.json"
    if not meta_file.is_file():
        raise LearnedSceneError(f"learned scene {p}: no scene.json there (make one with depthguard rig learn-scene)")
    try:
        meta = json.loads(meta_file.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise LearnedSceneError(f"learned scene {p}: scene.json is not valid JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or not isinstance(meta.get("cameras"), dict):
        raise LearnedSceneError(f"learned scene {p}: scene.json is not a {FORMAT} file")
    out = {}
    for cam in cameras:
        rec = meta["cameras"].get(cam.id)
        if rec is None:
            continue
        try:
            problem = camera_problem(rec, cam)
        except (KeyError, TypeError, ValueError) as exc:
            raise LearnedSceneError(f"learned scene {p}: camera {cam.id}'s entry is incomplete ({exc})") from None
        if problem:
            raise LearnedSceneError(f"learned scene {p}: camera {cam.id}: {problem}; relearn it "
                                    f"(depthguard rig learn-scene) or fix the rig")
        try:
            with np.load(p / str(rec.get("file", f"{cam.id}.npz"))) as z:
                depth, sigma, seen = (np.asarray(z[k]) for k in ("depth", "sigma", "seen"))
        except (OSError, KeyError, ValueError) as exc:
            raise LearnedSceneError(f"learned scene {p}: camera {cam.id}'s arrays cannot be read ({exc})") from None
        if depth.shape != cam.shape or sigma.shape != cam.shape or seen.shape != cam.shape:
            raise LearnedSceneError(f"learned scene {p}: camera {cam.id}'s arrays are {depth.shape}, "
                                    f"the camera is {cam.shape}")
        depth = depth.astype(np.float32)
        if not (np.all(np.isfinite(depth)) and np.all(depth >= 0) and np.all(np.isfinite(sigma))):
            raise LearnedSceneError(f"learned scene {p}: camera {cam.id}'s depth has negative or non-finite values")
        out[cam.id] = LearnedScene(cam, depth, sigma.astype(np.float32), seen.astype(np.uint16),
                                   int(rec.get("frames", 0)))
    return out
