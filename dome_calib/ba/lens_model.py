"""Which lens terms of each camera the observations support: free those, hold the others at the prior.

A camera seen in one view of one scene (a real capture with few tent positions, a camera at the edge of the
dome) does not pin down five distortion terms and a principal point: the bundle adjustment then fits them to
noise and the pose pays for it (a principal-point shift looks like a small rotation). This module chooses, per
camera, which of ``cx, cy, k1, k2, p1, p2, k3`` to refine; the focal lengths are always refined (a prior's focal
can be off by percents, and the depth of the scene pins it).

1. Smallest model: a bundle adjustment with every lens term but the focal lengths held at the prior (well posed
   however few the views; a fit with everything free can wander far on weak data, so it is not the reference).
2. At that solution the problem is linearised once over every term the caller left free (reduced camera system
   S with the points eliminated, right-hand side b: the quadratic model of the fit with everything free). The
   pixel noise sigma is the one that model's fit leaves (evaluated after a Levenberg-Marquardt step, with its
   degrees of freedom): the smallest model's own residuals also hold the unmodelled lens.
3. Groups are judged in the order ``principal point, k3, p1 + p2, k2, k1``, each in the quadratic model with
   the groups before it as already decided (Gauss-Newton step ``S^-1 b`` for where the fit would move it from the
   prior, ``sigma^2 S^-1`` for how well). A group is **held at the prior** when both

   - it is poorly determined: one standard deviation of what it adds to the camera's image moves some point of
     a grid over the whole image (the region a calibration is used in, not only where the tent was seen) by more
     than ``max_sigma_px`` (0.5 px, two to three times the feature noise). For a distortion group "what it adds"
     lets the camera's other free distortion terms follow it as the data tie them (k3 alone moves the corners
     by many pixels, but k1 and k2 largely compensate where the points are): the field ``A Sigma_gg A^T`` with
     ``A = J_g + J_r Sigma_rg Sigma_gg^-1``. The principal point is judged by itself against a wider limit,
     ``max_principal_point_sigma_px`` (5 px): a principal point held a few pixels off turns its camera and,
     through the shared points, drags the weak common mode of every camera's principal point and rotation (on
     the panel dome, holding one camera's principal point 2.5 px off moved the median principal-point error of
     all 60 cameras from 1.2 to 2.2 px), so it is held only when the data leave it grossly open (11 to 22 px for
     one view of a real scene; at most 3.9 px on the synthetic panel dome); and
   - the residuals do not need it: its Wald statistic (the change from the prior in units of its covariance,
     ``d^T Sigma^-1 d``, i.e. the cost increase in chi^2 units when it is held) stays below the chi^2 quantile
     of ``needed_p_value`` (1 %: 6.63 for one term, 9.21 for two), i.e. the data do not contradict the prior.

   The principal point's verdict sorts the cameras. Where it is determined, the camera is seen from enough
   directions that only the corners of its lens can be open, where k3 lives: only k3 is judged, p1, p2, k2 and
   k1 stay free. Holding them there would cost more than it saves: decentering is to first order a
   principal-point shift growing with the radius, and k2 trades with the focal length, so a design value held
   a little off is paid for by the principal point, the rotation and, through the shared points, the dome's
   common focal-and-depth mode (on the panel dome: one HD camera's p1, p2 held at the design moved its principal
   point by 7 px and turned it by 0.3 deg; k2 held on 16 cameras moved the mean signed focal error of all 60
   from -0.02 % (only k3 held) to +0.07..0.09 %). Where the principal point is held (one view per camera),
   every distortion group is judged.

4. A bundle adjustment of the chosen model from the smallest model's solution (held terms at the prior). The
   decisions are then taken again at that solution (the linearisation is now close to the chosen fit); if they
   change (in more than ``settled_fraction`` of the judged terms, 0.5 %), solve again (at most ``max_passes``
   passes). Usually two or three solves in all; the linear
   algebra is one factorisation of the reduced camera system per level and pass. Every solve after the first
   is warm-started (``solve(problem, previous)``): from the previous solution and its inliers, so it skips the
   robust stage and re-judges the outliers at the new model's noise; it costs a few iterations, not a
   whole schedule. Uncertainties are the caller's, once, at the returned solution.

**Marginal, not conditional.** Every sigma and Wald statistic above is computed from the group's block of the
INVERSE of the reduced normal matrix over every candidate-free parameter (the points eliminated by the Schur
complement, which marginalises them; rotation, translation, focal lengths, the camera's other lens terms and
every other camera's parameters in the inverse): the group's marginal covariance, how well the data fix it when
everything it trades with is estimated as well. The conditional covariance (the inverse of the group's own
diagonal block: everything else held at its value) is smaller by the factor ``1 - R^2`` (R^2 the group's squared
multiple correlation with the other parameters) and is the wrong one for a term that trades with others: the
principal point of one view of a nearly flat scene (a plane fixes a homography, 8 numbers, against the 9 of pose,
focal length and principal point) has a conditional sigma of 0.01 px and a marginal one of tens of px (tests:
8 views of a 6 x 4 m facade with 5 cm of relief). The Wald statistic likewise uses the marginal covariance:
``d^T Sigma^-1 d`` is then the increase of the cost when the group is held and everything else re-adjusts
(the profile likelihood), not when everything else stays where it is. Where the depth and the other views
resolve the trade (the ring of the tests: twelve cameras around a 3 m cube), the marginal sigma is under 2 px,
still several times the conditional one, and the principal point is freed.

**The noise floor.** The sigma of the decisions is at least ``min_noise_px`` (0.2 px: SIFT's keypoint noise on
the projector patterns, 0.195 px on the panel dome against the rendered truth). After the keypoint refinement
(:mod:`projector.refine`) the residuals measure how consistent a track's keypoints are with EACH OTHER (0.06 px
on the tent), not how far the images are from the camera model: what the refinement aligns is each view's
patch to the reference view's through a locally planar warp, and any error of the model common to a track
(relief inside the patch, the lens between the views, lighting) stays in the observations without showing in
the residuals. Judged at the residuals' 0.07 px, Herz-Jesu-P8 (bench/real.py) freed 34 instead of 15 lens terms
and every figure got worse (pairwise rotations 0.037 -> 0.100 deg, lens 0.40 -> 1.57 px median, the reference
lens being distortion-free), while the same refined observations with the SIFT run's 15 terms improved every
figure (0.037 -> 0.027 deg, centres 0.130 -> 0.105 cm). The floor keeps the decisions at the detector's noise,
what the data were shown to support independently of the refinement; the solve itself still weighs the refined
observations. Measured on the refined observations (floor 0 / 0.1 / 0.15 / 0.2 px), Herz-Jesu pairwise
rotations 0.100 / 0.080 / 0.040 / 0.032 deg; the panel dome at 0 / 0.2: centres 0.177 / 0.179 mm median,
0.56 / 0.48 mm max, focal 0.063 / 0.046 %.

Comparisons use quantised values (:data:`QUANTUM`), so the same observations give the same model on every machine.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
import scipy.stats

from dome_calib.ba.problem import CAMERA_PARAMS, BAProblem
from dome_calib.ba.quadratic import QuadraticModel
from dome_calib.ba.result import BAResult
from dome_calib.ba.schur import Workspace
from dome_calib.ba.solver import BAOptions, bundle_adjust
from dome_calib.camera import distort_with_jacobians, pixels_to_normalized
from dome_calib.options import AtLeast, Field, UnitInterval, options
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)

#: The lens terms (columns 6..14 of a camera's parameters); the focal lengths are always free.
LENS_TERMS = CAMERA_PARAMS[6:]
FOCAL_TERMS = ("fx", "fy")
#: Groups in the order they are judged: (name, terms, is a distortion group).
LEVELS: tuple[tuple[str, tuple[str, ...], bool], ...] = (
    ("principal_point", ("cx", "cy"), False),
    ("k3", ("k3",), True),
    ("tangential", ("p1", "p2"), True),
    ("k2", ("k2",), True),
    ("k1", ("k1",), True),
)
#: Groups judged only on cameras whose principal point is held.
PRINCIPAL_POINT_HELD_ONLY = ("tangential", "k2", "k1")
PRINCIPAL_POINT_COLUMNS = [CAMERA_PARAMS.index("cx"), CAMERA_PARAMS.index("cy")]
DISTORTION_COLUMNS = tuple(CAMERA_PARAMS.index(t) for t in ("k1", "k2", "p1", "p2", "k3"))
#: Comparisons are made on values rounded to this (px and chi^2 alike).
QUANTUM = 1e-3


@options
class LensModelOptions:
    """Rule of :func:`select_lens_model`. A distortion group is determined when one standard deviation of it
    moves no point of the image by more than ``max_sigma_px``; the principal point when its standard deviation is
    at most ``max_principal_point_sigma_px``. It is needed when its Wald statistic reaches the chi^2 quantile
    (as many degrees of freedom as terms) of ``needed_p_value``. ``grid``: columns x rows of image points."""

    max_sigma_px: PosFinite = 0.5
    max_principal_point_sigma_px: PosFinite = 5.0
    needed_p_value: Annotated[float, Field(gt=0, lt=1)] = 0.01
    grid: tuple[AtLeast(2), AtLeast(2)] = (17, 13)
    # a pass whose choice differs from the solved one in at most this fraction of the judged lens terms ends the
    # selection with the solved choice (borderline groups flipping at the threshold, each changing the fit by
    # about its chi2 penalty: the full dome's third pass changed 2, then 4 of 3,647 terms, and each time cost a
    # fourth solve of 28-32 s)
    settled_fraction: UnitInterval = 5e-3
    # the pixel sigma the decisions use is at least this (see "The noise floor" in the module docstring)
    min_noise_px: NonNegFinite = 0.2
    # decide-and-solve passes at most (each one after the first judges again at the last solution)
    max_passes: AtLeast(1) = 3

    def limit_px(self, level: str) -> float:
        return self.max_principal_point_sigma_px if level == "principal_point" else self.max_sigma_px


@dataclass(kw_only=True)
class GroupDecision:
    """One level for one camera. sigma_px: largest 1-sigma image displacement of the group (px); wald_chi2:
    predicted change from the prior in chi^2 units; penalty_chi2: what it has to reach to be needed."""

    group: str
    terms: tuple[str, ...]
    free: bool
    reason: str
    sigma_px: float | None = None
    wald_chi2: float | None = None
    penalty_chi2: float | None = None

    def as_dict(self) -> dict:
        out = {"group": self.group, "terms": list(self.terms), "free": self.free, "reason": self.reason}
        for key in ("sigma_px", "wald_chi2", "penalty_chi2"):
            value = getattr(self, key)
            if value is not None:
                out[key] = round(float(value), 3)
        return out


@dataclass(kw_only=True)
class CameraLensModel:
    """The lens terms of one camera that were refined and those held at the prior, with the decisions."""

    name: str
    free: list[str]
    held: list[str]
    decisions: list[GroupDecision] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"free": self.free, "held": self.held, "decisions": [d.as_dict() for d in self.decisions]}


@dataclass(kw_only=True)
class LensModel:
    """Per camera (by name) the chosen lens model; ``iterations``: the Levenberg-Marquardt iterations of each
    bundle adjustment run (``solves`` of them); ``noise_px``: the pixel sigma the tests used; ``note``: why nothing
    was selected, if so."""

    cameras: dict[str, CameraLensModel]
    options: LensModelOptions
    iterations: list[int]
    noise_px: float | None = None
    note: str = ""

    @property
    def solves(self) -> int:
        return len(self.iterations)

    def as_dict(self) -> dict:
        o = self.options
        rule = (f"fx, fy always free; cx,cy | k3 | p1,p2 | k2 | k1 judged in that order and held at the prior when "
                f"one sigma of what the group adds moves some image point by more than {o.max_sigma_px:g} px "
                f"({o.max_principal_point_sigma_px:g} px for cx,cy) AND its Wald chi2 is below "
                f"the chi2 quantile of p = {o.needed_p_value:g} (the prior is not contradicted at that level); "
                "p1,p2, k2, k1 are judged only where cx,cy are held")
        return {"rule": rule, "max_sigma_px": o.max_sigma_px,
                "max_principal_point_sigma_px": o.max_principal_point_sigma_px,
                "needed_p_value": o.needed_p_value, "noise_px": self.noise_px, "solves": self.solves,
                "iterations_per_solve": list(self.iterations),
                "note": self.note,
                "cameras": {n: c.as_dict() for n, c in sorted(self.cameras.items())}}

    def held_count(self) -> int:
        return sum(len(c.held) for c in self.cameras.values())


def image_jacobian(camera_params: np.ndarray, resolution: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """(N, 2, 9) d pixel / d lens term (LENS_TERMS order) at the rays of a grid of N pixels spanning the image,
    for fixed rays (pose and points unchanged). Rays that the lens cannot undistort are left out."""
    w, h = resolution
    u, v = np.meshgrid(np.linspace(0.0, w - 1.0, grid[0]), np.linspace(0.0, h - 1.0, grid[1]))
    p = np.asarray(camera_params, dtype=float)
    xn = pixels_to_normalized(np.stack([u.ravel(), v.ravel()], -1), p[6:10], p[10:15])
    xn = xn[np.all(np.isfinite(xn), axis=1)]
    xd, _, J_dist = distort_with_jacobians(xn, np.broadcast_to(p[10:15], (len(xn), 5)))
    J = np.zeros((len(xn), 2, 9))
    J[:, 0, 0], J[:, 1, 1] = xd[:, 0], xd[:, 1]
    J[:, 0, 2] = J[:, 1, 3] = 1.0
    J[:, :, 4:] = J_dist * p[6:8][None, :, None]
    return J


def field_sigma_px(cov: np.ndarray, J: np.ndarray, group: list[int] | None = None) -> float:
    """Largest 1-sigma displacement (px) over N image points that terms with covariance (k, k) and image
    Jacobian (N, 2, k) leave open: ``sqrt`` of the largest eigenvalue of ``J Sigma J^T`` at any point.

    With ``group`` (indices into the k terms), only what that group adds: the other terms follow it as the
    data tie them (their regression on it), so the displacement per unit of the group is
    ``A = J_g + J_r Sigma_rg Sigma_gg^-1`` and its field covariance ``A Sigma_gg A^T`` (the part of the field
    covariance that holding the group would remove).
    """
    if group is not None and len(group) < cov.shape[0]:
        rest = [k for k in range(cov.shape[0]) if k not in group]
        S_gg = cov[np.ix_(group, group)]
        regression = cov[np.ix_(rest, group)] @ np.linalg.pinv(S_gg, rcond=1e-12, hermitian=True)
        J, cov = J[:, :, group] + J[:, :, rest] @ regression, S_gg
    V = np.einsum("nik,kl,njl->nij", J, cov, J)
    return float(np.sqrt(max(np.linalg.eigvalsh(V)[:, -1].max(initial=0.0), 0.0)))


def wald_chi2(cov: np.ndarray, delta: np.ndarray) -> float:
    """``delta^T Sigma^-1 delta``: a change (k,) from the prior in units of its covariance (k, k)."""
    return float(delta @ np.linalg.pinv(cov, rcond=1e-12, hermitian=True) @ delta)


def _cols(terms: tuple[str, ...]) -> list[int]:
    return [CAMERA_PARAMS.index(t) for t in terms]


def _q(x: float) -> float:
    return round(x / QUANTUM) * QUANTUM


def _penalty(n_terms: int, options: LensModelOptions) -> float:
    """The Wald chi^2 a group of ``n_terms`` must reach to count as needed (its ``needed_p_value`` quantile)."""
    return float(scipy.stats.chi2.isf(options.needed_p_value, n_terms))


def _decide(level: str, terms: tuple[str, ...], sigma_px: float, wald: float, penalty: float,
            options: LensModelOptions) -> GroupDecision:
    determined = _q(sigma_px) <= _q(options.limit_px(level))
    needed = _q(wald) >= _q(penalty)
    if determined:
        reason = f"determined: one sigma moves the image by at most {sigma_px:.3f} px"
    elif needed:
        reason = (f"needed: the fit moves it from the prior by chi2 {wald:.1f} >= {penalty:.1f}, although one sigma "
                  f"moves the image by {sigma_px:.3f} px")
    else:
        reason = (f"held at the prior: one sigma would move the image by {sigma_px:.3f} px and the fit needs it "
                  f"only by chi2 {wald:.1f} < {penalty:.1f}")
    return GroupDecision(group=level, terms=terms, free=determined or needed, reason=reason, sigma_px=sigma_px,
                         wald_chi2=wald, penalty_chi2=penalty)


def _walk(model: QuadraticModel, point: BAResult, initial: BAProblem, candidate: np.ndarray, judged: list[int],
          options: LensModelOptions) -> tuple[np.ndarray, dict[str, list[GroupDecision]]]:
    """The groups judged top-down in the quadratic model at ``point``: the free mask and the decisions."""
    names = initial.camera_names
    sigma2 = model.noise_px ** 2
    free = candidate.copy()
    decisions: dict[str, list[GroupDecision]] = {n: [] for n in names}
    for level, terms, distortion in LEVELS:
        cols = [CAMERA_PARAMS.index(t) for t in terms]
        groups = {i: [c for c in cols if free[i, c] and model.index[i, c] >= 0] for i in judged}
        if level in PRINCIPAL_POINT_HELD_ONLY:  # see the module docstring: judged only with the principal point held
            groups = {i: g for i, g in groups.items() if not free[i, PRINCIPAL_POINT_COLUMNS].any()}
        groups = {i: g for i, g in groups.items() if g}
        if not groups:
            continue
        # a distortion group is judged by what it adds to the camera's distortion field (the other free
        # distortion terms following it); the principal point by itself
        field = {i: [c for c in DISTORTION_COLUMNS if free[i, c]] if distortion else g for i, g in groups.items()}
        step, blocks = model.step(free, field)
        for i, g in sorted(groups.items()):
            J = image_jacobian(point.problem.camera_params[i], initial.cameras[i].resolution, options.grid)
            in_field = [field[i].index(c) for c in g]
            sigma_px = field_sigma_px(sigma2 * blocks[i], J[:, :, [c - 6 for c in field[i]]], in_field)
            delta = point.problem.camera_params[i, g] + step[i, g] - initial.camera_params[i, g]
            wald = wald_chi2(sigma2 * blocks[i][np.ix_(in_field, in_field)], delta)
            penalty = _penalty(len(g), options)
            decision = _decide(level, tuple(CAMERA_PARAMS[c] for c in g), sigma_px, wald, penalty, options)
            decisions[names[i]].append(decision)
            if not decision.free:
                free[i, g] = False
    return free, decisions


def warm_solver(options: BAOptions, workspace: Workspace | None = None
                ) -> Callable[[BAProblem, BAResult | None], BAResult]:
    """The ``solve`` of :func:`select_lens_model` with :func:`dome_calib.ba.solver.bundle_adjust`: the whole
    schedule for the first solve, warm starts (the previous solution and inliers) for the others; every solve's
    large arrays in ``workspace`` (:class:`dome_calib.ba.schur.Workspace`, default one of the solver's own)."""
    workspace = Workspace() if workspace is None else workspace

    def solve(problem: BAProblem, previous: BAResult | None) -> BAResult:
        if previous is None:
            return bundle_adjust(problem, options, workspace=workspace)
        return bundle_adjust(problem, options, start_inlier=previous.inlier, workspace=workspace)
    return solve


def select_lens_model(initial: BAProblem, solve: Callable[[BAProblem, BAResult | None], BAResult],
                      options: LensModelOptions | None = None, *, n_threads: int = 2,
                      workspace: Workspace | None = None) -> tuple[BAResult, LensModel]:
    """Bundle adjustment with, per camera, only the lens terms the observations support (module docstring).

    Args:
        initial: the problem as given; its parameter values are the prior that held terms keep, its ``free``
            mask the most that may be refined (terms the caller holds stay held and are not judged).
        solve: the bundle adjustment, ``solve(problem, previous)``: the first call with None (the whole
            schedule from ``initial``), the later ones with the previous solve's result to warm-start from (its
            inliers; ``problem`` starts at its solution), see :func:`warm_solver`.
        workspace: where the quadratic models keep their large arrays; the one ``solve`` uses, to share its pages
            (:class:`dome_calib.ba.schur.Workspace`; default a new one).
    Returns:
        the result of the final solve (the chosen model; uncertainties as ``solve`` gives them) and the
        per-camera :class:`LensModel`.
    Example:
        >>> result, lens = select_lens_model(problem, warm_solver(BAOptions(compute_uncertainty=False)))
        >>> lens.cameras["00_03"].held
        ['cx', 'cy', 'p1', 'p2', 'k3']
    """
    options = options or LensModelOptions()
    candidate = initial.free.copy()
    lens_cols = [CAMERA_PARAMS.index(t) for t in LENS_TERMS if t not in FOCAL_TERMS]
    judged = [i for i in range(initial.n_cameras) if candidate[i, lens_cols].any()]
    if not judged:  # nothing to choose (e.g. every lens term held by the caller)
        result = solve(initial, None)
        return result, _lens_model(initial, candidate, {}, options, [len(result.iterations)], None)
    smallest = initial.copy()
    smallest.free[:, lens_cols] = False
    point = solve(smallest, None)
    iterations = [len(point.iterations)]
    free = smallest.free
    n_judged_terms = int(candidate[judged][:, lens_cols].sum())
    solved_with: tuple[dict[str, list[GroupDecision]], float] | None = None
    for _ in range(options.max_passes):
        model = QuadraticModel.at(point, candidate, n_threads=n_threads, noise_floor_px=options.min_noise_px,
                                  workspace=workspace)
        chosen, decisions = _walk(model, point, initial, candidate, judged, options)
        if len(iterations) > 1:
            flipped = int(np.sum(chosen[judged][:, lens_cols] != free[judged][:, lens_cols]))
            if flipped == 0:
                break  # the chosen model's own solution confirms it
            if flipped <= options.settled_fraction * n_judged_terms:
                logger.info("lens model: %d of %d judged terms would flip at the threshold; keeping the solved choice",
                            flipped, n_judged_terms)
                decisions, noise_px = solved_with
                return point, _lens_model(initial, free, decisions, options, iterations, noise_px)
        free = chosen
        solved_with = (decisions, model.noise_px)
        logger.info("lens model: %d of %d candidate lens terms freed (noise %.3f px)",
                    int(free[judged][:, lens_cols].sum()), int(candidate[judged][:, lens_cols].sum()), model.noise_px)
        trial = point.problem.copy()
        trial.camera_params[~free] = initial.camera_params[~free]  # held terms back at the prior
        trial.free = free.copy()
        point = solve(trial, point)
        iterations.append(len(point.iterations))
    return point, _lens_model(initial, free, decisions, options, iterations, model.noise_px)


def _lens_model(initial: BAProblem, free: np.ndarray, decisions: dict[str, list[GroupDecision]],
                options: LensModelOptions, iterations: list[int], noise_px: float | None) -> LensModel:
    cameras = {}
    for i, name in enumerate(initial.camera_names):
        rows = list(decisions.get(name, []))
        seen = {d.group for d in rows}
        for level, terms, _ in LEVELS:
            if level in seen:
                continue
            by_caller = tuple(t for t in terms if not initial.free[i, CAMERA_PARAMS.index(t)])
            if by_caller:
                rows.append(GroupDecision(group=level, terms=by_caller, free=False, reason="held by the caller"))
            elif level in PRINCIPAL_POINT_HELD_ONLY and noise_px is not None and free[i, _cols(terms)].all():
                rows.append(GroupDecision(group=level, terms=terms, free=True, reason="free: the principal point is "
                                          "determined, so only k3 is judged"))
        cameras[name] = CameraLensModel(
            name=name, free=[t for t in LENS_TERMS if free[i, CAMERA_PARAMS.index(t)]],
            held=[t for t in LENS_TERMS if not free[i, CAMERA_PARAMS.index(t)]], decisions=rows)
    return LensModel(cameras=cameras, options=options, iterations=list(iterations), noise_px=noise_px,
                     note="" if noise_px is not None else "no lens term to choose: the caller's free mask is used")
