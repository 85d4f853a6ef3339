"""Several frames of one camera on a still scene fused into one depth image (R21, R25).

Before a machine moves, the space it moves into is judged from the cameras
(R21, R22). The scene is still for that moment, so each camera can give a few
consecutive frames; their per-pixel **median** has less noise than one frame
(for Gaussian noise ``sigma_med = c_n * sigma``: ``c_3 ≈ 0.670``, ``c_5 ≈
0.536``), so a smaller depth margin keeps the same safety and frees more of
the space just in front of surfaces.

A median is only right where the n measurements see the same surface. At a
depth edge the samples mix the near and the far side (ToF flying pixels, edge
dropouts), and anything that moves between frames makes them differ too;
there the median can lie *behind* the nearest surface — the wrong side for
safety. So, per pixel, with ``d_1 <= ... <= d_n`` the valid samples:

- all n valid and ``d_n - d_1 <= k_n * sigma(d_med)`` (the spread a still
  surface shows with probability ``p``, 0.999 by default: ``k_3 ≈ 5.1``,
  ``k_5 ≈ 5.5``): the **median**;
- otherwise, if at least half are valid: the **nearest**, ``d_1`` (what a
  camera saw closest in the window: never behind anything it saw);
- otherwise: invalid (0).

``sigma(z) = sigma_a + sigma_z2 * z**2`` is the sensor's depth noise
(:func:`depthguard.sources.noise.depth_sigma`). The fused image then has the
noise ``c_n * sigma`` where the samples agreed; a free-space margin of
``2 * c_n * sigma`` has the safety of a 2 sigma margin on one frame.

:func:`fuse_kernel` is the numba kernel (parallel over rows, no allocation);
:func:`fuse_numpy` its plain-numpy twin for the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numba
import numpy as np

__all__ = ["StillFusion", "median_noise_factor", "range_quantile", "fuse_kernel", "fuse_numpy"]

MAX_FRAMES = 15


def _phi_cdf(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


_X = np.linspace(-9.0, 9.0, 7201)
_PDF = np.exp(-0.5 * _X ** 2) / math.sqrt(2.0 * math.pi)


def median_noise_factor(n: int) -> float:
    """``c_n``: standard deviation of the median of ``n`` (odd) independent standard normal
    samples, by integrating the density of the middle order statistic."""
    n = _check_n(n)
    m = n // 2
    F = _phi_cdf(_X)
    f = math.comb(n, m) * (n - m) * F ** m * (1.0 - F) ** m * _PDF
    return float(math.sqrt(np.trapezoid(_X ** 2 * f, _X)))


def range_quantile(n: int, p: float = 0.999) -> float:
    """``k``: the ``p``-quantile of the range ``max - min`` of ``n`` independent standard normal
    samples (``P(range <= r) = n ∫ φ(x) (Φ(x + r) - Φ(x))^(n-1) dx``, solved by bisection)."""
    n = _check_n(n)
    if not (0.0 < p < 1.0):
        raise ValueError(f"p must lie in (0, 1), got {p!r}")
    if n == 1:
        return 0.0
    F = _phi_cdf(_X)
    dx = _X[1] - _X[0]

    def cdf(r):
        shift = int(round(r / dx))
        Fr = np.concatenate([F[shift:], np.ones(shift)])
        return n * np.trapezoid(_PDF * (Fr - F) ** (n - 1), _X)

    lo, hi = 0.0, 12.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < p else (lo, mid)
    return 0.5 * (lo + hi)


def _check_n(n) -> int:
    if not (isinstance(n, (int, np.integer)) and 1 <= n <= MAX_FRAMES and n % 2 == 1):
        raise ValueError(f"the number of frames must be odd and in 1..{MAX_FRAMES}, got {n!r}")
    return int(n)


@dataclass(frozen=True)
class StillFusion:
    """Fusion of ``n`` frames of a camera on a still scene (module docstring).

    ``sigma_a`` (m) and ``sigma_z2`` (1/m): the sensor's depth noise ``sigma_a + sigma_z2 z²``
    (:class:`~depthguard.sensors.SensorModel`); ``p``: how often a still surface's
    samples must count as agreeing.
    """
    n: int
    sigma_a: float
    sigma_z2: float = 0.0
    p: float = 0.999
    factor: float = field(init=False)     # c_n: noise of the median / noise of one sample
    k: float = field(init=False)          # agreement limit on the spread, in sigma

    def __post_init__(self):
        _check_n(self.n)
        if not (math.isfinite(self.sigma_a) and math.isfinite(self.sigma_z2) and self.sigma_a >= 0
                and self.sigma_z2 >= 0 and self.sigma_a + self.sigma_z2 > 0):
            raise ValueError(f"sensor noise must be sigma_a >= 0, sigma_z2 >= 0, not both 0 "
                             f"(got {self.sigma_a!r}, {self.sigma_z2!r})")
        object.__setattr__(self, "factor", median_noise_factor(self.n))
        object.__setattr__(self, "k", range_quantile(self.n, self.p))

    @classmethod
    def for_sensor(cls, model, n: int, p: float = 0.999) -> "StillFusion":
        """From a :class:`~depthguard.sensors.SensorModel` (its Gaussian depth noise)."""
        return cls(n, float(model.sigma_a), float(model.sigma_z2), p)

    def sigma(self, z: float) -> float:
        """Noise (m) of the fused depth at ``z`` m where the samples agreed: ``c_n * sigma(z)``."""
        return self.factor * (self.sigma_a + self.sigma_z2 * z * z)

    def fuse(self, frames: Sequence[np.ndarray] | np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``n`` depth images (each (H, W), metres, 0 / NaN = invalid) -> (H, W) float32."""
        stack = np.asarray(frames)
        if stack.ndim != 3 or stack.shape[0] != self.n:
            raise ValueError(f"need {self.n} frames of shape (H, W), got an array of shape {stack.shape}")
        stack = np.ascontiguousarray(stack, dtype=np.float32)
        if out is None:
            out = np.empty(stack.shape[1:], np.float32)
        elif out.shape != stack.shape[1:] or out.dtype != np.float32:
            raise ValueError(f"out must be float32 of shape {stack.shape[1:]}, got {out.dtype} {out.shape}")
        return fuse_kernel(stack, self.k, self.sigma_a, self.sigma_z2, out)


