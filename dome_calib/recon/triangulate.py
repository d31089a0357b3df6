"""Robust weighted triangulation of 2D detections seen by many views, vectorised over a batch of points.

Pipeline per point (all points of a batch at once, no Python loop over points):

1. rays: detections -> undistorted normalised coordinates (batched Newton inverse of the lens model);
2. RANSAC over views: pairs of views give two-view (midpoint) hypotheses. A point with few views tries every pair;
   otherwise the pairs and the scoring views are drawn at random, and the draws of a point are a function of its
   own detections only (a counter-based hash of them, :func:`point_draws`), never of the batch it is in: the same
   detections give the same point whatever else is triangulated with them. Each hypothesis is refitted to the
   scoring views it explains (local optimisation, LO-RANSAC: within twice the threshold, then within it), and the
   refitted point explaining the most views wins, ties going to the truncated, confidence-weighted squared
   reprojection error (MSAC). A two-view point fits its two views exactly (two rays always meet), so scored on the
   error alone a pair beat three views that agree within the threshold whenever the midpoint of two of the three
   missed the third (Pose2Sim's real balancing trial: a phone's left hip 50 px from three that agree, winning with
   one of them in 9 of 10 frames); Pose2Sim's own triangulation also keeps the most cameras within its threshold;
3. weighted linear triangulation (DLT on the rays of the views the hypothesis explains, weights = confidence);
4. Levenberg-Marquardt on the confidence-weighted reprojection error ``sum_v c_v |pi_v(X) - u_v|^2`` over those
   views (the weighted cost of the Panoptic 3D node proposals), with the analytic point Jacobian of the camera model;
5. final inliers: views whose reprojection error is below ``inlier_threshold_px``.

Inputs are (P, V, 2) pixels and (P, V) confidences (0 or NaN pixels = no detection) for the views of a
:class:`~dome_calib.recon.project.ViewSet`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from dome_calib.camera import MIN_DEPTH
from dome_calib.options import AtLeast, options
from dome_calib.schema import NonNegFinite, PosFinite
from dome_calib.recon.errors import ReconError
from dome_calib.recon.kernel import F32, CameraKernel, Evaluation, normal_equations
from dome_calib.recon.project import ViewSet
from dome_calib.arrays import per_row
from dome_calib.rows import rows_product

logger = logging.getLogger(__name__)

#: Scale (cm) that conditions the DLT: world points are solved in metres.
_DLT_SCALE_CM = 100.0
#: Smallest sin^2 of the angle between the two rays of a RANSAC hypothesis (about 3 degrees).
_MIN_SIN2_PAIR = np.sin(np.radians(3.0)) ** 2


@options
class TriangulationOptions:
    """Options of :func:`triangulate`.

    inlier_threshold_px: a view supports a point if its reprojection error is below this (pixels of that view).
    ransac_hypotheses: two-view hypotheses per point. With 10 % wrong detections a random pair is clean with
        probability 0.81, so 16 hypotheses all fail with probability 0.19^16 ~ 3e-12. A point with so few views
        that it has no more pairs than this (6 views: 15 pairs) tries every pair instead.
    ransac_score_views: views (random subset of the point's detections) that score each hypothesis.
    lm_iterations: Levenberg-Marquardt iterations (each one projection; one is enough from the DLT start).
    min_views: fewer inlier views than this -> the point is not reconstructed (NaN, confidence -1).
    min_confidence: detections with confidence <= this are ignored.
    seed: mixed into every point's draws (results are reproducible; the draws depend on the point's own
        detections and this seed, not on the other points of the call).
    """

    inlier_threshold_px: PosFinite = 8.0
    ransac_hypotheses: AtLeast(1) = 16
    ransac_score_views: AtLeast(2) = 32
    lm_iterations: AtLeast(0) = 2
    min_views: AtLeast(2) = 2  # a point needs two views
    min_confidence: NonNegFinite = 0.0
    seed: AtLeast(0) = 0


@dataclass(frozen=True)
class Triangulation:
    """Result of :func:`triangulate` for P points and V views.

    X_cm (P, 3) world points (NaN where not reconstructed); confidence (P,) mean detection confidence of the
    inlier views (-1 where not reconstructed); inliers (P, V) bool; n_inliers (P,); rms_px (P,) RMS
    reprojection error over the inlier views.
    """

    X_cm: np.ndarray
    confidence: np.ndarray
    inliers: np.ndarray
    n_inliers: np.ndarray
    rms_px: np.ndarray


def undistort_detections(views: ViewSet | CameraKernel, uv_px: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(P, V, 2) pixels -> (P, V, 2) undistorted normalised coordinates (0 where not ``valid``).

    Batched Newton inverse of the lens model (:meth:`CameraKernel.undistort`, float32): enough for the
    initialisation; the refinement uses the exact forward model.
    """
    kernel = views if isinstance(views, CameraKernel) else CameraKernel(views)
    x, y = kernel.undistort(uv_px[..., 0], uv_px[..., 1])
    xn = np.stack([x, y], axis=-1).astype(float)
    return np.where(valid[..., None] & np.isfinite(xn), xn, 0.0)


