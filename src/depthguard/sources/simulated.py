"""Simulated depth cameras and the simulated frame source (issue 2 §6).

:class:`SimulatedCamera` renders the ideal depth of a list of meshes with the
shared :class:`depthguard.render.Renderer` and applies its sensor's noise
(:mod:`depthguard.sources.noise`). :class:`SimSource` does this for every
camera of a rig, for a :class:`depthguard.sim.Scene` at time ``t``.

Determinism: with ``stamp`` given, the noise of a capture is drawn from a
generator seeded by ``(seed, camera id, stamp)``, so a frame is a pure
function of the scene, the seed and the time; without ``stamp`` the camera's
own generator (seeded once with ``seed``) advances from capture to capture.
"""

from __future__ import annotations

import functools
import zlib
from typing import Sequence

import numpy as np

from depthguard.camera import Camera
from depthguard.sensors import SensorModel, sensor_model
from depthguard.sources.frame import Frame
from depthguard.sources.noise import NoiseWorkspace, apply_noise

__all__ = ["SimulatedCamera", "SimSource", "frame_rng", "returns_beyond_the_model", "BEYOND_RANGE"]

BEYOND_RANGE = 1.5       # x max_range: where a ray that meets nothing modelled returns from (R28)


def returns_beyond_the_model(measured: np.ndarray, ideal: np.ndarray, cam: Camera) -> np.ndarray:
    """``measured`` (H, W) float32 m, changed in place: where the ideal render met nothing the
    scene models (``ideal <= 0``: a user's rig without walls), a return from beyond the rated
    range (``BEYOND_RANGE x max_range``), as a real cell's walls would give — free up to
    ``max_range``, unknown behind (R28). Dropouts on modelled surfaces stay "no return"."""
    measured[ideal <= 0] = np.float32(BEYOND_RANGE * cam.max_range)
    return measured


def frame_rng(seed: int, camera_id: str, stamp: float) -> np.random.Generator:
    """The generator of the noise of one frame: seeded by ``(seed, crc32(camera id), stamp in µs)``."""
    key = [int(seed) & 0xFFFFFFFF, _crc32(camera_id), int(round(float(stamp) * 1e6)) & 0xFFFFFFFFFFFF]
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(key)))   # default_rng's, its wrapper aside


@functools.lru_cache(maxsize=256)
def _crc32(camera_id: str) -> int:
    """``zlib.crc32`` of the camera id (asked at every frame)."""
    return zlib.crc32(camera_id.encode())


class SimulatedCamera:
    """A depth camera that sees meshes through a sensor noise model.

    Parameters
    ----------
    cam : the pinhole camera (intrinsics, pose, range).
    model : a :class:`SensorModel` or its name; default ``cam.sensor`` (or
        ``"ideal"`` when the camera names none).
    seed : seed of the noise.
    noiseless : no noise at all: the rendered depth, 0 outside ``[cam.min_range, cam.max_range]``.

    The valid range is the camera's (``cam.min_range``, ``cam.max_range``),
    which the rig takes from the sensor preset unless it overrides it.
    """

    def __init__(self, cam: Camera, model: SensorModel | str | None = None, seed: int = 0,
                 noiseless: bool = False):
        if model is None:
            model = cam.sensor or "ideal"
        if isinstance(model, str):
            model = sensor_model(model)
        if not isinstance(model, SensorModel):
            raise ValueError(f"camera {cam.id!r}: model must be a SensorModel or a preset name, got {model!r}")
        self.cam = cam
        self.model = model
        self.seed = int(seed)
        self.noiseless = bool(noiseless)
        self.rng = np.random.default_rng(self.seed)
        self._ws = NoiseWorkspace(cam.shape)
        self.bank = None                 # a NormalBank: the normals of real-time simulations (noise.py)
        self._renderer = None

    @property
    def renderer(self):
        if self._renderer is None:
            from depthguard.render import Renderer
            self._renderer = Renderer(self.cam)
        return self._renderer

    def measure(self, ideal: np.ndarray, stamp: float | None = None) -> np.ndarray:
        """Measured depth (H, W) float32 (0 = invalid) from an ideal rendered depth image."""
        rng = self.rng if stamp is None else frame_rng(self.seed, self.cam.id, stamp)
        return apply_noise(ideal, self.model, self.cam.fx, rng, self.cam.min_range, self.cam.max_range,
                           noiseless=self.noiseless, ws=self._ws, bank=self.bank)

    def capture_with_labels(self, meshes: Sequence, stamp: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(depth, labels)``: measured (H, W) float32 metres and the renderer's (H, W) int32
        labels (index into ``meshes``, -1 = nothing) of the ideal image."""
        ideal, labels = self.renderer.render(list(meshes))
        return self.measure(ideal, stamp), np.array(labels, copy=True)

    def capture(self, meshes: Sequence, stamp: float | None = None) -> np.ndarray:
        """Measured depth (H, W) float32 metres, 0 = invalid, of ``meshes`` (world ``(V, F)`` pairs)."""
        ideal, _ = self.renderer.render(list(meshes))
        return self.measure(ideal, stamp)


class SimSource:
    """Frames of every camera of a rig looking at a scene.

    ``SimSource(cell)`` or ``SimSource(rig=rig, scene=scene)``. ``frames(t)``
    returns ``{camera id: Frame}`` for scene time ``t``; the noise is a pure
    function of ``(seed, camera, t)``. The frames are the package's one camera
    simulator's (:class:`~depthguard.sources.camera_sim.CameraSim`: the static scene
    rendered once, the robot and the people per frame; the raw sensor, 0 where nothing
    returns); with ``labels`` the whole scene is rendered at once, for its labels.
    """

    def __init__(self, cell=None, *, rig=None, scene=None, seed: int = 0, noiseless: bool = False,
                 cameras: Sequence[str] | None = None):
        from depthguard.sources.camera_sim import CameraSim

        if cell is not None:
            rig, scene = cell.rig, cell.scene
        if rig is None or scene is None:
            raise ValueError("SimSource needs a cell, or both rig= and scene=")
        self.rig, self.scene = rig, scene
        cams = rig.cameras if cameras is None else [rig.camera(c) for c in cameras]
        self.sim = CameraSim(cams, robot=scene.robot, static_meshes=scene.static_meshes, seed=seed,
                             noiseless=noiseless, invalid=None)
        self.cameras = self.sim.sims            # {camera id: SimulatedCamera}
        from depthguard.sim.posed import PosedMeshes
        self._posed = PosedMeshes(scene)

    def frames(self, t: float, labels: bool = False, robot: bool = True) -> dict[str, Frame]:
        """``{camera id: Frame}`` at scene time ``t`` (robot included unless ``robot=False``).

        With ``labels=True`` each frame carries the (H, W) int32 ground-truth
        labels, indices into ``scene.meshes_at(t)[1]`` (the mesh names).
        """
        if labels:
            meshes, _names = self.scene.meshes_at(t, robot=robot)
            out = {}
            for cid, sc in self.cameras.items():
                d, lab = sc.capture_with_labels(meshes, stamp=t)
                out[cid] = Frame(cid, d, float(t), lab)
            return out
        moving = self._posed.at(float(t))            # posed once for all cameras (sim/posed.py)
        q = self.scene.robot_q(t) if (robot and self.scene.robot is not None) else None
        return {cid: Frame(cid, self.sim.depth(cid, t, q, moving), float(t)) for cid in self.cameras}
