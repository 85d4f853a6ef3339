"""Standard Denavit–Hartenberg tables as chains (R16).

Row ``i`` (joint ``i``, standard / distal DH as in Oščádal et al. 2022,
Algorithm 5)::

    ᶦ⁻¹Tᵢ = Rz(θᵢ) · Tz(dᵢ) · Tx(aᵢ) · Rx(αᵢ),     θᵢ = q_i + θ0ᵢ   (revolute)
                                                  dᵢ = q_i + d0ᵢ   (prismatic)

Since ``Rz`` and ``Tz`` commute, the joint motion comes first and the rest
is the fixed ``post`` transform of :class:`~depthguard.robot.chain.LinkSpec`:
``post = Rz(θ0) Tz(d0) Tx(a) Rx(α)``, motion about / along the local z axis.
Link ``i`` of the resulting chain *is* DH frame ``i``; link 0 (``base``) is
DH frame 0 and the last link the flange.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard.robot.chain import PRISMATIC, REVOLUTE, LinkSpec

__all__ = ["DHRow", "dh_transform", "dh_links"]


@dataclass(frozen=True)
class DHRow:
    """One standard DH row: lengths in metres, angles in radians."""
    d: float = 0.0
    a: float = 0.0
    alpha: float = 0.0
    theta: float = 0.0          # joint offset θ0 (revolute) or fixed θ (prismatic)
    prismatic: bool = False
    lower: float = -np.inf
    upper: float = np.inf
    vmax: float = np.inf


def dh_transform(d: float, a: float, alpha: float, theta: float) -> np.ndarray:
    """``Rz(θ) Tz(d) Tx(a) Rx(α)`` as a 4x4 matrix (the textbook closed form)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct],
                     [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def dh_links(rows: list[DHRow], link_names: list[str] | None = None,
             joint_names: list[str] | None = None, base_name: str = "base") -> list[LinkSpec]:
    """Chain rows for a serial DH robot: the base link plus one link per row."""
    n = len(rows)
    link_names = link_names or [f"link{i + 1}" for i in range(n)]
    joint_names = joint_names or [f"joint{i + 1}" for i in range(n)]
    if len(link_names) != n or len(joint_names) != n:
        raise ValueError(f"need {n} link and joint names for {n} DH rows")
    out = [LinkSpec(base_name)]
    parent = base_name
    for row, ln, jn in zip(rows, link_names, joint_names):
        post = dh_transform(row.d, row.a, row.alpha, row.theta)
        out.append(LinkSpec(ln, parent=parent, joint=jn, jtype=PRISMATIC if row.prismatic else REVOLUTE,
                            pre=np.eye(4), axis=np.array([0.0, 0.0, 1.0]), post=post,
                            lower=row.lower, upper=row.upper, vmax=row.vmax))
        parent = ln
    return out