def _dlt_blocks(views: ViewSet) -> np.ndarray:
    """(4, V, 16) per-view blocks so that the weighted DLT normal matrix is a product of (P, V) sums with them.

    For a view with P = [R | t] (metres) and ray (x, y): r1 = x P3 - P1, r2 = y P3 - P2 and
    r1 r1^T + r2 r2^T = (x^2 + y^2) P3 P3^T - x (P3 P1^T + P1 P3^T) - y (P3 P2^T + P2 P3^T) + P1 P1^T + P2 P2^T.
    """
    Pm = np.concatenate([views.R, views.t_cm[:, :, None] / _DLT_SCALE_CM], axis=2)  # (V, 3, 4)
    P1, P2, P3 = Pm[:, 0], Pm[:, 1], Pm[:, 2]
    outer = lambda a, b: np.einsum("vi,vj->vij", a, b).reshape(len(a), 16)  # noqa: E731
    return np.stack([outer(P3, P3), -(outer(P3, P1) + outer(P1, P3)), -(outer(P3, P2) + outer(P2, P3)),
                     outer(P1, P1) + outer(P2, P2)])


def triangulate_dlt(views: ViewSet, xn: np.ndarray, weight: np.ndarray, blocks: np.ndarray | None = None) -> np.ndarray:
    """Weighted linear triangulation of (P, V, 2) normalised rays with (P, V) weights -> (P, 3) cm.

    Minimises ``sum_v w_v (|x_v P3 - P1|^2 + |y_v P3 - P2|^2)`` over homogeneous X (rows of each view's [R | t]):
    the eigenvector of the smallest eigenvalue of the (P, 4, 4) normal matrix. Fewer than 2 weighted views: NaN.
    """
    blocks = _dlt_blocks(views) if blocks is None else blocks
    w = np.maximum(np.where(np.isfinite(weight), weight, 0.0), 0.0)
    x, y = xn[..., 0], xn[..., 1]
    # view by view in camera order, each point's four terms of a view together (dome_calib.rows: a BLAS product's
    # rows change their last bits with the batch's size, a batch of 2 times against 16)
    coefs = np.stack((w * (x * x + y * y), w * x, w * y, w), axis=2)  # (P, V, 4)
    coefs = per_row(coefs)  # (P, V * 4), for P = 0 too
    if blocks.ndim == 4:  # (4, P, K, 16): each point's own views (:func:`triangulate` ``few_views``)
        own = blocks.transpose(1, 2, 0, 3).reshape(len(coefs), coefs.shape[1], blocks.shape[-1])  # (P, K * 4, 16)
        normal = rows_product(coefs, own)
    else:
        normal = rows_product(coefs, blocks.transpose(1, 0, 2).reshape(coefs.shape[1], blocks.shape[-1]))
    _, vecs = np.linalg.eigh(normal.reshape(-1, 4, 4))
    Xh = vecs[:, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = Xh[:, :3] / Xh[:, 3:4] * _DLT_SCALE_CM
    X[(w > 0).sum(axis=1) < 2] = np.nan
    return X


def point_jacobian(views: ViewSet, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (P, V, 2) of (P, 3) points in every view and d(uv)/d(X) (P, V, 2, 3), float32 (NaN behind).

    The point block of :func:`dome_calib.camera.project_with_jacobians` (``d_point``), computed by the batched
    :class:`~dome_calib.recon.kernel.CameraKernel` that the refinement uses.
    """
    P, V = len(X_world), len(views.names)
    ev = CameraKernel(views).evaluate(X_world, np.zeros((P, V), F32), np.zeros((P, V), F32), jacobian=True)
    J = ev.J.reshape(P, 2, 3, V).transpose(0, 3, 1, 2)
    return np.stack([ev.r_u, ev.r_v], axis=-1), J


def reprojection_error_px(views: ViewSet, X_world: np.ndarray, uv_px: np.ndarray) -> np.ndarray:
    """(P, V) pixel distance between the projection of (P, 3) points and (P, V, 2) detections (NaN if none)."""
    return CameraKernel(views).reprojection_error_px(X_world, uv_px[..., 0].astype(F32), uv_px[..., 1].astype(F32))


def refine_lm(views: ViewSet | CameraKernel, X0: np.ndarray, uv_px: np.ndarray, weight: np.ndarray, *,
              iterations: int = 2, gate_px: float | None = None, penalty_px: float = 100.0
              ) -> tuple[np.ndarray, Evaluation]:
    """Levenberg-Marquardt on ``sum_v w_v |pi_v(X) - u_v|^2`` for each of P points independently (batched).

    Args: X0 (P, 3) cm start; uv_px (P, V, 2); weight (P, V) (0 = view unused); gate_px: if given, views whose
    residual at X0 is not below it get weight 0 (inlier gating on the first evaluation, saving a projection).
    Each point keeps its own damping; a step is kept only where it lowers that point's cost.
    Returns: (P, 3) cm and the residuals at the returned points (for inlier tests).
    """
    kernel = views if isinstance(views, CameraKernel) else CameraKernel(views)
    X = np.array(X0, dtype=float)
    u_obs, v_obs = uv_px[..., 0].astype(F32), uv_px[..., 1].astype(F32)
    start = np.where(np.all(np.isfinite(X), axis=1)[:, None], X, 0.0)
    ev = kernel.evaluate(start, u_obs, v_obs, jacobian=iterations > 0)
    if iterations == 0:
        return X, ev
    w = np.where(np.all(np.isfinite(X), axis=1)[:, None], weight, 0.0)
    if gate_px is not None:
        w = np.where(ev.r_u * ev.r_u + ev.r_v * ev.r_v < F32(gate_px) ** 2, w, 0.0)
    H, g, cost = normal_equations(ev, w, penalty_px)
    lam = np.full(len(X), 1e-4)
    eye = np.eye(3)
    Xs = start
    for it in range(iterations):
        diag = np.einsum("pii->pi", H)
        A = H + (lam[:, None] * np.maximum(diag, 1e-9))[:, :, None] * eye + 1e-12 * eye
        step = -np.linalg.solve(A, g[..., None])[..., 0]
        X_new = Xs + step
        last = it == iterations - 1
        ev_new = kernel.evaluate(X_new, u_obs, v_obs, jacobian=not last)
        H_new, g_new, cost_new = normal_equations(ev_new, w, penalty_px)
        better = cost_new < cost
        Xs = np.where(better[:, None], X_new, Xs)
        sel = better[:, None]
        ev = Evaluation(np.where(sel, ev_new.r_u, ev.r_u), np.where(sel, ev_new.r_v, ev.r_v), None)
        if not last:
            H = np.where(better[:, None, None], H_new, H)
            g = np.where(better[:, None], g_new, g)
        cost = np.where(better, cost_new, cost)
        lam = np.where(better, np.maximum(lam * 0.1, 1e-9), lam * 10.0)
    X = np.where(np.all(np.isfinite(X), axis=1)[:, None], Xs, np.nan)
    return X, ev


#: Quanta of the detections that key a point's random draws: 1/64 px, 2^-16 of confidence.
_DRAW_PX_STEPS, _DRAW_CONF_STEPS = 64.0, 65536.0
_U64 = np.uint64
_GOLDEN = _U64(0x9E3779B97F4A7C15)


def _mix64(x: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser: a bijection of uint64 whose outputs look independent (wrapping arithmetic)."""
    x = (x ^ (x >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> _U64(27))) * _U64(0x94D049BB133111EB)
    return x ^ (x >> _U64(31))


def point_draws(uv_px: np.ndarray, conf: np.ndarray, valid: np.ndarray, seed: int, n: int,
                cols: np.ndarray | None = None) -> np.ndarray:
    """(P, n) uniform numbers in [0, 1) for each of P points, a function of that point's own detections only.

    The key of a point hashes its valid views (index, pixels quantised to 1/64 px, confidence to 2^-16): a sum of
    per-view hashes, so it does not depend on the order of the arithmetic; draw k is splitmix64 of key + k. The
    same detections give the same draws in any batch, chunk or process (results do not depend on how the work is
    cut), and they are the same on every machine (integer arithmetic only). ``cols`` (P, K): the columns are each
    point's own views at these positions of the view set (the view index of the hash is the position).
    """
    return draws_at(point_keys(uv_px, conf, valid, seed, cols), np.arange(n)[None, :])


def point_keys(uv_px: np.ndarray, conf: np.ndarray, valid: np.ndarray, seed: int,
               cols: np.ndarray | None = None) -> np.ndarray:
    """(P,) uint64 keys of :func:`point_draws`."""
    P, V = valid.shape
    with np.errstate(over="ignore"):
        q = [np.rint(np.clip(np.where(valid, a, 0.0) * step, -2.0**53, 2.0**53)).astype(np.int64).view(_U64)
             for a, step in ((uv_px[..., 0], _DRAW_PX_STEPS), (uv_px[..., 1], _DRAW_PX_STEPS),
                             (conf, _DRAW_CONF_STEPS))]
        view = (np.arange(V)[None, :] if cols is None else cols).astype(_U64) + _U64(1)
        h = _mix64(q[0] + _mix64(q[1] + _mix64(q[2] + _mix64(view * _GOLDEN))))
        return _mix64(np.where(valid, h, _U64(0)).sum(axis=1, dtype=_U64) + _U64(seed % 2**64) * _GOLDEN)


def draws_at(key: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Draws number ``k`` (broadcast against (P, 1), from 0) of points with keys (P,) -> uniform in [0, 1)."""
    with np.errstate(over="ignore"):
        bits = _mix64(key[:, None] + (np.asarray(k).astype(_U64) + _U64(1)) * _GOLDEN)
    return (bits >> _U64(11)).astype(float) * 2.0**-53


def _all_pairs(n_max: int) -> dict[int, np.ndarray]:
    """For each view count n in 2..n_max, the (n (n - 1) / 2, 2) pairs (i < j) of positions 0..n-1."""
    return {n: np.array([(i, j) for i in range(n) for j in range(i + 1, n)]) for n in range(2, n_max + 1)}


def _scoring_err2(views: ViewSet, sv: np.ndarray, xn: np.ndarray, X: np.ndarray,
                  sv_view: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Squared reprojection errors (px^2, in each view's focal units) of hypotheses X (P, H, 3) in the scoring views
    sv (P, S) of normalised detections xn (P, V, 2) -> err2 (P, H, S), depths zc (P, H, S) (float32). ``sv_view``:
    those views' positions in ``views`` where the columns of ``xn`` are each point's own (default ``sv``)."""
    rows = np.arange(len(sv))[:, None]
    sv_view = sv if sv_view is None else sv_view
    Rs = views.R[sv_view].astype(F32)[:, None]  # (P, 1, S, 3, 3)
    ts = views.t_cm[sv_view].astype(F32)[:, None]  # (P, 1, S, 3)
    Xh = np.where(np.isfinite(X), X, 0.0).astype(F32)[:, :, None]  # (P, H, 1, 3)
    xc, yc, zc = (Rs[..., i, 0] * Xh[..., 0] + Rs[..., i, 1] * Xh[..., 1] + Rs[..., i, 2] * Xh[..., 2] + ts[..., i]
                  for i in range(3))  # (P, H, S)
    front = zc > MIN_DEPTH
    inv_z = 1.0 / np.where(front, zc, F32(1.0))
    f = views.intr[sv_view].astype(F32)[:, None]  # (P, 1, S, 4)
    obs = xn[rows, sv].astype(F32)[:, None]  # (P, 1, S, 2)
    err2 = ((xc * inv_z - obs[..., 0]) * f[..., 0]) ** 2 + ((yc * inv_z - obs[..., 1]) * f[..., 1]) ** 2
    return err2, zc


def _refit_rays(views: ViewSet, sv: np.ndarray, xn: np.ndarray, X: np.ndarray, w: np.ndarray,
                zc: np.ndarray, sv_view: np.ndarray | None = None) -> np.ndarray:
    """Hypotheses X (P, H, 3) refitted to the rays of the scoring views sv (P, S) with weights w (P, H, S): the point
    nearest the rays, each ray's squared distance over the hypothesis' depth squared (about the reprojection error
    in normalised units). Hypotheses with fewer than 2 weighted views keep X."""
    rows = np.arange(len(sv))[:, None]
    sv_view = sv if sv_view is None else sv_view
    xh = np.concatenate([xn[rows, sv], np.ones(sv.shape + (1,))], axis=-1)  # (P, S, 3)
    d = np.einsum("psji,psj->psi", views.R[sv_view], xh)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    M = np.eye(3) - d[..., :, None] * d[..., None, :]  # (P, S, 3, 3)
    c = views.center_cm[sv_view]  # (P, S, 3)
    ww = w / np.maximum(np.asarray(zc, dtype=float), MIN_DEPTH) ** 2  # (P, H, S)
    A = np.einsum("phs,psij->phij", ww, M)
    b = np.einsum("phs,psij,psj->phi", ww, M, c)
    enough = (w > 0).sum(axis=-1) >= 2
    A = np.where(enough[..., None, None], A, np.eye(3))
    with np.errstate(invalid="ignore"):
        Xr = np.linalg.solve(A + 1e-12 * np.trace(A, axis1=-2, axis2=-1)[..., None, None] * np.eye(3),
                             b[..., None])[..., 0]
    return np.where(enough[..., None], Xr, X)


def _ransac(views: ViewSet, xn: np.ndarray, conf: np.ndarray, valid: np.ndarray,
            options: TriangulationOptions, uv_px: np.ndarray, cols: np.ndarray | None = None) -> np.ndarray:
    """Best two-view hypothesis (P, 3) per point by MSAC over a subset of its views (NaN if none).

    Points with no more view pairs than ``ransac_hypotheses`` try every pair; the others draw them, and their
    scoring views, with :func:`point_draws` (each point's draws depend on its own detections only). ``cols``
    (P, K): the columns are each point's own views at these positions of ``views`` (the same draws as the full
    columns: a view's draw is keyed by its position).
    """
    P, V = valid.shape
    H = options.ransac_hypotheses
    V_all = len(views.names)
    key = point_keys(uv_px, conf, valid, options.seed, cols)
    keys = draws_at(key, np.arange(V)[None, :] if cols is None else cols)
    keys[~valid] = 2.0
    at_view = (lambda c: c) if cols is None else (lambda c: np.take_along_axis(cols, c, axis=1))
    order = np.argsort(keys, axis=1, kind="stable")  # the point's views in random order, valid ones first
    n_valid = valid.sum(axis=1)
    u = draws_at(key, V_all + np.arange(2 * H)[None, :]).reshape(P, H, 2)
    nv = np.maximum(n_valid, 2)[:, None]
    i = np.minimum((u[..., 0] * nv).astype(np.int64), nv - 1)
    j = (i + 1 + np.minimum((u[..., 1] * (nv - 1)).astype(np.int64), nv - 2)) % nv
    n_max = 2
    while (n_max + 1) * n_max // 2 <= H:
        n_max += 1
    for n, pairs in _all_pairs(n_max).items():  # few views: every pair once (the rest repeat the first)
        few = n_valid == n
        if few.any():
            take = np.minimum(np.arange(H), len(pairs) - 1)
            i[few], j[few] = pairs[take, 0], pairs[take, 1]
    vi, vj = np.take_along_axis(order, i, axis=1), np.take_along_axis(order, j, axis=1)  # (P, H) columns
    gi, gj = at_view(vi), at_view(vj)  # their views
    centers = views.center_cm
    rows = np.arange(P)[:, None]

    def ray(v: np.ndarray, g: np.ndarray) -> np.ndarray:
        xh = np.concatenate([xn[rows, v], np.ones((P, H, 1))], axis=-1)
        return np.einsum("phji,phj->phi", views.R[g], xh)  # R^T [x, y, 1]: world direction

    di, dj = ray(vi, gi), ray(vj, gj)
    w0 = centers[gi] - centers[gj]
    a, b, c = (di * di).sum(-1), (di * dj).sum(-1), (dj * dj).sum(-1)
    d, e = (di * w0).sum(-1), (dj * w0).sum(-1)
    den = a * c - b * b
    good = (den > _MIN_SIN2_PAIR * a * c) & (n_valid[:, None] >= 2)
    den = np.where(good, den, 1.0)
    s, t = (b * e - c * d) / den, (a * e - b * d) / den
    good &= (s > 0) & (t > 0)
    X_h = 0.5 * (centers[gi] + s[..., None] * di + centers[gj] + t[..., None] * dj)  # (P, H, 3)

    S = min(options.ransac_score_views, V)
    sv = order[:, :S]  # (P, S)
    sv_view = at_view(sv)
    s_ok = (np.arange(S)[None, :] < n_valid[:, None])[:, None, :]  # (P, 1, S)
    c_s = np.where(s_ok, conf[rows, sv][:, None, :], 0.0)  # (P, 1, S)
    thr2 = F32(options.inlier_threshold_px**2)
    # local optimisation (LO-RANSAC): every hypothesis is refitted to the views it explains, loosely (2 x the
    # threshold: a two-view point is noisy) and then at the threshold, so a set of views that agree is judged by
    # its own point, not by the midpoint of two of its rays (which can miss the third view by more than the
    # threshold where the three meet within it)
    X_lo = X_h.copy()
    err2, zc = _scoring_err2(views, sv, xn, X_h, sv_view)
    seen = s_ok & (zc > MIN_DEPTH)
    n_h = np.where(good, (seen & (err2 < thr2)).sum(axis=-1), -1)
    n_loose = np.where(good, (seen & (err2 < F32(4.0) * thr2)).sum(axis=-1), -1)
    # only a point where some pair point comes near (within twice the threshold) more views than the best one
    # explains can gain a view by the refit (with few wrong detections, most points have none)
    need = np.flatnonzero((n_loose > n_h.max(axis=1, keepdims=True)).any(axis=1))
    if need.size:
        Xs, e2, z, sv_n, xn_n, g_n = X_h[need], err2[need], zc[need], sv[need], xn[need], sv_view[need]
        for loose in (4.0, 1.0):
            Xs = _refit_rays(views, sv_n, xn_n, Xs, c_s[need] * ((e2 < thr2 * F32(loose)) & (z > MIN_DEPTH)), z, g_n)
            e2, z = _scoring_err2(views, sv_n, xn_n, Xs, g_n)
        X_lo[need], err2[need], zc[need] = Xs, e2, z
    good &= np.all(np.isfinite(X_lo), axis=-1)
    inlier = s_ok & (zc > MIN_DEPTH) & (err2 < thr2)
    err2 = np.where(zc > MIN_DEPTH, np.minimum(err2, thr2), thr2)
    score = np.einsum("phs,phs->ph", err2, c_s.astype(F32) * np.ones_like(err2))
    # the most views first (a pair always meets, so two views fitted exactly must not outscore three that agree
    # within the threshold), then the truncated, confidence-weighted squared error (MSAC)
    n_in = np.where(good, inlier.sum(axis=-1), -1)
    score = np.where(good & (n_in == n_in.max(axis=1, keepdims=True)), score, np.inf)
    best = np.argmin(score, axis=1)
    X_best = X_lo[np.arange(P), best]
    X_best[~np.isfinite(score[np.arange(P), best])] = np.nan
    return X_best


def triangulate(views: ViewSet, uv_px: np.ndarray, conf: np.ndarray,
                options: TriangulationOptions | None = None, *, few_views: int = 0) -> Triangulation:
    """Triangulate P points from detections in V views, robust to wrong detections.

    Args:
        views: the V cameras (order of the second axis of ``uv_px``).
        uv_px: (P, V, 2) OpenCV pixels; NaN = no detection.
        conf: (P, V) detection confidence in [0, 1] (else ReconError); <= ``options.min_confidence`` or NaN = no
            detection.
        few_views: K > 0: each point is solved in K columns, its detected views (at most K, else ReconError)
            then views it was not detected in, instead of all V: for points seen in a few of many views (a patch
            flown in 8 of a dome's 521 cameras). The same draws (a view's is keyed by its position in ``views``)
            and the same operations per point and view; sums over a point's views run over K columns instead of
            V, so the last bits may differ from K = 0 (all V). K is the caller's, not the batch's: a point's
            result does not depend on the other points of the call.
    Returns:
        :class:`Triangulation`.
    Example:
        >>> tri = triangulate(view_set(bundle), uv, conf)   # uv (19 * frames, 520, 2)
        >>> tri.X_cm[tri.n_inliers >= 2]
    """
    options = options or TriangulationOptions()
    uv_px = np.asarray(uv_px, dtype=float)
    conf = np.asarray(conf, dtype=float)
    P, V = conf.shape
    if uv_px.shape != (P, V, 2) or V != len(views.names):
        raise ReconError(f"detections have shape {uv_px.shape} / confidences {conf.shape} but expected "
                         f"(P, {len(views.names)}, 2) / (P, {len(views.names)}) for the {len(views.names)} views")
    if np.any(conf < 0) or np.any(conf > 1):
        bad = np.argwhere((conf < 0) | (conf > 1))[0]
        raise ReconError(f"confidence {conf[tuple(bad)]:g} of point {bad[0]} in view {views.names[bad[1]]} is outside "
                         "[0, 1] (NaN = not detected)")
    valid = np.isfinite(conf) & (conf > options.min_confidence) & np.all(np.isfinite(uv_px), axis=-1)
    cols = None
    if few_views > 0:  # each point's detected views first, in view order (then padding: views it was not seen in)
        K = min(max(int(few_views), 2), V)
        if P and valid.sum(axis=1).max() > K:
            p = int(np.argmax(valid.sum(axis=1)))
            raise ReconError(f"point {p} is detected in {int(valid[p].sum())} views, more than few_views={K}")
        cols = np.argsort(~valid, axis=1, kind="stable")[:, :K]
        valid = np.take_along_axis(valid, cols, axis=1)
        conf = np.take_along_axis(conf, cols, axis=1)
        uv_px = np.take_along_axis(uv_px, cols[..., None], axis=1)
    w = np.where(valid, conf, 0.0)
    uv = np.where(valid[..., None], uv_px, 0.0)
    thr = options.inlier_threshold_px
    kernel = CameraKernel(views) if cols is None else CameraKernel(views).per_point(cols)
    xn = undistort_detections(kernel, uv, valid)
    u_obs, v_obs = uv[..., 0].astype(F32), uv[..., 1].astype(F32)

    X = _ransac(views, xn, w, valid, options, uv, cols)
    have = np.all(np.isfinite(X), axis=1, keepdims=True)
    err = kernel.reprojection_error_px(np.where(have, X, 0.0), u_obs, v_obs)
    inl = valid & have & (err < thr)  # the views the hypothesis, refitted to them (_ransac), explains
    X = triangulate_dlt(views, xn, np.where(inl, w, 0.0), None if cols is None else _dlt_blocks(views)[:, cols])
    X, ev = refine_lm(kernel, X, uv, np.where(inl, w, 0.0), iterations=options.lm_iterations)
    err = np.sqrt(ev.r_u * ev.r_u + ev.r_v * ev.r_v).astype(float)
    inl = valid & (err < thr)
    n_inl = inl.sum(axis=1)
    ok = (n_inl >= options.min_views) & np.all(np.isfinite(X), axis=1)
    X[~ok] = np.nan
    wsum = np.where(inl, w, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        confidence = np.where(ok, wsum / np.maximum(n_inl, 1), -1.0)
        rms = np.sqrt(np.where(inl, err**2, 0.0).sum(axis=1) / n_inl)
    rms[~ok] = np.nan
    inl[~ok] = False
    if cols is not None:
        inl_all = np.zeros((P, V), bool)
        np.put_along_axis(inl_all, cols, inl, axis=1)  # padding columns are never inliers (not valid)
        inl = inl_all
    logger.debug("triangulated %d/%d points, median %d inlier views", ok.sum(), P,
                 int(np.median(n_inl)) if P else 0)
    return Triangulation(X_cm=X, confidence=confidence, inliers=inl, n_inliers=np.where(ok, n_inl, 0), rms_px=rms)
