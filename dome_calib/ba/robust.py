"""Robust losses on the squared pixel error of one observation, as IRLS weights.

Each observation's squared reprojection error ``z = |r|^2`` (px^2) costs ``rho(z) / 2`` (the same convention as
Ceres: the loss acts on the squared norm of the 2-vector residual block). Gauss-Newton with the IRLS weight
``w = rho'(z)`` gives the exact gradient of the robust cost; ``scale_px`` is where the loss leaves the quadratic.

- trivial: rho(z) = z (least squares, the maximum-likelihood cost for Gaussian pixel noise);
- huber: rho(z) = z for sqrt(z) <= s, 2 s sqrt(z) - s^2 beyond (convex, bounded influence);
- cauchy: rho(z) = s^2 log(1 + z / s^2) (redescending: gross outliers get weight -> 0).
"""
from __future__ import annotations

from enum import StrEnum

import numpy as np


class LossKind(StrEnum):
    TRIVIAL = "trivial"
    HUBER = "huber"
    CAUCHY = "cauchy"


def robust_cost_and_weight(sq_error_px2: np.ndarray, kind: LossKind | str, scale_px: float
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(rho(z), rho'(z)) per observation for squared errors z (px^2); see the module docstring."""
    z = np.asarray(sq_error_px2, dtype=float)
    kind = LossKind(kind)
    if kind is LossKind.TRIVIAL:
        return z.copy(), np.ones_like(z)
    s = float(scale_px)
    s2 = s * s
    if kind is LossKind.HUBER:
        e = np.sqrt(z)
        outer = e > s
        rho = np.where(outer, 2.0 * s * e - s2, z)
        w = np.where(outer, s / np.where(outer, e, 1.0), 1.0)
        return rho, w
    rho = s2 * np.log1p(z / s2)
    return rho, 1.0 / (1.0 + z / s2)


def robust_sigma_px(residuals_px: np.ndarray) -> float:
    """Robust per-axis noise estimate (px) from (M, 2) residuals: the median of |r| scaled for a 2D Gaussian.

    For r ~ N(0, sigma^2 I_2), |r| is Rayleigh with median sigma * sqrt(2 ln 2).
    """
    norms = np.linalg.norm(np.asarray(residuals_px, dtype=float).reshape(-1, 2), axis=1)
    if len(norms) == 0:
        return 0.0
    return float(np.median(norms) / np.sqrt(2.0 * np.log(2.0)))
