"""Repulsive velocity at the end effector and the risk function (R13, R14).

Flacco 2014 §5.1, eqs. (16)–(18), (20), with the SPEC's sign **[fix]**: the
distance direction ``V`` points from the control point *towards* the
obstacle, so the repulsion is ``−v(D)·V`` (away from it).

    v(D) = Vmax / (1 + exp((D·2/ρ − 1)·α))          (R13, eq. 17)
    f(D) = 1    / (1 + exp((D·2/ρ − 1)·α))          (R14, eq. 20)
    ẋ_rep = −v(D) · V,   ẋ_c = ẋ_d + ẋ_rep

Values at the ends of the region of surveillance (exact, not limits):

* ``D = 0``: ``v = Vmax / (1 + e^{−α})`` — 0.9933·Vmax for α = 5, not Vmax.
* ``D = ρ``: ``v = Vmax / (1 + e^{α})`` — 0.0067·Vmax (1.0 cm/s for
  Vmax = 1.5 m/s, α = 5), small but not zero. Beyond ρ the distance function
  reports ``D = inf`` ("no obstacle within ρ", R7) and the repulsion is
  exactly 0, so a step of ``Vmax/(1+e^α)`` occurs when an obstacle crosses ρ.
  We keep the paper's formula (SPEC R13) and accept this 1 cm/s step.
* ``D = inf``: 0 (no repulsion), never NaN.
"""

from __future__ import annotations

import numpy as np

__all__ = ["risk", "repulsive_magnitude", "repulsive_velocity", "check_repulsion_params"]


def check_repulsion_params(rho: float, alpha: float, v_max: float | None = None) -> None:
    """Raise ``ValueError`` unless ``rho > 0``, ``alpha > 0`` (and ``v_max >= 0``)."""
    if not (np.isfinite(rho) and rho > 0):
        raise ValueError(f"rho must be a positive distance in metres, got {rho!r}")
    if not (np.isfinite(alpha) and alpha > 0):
        raise ValueError(f"alpha (shape factor) must be > 0, got {alpha!r}")
    if v_max is not None and not (np.isfinite(v_max) and v_max >= 0):
        raise ValueError(f"v_max must be a finite speed >= 0 m/s, got {v_max!r}")


def risk(D, rho: float, alpha: float) -> np.ndarray:
    """Risk of collision ``f(D) = 1 / (1 + exp((2D/ρ − 1)·α))`` (R14, eq. 20).

    ``D``: scalar or (N,) distances in metres, ``inf`` = no obstacle within ρ
    (f = 0). Negative or NaN distances are rejected. Returns float64 of the
    shape of ``D``, values in (0, 1).
    """
    check_repulsion_params(rho, alpha)
    d = np.asarray(D, dtype=np.float64)
    if np.any(np.isnan(d)) or np.any(d < 0):
        raise ValueError("distances D must be >= 0 or inf (no obstacle within rho); got NaN or negative")
    with np.errstate(over="ignore"):
        e = np.exp((d * (2.0 / rho) - 1.0) * alpha)   # inf for D = inf -> f = 0
    return 1.0 / (1.0 + e)


def repulsive_magnitude(D, rho: float, v_max: float, alpha: float) -> np.ndarray:
    """``v(D) = Vmax · f(D)`` in m/s (R13, eq. 17); 0 for ``D = inf``."""
    check_repulsion_params(rho, alpha, v_max)
    return v_max * risk(D, rho, alpha)


def repulsive_velocity(D, V, rho: float, v_max: float, alpha: float) -> np.ndarray:
    """Repulsive velocity ``ẋ_rep = −v(D)·V`` (R13 with the sign [fix]).

    ``D``: scalar or (N,) hybrid distances (m, ``inf`` = nothing within ρ);
    ``V``: (3,) or (N, 3) unit vectors in the world frame pointing *towards*
    the obstacle (the direction of ``depth_space_distance``/``DepthGridMap``).
    Returns (3,) or (N, 3) m/s, pointing away from the obstacle; exactly 0
    where ``D = inf`` (whatever ``V`` holds there, e.g. NaN).
    """
    d = np.asarray(D, dtype=np.float64)
    v = np.asarray(V, dtype=np.float64)
    if v.shape[-1:] != (3,) or v.shape[:-1] != d.shape:
        raise ValueError(f"V must have shape D.shape + (3,) = {d.shape + (3,)}, got {v.shape}")
    mag = repulsive_magnitude(d, rho, v_max, alpha)
    out = -mag[..., None] * np.where(np.isfinite(d)[..., None], v, 0.0)
    return out
