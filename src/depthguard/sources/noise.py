"""Noise models of simulated depth cameras (SPEC §1, issue 2 §6).

Each model turns an *ideal* depth image (rendered, ``(H, W)`` metres, 0 where
nothing was hit) into a *measured* one, the way the sensor would:

- ``structured_light`` (Kinect v1): depth ``z`` becomes disparity
  ``δ = fx·b / z`` (pixels), Gaussian disparity noise ``σ_δ`` is added, the
  disparity is quantised to ``1 / 2**disparity_bits`` pixel (1/8 for the
  Kinect) and turned back into depth. ``σ_δ = sigma_z2 · fx · b`` so that
  the depth noise before quantisation is ``σ_z = sigma_z2 · z²``; the
  quantisation steps in depth are ``Δz ≈ z² / (fx · b · 2**bits)``.
- ``stereo`` (RealSense D435): ``z + N(0, σ)``, ``σ = sigma_a + sigma_z2·z²``.
- ``tof`` (time of flight): ``z + N(0, σ)``, ``σ = sigma_a + sigma_z2·z²``
  (about 1 cm), and *flying pixels*: a share ``flying_fraction`` of the
  pixels on a depth edge between two surfaces take a depth uniformly
  between the two sides.
- ``ideal``: no noise.

For all models: pixels on a depth edge miss their return with probability
``edge_dropout`` (→ 0), and measured depths outside ``[min_range,
max_range]`` are invalid (→ 0). In noiseless mode only the range rule is
applied, to the ideal depth.

A depth *edge* pixel is a valid pixel with a 4-neighbour that is either
invalid (a silhouette against nothing) or differs in depth by more than
``jump_abs + jump_rel · min(z_p, z_q)`` metres.

All randomness comes from the ``numpy.random.Generator`` passed in, so the
output is a deterministic function of the input and the generator's state.
The workspace :class:`NoiseWorkspace` holds the scratch buffers, reused
from call to call.
"""

from __future__ import annotations

import numpy as np

from depthguard.sources.sensors import SensorModel

__all__ = ["NoiseWorkspace", "apply_noise", "depth_edges", "kinect_quantise", "depth_sigma",
           "EDGE_JUMP_ABS", "EDGE_JUMP_REL"]

EDGE_JUMP_ABS = 0.03   # metres
EDGE_JUMP_REL = 0.02   # per metre of depth


class NoiseWorkspace:
    """Preallocated scratch buffers for :func:`apply_noise` on ``(H, W)`` images."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = tuple(int(s) for s in shape)
        self.z = np.empty(self.shape, np.float64)       # working depth
        self.gauss = np.empty(self.shape, np.float64)   # N(0, 1) draws
        self.uni = np.empty(self.shape, np.float64)     # U(0, 1) draws (flying pixels)
        self.uni2 = np.empty(self.shape, np.float64)    # U(0, 1) draws (edge dropout)
        self.other = np.empty(self.shape, np.float64)   # depth across the edge
        self.jump = np.empty(self.shape, np.float64)    # largest |depth step| to a neighbour
        self.edge = np.empty(self.shape, bool)
        self.valid = np.empty(self.shape, bool)
        self.mask = np.empty(self.shape, bool)


def depth_sigma(model: SensorModel, z: np.ndarray | float) -> np.ndarray | float:
    """Standard deviation (metres) of the Gaussian depth noise at depth ``z``: ``sigma_a + sigma_z2·z²``.

    For the Kinect this is the noise before disparity quantisation.
    """
    return model.sigma_a + model.sigma_z2 * np.square(z)


def kinect_quantise(z: np.ndarray, fx: float, baseline: float, bits: int,
                    disparity_noise: np.ndarray | None = None) -> np.ndarray:
    """Depth through quantised disparity: ``fx·b / (round((fx·b/z + n)·2**bits) / 2**bits)``.

    ``z``: depths (> 0), metres; ``disparity_noise``: optional pixels added to
    the disparity before quantisation. Returns depths in metres; 0 where the
    quantised disparity is ≤ 0 (beyond any range).
    """
    z = np.asarray(z, dtype=np.float64)
    fb = fx * baseline
    steps = float(2 ** bits)
    disp = fb / z
    if disparity_noise is not None:
        disp = disp + disparity_noise
    q = np.rint(disp * steps) / steps
    with np.errstate(divide="ignore"):
        return np.where(q > 0, fb / np.where(q > 0, q, 1.0), 0.0)


def depth_edges(depth: np.ndarray, jump_abs: float = EDGE_JUMP_ABS, jump_rel: float = EDGE_JUMP_REL,
                ws: NoiseWorkspace | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Edge pixels of a depth image and the depth on the other side.

    Returns ``(edge, other)``: ``edge`` (H, W) bool marks valid pixels next
    to an invalid pixel or to a depth step larger than
    ``jump_abs + jump_rel·min(z_p, z_q)``; ``other`` (H, W) float64 holds,
    for edge pixels, the depth of the 4-neighbour with the largest step
    (0 when the largest step is to an invalid pixel). The arrays belong to
    ``ws`` when given (overwritten by the next call).
    """
    d = np.asarray(depth)
    ws = ws or NoiseWorkspace(d.shape)
    z, valid, edge, other, jump = ws.z, ws.valid, ws.edge, ws.other, ws.jump
    np.copyto(z, d)
    np.greater(z, 0.0, out=valid)
    valid &= np.isfinite(z)
    z[~valid] = 0.0
    edge.fill(False)
    other.fill(0.0)
    jump.fill(0.0)
    H, W = z.shape
    # four neighbours: (slice of p, slice of q)
    shifts = (
        ((slice(None), slice(1, None)), (slice(None), slice(0, W - 1))),
        ((slice(None), slice(0, W - 1)), (slice(None), slice(1, None))),
        ((slice(1, None), slice(None)), (slice(0, H - 1), slice(None))),
        ((slice(0, H - 1), slice(None)), (slice(1, None), slice(None))),
    )
    for sp, sq in shifts:
        zp, zq = z[sp], z[sq]
        vp, vq = valid[sp], valid[sq]
        step = np.where(vq, np.abs(zp - zq), np.inf)
        is_edge = vp & ((~vq) | (step > jump_abs + jump_rel * np.minimum(zp, zq)))
        larger = is_edge & (step > jump[sp])
        jump[sp] = np.where(larger, step, jump[sp])
        other[sp] = np.where(larger, zq, other[sp])
        edge[sp] |= is_edge
    return edge, other


