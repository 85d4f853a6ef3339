"""Drift watch: is a running camera still where the rig says it is? (R34)

Each camera's worker thread (:class:`~depthguard.runtime.ingest.CameraWorker`)
feeds every frame to its :class:`DriftWatch`, off the control thread. The
watch compares a fixed subsample of pixels (every ``stride``-th pixel in
both directions, about 5000-20000 of them) with the expected depth of the
**static** scene at the rig's pose:

- a pixel measured **nearer** than expected says nothing: people, boxes and
  the robot occlude the scene (they only ever make depth nearer);
- a pixel measured **farther** than expected by more than
  ``drift_sigma * sigma(z) + 1 cm`` sees through where the known scene
  should be: the camera moved (bumped, a drooping mount), or the scene
  changed. Its share among the non-occluded valid pixels is the frame's
  statistic ``share``.

Pixels on the expected depth edges (mixed and flying pixels), outside the
camera's rated range, or without a static surface are not sampled. A frame
with fewer than :data:`MIN_JUDGED` non-occluded valid samples cannot be
judged and changes nothing.

A camera is flagged **untrusted** after ``drift_frames`` consecutive judged
frames with ``share > baseline + drift_share`` (30 Hz, 3 frames: 0.1 s;
the monitor then stops the robot, reason ``untrusted:<camera>``). It stays
untrusted — the watch latches — until it is recalibrated (a new rig, a new
monitor) or the user accepts it (:meth:`DriftWatch.accept`: the current
level becomes the baseline; a further growth is flagged again).

Cost per frame: one gather and a few comparisons on the subsample
(vectorised numpy, about 0.1 ms at 640x480 with stride 4).
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np
from numba import njit

from depthguard.calibration.residuals import depth_sigma_of, edge_mask

__all__ = ["DriftWatch", "MIN_JUDGED", "ABS_MARGIN"]

#: fewer non-occluded valid samples than this: the frame cannot be judged
MIN_JUDGED = 200
#: added to k sigma(z) (m): the CAD's and the mounting's tolerance
ABS_MARGIN = 0.01


class DriftWatch:
    """The drift statistic and latch of one camera (module docstring).

    cam : the :class:`~depthguard.camera.Camera` (rig pose); static : (H, W) float32 m, the
    expected depth of the static scene (0 = nothing); k_sigma, share, frames : the monitor's
    ``drift_sigma``, ``drift_share``, ``drift_frames``; stride : 0 = chosen for about 10000 samples;
    sigma : (H, W) float32 m or None, a per-pixel noise that floors the sensor model's (a learned
    scene's observed spread, issue 31).

    ``update(depth, stamp)`` per frame (worker thread); ``untrusted``, ``message``, ``share``
    (last judged statistic), ``flagged_at`` (stamp of the frame that flagged) are read by the
    control thread (plain attribute reads).
    """

    def __init__(self, cam, static: np.ndarray, k_sigma: float = 3.0, share: float = 0.02, frames: int = 3,
                 stride: int = 0, sigma=None):
        H, W = cam.shape
        if stride <= 0:
            stride = max(1, int(round(np.sqrt(H * W / 10000.0))))
        self.camera_id = cam.id
        self.stride = int(stride)
        s = np.asarray(static, dtype=np.float32)
        ok = (s >= cam.min_range) & (s <= cam.max_range)
        edges = edge_mask(s)
        from scipy.ndimage import binary_dilation
        ok &= ~binary_dilation(edges, iterations=2)
        grid = np.zeros((H, W), dtype=bool)
        grid[::self.stride, ::self.stride] = True
        self.index = np.flatnonzero(ok & grid)
        z = s.ravel()[self.index].astype(np.float64)
        self.expected = z.astype(np.float32)
        sig = depth_sigma_of(cam, z)
        if sigma is not None:
            sig = np.maximum(sig, np.asarray(sigma, dtype=np.float64).ravel()[self.index])
        tol = k_sigma * sig + ABS_MARGIN
        self.far_limit = (z + tol).astype(np.float32)
        self.near_limit = (z - tol).astype(np.float32)
        self.k_sigma, self.share_limit, self.frames_needed = float(k_sigma), float(share), int(frames)
        self.baseline = 0.0
        self._lock = threading.Lock()
        self._run = 0
        self._recent: deque = deque(maxlen=15)
        self.share = float("nan")
        self.judged = 0
        self.untrusted = False
        self.message = ""
        self.flagged_at = float("nan")

    @property
    def samples(self) -> int:
        """Number of sampled pixels (0: this camera sees no static scene; it is never judged)."""
        return int(self.index.size)

    def statistic(self, depth: np.ndarray) -> tuple[float, int]:
        """``(share farther than expected, judged samples)`` of one (H, W) frame (module docstring);
        ``(nan, n)`` when fewer than :data:`MIN_JUDGED` samples can be judged. One compiled loop
        over the samples (:func:`_drift_counts`; nothing allocated for a C-contiguous float
        frame), the same counts as :meth:`statistic_numpy`."""
        d = np.asarray(depth)
        if d.dtype in (np.float32, np.float64) and d.flags.c_contiguous:
            far, n = _drift_counts(d.reshape(-1), self.index, self.near_limit, self.far_limit)
        else:
            far, n = self._counts_numpy(d)
        if n < MIN_JUDGED:
            return float("nan"), int(n)
        return float(far) / n, int(n)

    def statistic_numpy(self, depth: np.ndarray) -> tuple[float, int]:
        """The plain-numpy twin of :meth:`statistic`."""
        far, n = self._counts_numpy(np.asarray(depth))
        if n < MIN_JUDGED:
            return float("nan"), n
        return float(far) / n, n

    def _counts_numpy(self, depth: np.ndarray) -> tuple[int, int]:
        m = depth.ravel()[self.index]
        with np.errstate(invalid="ignore"):
            far = m > self.far_limit
            seen = (m >= self.near_limit) & np.isfinite(m)      # valid and not occluded
        return int(far.sum()), int(seen.sum())

    def update(self, depth: np.ndarray, stamp: float) -> bool:
        """Judge one frame; True when this frame flagged the camera."""
        if not self.index.size:
            return False
        share, n = self.statistic(depth)
        if share != share:                 # nan: cannot judge, nothing changes
            return False
        with self._lock:
            self.share = share
            self.judged += 1
            self._recent.append(share)
            if share > self.baseline + self.share_limit:
                self._run += 1
            else:
                self._run = 0
            if not self.untrusted and self._run >= self.frames_needed:
                # the message first: the control thread reads ``untrusted`` without the lock
                self.flagged_at = float(stamp)
                self.message = (f"camera {self.camera_id}: {100 * share:.1f} % of the pixels that see the known "
                                f"scene measure farther than it (> {self.k_sigma:g} sigma + "
                                f"{ABS_MARGIN * 100:g} cm; allowed {100 * (self.baseline + self.share_limit):.1f} %) "
                                f"in {self._run} frames: the camera moved or the scene changed - untrusted until "
                                f"recalibrated (depthguard calibrate) or accepted (R34)")
                self.untrusted = True
                return True
        return False

    def accept(self) -> None:
        """The user trusts the camera as it is now: clear the flag; the current level (the median of
        the recent judged frames) becomes the baseline, so a further growth is flagged again."""
        with self._lock:
            self.baseline = float(np.median(self._recent)) if self._recent else 0.0
            self.untrusted = False
            self.message = ""
            self._run = 0
            self.flagged_at = float("nan")


@njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def _drift_counts(flat, index, near_limit, far_limit):
    """``(far, seen)`` of :meth:`DriftWatch.statistic` over the samples ``index`` (S,) int64 of the
    frame ``flat`` (H * W,) m: ``far`` the samples measured beyond ``far_limit`` (S,) float32 m
    (+inf included, as numpy counts it), ``seen`` those at or beyond ``near_limit`` (S,) and
    finite (valid and not occluded; a NaN fails the compare). Compared in float32 as numpy
    compares a float32 frame with the float32 limits (a float64 frame: in float64)."""
    far = 0
    seen = 0
    for i in range(index.shape[0]):
        m = flat[index[i]]
        far += m > far_limit[i]
        seen += (m >= near_limit[i]) & (m != np.inf)
    return far, seen
