"""One body per person over time: each track's joints fitted to its detections, its own bone lengths and smooth
motion, all times of a span at once (a window of the session: :mod:`~dome_calib.recon.people.windows`).

After association and tracking, every track (a person with an id) has per-frame joints (the robust triangulation,
with joints missing where too few views agreed) and the detections assigned to it in every view
(:class:`~dome_calib.recon.people.bodies.Observations`). This stage minimises, over all joints of all its times,

    sum_obs  c * rho(|pi_v(X_j(t)) - u|^2 / sigma_v^2)           robust reprojection (Geman-McClure, scale k sigma_v)
  + sum_bones (|X_a(t) - X_b(t)| - L_ab)^2 / sigma_L^2          the track's own bone lengths, held
  + sum_j  integral |X_j''(t)|^2 dt / q_j                        smooth motion (white-noise acceleration)

- ``sigma_v``, the detector's pixel noise, is measured on the input itself, once over the whole session: per
  camera, the median distance between its detections and the per-frame joints (a 2D Gaussian's median radius is
  1.177 sigma), so a camera with a worse view or a worse lens weighs less; ``c`` is the detection confidence
  (clipped to [0, 1]).
- ``L_ab``, per track, once over the whole session: the median over all its times of the per-frame bone length
  where both joints had at least ``bone_min_views`` inlier views. ``sigma_L`` (1.5 cm) is the play of a detector's
  joint centres, not of bones. A limb or trunk bone never measured so (a joint only two cameras see) is the body's
  size x its nominal length (:func:`~dome_calib.recon.people.windows.infer_unmeasured_bones`), held with
  ``inferred_bone_sigma_cm`` (3 cm: on Pose2Sim's real balancing trial the nine limb and trunk bones' measured /
  nominal spread 0.92-1.02 about their median 0.957, SD 3.6 %, so a bone put at the median is typically 1.5 cm and
  at worst 3 cm off a shin's 42). Both come in :class:`SessionPriors`.
- ``q_j`` (cm^2/s^3): the spectral density of a joint's acceleration, from the body (``2 a_rms^2 tau`` with RMS
  accelerations of everyday motion: trunk and head 300 cm/s^2, elbows and knees 800, wrists and ankles 1,200, over a
  correlation time of 0.1 s). The integral penalty is the cubic smoothing spline (the posterior mean of an
  integrated Wiener process): unbiased for constant velocity, on uneven time steps and across short gaps.

A left/right swap or a neighbour's limb in one view sits tens of pixels from where the body puts the joint: the
Geman-McClure weight ``1 / (1 + (r / k sigma_v)^2)^2`` falls to a few percent, and so does its pull (weight x r, at
most 0.35 sigma_v beyond the outvoted distance of 5 sigma_v with k = 3), and the body is not moved (it is counted as
outvoted). Cauchy's weight ``1 / (1 + (r / k sigma_v)^2)`` fell too, but its pull did not: ``k^2 sigma_v^2 / r``,
1.3 sigma_v at 5 sigma_v, more than an inlier's; on Pose2Sim's balancing trial one camera's left hip, 40-55 px
from the other three's, held the hip 5 cm from where they put it. Joints the per-frame triangulation left out are
placed by the body where their views, bones and motion constrain them well enough (``max_sigma_cm``).

Solver (no Python per factor: every term is an array operation over all records, joints and times): Gauss-Newton
with iteratively reweighted least squares (``iterations``). Each step is one sparse system over every joint of
every track of the span, solved by conjugate gradients preconditioned by the exact solution of each joint's own
time chain (a banded factorisation: the chains hold the stiff time coupling; only the bones are left to the
iterations). Cost linear in records and in time.

``c`` of an output joint is the model's probability that the joint lies within 5 cm of where it is put (3D
Gaussian with the joint's variance: the inverse of its information from the data, the bones and its neighbours in
time, inflated by ``q d^3 / 3`` where the joint was not triangulated for d seconds); measured against the truth in
bench/fewcam.py.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.special import gammainc

from dome_calib.arrays import per_row
from dome_calib.options import AtLeast, Field, options
from dome_calib.recon.body_models import BONE_LENGTH_CM, JOINTS19
from dome_calib.schema import PosFinite, Vec
from dome_calib.recon.kernel import camera_table
from dome_calib.recon.people.bodies import Bodies, Observations
from dome_calib.recon.people.compiled import residuals_px, robust_blocks
from dome_calib.recon.project import ViewSet

BONE_A = np.array([JOINTS19.index(a) for a, _ in BONE_LENGTH_CM])
BONE_B = np.array([JOINTS19.index(b) for _, b in BONE_LENGTH_CM])
#: RMS acceleration of each joint in everyday motion (cm/s^2): trunk and head, elbows and knees, wrists and ankles.
_ACCEL_GROUPS = {300.0: ("neck", "nose", "body_center", "l_shoulder", "r_shoulder", "l_hip", "r_hip", "l_eye",
                         "r_eye", "l_ear", "r_ear"),
                 800.0: ("l_elbow", "r_elbow", "l_knee", "r_knee"),
                 1200.0: ("l_wrist", "r_wrist", "l_ankle", "r_ankle")}
ACCEL_RMS_CM_S2 = np.array([next(a for a, names in _ACCEL_GROUPS.items() if n in names) for n in JOINTS19])


@options
class TemporalOptions:
    """Options of :func:`refine_tracks` (see the module docstring). enabled: False keeps the per-frame joints;
    robust_k: Geman-McClure scale in units of the camera's pixel noise; outvoted_k: a detection farther than this many
    sigma from the body is outvoted; bone_sigma_cm; bone_min_views: frames whose two joints have this many inlier
    views estimate a bone; accel_scale: multiplies the body's RMS accelerations; correlation_s; prior_sigma_cm: weak
    pull to the start (only directions nothing else holds); inferred_bone_sigma_cm: the play of a bone inferred from
    the body's size (never measured); max_sigma_cm: a joint the per-frame triangulation left
    out is output only if its standard deviation is below this; min_noise_px: floor of a camera's pixel noise;
    max_views_per_joint: the fit reweighs a joint's most confident detections up to this many at every round; the
    others are weighed once at the start and held (every detection is judged at the end); window_edge_influence,
    window_margins: the session is fitted in windows whose margin M is the smoother's reach down to this influence,
    and whose own times are ``window_margins`` x M (:mod:`~dome_calib.recon.people.windows`; neither changes the
    result beyond that influence)."""

    enabled: bool = True
    iterations: AtLeast(1) = 4
    robust_k: PosFinite = 3.0
    outvoted_k: PosFinite = 5.0
    bone_sigma_cm: PosFinite = 1.5
    inferred_bone_sigma_cm: PosFinite = 3.0
    bone_min_views: AtLeast(2) = 3
    accel_scale: PosFinite = 1.0
    correlation_s: PosFinite = 0.1
    prior_sigma_cm: PosFinite = 30.0
    max_sigma_cm: PosFinite = 6.0
    min_noise_px: PosFinite = 0.5
    max_views_per_joint: AtLeast(2) = 32
    cg_tolerance: PosFinite = 1e-6
    cg_max_iterations: AtLeast(1) = 300
    accel_rms_cm_s2: Vec(19, PosFinite) = field(default_factory=lambda: ACCEL_RMS_CM_S2.tolist())
    window_edge_influence: Annotated[float, Field(gt=0, lt=1)] = 1e-3
    window_margins: AtLeast(1) = 6

    def spectral_density(self) -> np.ndarray:
        """(19,) q of each joint's white-noise acceleration (cm^2/s^3): 2 (accel_scale a_rms)^2 correlation_s."""
        return 2.0 * (self.accel_scale * np.asarray(self.accel_rms_cm_s2)) ** 2 * self.correlation_s