def apply_noise(ideal: np.ndarray, model: SensorModel, fx: float, rng: np.random.Generator,
                min_range: float | None = None, max_range: float | None = None,
                noiseless: bool = False, ws: NoiseWorkspace | None = None,
                out: np.ndarray | None = None) -> np.ndarray:
    """Measured depth from ideal depth with ``model``'s noise (module docstring).

    Parameters
    ----------
    ideal : (H, W) float, metres; 0 / non-finite = nothing hit.
    model : the sensor model (``sources/sensors.py``).
    fx : focal length in pixels (the Kinect disparity depends on it).
    rng : the generator all random draws come from.
    min_range, max_range : valid range in metres (default: the model's).
    noiseless : only the range rule, no noise, no dropout.
    ws, out : optional preallocated workspace and (H, W) float32 output.

    Returns
    -------
    (H, W) float32 metres, 0 = invalid.
    """
    d = np.asarray(ideal)
    if d.ndim != 2:
        raise ValueError(f"ideal depth must be a 2-D image, got shape {d.shape}")
    lo = model.min_range if min_range is None else float(min_range)
    hi = model.max_range if max_range is None else float(max_range)
    if ws is None or ws.shape != d.shape:
        ws = NoiseWorkspace(d.shape)
    if out is None:
        out = np.empty(d.shape, np.float32)
    elif out.shape != d.shape or out.dtype != np.float32:
        raise ValueError(f"out must be float32 of shape {d.shape}, got {out.dtype} {out.shape}")

    if noiseless or model.kind == "ideal":
        z = ws.z
        np.copyto(z, d)
        z[~np.isfinite(z)] = 0.0
    else:
        edge, other = depth_edges(d, ws=ws)   # fills ws.z, ws.valid too
        z, valid = ws.z, ws.valid
        rng.standard_normal(out=ws.gauss)
        rng.random(out=ws.uni)
        rng.random(out=ws.uni2)
        if model.kind == "structured_light":
            fb = fx * model.baseline
            if fb <= 0 or model.disparity_bits <= 0:
                raise ValueError(f"sensor {model.name!r}: structured light needs baseline > 0 and disparity_bits > 0")
            zq = kinect_quantise(np.where(valid, z, 1.0), fx, model.baseline, model.disparity_bits,
                                 disparity_noise=ws.gauss * (model.sigma_z2 * fb))
            if model.sigma_a:  # a depth-independent term on top, from its own draws
                rng.standard_normal(out=ws.jump)
                zq = zq + model.sigma_a * ws.jump
            np.copyto(z, np.where(valid, zq, 0.0))
        elif model.kind in ("stereo", "tof"):
            sig = depth_sigma(model, z)
            z += sig * ws.gauss
            if model.kind == "tof" and model.flying_pixels and model.flying_fraction > 0:
                # the uniform draws decide (a) which edge pixels fly and (b) where they land
                fly = edge & (other > 0) & (ws.uni < model.flying_fraction)
                frac = ws.uni / model.flying_fraction  # U(0,1) again on the flying subset
                z[fly] = ideal_between(d, other, frac, fly)
        else:
            raise ValueError(f"sensor {model.name!r}: unknown kind {model.kind!r}")
        z[~valid] = 0.0
        if model.edge_dropout > 0:
            np.less(ws.uni2, model.edge_dropout, out=ws.mask)
            ws.mask &= edge
            z[ws.mask] = 0.0
    np.logical_or(z < lo, z > hi, out=ws.mask)
    z[ws.mask] = 0.0
    np.copyto(out, z, casting="same_kind")
    return out


def ideal_between(d: np.ndarray, other: np.ndarray, frac: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Flying-pixel depths ``z_p + frac·(z_other − z_p)`` on ``mask`` (1-D, mask order)."""
    zp = np.asarray(d, dtype=np.float64)[mask]
    return zp + frac[mask] * (other[mask] - zp)

