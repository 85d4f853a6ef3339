"""Measured against expected depth of the static scene: noise, residual statistics, verdict (R34).

A camera's pose is checked by comparing its measured depth (H, W) float32
metres with the depth the known static scene should give at that pose
(:class:`~depthguard.filtering.expected.ExpectedDepth` ``.static``). Only
pixels that can say something about the pose are compared:

- the static scene is expected there (``expected > 0``) within the camera's
  rated range, and the pixel is not on a depth edge of the expected image
  (mixed pixels, dropouts, flying pixels live there);
- the measurement is valid (finite, > 0, within the rated range);
- the robot is not expected there (its rendered silhouette, dilated by a
  margin: joints and pose are not exact).

Of those, a pixel measured **nearer** than expected by more than ``k`` sigma
(``k = 3``) is an occluder — a person, a box, a cable — and says nothing
about the pose; it is counted (``share_near``) but left out of the
statistics. A pixel measured **farther** than expected by more than ``k``
sigma sees through where the known scene should be: only a moved camera
(or a changed scene) does that (``share_far``). The median and the spread
(1.4826 MAD) of ``measured - expected`` are taken over the non-occluded
pixels.

Noise ``sigma(z)`` (metres) is the camera's sensor model
(:mod:`depthguard.sensors`): ``sigma_a + sigma_z2 z^2``, with the
Kinect's disparity quantisation step ``z^2 / (f b 2^bits)`` added as a
uniform error (``step / sqrt(12)``), never below :data:`SIGMA_FLOOR` (the
CAD's own accuracy). A camera without a sensor model gets
:data:`GENERIC_NOISE`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the noise law sigma(z) lives with the sensor models (the learned scene's band uses it too)
from depthguard.sensors import GENERIC_NOISE, SIGMA_FLOOR
from depthguard.sensors import depth_sigma as depth_sigma_of

__all__ = ["depth_sigma_of", "ResidualStats", "residual_stats", "comparable_mask", "edge_mask",
           "VERDICTS", "SIGMA_FLOOR", "GENERIC_NOISE", "K_SIGMA", "MIN_PIXELS"]

#: a pixel off by more than this many sigma is "off"
K_SIGMA = 3.0
#: fewer comparable pixels than this: the camera cannot be judged
MIN_PIXELS = 500
#: verdicts of a camera's check, best first; ``unknown`` = too few comparable pixels (cannot judge)
VERDICTS = ("good", "suspicious", "wrong", "unknown")

# verdict thresholds (shares of the non-occluded comparable pixels; see docs/CALIBRATION.md)
GOOD_FAR = 0.03          # at most 3 % farther than 3 sigma ...
GOOD_MEDIAN = 1.0        # ... and |median| at most 1 sigma (of the median depth)
WRONG_FAR = 0.10         # more than 10 % farther than 3 sigma
WRONG_NEAR = 0.60        # or more than 60 % nearer (the camera moved towards the scene)
BOTH_NEAR = 0.25         # or more than 3 % farther together with more than 25 % nearer


def edge_mask(expected: np.ndarray, jump_abs: float = 0.03, jump_rel: float = 0.02) -> np.ndarray:
    """(H, W) bool: pixels of an expected depth image on a depth edge — a 4-neighbour with
    nothing expected or a step larger than ``jump_abs + jump_rel * z`` metres."""
    e = np.asarray(expected, dtype=np.float32)
    out = np.zeros(e.shape, dtype=bool)
    for a, b in (((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                 ((slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
        za, zb = e[a], e[b]
        step = (np.abs(za - zb) > jump_abs + jump_rel * np.minimum(za, zb)) | (za <= 0) | (zb <= 0)
        out[a] |= step
        out[b] |= step
    return out


def comparable_mask(cam, measured: np.ndarray, expected: np.ndarray, robot: np.ndarray | None = None,
                    robot_margin_px: int = 4) -> np.ndarray:
    """(H, W) bool: the pixels worth comparing (module docstring) — expected static surface
    within the rated range, off its depth edges, valid measurement, no robot near."""
    m = np.asarray(measured, dtype=np.float32)
    e = np.asarray(expected, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        ok = (e >= cam.min_range) & (e <= cam.max_range) & np.isfinite(m) & (m >= cam.min_range) \
            & (m <= cam.max_range)
    ok &= ~edge_mask(e)
    if robot is not None:
        r = np.asarray(robot) > 0
        if r.any():
            if robot_margin_px > 0:
                from scipy.ndimage import binary_dilation
                r = binary_dilation(r, iterations=int(robot_margin_px))
            ok &= ~r
    return ok


@dataclass(frozen=True)
class ResidualStats:
    """Residuals ``measured - expected`` (m) of one camera against the static scene (R34).

    ``pixels``: comparable pixels; ``share_near`` of them nearer than ``K_SIGMA`` sigma
    (occluders: left out); ``share_far`` of the rest farther than ``K_SIGMA`` sigma;
    ``median``, ``spread`` (1.4826 MAD) in metres and ``median_sigma`` (the median in units of
    the noise at the median depth) over the non-occluded pixels; ``verdict`` one of
    :data:`VERDICTS`; ``reason`` a sentence.
    """
    pixels: int
    share_near: float
    share_far: float
    median: float
    spread: float
    median_sigma: float
    verdict: str
    reason: str

    def as_dict(self) -> dict:
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in self.__dict__.items()}

    def line(self) -> str:
        """One line for a report."""
        if self.verdict == "unknown":
            return f"unknown: {self.reason}"
        return (f"{self.verdict}: median {self.median * 1e3:+.1f} mm ({self.median_sigma:+.1f} sigma), "
                f"spread {self.spread * 1e3:.1f} mm, {100 * self.share_far:.1f} % farther and "
                f"{100 * self.share_near:.1f} % nearer than {K_SIGMA:g} sigma, {self.pixels} pixels"
                + ("" if self.verdict == "good" else f" - {self.reason}"))


def residual_stats(cam, measured: np.ndarray, expected: np.ndarray, robot: np.ndarray | None = None,
                   robot_margin_px: int = 4) -> ResidualStats:
    """Residual statistics and verdict of camera ``cam`` (module docstring).

    measured, expected : (H, W) float metres (0 = nothing); robot : optional (H, W) robot depth
    (> 0 where the robot is expected)."""
    ok = comparable_mask(cam, measured, expected, robot, robot_margin_px)
    n = int(ok.sum())
    if n < MIN_PIXELS:
        return ResidualStats(n, math.nan, math.nan, math.nan, math.nan, math.nan, "unknown",
                             f"only {n} pixels show the known static scene (fewer than {MIN_PIXELS}): "
                             f"the pose cannot be judged")
    e = np.asarray(expected, dtype=np.float64)[ok]
    r = np.asarray(measured, dtype=np.float64)[ok] - e
    s = depth_sigma_of(cam, e)
    near = r < -K_SIGMA * s
    keep = ~near
    share_near = float(near.mean())
    rk, sk = r[keep], s[keep]
    if rk.size < MIN_PIXELS:
        return ResidualStats(n, share_near, math.nan, math.nan, math.nan, math.nan, "wrong",
                             f"{100 * share_near:.0f} % of the {n} comparable pixels are nearer than the known "
                             f"scene: the camera moved towards it, or the cell is full of unknown objects")
    share_far = float((rk > K_SIGMA * sk).mean())
    med = float(np.median(rk))
    spread = float(1.4826 * np.median(np.abs(rk - med)))
    med_sigma = med / float(np.median(sk))
    if share_far > WRONG_FAR or share_near > WRONG_NEAR or (share_far > GOOD_FAR and share_near > BOTH_NEAR):
        verdict = "wrong"
        why = (f"{100 * share_far:.0f} % of the pixels see farther than the known scene allows"
               if share_far > WRONG_FAR else f"{100 * share_near:.0f} % of the pixels are nearer than the scene"
               if share_near > WRONG_NEAR else
               f"{100 * share_far:.1f} % of the pixels see farther and {100 * share_near:.0f} % nearer than the "
               f"scene: the scene is displaced both ways, as by a turned camera")
    elif share_far <= GOOD_FAR and abs(med_sigma) <= GOOD_MEDIAN:
        verdict, why = "good", "the measured depth matches the known scene within the sensor's noise"
    else:
        verdict = "suspicious"
        why = (f"{100 * share_far:.1f} % farther than {K_SIGMA:g} sigma (good: <= {100 * GOOD_FAR:.0f} %), "
               f"median {med_sigma:+.1f} sigma (good: within +-{GOOD_MEDIAN:g})")
    return ResidualStats(n, share_near, share_far, med, spread, med_sigma, verdict, why)