@dataclass(frozen=True)
class SessionPriors:
    """What the fit holds, measured once over the whole session (:mod:`~dome_calib.recon.people.windows`): each
    track's bone lengths, bone_cm (K, E) for the track ids ``track_ids`` (K,) increasing (NaN: a bone never seen
    well), ``BONE_LENGTH_CM``'s order; noise_px (V,) each camera's pixel noise (finite); bone_inferred (K, E): the
    bones inferred from the body's size, not measured (None: none)."""

    track_ids: np.ndarray
    bone_cm: np.ndarray
    noise_px: np.ndarray
    bone_inferred: np.ndarray | None = None

    def bones_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(len(ids), E) the bone lengths of the given track ids (NaN rows for ids not measured), and (len(ids), E)
        which of them were inferred."""
        E = self.bone_cm.shape[1]
        if not len(self.track_ids):
            return np.full((len(ids), E), np.nan), np.zeros((len(ids), E), bool)
        k = np.clip(np.searchsorted(self.track_ids, ids), 0, len(self.track_ids) - 1)
        found = self.track_ids[k] == ids
        inferred = self.bone_inferred if self.bone_inferred is not None else np.zeros(self.bone_cm.shape, bool)
        return np.where(found[:, None], self.bone_cm[k], np.nan), found[:, None] & inferred[k]


@dataclass(frozen=True)
class TemporalResult:
    """The refined bodies (same times, same people, same ids) and the verdict on every detection record of
    ``obs``: record_time (M,) its time index, residual_px (M,) its distance to the final body (NaN where its joint
    is not put out: not judged), outvoted (M,) farther than ``outvoted_k`` sigma of its camera's noise, offset_px
    (M, 2) the detection minus the final body's joint projected into its camera (px; NaN where residual_px is): a
    camera that moved shifts its detections to one side (:mod:`~dome_calib.recon.people.agreement`)."""

    bodies: list[Bodies]
    record_time: np.ndarray
    residual_px: np.ndarray
    outvoted: np.ndarray
    offset_px: np.ndarray


@dataclass
class _Layout:
    """The unknowns: body-frames (BF) sorted by (track, time); joint chains (track, joint) contiguous in time."""

    bf_k: np.ndarray  # (BF,) time index
    bf_p: np.ndarray  # (BF,) body index at that time
    bf_track: np.ndarray  # (BF,) track
    bf_pos: np.ndarray  # (BF,) position within its track
    var: np.ndarray  # (BF, 19) unknown point index (-1: joint not solved)
    n_var: int


def _layout(bodies: list[Bodies]) -> _Layout:
    k = np.concatenate([np.full(len(b.ids), i) for i, b in enumerate(bodies)] + [np.zeros(0, np.int64)])
    p = np.concatenate([np.arange(len(b.ids)) for b in bodies] + [np.zeros(0, np.int64)])
    ids = np.concatenate([b.ids for b in bodies] + [np.zeros(0, np.int64)])
    order = np.lexsort((k, ids))
    k, p, ids = k[order], p[order], ids[order]
    _, track, counts = np.unique(ids, return_inverse=True, return_counts=True)
    starts = np.concatenate([[0], np.cumsum(counts)])
    pos = np.arange(len(ids)) - starts[track]
    X = np.stack([bodies[a].X_cm[b] for a, b in zip(k, p)]) if len(k) else np.zeros((0, 19, 3))
    have = np.isfinite(X).all(-1)  # (BF, 19)
    chain_on = np.zeros((len(counts), 19), bool)
    np.logical_or.at(chain_on, track, have)
    # chain-major numbering: track by track, joint by joint, time within
    n_chain = np.where(chain_on, counts[:, None], 0)  # (tracks, 19)
    chain_start = np.concatenate([[0], np.cumsum(n_chain.ravel())])[:-1].reshape(n_chain.shape)
    var = np.where(chain_on[track], chain_start[track] + pos[:, None], -1)
    return _Layout(bf_k=k, bf_p=p, bf_track=track, bf_pos=pos, var=var, n_var=int(n_chain.sum()))


def _initial_points(lay: _Layout, X: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """(n_var, 3) start: the per-frame joints; joints missing at a time interpolated linearly over the track's time
    (the nearest frame's beyond its ends)."""
    out = np.zeros((lay.n_var, 3))
    t = times_s[lay.bf_k]
    for tr in np.unique(lay.bf_track):
        rows = np.flatnonzero(lay.bf_track == tr)
        for j in np.flatnonzero((lay.var[rows] >= 0).any(0)):
            have = np.isfinite(X[rows, j]).all(-1)
            for ax in range(3):
                out[lay.var[rows, j], ax] = np.interp(t[rows], t[rows][have], X[rows[have], j, ax])
    return out


def _smoothness(lay: _Layout, times_s: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Second-difference rows of every chain: (S, 3) point indices, (S, 3) coefficients (acceleration, 1/s^2),
    (S,) weights tau / q (the integral of |x''|^2 / q over the interval the row stands for)."""
    track = lay.bf_track
    mid = np.arange(1, max(len(track) - 1, 1))
    mid = mid[(track[mid - 1] == track[mid]) & (track[np.minimum(mid + 1, len(track) - 1)] == track[mid])
              & (mid + 1 < len(track))]
    a, b, c = mid - 1, mid, mid + 1
    t = times_s[lay.bf_k]
    dt0, dt1 = t[b] - t[a], t[c] - t[b]
    alpha, gamma = 2.0 / (dt0 * (dt0 + dt1)), 2.0 / (dt1 * (dt0 + dt1))
    coef = np.stack([alpha, -(alpha + gamma), gamma], axis=1)  # (S_bf, 3)
    tau = 0.5 * (dt0 + dt1)
    idx = np.stack([lay.var[a], lay.var[b], lay.var[c]], axis=-1)  # (S_bf, 19, 3)
    on = (idx >= 0).all(-1)
    s, j = np.nonzero(on)
    return idx[s, j], coef[s], tau[s] / q[j]


def _blocks(n: int, idx_a: np.ndarray, idx_b: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, ...]:
    """COO entries of (K, 3, 3) blocks M at point rows idx_a, point columns idx_b."""
    r = (3 * idx_a)[:, None, None] + np.arange(3)[None, :, None]
    c = (3 * idx_b)[:, None, None] + np.arange(3)[None, None, :]
    return np.broadcast_to(r, M.shape).ravel(), np.broadcast_to(c, M.shape).ravel(), M.ravel()


def refine_tracks(views: ViewSet, times_ms: np.ndarray, bodies: list[Bodies], obs: Observations,
                  priors: SessionPriors, options: TemporalOptions | None = None, ties=None) -> TemporalResult:
    """The tracked bodies of a span of times (ids >= 0) -> the same bodies fitted over time (see the module
    docstring). obs: their detections, rows numbering the bodies in time order
    (:func:`~dome_calib.recon.people.bodies.observations_of`); priors: the session's bone lengths and camera noise;
    views: the cameras ``obs.view`` and ``priors.noise_px`` index; ties: the patches' part motions as a further
    term (:class:`~dome_calib.recon.patches.body.JointTies`; None: absent)."""
    options = options or TemporalOptions()
    lay = _layout(bodies)
    BF = len(lay.bf_k)
    M = len(obs.row)
    none = TemporalResult(bodies=bodies, record_time=np.zeros(M, np.int64), residual_px=np.full(M, np.nan),
                          outvoted=np.zeros(M, bool), offset_px=np.full((M, 2), np.nan, np.float32))
    if BF == 0 or lay.n_var == 0 or not options.enabled:
        return none
    X0 = np.stack([bodies[a].X_cm[b] for a, b in zip(lay.bf_k, lay.bf_p)])
    first = np.cumsum([0] + [len(b.ids) for b in bodies])
    row_bf = np.full(int(first[-1]), -1, dtype=np.int32)
    row_bf[first[lay.bf_k] + lay.bf_p] = np.arange(BF)
    times_s = np.asarray(times_ms, dtype=float) / 1000.0
    cam = camera_table(views)
    sigma_v = priors.noise_px
    # each record's point (-1: its joint is not solved); each joint's strongest records, reweighed every round
    bf_rec = row_bf[obs.row]  # int32 (a window holds millions of records)
    rec_var = lay.var[bf_rec, obs.joint].astype(np.int32)
    sel = np.flatnonzero(obs.strong & (rec_var >= 0))
    sel_var, sel_view, sel_uv, sel_c = rec_var[sel], obs.view[sel], obs.uv_px[sel], obs.conf[sel]
    q = options.spectral_density()
    s_idx, s_coef, s_w = _smoothness(lay, times_s, q)
    L, inferred = priors.bones_of(np.unique(np.concatenate([b.ids for b in bodies])))  # (tracks, E), _layout's
    bone_bf, bone_e = np.nonzero((lay.var[:, BONE_A] >= 0) & (lay.var[:, BONE_B] >= 0)
                                 & np.isfinite(L[lay.bf_track]))
    ba, bb = lay.var[bone_bf, BONE_A[bone_e]], lay.var[bone_bf, BONE_B[bone_e]]
    bone_len = L[lay.bf_track[bone_bf], bone_e]
    w_bone = 1.0 / np.where(inferred[lay.bf_track[bone_bf], bone_e], options.inferred_bone_sigma_cm,
                            options.bone_sigma_cm)[:, None] ** 2
    P = _initial_points(lay, X0, times_s)
    P_start = P.copy()
    w0 = 1.0 / options.prior_sigma_cm ** 2
    n = 3 * lay.n_var
    # the time chains' matrix (smoothness, prior) is the same at every iteration: CSR for products, banded for the
    # preconditioner (a chain's points are consecutive: second differences reach 2 points = 6 rows)
    sr, sc, sv = [], [], []
    for i in range(3):
        for k in range(3):
            r, c, v = _blocks(n, s_idx[:, i], s_idx[:, k],
                              (s_w * s_coef[:, i] * s_coef[:, k])[:, None, None] * np.eye(3)[None])
            sr.append(r), sc.append(c), sv.append(v)
    chain = sp.coo_matrix((np.concatenate(sv), (np.concatenate(sr), np.concatenate(sc))), shape=(n, n)).tocsr()
    chain = (chain + w0 * sp.identity(n, format="csr")).tocsr()
    if ties is not None:  # linear: joins the chains (consecutive times) and the prior's constant
        H_tie, b_tie = ties.system(lay, times_ms, bodies)
        chain, P_start = (chain + H_tie).tocsr(), P_start + b_tie / w0
    chain_band = _upper_band(chain, _BAND)
    both = np.concatenate([ba, bb])
    # the detections beyond each joint's strongest: weighed once at the start, then held as a quadratic term
    H_rest, g_rest = robust_blocks(P, rec_var, obs.view, obs.uv_px, obs.conf, sigma_v, cam, options.robust_k,
                                   use=~obs.strong)
    P_lin = P.copy()
    for _ in range(options.iterations):
        H_d, g = robust_blocks(P, sel_var, sel_view, sel_uv, sel_c, sigma_v, cam, options.robust_k)
        H_d += H_rest
        g += g_rest + np.einsum("nij,nj->ni", H_rest, P - P_lin)
        # bones, linearised along their current direction
        d = P[ba] - P[bb]
        length = np.maximum(np.linalg.norm(d, axis=1), 1e-6)
        u = d / length[:, None]
        uu = w_bone[:, :, None] * u[:, :, None] * u[:, None, :]
        rb = (length - bone_len)[:, None] * u * w_bone
        H_diag = H_d + _sum_by(both, np.concatenate([uu, uu]), lay.n_var)
        g += _sum_by(both, np.concatenate([rb, -rb]), lay.n_var)
        g += (chain @ P.ravel() - w0 * P_start.ravel()).reshape(-1, 3)  # smoothness (linear) and the prior

        def product(x: np.ndarray, H_diag=H_diag, uu=uu) -> np.ndarray:
            """The full system times x: chains, each point's own block, the bones between points."""
            X = x.reshape(-1, 3)
            y = chain @ x + np.einsum("nij,nj->ni", H_diag, X).ravel()
            cross = -np.concatenate([np.einsum("kij,kj->ki", uu, X[bb]), np.einsum("kij,kj->ki", uu, X[ba])])
            return y + _sum_by(both, cross, lay.n_var).ravel()

        P = P + _pcg(product, -g.ravel(), _banded_solver(chain_band, H_diag), options.cg_tolerance,
                     options.cg_max_iterations).reshape(-1, 3)
    # each joint's standard deviation, then the final judgement of every record of the solved joints (also those
    # the fit held after weighing them once: the full dome's beyond the strongest)
    info = np.linalg.eigvalsh(H_diag + np.asarray(chain.diagonal()).reshape(-1, 3)[:, :, None] * np.eye(3))[:, 0]
    var_cm2 = 1.0 / np.maximum(info, 1e-12)
    gap = _gap_variance(lay, X0, times_s, q)
    var_cm2 += gap if ties is None else ties.gap_variance(lay, X0, times_ms, bodies, gap, q)
    sigma = np.sqrt(var_cm2)
    shown = _shown(lay, X0, sigma, options.max_sigma_cm)
    offset = residuals_px(P, rec_var, obs.view, obs.uv_px, cam)
    residual = np.hypot(offset[:, 0], offset[:, 1]).astype(np.float32)  # float32: millions of them
    residual[~shown[rec_var] | (rec_var < 0)] = np.nan
    offset = offset.astype(np.float32)
    offset[np.isnan(residual)] = np.nan
    judged = np.isfinite(residual)
    inlier = judged & (residual < (options.outvoted_k * sigma_v).astype(np.float32)[obs.view])
    n_inl = np.bincount(rec_var[inlier], minlength=lay.n_var)
    outvoted = judged & ~inlier
    return TemporalResult(bodies=_write_back(bodies, lay, P, sigma, n_inl, shown),
                          record_time=lay.bf_k[bf_rec].astype(np.int32), residual_px=residual, outvoted=outvoted,
                          offset_px=offset)


def _sum_by(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(K, ...) values summed into (n, ...) by (K,) index (bincount per component: no BLAS, no ufunc.at)."""
    flat = per_row(values)
    out = np.stack([np.bincount(index, weights=flat[:, c], minlength=n) for c in range(flat.shape[1])], axis=1)
    return out.reshape((n,) + values.shape[1:])


#: Upper bandwidth of the time chains' matrix: a point's 3 rows reach the rows of the points 2 times away.
_BAND = 8


def _upper_band(A: sp.spmatrix, u: int) -> np.ndarray:
    """LAPACK's upper banded storage (u + 1, n) of a symmetric matrix whose entries lie within u of the diagonal."""
    C = A.tocoo()
    upper = C.col >= C.row
    r, c, v = C.row[upper], C.col[upper], C.data[upper]
    if len(r) and int((c - r).max()) > u:
        raise ValueError(f"matrix bandwidth {int((c - r).max())} > {u}")
    ab = np.zeros((u + 1, A.shape[0]))
    np.add.at(ab, (u + r - c, c), v)
    return ab


def _banded_solver(chain_band: np.ndarray, H_diag: np.ndarray):
    """x -> M^-1 x for M = the time chains + each point's own 3 x 3 block (the system without the bones between
    points), by a banded Cholesky factorisation (LAPACK; the numbering keeps a chain's points consecutive)."""
    u = chain_band.shape[0] - 1
    ab = chain_band.copy()
    base = 3 * np.arange(len(H_diag))
    for i in range(3):
        for k in range(i, 3):
            ab[u + i - k, base + k] += H_diag[:, i, k]
    factor = cholesky_banded(ab, lower=False, check_finite=False)
    return lambda x: cho_solve_banded((factor, False), x, check_finite=False)


def _pcg(A, b: np.ndarray, precondition, tolerance: float, max_iterations: int) -> np.ndarray:
    """Preconditioned conjugate gradients for A(x) = b (A: the product with a symmetric positive definite matrix),
    from x = 0, until the residual is ``tolerance`` x |b|. Dot products by einsum: a multi-threaded BLAS on short
    vectors only contends."""
    dot = lambda u, v: float(np.einsum("i,i->", u, v))  # noqa: E731
    x = np.zeros_like(b)
    r = b.copy()
    z = precondition(r)
    p = z.copy()
    rz = dot(r, z)
    stop = tolerance ** 2 * dot(b, b)
    for _ in range(max_iterations):
        if dot(r, r) <= stop:
            break
        Ap = A(p)
        alpha = rz / dot(p, Ap)
        x += alpha * p
        r -= alpha * Ap
        z = precondition(r)
        rz, rz_old = dot(r, z), rz
        p = z + (rz / rz_old) * p
    return x


def _gap_variance(lay: _Layout, X0: np.ndarray, times_s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(n_var,) q d^3 / 3 where d (s) is the time to the nearest frame of the track at which the per-frame
    triangulation had the joint (0 where it had it)."""
    out = np.zeros(lay.n_var)
    t = times_s[lay.bf_k]
    have = np.isfinite(X0).all(-1)
    for tr in np.unique(lay.bf_track):
        rows = np.flatnonzero(lay.bf_track == tr)
        for j in np.flatnonzero((lay.var[rows] >= 0).any(0)):
            th, tr_t = t[rows][have[rows, j]], t[rows]
            idx = np.searchsorted(th, tr_t)
            left, right = th[np.clip(idx - 1, 0, len(th) - 1)], th[np.clip(idx, 0, len(th) - 1)]
            d = np.minimum(np.abs(tr_t - left), np.abs(right - tr_t))
            out[lay.var[rows, j]] = q[j] * d ** 3 / 3.0
    return out


def _shown(lay: _Layout, X0: np.ndarray, sigma: np.ndarray, max_sigma_cm: float) -> np.ndarray:
    """(n_var,) the solved joints put out: those the per-frame triangulation had, and those whose standard deviation
    is below ``max_sigma_cm``."""
    shown = sigma <= max_sigma_cm
    had = lay.var >= 0
    shown[lay.var[had & np.isfinite(X0).all(-1)]] = True
    return shown


def _write_back(bodies: list[Bodies], lay: _Layout, P: np.ndarray, sigma: np.ndarray, n_inl: np.ndarray,
                shown: np.ndarray) -> list[Bodies]:
    """New bodies with the joints put out (``shown``); c = P(error < 5 cm) under a 3D Gaussian of their sigma."""
    out = [Bodies(X_cm=b.X_cm.copy(), confidence=b.confidence.copy(), n_inliers=b.n_inliers.copy(),
                  n_views=b.n_views, ids=b.ids, assigned=b.assigned) for b in bodies]
    for f in range(len(lay.bf_k)):
        b = out[lay.bf_k[f]]
        p = lay.bf_p[f]
        v = np.maximum(lay.var[f], 0)
        show = (lay.var[f] >= 0) & shown[v]
        b.X_cm[p] = np.where(show[:, None], P[v], np.nan)
        b.confidence[p] = np.where(show, within_probability(5.0, sigma[v]), -1.0)
        b.n_inliers[p] = np.where(show, n_inl[v], 0)
    return out


def within_probability(radius_cm: float, sigma_cm: np.ndarray) -> np.ndarray:
    """P(|e| < radius) for e ~ N(0, sigma^2 I_3): the chi distribution with 3 degrees of freedom."""
    return gammainc(1.5, 0.5 * (radius_cm / np.maximum(sigma_cm, 1e-9)) ** 2)