@numba.njit(cache=True, parallel=True, nogil=True)
def fuse_kernel(stack, k, sigma_a, sigma_z2, out):
    """Kernel of :meth:`StillFusion.fuse`: ``stack`` (n, H, W) float32 -> ``out`` (H, W) float32."""
    n, H, W = stack.shape
    for v in numba.prange(H):
        buf = np.empty(n, np.float32)
        for u in range(W):
            m = 0
            for i in range(n):                   # the valid samples, insertion-sorted
                d = stack[i, v, u]
                if d > 0.0 and math.isfinite(d):
                    j = m
                    while j > 0 and buf[j - 1] > d:
                        buf[j] = buf[j - 1]
                        j -= 1
                    buf[j] = d
                    m += 1
            if 2 * m < n + 1:
                out[v, u] = 0.0
                continue
            med = buf[n // 2]
            s = sigma_a + sigma_z2 * med * med
            if m == n and buf[n - 1] - buf[0] <= k * s:
                out[v, u] = med
            else:
                out[v, u] = buf[0]
    return out


def fuse_numpy(stack: np.ndarray, k: float, sigma_a: float, sigma_z2: float) -> np.ndarray:
    """Plain-numpy twin of :func:`fuse_kernel` (returns (H, W) float32)."""
    st = np.asarray(stack, dtype=np.float32)
    n = st.shape[0]
    valid = np.isfinite(st) & (st > 0)
    nv = valid.sum(axis=0)
    srt = np.sort(np.where(valid, st, np.float32(np.inf)), axis=0)   # invalid last
    nearest = srt[0]
    med = srt[n // 2]
    med64 = med.astype(np.float64)
    with np.errstate(invalid="ignore"):
        s = float(sigma_a) + float(sigma_z2) * med64 * med64          # float64, as in the kernel
        agree = (nv == n) & ((srt[n - 1] - srt[0]) <= float(k) * s)
    out = np.where(agree, med, nearest)
    return np.where(2 * nv >= n + 1, out, 0.0).astype(np.float32)
