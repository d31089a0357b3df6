"""Rotations as rotation vectors (axis * angle, radians), vectorised, with the exact derivative used by the
bundle adjustment. Conversions delegate to scipy; only the derivative is ours.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

_SMALL_ANGLE_RAD = 1e-5


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 3, 3) rotation matrices (same as cv2.Rodrigues)."""
    rotvec = np.asarray(rotvec, dtype=float)
    flat = rotvec.reshape(-1, 3)
    return Rotation.from_rotvec(flat).as_matrix().reshape(*rotvec.shape[:-1], 3, 3)


def matrix_to_rotvec(matrix: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) rotation vectors with angle in [0, pi]."""
    matrix = np.asarray(matrix, dtype=float)
    flat = matrix.reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape(*matrix.shape[:-2], 3)


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices [v]_x."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def right_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) right Jacobian J_r of SO(3): R(r + dr) ~= R(r) exp([J_r(r) dr]_x)."""
    r = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    K2 = K @ K
    small = theta < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    cube = safe * safe * safe  # not safe ** 3: np.power is Intel's SVML on an AVX-512 CPU (docs/benchmarks.md)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (safe - np.sin(safe)) / cube)
    return np.eye(3) - a * K + b * K2


def d_rotate_d_rotvec(rotvec: np.ndarray, R: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Derivative of R(r) @ X with respect to the rotation vector r.

    Args:
        rotvec: (..., 3) rotation vectors; R: (..., 3, 3) their matrices; X: (..., 3) points.
    Returns:
        (..., 3, 3) with [..., i, j] = d(R X)_i / d r_j, equal to -R [X]_x J_r(r).
    """
    return -R @ skew(X) @ right_jacobian(rotvec)


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """(...,) angle of ``R_a @ R_b.T`` in degrees, for (..., 3, 3) rotations."""
    rel = np.asarray(R_a) @ np.swapaxes(np.asarray(R_b), -1, -2)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    vee = np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(vee, axis=-1) / 2.0, cos))  # accurate near 0, unlike arccos


def rigid_fit(A: np.ndarray, B: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The rotation and translation (no scale) taking the points A (K, 3) onto B (K, 3) in weighted least squares:
    (R (3, 3), t (3,)) minimising ``sum w |R A + t - B|^2`` with det R = +1 (w (K,); None: equal). The rotation is
    scipy's weighted Kabsch (``Rotation.align_vectors``) on the centred points."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    w = np.ones(len(A)) if w is None else np.asarray(w, dtype=float)
    ca, cb = (w @ A) / w.sum(), (w @ B) / w.sum()
    R = Rotation.align_vectors(B - cb, A - ca, weights=w)[0].as_matrix()
    return R, cb - R @ ca
