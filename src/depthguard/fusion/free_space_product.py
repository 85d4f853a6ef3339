"""The product's free-space map: still frames fused, a margin of the fused noise, the room shell (R21, R22).

Before a machine moves, the space it moves into is judged from the cameras
(R21) and each intended motion gets its verdict in that map (R22,
:mod:`depthguard.control.motion_check`). :class:`FreeSpaceProduct` assembles
the map the product judges motions in, from three pieces that exist on their
own:

- **Several frames before a motion check.** The scene is still while a motion
  is judged, so each camera gives ``frames`` (default :data:`STILL_FRAMES` = 3)
  consecutive frames, fused per pixel by
  :class:`~depthguard.fusion.temporal.StillFusion`: the median where they
  agree within the spread a still surface shows (99.9 %), the nearest sample
  where they do not (depth edges, ToF flying pixels, anything that moved),
  invalid where most are invalid. The fused noise is ``c_n sigma`` (``c_3 ≈
  0.670``), so a margin of :data:`MARGIN_SIGMAS` = 2 *fused* sigma (1.34 cm
  for the 1 cm ToF) keeps the safety of a 2 sigma margin on one frame while
  freeing more of the space just in front of surfaces; flying pixels no longer
  pass for depth, so fewer objects are seen as free. Not for moving scenes:
  the distance loop (R12) uses each frame as it comes.
- **One margin for the whole room.** The margin is a fixed number of metres
  for every voxel and camera, so the sensor's noise must not depend on depth
  (``sigma_z2 = 0``, e.g. the ToF model); a depth-dependent model (structured
  light, stereo) is refused rather than given a margin that is too small far
  away.
- **Known room shell in free space.** The fixed floor, walls and ceiling are
  rendered once per camera (:class:`~depthguard.filtering.expected.ExpectedDepth`,
  the one expected depth of the known scene) and set as the map's background
  (:meth:`~depthguard.fusion.free_space.FreeSpaceMap.set_background`): a
  measurement within the tolerance of the shell — :data:`TOLERANCE_SIGMAS` = 5
  fused sigma, i.e. the margin + 3 sigma — is the shell, not a surface inside
  a voxel, so the layer of voxels along the shell needs one free view instead
  of three. The price: anything within the tolerance in front of the shell
  (a hand flat on a wall, a foot on the floor) counts as shell, like the R17
  filter's offset.

The map itself (:class:`~depthguard.fusion.free_space.FreeSpaceMap`) keeps the
paper's rule: centre pixel, centre depth test, a surface needs three free views
to be overruled, unknown is obstacle (R25). ``reproduce hamersma2011`` reports
this map as ``shell`` (the product) beside the paper's own method.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from depthguard.fusion.free_space import FreeSpaceMap
from depthguard.fusion.temporal import StillFusion
from depthguard.geometry.voxel_grid import VoxelGrid

__all__ = ["FreeSpaceProduct", "STILL_FRAMES", "MARGIN_SIGMAS", "TOLERANCE_SIGMAS", "product_margins",
           "shell_backgrounds", "fuse_still"]

STILL_FRAMES = 3          # frames per camera of the still scene fused before a motion check
MARGIN_SIGMAS = 2.0       # free-space margin in fused sigma
TOLERANCE_SIGMAS = 5.0    # shell tolerance in fused sigma: the margin + 3 sigma


def product_margins(fusion: StillFusion) -> tuple[float, float]:
    """``(margin, shell tolerance)`` in metres: :data:`MARGIN_SIGMAS` and :data:`TOLERANCE_SIGMAS`
    times the fused noise ``fusion.sigma(0)``.

    Raises ``ValueError`` for depth-dependent noise (``fusion.sigma_z2 != 0``): one margin for
    the whole room needs a noise that is the same at every depth.
    """
    if fusion.sigma_z2 != 0.0:
        raise ValueError("the product's margin assumes depth-independent sensor noise (sigma_z2 = 0); "
                         f"got sigma_z2 = {fusion.sigma_z2!r} 1/m")
    sig = fusion.sigma(0.0)
    return MARGIN_SIGMAS * sig, TOLERANCE_SIGMAS * sig


def shell_backgrounds(cameras, shell_meshes: Sequence) -> dict[str, np.ndarray]:
    """Expected depth of the room's fixed shell per camera: camera id -> (H, W) float32 metres
    (0 = nothing), as the cameras are believed to be placed.

    ``shell_meshes``: world :class:`~depthguard.geometry.Mesh` es of the floor, walls, ceiling;
    rendered by :class:`~depthguard.filtering.expected.ExpectedDepth` (its ``static`` image).
    """
    from depthguard.filtering.expected import ExpectedDepth
    meshes = list(shell_meshes)
    return {c.id: ExpectedDepth(c, None, meshes).static for c in cameras}


def fuse_still(fusion: StillFusion, frames: Sequence[Mapping[str, np.ndarray]],
               ids: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Fuse ``fusion.n`` consecutive frames of a still scene per camera.

    ``frames``: a list of ``fusion.n`` dicts camera id -> (H, W) depth in metres (0 / NaN =
    invalid), frame 0 first; ``ids``: the cameras to fuse (default: those of frame 0, each must
    be in every frame). Returns camera id -> (H, W) float32 fused depth in metres.
    """
    frames = list(frames)
    if len(frames) != fusion.n:
        raise ValueError(f"need {fusion.n} frames per camera (a list of {fusion.n} dicts), got {len(frames)}")
    ids = list(frames[0]) if ids is None else list(ids)
    for k, f in enumerate(frames):
        missing = [cid for cid in ids if cid not in f]
        if missing:
            raise ValueError(f"frame {k} has no image of cameras {missing}")
    return {cid: fusion.fuse([f[cid] for f in frames]) for cid in ids}


