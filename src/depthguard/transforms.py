"""Rigid transforms: 4x4 homogeneous matrices, quaternions ``xyzw`` (R2)."""

from __future__ import annotations

import numpy as np

__all__ = ["as_rigid", "invert_rigid", "quat_to_matrix", "matrix_to_quat", "pose",
           "rot_x", "rot_y", "rot_z", "look_at", "transform_points"]

ORTHO_TOL = 1e-6


def as_rigid(T: np.ndarray, tol: float = ORTHO_TOL) -> np.ndarray:
    """Validate a 4x4 rigid transform and return it as a float64 copy.

    Raises ``ValueError`` naming the problem: wrong shape, non-finite entries,
    a bottom row other than ``[0, 0, 0, 1]``, or a rotation block that is not
    orthonormal with determinant +1.
    """
    M = np.array(T, dtype=np.float64)
    if M.shape != (4, 4):
        raise ValueError(f"must be a 4x4 matrix, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError("has non-finite entries")
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise ValueError(f"bottom row must be [0, 0, 0, 1], got {M[3].tolist()}")
    R = M[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > tol:
        raise ValueError(f"rotation is not orthonormal (max |R^T R - I| = {err:.2e})")
    det = np.linalg.det(R)
    if det < 0:
        raise ValueError("rotation has determinant -1 (a reflection, not a rotation)")
    M[3] = [0.0, 0.0, 0.0, 1.0]
    return M


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def quat_to_matrix(q_xyzw: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` -> (3, 3) rotation.

    The norm must be within ``tol`` of 1 (a far-off norm is a typo, not a
    rotation); it is then normalised exactly.
    """
    q = np.asarray(q_xyzw, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"quaternion must be 4 finite numbers x, y, z, w (got {q_xyzw!r})")
    n = np.linalg.norm(q)
    if abs(n - 1.0) > tol:
        raise ValueError(f"quaternion must have unit norm (got norm {n:.6f})")
    x, y, z, w = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> unit quaternion ``(x, y, z, w)`` with ``w >= 0``."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def pose(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """4x4 transform from a rotation and a translation."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``world_from_camera`` of an OpenCV camera at ``eye`` looking at ``target``.

    The camera's z axis points at the target, its y axis down (against ``up``).
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    n = np.linalg.norm(z)
    if n == 0:
        raise ValueError("look_at: eye and target coincide")
    z /= n
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along up: pick any x
        x = np.cross(z, [1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return pose(np.stack([x, y, z], axis=1), eye)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]
