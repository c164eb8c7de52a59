"""Rigid transforms in SE(3): quaternions ``(x, y, z, w)``, homogeneous 4x4 matrices, slerp."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "check_rigid",
    "invert_transform",
    "matrix_to_quaternion",
    "quaternion_to_matrix",
    "rotate_vectors",
    "slerp",
    "transform_matrix",
]


def normalize_quaternions(q: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
        raise ValueError("rotation quaternions must be finite and non-zero")
    return q / norm


def quaternion_to_matrix(q: Any) -> np.ndarray:
    """Rotation matrices of unit quaternions ``(x, y, z, w)``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    numpy.ndarray, shape (..., 3, 3)
    """
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.empty(q.shape[:-1] + (3, 3), dtype=np.float64)
    m[..., 0, 0] = 1 - 2 * (yy + zz)
    m[..., 0, 1] = 2 * (xy - wz)
    m[..., 0, 2] = 2 * (xz + wy)
    m[..., 1, 0] = 2 * (xy + wz)
    m[..., 1, 1] = 1 - 2 * (xx + zz)
    m[..., 1, 2] = 2 * (yz - wx)
    m[..., 2, 0] = 2 * (xz - wy)
    m[..., 2, 1] = 2 * (yz + wx)
    m[..., 2, 2] = 1 - 2 * (xx + yy)
    return m


def matrix_to_quaternion(m: Any) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)``, ``w >= 0``, of a 3x3 rotation (or 4x4 transform).

    Parameters
    ----------
    m : array_like, shape (3, 3) or (4, 4)

    Returns
    -------
    numpy.ndarray, shape (4,)
    """
    r = np.asarray(m, dtype=np.float64)[:3, :3]
    tr = np.trace(r)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s]
    qa = np.asarray(q, dtype=np.float64)
    qa /= np.linalg.norm(qa)
    return -qa if qa[3] < 0 else qa


def transform_matrix(translation: Any, rotation: Any) -> np.ndarray:
    """Homogeneous matrices from translations and quaternions ``(x, y, z, w)``.

    Parameters
    ----------
    translation : array_like, shape (..., 3)
    rotation : array_like, shape (..., 4)
        Normalized here.

    Returns
    -------
    numpy.ndarray, shape (..., 4, 4)
    """
    t = np.asarray(translation, dtype=np.float64)
    q = normalize_quaternions(np.asarray(rotation, dtype=np.float64))
    shape = np.broadcast_shapes(t.shape[:-1], q.shape[:-1])
    m = np.zeros(shape + (4, 4), dtype=np.float64)
    m[..., :3, :3] = quaternion_to_matrix(q)
    m[..., :3, 3] = t
    m[..., 3, 3] = 1.0
    return m


def invert_transform(m: Any) -> np.ndarray:
    """Inverse of rigid homogeneous transforms (``R^T``, ``-R^T t``), shape (..., 4, 4)."""
    m = np.asarray(m, dtype=np.float64)
    if m.ndim == 2:
        rt = m[:3, :3].T
        out = np.eye(4)
        out[:3, :3] = rt
        out[:3, 3] = -(rt @ m[:3, 3])
        return out
    out = np.zeros_like(m)
    rt = np.swapaxes(m[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, m[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def rotate_vectors(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v (K, 3) rotated by unit quaternions q (K, 4) ``(x, y, z, w)``, one per row.

    ``v + w t + u x t`` with ``u = (x, y, z)`` and ``t = 2 u x v``: the product ``q v q*``
    without forming rotation matrices.
    """
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    vx, vy, vz = v[:, 0], v[:, 1], v[:, 2]
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    out = np.empty(v.shape, dtype=np.float64)
    out[:, 0] = vx + w * tx + (y * tz - z * ty)
    out[:, 1] = vy + w * ty + (z * tx - x * tz)
    out[:, 2] = vz + w * tz + (x * ty - y * tx)
    return out


def slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Shortest-arc slerp between unit quaternions (K, 4) at fractions a (K,)."""
    return slerp_at(q0, *slerp_arcs(q0, q1), a)


def slerp_arcs(q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`slerp` needs of each pair of unit quaternions (K, 4), whatever the
    fraction: ``q1`` on the short arc's side, the arc's angle and its sine (K,)."""
    d = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where((d < 0)[:, None], -q1, q1)
    theta = np.arccos(np.clip(np.abs(d), -1.0, 1.0))
    return q1, theta, np.sin(theta)


def slerp_at(
    q0: np.ndarray, q1: np.ndarray, theta: np.ndarray, sin_t: np.ndarray, a: np.ndarray
) -> np.ndarray:
    """Slerp at fractions a (K,) between q0 and q1 (K, 4) given their :func:`slerp_arcs`."""
    small = sin_t < 1e-9
    safe = np.where(small, 1.0, sin_t)
    w0 = np.where(small, 1.0 - a, np.sin((1.0 - a) * theta) / safe)
    w1 = np.where(small, a, np.sin(a * theta) / safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


#: largest deviation of R^T R from the identity (and of det R from 1) a rigid transform may have
RIGID_TOL = 1e-6


def check_rigid(T, what: str = "T") -> np.ndarray:
    """``T`` as a (4, 4) float64 C-contiguous array, or ``ValueError`` naming what is wrong:
    the shape, a NaN or infinite entry (with its index), a last row other than 0 0 0 1, a
    rotation part that is not orthonormal or is a reflection (det -1)."""
    try:
        A = np.array(T, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a 4x4 matrix of numbers, got {T!r}") from None
    if A.shape != (4, 4):
        raise ValueError(f"{what} must be a 4x4 homogeneous matrix, got shape {A.shape}")
    bad = np.argwhere(~np.isfinite(A))
    if len(bad):
        i, j = bad[0]
        raise ValueError(f"{what}[{i}, {j}] is {A[i, j]}: a transform must be finite")
    if not np.allclose(A[3], (0.0, 0.0, 0.0, 1.0), atol=1e-12, rtol=0.0):
        raise ValueError(
            f"{what} is not a rigid transform: its last row is "
            f"{np.array2string(A[3], precision=6)}, expected [0 0 0 1]"
        )
    R = A[:3, :3]
    dev = float(np.abs(R.T @ R - np.eye(3)).max())
    if dev > RIGID_TOL:
        raise ValueError(
            f"{what} is not a rigid transform: its rotation part is not orthonormal "
            f"(R^T R differs from the identity by {dev:.3g}; scale or shear?): "
            f"{np.array2string(R, precision=6)}"
        )
    det = float(np.linalg.det(R))
    if det < 0:
        raise ValueError(
            f"{what} is not a rigid transform: its rotation part is a reflection (det = {det:.6g})"
        )
    return np.ascontiguousarray(A)