class FreeSpaceProduct:
    """The product's free-space map (R21; module docstring): fused still frames, a margin of
    2 fused sigma, the room's shell as background.

    Parameters
    ----------
    cameras : sequence of :class:`~depthguard.camera.Camera` (ids unique), as the map believes
        they are placed (the shell is rendered with these).
    bounds : ``(lo, hi)`` two 3-vectors, metres: the box, rounded up to whole voxels.
    voxel_size : float, metres.
    sensor : the cameras' one sensor model (a
        :class:`~depthguard.sensors.SensorModel`; its Gaussian depth noise
        ``sigma_a + sigma_z2 z²``) or a ready :class:`~depthguard.fusion.temporal.StillFusion`.
        Depth-dependent noise (``sigma_z2 != 0``) is refused (``ValueError``).
    shell_meshes : world :class:`~depthguard.geometry.Mesh` es of the room's fixed shell (floor,
        walls, ceiling); empty: no background (the plain rule of the paper).
    frames : consecutive frames fused per camera (odd, 1..15); default :data:`STILL_FRAMES`,
        or the StillFusion's ``n``, which it must match if both are given.

    Attributes
    ----------
    fusion : the :class:`~depthguard.fusion.temporal.StillFusion`.
    margin, tolerance : metres, 2 and 5 fused sigma (:func:`product_margins`).
    backgrounds : camera id -> (H, W) float32 expected shell depth (empty without a shell).
    map : the :class:`~depthguard.fusion.free_space.FreeSpaceMap` (centre pixel, centre depth
        test, ``margin``, background with ``tolerance``).
    """

    def __init__(self, cameras, bounds, voxel_size: float, sensor, shell_meshes: Sequence = (),
                 frames: int | None = None):
        if isinstance(sensor, StillFusion):
            if frames is not None and frames != sensor.n:
                raise ValueError(f"frames={frames!r} differs from the StillFusion's n={sensor.n}")
            fusion = sensor
        else:
            if not (hasattr(sensor, "sigma_a") and hasattr(sensor, "sigma_z2")):
                raise ValueError("sensor must be a SensorModel (sigma_a, sigma_z2) or a StillFusion, "
                                 f"got {type(sensor).__name__}")
            fusion = StillFusion.for_sensor(sensor, STILL_FRAMES if frames is None else frames)
        self.fusion = fusion
        self.margin, self.tolerance = product_margins(fusion)     # refuses depth-dependent noise
        cams = list(cameras)
        self.map = FreeSpaceMap(cams, bounds, voxel_size, margin=self.margin)
        meshes = list(shell_meshes)
        self.backgrounds = shell_backgrounds(cams, meshes) if meshes else {}
        if meshes:
            self.map.set_background(self.backgrounds, tolerance=self.tolerance)

    @property
    def frames(self) -> int:
        """Frames per camera that :meth:`update` fuses."""
        return self.fusion.n

    @property
    def grid(self) -> VoxelGrid:
        return self.map.grid

    @property
    def occupied(self) -> np.ndarray:
        """(nx, ny, nz) bool: the current map (True = occupied or unknown); the map's buffer."""
        return self.map.occupied

    @property
    def machine(self) -> np.ndarray:
        """(nx, ny, nz) bool: the machine's own volume freed since the last update."""
        return self.map.machine

    def fuse(self, frames: Sequence[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
        """``frames`` (a list of :attr:`frames` dicts camera id -> (H, W) depth, metres, frame 0
        first) -> camera id -> (H, W) float32 fused depth (:func:`fuse_still`)."""
        return fuse_still(self.fusion, frames)

    def update(self, frames: Sequence[Mapping[str, np.ndarray]], accumulate: bool = False) -> np.ndarray:
        """R21 on a still scene: fuse ``frames`` per camera, then update the map.

        ``frames``: a list of :attr:`frames` consecutive dicts camera id -> (H, W) depth in
        metres (0 / NaN = invalid); cameras left out say nothing. Returns ``occupied``
        (nx, ny, nz) bool, a view of the map's buffer valid until the next update (copy it).
        """
        return self.map.update(self.fuse(frames), accumulate=accumulate)

    def add_free_volume(self, primitives, padding: float = 0.0) -> np.ndarray:
        """Free the machine's own current volume (R21); call after each :meth:`update`
        (:meth:`FreeSpaceMap.add_free_volume`). Returns the (nx, ny, nz) bool mask."""
        return self.map.add_free_volume(primitives, padding)
