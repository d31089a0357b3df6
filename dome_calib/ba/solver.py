"""Levenberg-Marquardt bundle adjustment with a robust loss and an outlier schedule.

Schedule (``BAOptions``): stage 1 minimises the robust cost (Huber by default, scale in px) over all
observations until it has found the basin (looser tolerance); then observations whose reprojection error
exceeds a threshold (``outlier_threshold_px``, or ``outlier_sigmas`` x the robust noise estimate) are
rejected and the problem is re-solved with ``final_loss`` (least squares by default: the maximum-likelihood
cost for Gaussian pixel noise once the gross outliers are gone). ``outlier_rounds`` repeats reject/re-solve;
each round re-judges every observation, so wrongly rejected ones come back; the rounds stop once a re-judging
changes at most ``outlier_change_tolerance`` of the observations (the solution it would move is then the same
within its noise). A round that is not the last takes ``intermediate_round_iterations`` LM steps (1): it only
hands its residuals to the next re-judging; if that re-judging settles, the round is converged and judged again,
so a solve ends on a converged stage.

LM follows Ceres' strategy: damping lambda * clamp(diag(J^T W J)), gain ratio rho = actual / predicted
decrease, on failure lambda *= nu, nu *= 2; on success lambda *= max(1/10, 1 - (2 rho - 1)^3) (Nielsen's
rule, but allowed to fall ten-fold instead of three-fold), and ten-fold whenever the model predicted at least
half the decrease (rho > 0.5): the dome's nearly degenerate directions (focal vs depth, k1 vs k2 vs k3)
converge only as fast as the damping vanishes, while the well-determined ones keep rho at 0.6-0.8 with
Nielsen's rule lowering lambda by only 10-50 % per step (measured on the panel dome's lens-model solve: 13
accepted steps at lambda ~5e-7 crawling along that valley, then 2 steps to converge once lambda reached 1e-11).
With ``robust_stage_nielsen`` (off by default) the robust first stage (far from the basin) lowers the damping by
Nielsen's own rule, at most three-fold: after a ten-fold fall its next step was rejected two or three times, each
rejection a new reduced system (``bench/ba.py``'s dome: 8 -> 5 rejected steps, 17 -> 14 systems, every error within
0.4 %); off until measured on the real dome (two path-dependent tests also move with it; docs/benchmarks.md).
Later stages start from the damping the previous stage ended with.

``shorten_rejected_steps`` (off) first tries a rejected step shortened along itself (:func:`_shortened`, one cost
evaluation); measured on the dome, it was taken once in 8 rejections (the others' ends are infinite or thousands of
times the model's), saved no system and moved the path (rotation median +1.3 %).

With ``chord_stop`` (off by default), a stage's last step, the one that meets the stopping rule, is first tried on
the previous accepted step's system and factor (:func:`dome_calib.ba.schur.chord_step`: the new gradient through
the kept elimination): taken when its predicted and actual decrease both meet the rule, it costs no new reduced
system or factorisation. It moves the path, and so the outlier verdicts: on the full dome the largest centre error
by +2.8 %, hence off (docs/benchmarks.md).

The first stage also ends when the outlier verdicts it hands to the rounds have settled (two accepted
iterates reject the same observations within ``outlier_change_tolerance``): its robust loss keeps decreasing
slowly on the gross outliers' linear part long after the inliers sit in the basin (``bench/ba.py --small``:
stage 0 went from 6 iterations with 7 rejected steps to 3, the whole solve from 26 reduced systems to 11).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from functools import partial
from typing import Annotated

import numpy as np

from dome_calib.ba.blas import blas_threads
from dome_calib.ba.evaluate import residuals, residuals_and_jacobians
from dome_calib.ba.gauge import Gauge, GaugeMode, choose_gauge, inner_constraint_basis
from dome_calib.ba.problem import BAProblem
from dome_calib.ba.result import BAResult, CameraUncertainty, IterationLog, camera_statistics
from dome_calib.ba.robust import LossKind, robust_cost_and_weight, robust_sigma_px
from dome_calib.ba.schur import Step, Structure, Workspace, buffer, build_reduced_system, build_structure, \
    chord_step, linearize, solve_reduced
from dome_calib.ba.uncertainty import camera_uncertainty
from dome_calib.options import AtLeast, Lax, UnitInterval, options
from dome_calib.schema import NonNegFinite, PosFinite

logger = logging.getLogger(__name__)
_MIN_LAMBDA = 1e-12
#: rejected steps in a row retried on the same reduced system (camera damping raised, points damped as before)
CHEAP_RETRIES = 3


@options
class BAOptions:
    """Options of :func:`bundle_adjust`. Tolerances are relative; scales and thresholds in pixels."""

    max_iterations: AtLeast(0) = 50  # per stage
    function_tolerance: NonNegFinite = 1e-7  # stop when the relative cost decrease of an accepted step is below
    first_stage_function_tolerance: NonNegFinite = 1e-3  # looser: the first stage only has to expose the outliers
    # also stop when an accepted step lowered the cost by less than this (relative) AND by less than
    # superlinear_ratio of the step before: Gauss-Newton is then converging quadratically and the next step would
    # gain about superlinear_ratio times as little again (the full dome's outlier rounds spent a third iteration,
    # ~10 s, lowering 53,162.66 by 0.0001 after 1.94)
    superlinear_tolerance: NonNegFinite = 1e-5
    superlinear_ratio: NonNegFinite = 1e-3
    parameter_tolerance: NonNegFinite = 1e-10  # stop when |step| / (|x| + tol) is below
    gradient_tolerance: NonNegFinite = 1e-12  # stop when max |gradient| / cost is below
    initial_lambda: PosFinite = 1e-4
    max_consecutive_rejections: AtLeast(1) = 12
    loss: Annotated[LossKind, Lax] = LossKind.HUBER
    loss_scale_px: PosFinite = 2.0
    outlier_rounds: AtLeast(0) = 3  # at most; stops early when re-judging changes (almost) no observation
    # re-judging has converged when it changes at most this fraction of the observations (for the dome's ~1e5-1e6
    # observations, tens to hundreds moving across the threshold by a hair; 0: none may change)
    outlier_change_tolerance: UnitInterval = 1e-3
    # LM steps of a round that is not the last: it only hands the next re-judging its residuals, which one
    # Gauss-Newton step from the previous round's solution already gives to within a hair (the full dome's second
    # steps lowered the cost by 1e-5 to 1e-8 of it); a round whose re-judging then settles is converged before the
    # solve ends (0: converge every round)
    intermediate_round_iterations: AtLeast(0) = 1
    outlier_threshold_px: PosFinite | None = None  # None: outlier_sigmas x robust noise estimate (dof-corrected)
    # the first stage (when outlier rounds follow) also ends once the outlier verdicts it would hand over have
    # settled: two accepted iterates in a row reject the same observations within outlier_change_tolerance
    first_stage_stops_when_outliers_settle: bool = True
    outlier_sigmas: PosFinite = 5.0
    final_loss: Annotated[LossKind, Lax] = LossKind.TRIVIAL
    final_loss_scale_px: PosFinite = 2.0
    gauge: Annotated[GaugeMode, Lax] = GaugeMode.AUTO
    gauge_reference_camera: str | None = None
    gauge_scale_camera: str | None = None
    n_threads: AtLeast(1) = 2
    compute_uncertainty: bool = True
    # a rejected step is first tried shortened along its own direction, to the minimiser of the cost's quadratic
    # interpolation along it (one cost evaluation, no new reduced system or factorisation). Off: measured on the
    # dome it saved no system and moved the path (module docstring)
    shorten_rejected_steps: bool = False
    # the robust stage lowers the damping by Nielsen's own rule (at most three-fold after an accepted step) instead of
    # ten-fold after every step of gain ratio above 0.5 (module docstring). Off by default: it saved 3 of 17 systems
    # on the synthetic dome, every error within 0.4 %, but is not measured on the real dome yet
    robust_stage_nielsen: bool = False
    # try the stopping step on the last accepted step's factor first (schur.chord_step): a stage's last iteration,
    # which only confirms convergence, then costs no new reduced system or factorisation. Off by default: on the
    # full dome it saved 6 of 25 reduced systems (CPU 0.80x of cc26ef0's) but moved the outlier verdicts, and the
    # largest centre error by +2.8 % (docs/benchmarks.md, "Fewer factorisations")
    chord_stop: bool = False


@dataclass(kw_only=True)
class _State:
    camera_params: np.ndarray
    points_cm: np.ndarray
    iterations: list[IterationLog] = field(default_factory=list)


def _cost(state: _State, problem: BAProblem, st: Structure, loss: LossKind, scale: float, n_threads: int = 1
          ) -> tuple[float, np.ndarray]:
    r = residuals(state.camera_params, state.points_cm, st.cam, st.pt, problem.uv_px[st.obs], n_threads=n_threads)
    rho, _ = robust_cost_and_weight(np.sum(r * r, axis=1), loss, scale)
    c = 0.5 * float(np.sum(rho))
    return (c if np.isfinite(c) else np.inf), r


def _decrease(rho: float, robust: bool = False) -> float:
    """Factor on the damping after an accepted step of gain ratio ``rho`` (module docstring); ``robust``: Nielsen's
    own rule, at most three-fold (the robust stage, far from the basin)."""
    if robust:
        return max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
    return 0.1 if rho > 0.5 else max(0.1, 1.0 - (2.0 * rho - 1.0) ** 3)


#: the shortened step's fraction of a rejected step is kept in [SHORTEST, LONGEST]
SHORTEST, LONGEST = 0.1, 0.5


def _shortened(step, lin, cost: float, new_cost: float) -> tuple[float, float] | None:
    """(alpha, the quadratic model's decrease for alpha x step): alpha the minimiser of the quadratic through the
    cost at the step's start (value and slope g.d) and at its end (``new_cost``, the rejected step's), clamped to
    [SHORTEST, LONGEST]; None when the step is no descent direction or its end cost is not finite. The model's
    decrease for alpha d is -alpha g.d - alpha^2 d^T H d / 2, with d^T H d = -g.d - d^T Lambda d from (H + Lambda) d =
    -g and d^T Lambda d = 2 x predicted decrease + g.d."""
    g_dot = float(np.sum(lin.g_c * step.dc) + np.sum(lin.g_p * step.dp))
    if not (g_dot < 0 and np.isfinite(new_cost)):
        return None
    curvature = new_cost - cost - g_dot  # phi(1) - phi(0) - phi'(0): > -g.d > 0 for a rejected step
    alpha = min(max(-g_dot / (2.0 * curvature), SHORTEST), LONGEST) if curvature > 0 else LONGEST
    d_lambda_d = 2.0 * step.predicted_decrease + g_dot
    d_h_d = -g_dot - d_lambda_d
    return alpha, -alpha * g_dot - 0.5 * alpha * alpha * d_h_d


def _outlier_verdicts(r: np.ndarray, st: Structure, options: BAOptions, judged: np.ndarray | None = None
                      ) -> tuple[np.ndarray, float]:
    """(inlier mask of the rows of ``r``, threshold px): ``options.outlier_threshold_px``, or ``outlier_sigmas`` x the
    robust noise of the rows ``judged`` (bool; default all) corrected for the degrees of freedom of the fit of
    ``st``."""
    err = np.linalg.norm(r, axis=1)
    judged = np.ones(len(r), dtype=bool) if judged is None else judged
    threshold_px = options.outlier_threshold_px
    if threshold_px is None:
        n_res = 2 * len(st.obs)
        n_par = len(st.free_flat) + 3 * int(st.live_points.sum())
        dof = max(1.0 - n_par / max(n_res, 1), 0.1)
        sigma = robust_sigma_px(r[judged & np.isfinite(err)]) / np.sqrt(dof)
        threshold_px = options.outlier_sigmas * sigma
    return np.isfinite(err) & (err <= threshold_px), threshold_px


def _apply(state: _State, st: Structure, dc: np.ndarray, dp: np.ndarray) -> _State:
    """New state with the step added to free parameters only (fixed ones stay bit-identical)."""
    cp = state.camera_params.copy()
    a = st.active_cameras
    cp[a] = np.where(st.free, cp[a] + dc, cp[a])
    pts = np.where(st.live_points[:, None], state.points_cm + dp, state.points_cm)
    return _State(camera_params=cp, points_cm=pts, iterations=state.iterations)


def _stops(decrease: float, cost_before: float, last_decrease: float, ftol: float, options: BAOptions) -> str | None:
    """The stopping rule on an accepted step's cost decrease (None: go on)."""
    rel_decrease = decrease / max(cost_before, 1e-300)
    if rel_decrease < ftol:
        return "function_tolerance"
    if rel_decrease < options.superlinear_tolerance and decrease < options.superlinear_ratio * last_decrease:
        return "superlinear"
    return None


def _chord_stop(problem: BAProblem, state: _State, st: Structure, options: BAOptions, lin, system, cost: float,
                last_decrease: float, ftol: float, loss: LossKind, scale: float, stage: int, it: int, t_start: float,
                n_res: int) -> tuple[_State, str] | None:
    """The chord step (:func:`dome_calib.ba.schur.chord_step`: the new gradient on the last accepted step's system and
    factor) when its predicted and its actual decrease both meet the stopping rule: (the state it reaches, the
    reason), logged as iteration ``it``; else None (the iteration then builds its system as usual)."""
    step = chord_step(st, lin, system)
    if step is None or not step.predicted_decrease > 0:
        return None
    if _stops(step.predicted_decrease, cost, last_decrease, ftol, options) is None:
        return None
    new_state = _apply(state, st, step.dc, step.dp)
    new_cost, new_r = _cost(new_state, problem, st, loss, scale, options.n_threads)
    decrease = cost - new_cost
    if not (np.isfinite(new_cost) and decrease > 1e-3 * step.predicted_decrease):
        return None
    reason = _stops(decrease, cost, last_decrease, ftol, options)
    if reason is None:
        return None
    step_norm = float(np.sqrt(np.sum(step.dc ** 2) + np.sum(step.dp ** 2)))
    rms = float(np.sqrt(np.sum(new_r * new_r) / n_res))
    entry = IterationLog(stage=stage, iteration=it, cost=new_cost, rms_px=rms, step_norm=step_norm,
                         lam=system.lam_cameras, rejected_steps=0, time_s=time.perf_counter() - t_start,
                         factorisations=0, reduced_systems=0)
    new_state.iterations.append(entry)
    logger.info("ba stage %d it %2d: cost %.9g  rms %.4f px  step %.3g  on the last factor (chord), %.1f s", stage, it,
                new_cost, rms, step_norm, entry.time_s)
    return new_state, reason


def _levenberg_marquardt(problem: BAProblem, state: _State, st: Structure, options: BAOptions, *,
                         loss: LossKind, scale: float, ftol: float, stage: int, lam: float, inner: bool = False,
                         until_outliers_settle: bool = False, max_iterations: int | None = None
                         ) -> tuple[_State, str, float]:
    """LM iterations from ``state``; ``until_outliers_settle``: also stop (reason ``outliers_settled``) once two
    accepted iterates in a row give the same outlier verdicts on the structure's observations (at most
    ``outlier_change_tolerance`` of them differ). ``max_iterations``: a cap below ``options.max_iterations``
    (reason ``capped`` when it ends the stage)."""
    nu = 2.0
    cost, r0 = _cost(state, problem, st, loss, scale, options.n_threads)
    verdicts = _outlier_verdicts(r0, st, options)[0] if until_outliers_settle else None
    # in the basin (least squares), a rejected step is retried with more damping on the cameras only (a new
    # factorisation of the kept reduced system, not a new elimination of the points); after CHEAP_RETRIES, from
    # scratch. Far from it (the robust stage), where the points' own steps can be what fails, always from scratch
    # (a test with 3 % outliers kept 24 wrongly rejected inliers)
    cheap = CHEAP_RETRIES if loss is LossKind.TRIVIAL else 0
    robust = loss is not LossKind.TRIVIAL and options.robust_stage_nielsen
    n_res = 2 * len(st.obs)
    reason = "max_iterations"
    t_start = time.perf_counter()
    last_decrease = 0.0  # no evidence of superlinear convergence before a second accepted step
    cap = options.max_iterations if max_iterations is None else min(max_iterations, options.max_iterations)
    if cap < options.max_iterations:
        reason = "capped"
    chord_from = None  # the last accepted step's system and factor (schur.chord_step)
    for it in range(1, cap + 1):
        M = len(st.obs)  # the Jacobians in the structure's kept buffers (dome_calib.ba.schur.buffer)
        res, Jc, Jp = residuals_and_jacobians(state.camera_params, state.points_cm, st.cam, st.pt,
                                              problem.uv_px[st.obs], n_threads=options.n_threads,
                                              out=(buffer(st, "res", (2, M)), buffer(st, "Jc", (2, 15, M)),
                                                   buffer(st, "Jp", (2, 3, M))))
        _, w = robust_cost_and_weight(res[0] ** 2 + res[1] ** 2, loss, scale)
        lin = linearize(st, res, Jc, Jp, w, n_threads=options.n_threads)
        del res, Jc, Jp
        g_max = max(np.abs(lin.g_c).max(initial=0.0), np.abs(lin.g_p).max(initial=0.0))
        if g_max <= options.gradient_tolerance * max(cost, 1e-300):
            reason = "gradient_tolerance"
            break
        if chord_from is not None and options.chord_stop:
            # the stopping step on the last system's factor: if its gain already meets the stopping rule, it is
            # taken and the stage ends without a new reduced system (module docstring, "Stopping")
            stop = _chord_stop(problem, state, st, options, lin, chord_from, cost, last_decrease, ftol, loss, scale,
                               stage, it, t_start, n_res)
            chord_from = None
            if stop is not None:
                state, reason = stop
                break
        basis = (inner_constraint_basis(state.camera_params[st.active_cameras], st.free, lin.D_c) if inner
                 else None)
        rejections, shortened, built = 0, False, 0
        system = None
        while True:
            try:
                if system is None or rejections % (cheap + 1) == 0:
                    system = None  # the old system's memory goes before the new one is built
                    system = build_reduced_system(st, lin, lam, n_threads=options.n_threads, gauge_basis=basis)
                    built += 1
                step = solve_reduced(st, lin, system, lam, n_threads=options.n_threads, keep_factor=options.chord_stop)
                new_state = _apply(state, st, step.dc, step.dp)
                new_cost, new_r = _cost(new_state, problem, st, loss, scale, options.n_threads)
            except np.linalg.LinAlgError:
                step, new_cost, new_r = None, np.inf, None
            rho = (cost - new_cost) / step.predicted_decrease if step and step.predicted_decrease > 0 else -1.0
            if np.isfinite(new_cost) and rho > 1e-3:
                lam = max(lam * _decrease(rho, robust), _MIN_LAMBDA)
                nu = 2.0
                break
            short = (_shortened(step, lin, cost, new_cost) if step is not None and options.shorten_rejected_steps
                     else None)
            if short is not None and short[1] > 0:
                alpha, predicted = short
                short_state = _apply(state, st, alpha * step.dc, alpha * step.dp)
                short_cost, short_r = _cost(short_state, problem, st, loss, scale, options.n_threads)
                if np.isfinite(short_cost) and cost - short_cost > 1e-3 * predicted:
                    # taken; the next system is damped as after one rejection (the full step's model was poor)
                    logger.debug("ba stage %d it %d: step rejected (rho %.3g), taken at %.3g of its length "
                                 "(rho %.3g)", stage, it, rho, alpha, (cost - short_cost) / predicted)
                    step = Step(dc=alpha * step.dc, dp=alpha * step.dp, predicted_decrease=predicted)
                    new_state, new_cost, new_r = short_state, short_cost, short_r
                    lam *= 2.0
                    nu = 2.0
                    shortened = True
                    break
            rejections += 1
            logger.debug("ba stage %d it %d: step rejected (rho %.3g), lambda %.3g -> %.3g", stage, it, rho,
                         lam, lam * nu)
            lam *= nu
            nu *= 2.0
            if rejections >= options.max_consecutive_rejections:
                return state, "no_decrease", options.initial_lambda
        step_norm = float(np.sqrt(np.sum(step.dc ** 2) + np.sum(step.dp ** 2)))
        x_norm = float(np.sqrt(np.sum(state.camera_params ** 2) + np.sum(state.points_cm ** 2)))
        decrease = cost - new_cost
        stop = _stops(decrease, cost, last_decrease, ftol, options)
        state, cost = new_state, new_cost
        chord_from = system if options.chord_stop else None
        rms = float(np.sqrt(np.sum(new_r * new_r) / n_res))  # plain RMS of the residuals, whatever the loss
        entry = IterationLog(stage=stage, iteration=it, cost=cost, rms_px=rms, step_norm=step_norm, lam=lam,
                             rejected_steps=rejections, time_s=time.perf_counter() - t_start,
                             factorisations=rejections + 1, reduced_systems=built,
                             shortened=shortened)
        state.iterations.append(entry)
        logger.info("ba stage %d it %2d: cost %.9g  rms %.4f px  step %.3g  lambda %.3g  (%d rejected%s, %.1f s)",
                    stage, it, cost, rms, step_norm, lam, rejections, ", shortened" if shortened else "",
                    entry.time_s)
        if stop is not None:
            reason = stop
            break
        last_decrease = decrease
        if verdicts is not None:
            new_verdicts = _outlier_verdicts(new_r, st, options)[0]
            settled = int(np.sum(new_verdicts != verdicts)) <= options.outlier_change_tolerance * len(new_r)
            verdicts = new_verdicts
            if settled:
                reason = "outliers_settled"
                break
        if step_norm <= options.parameter_tolerance * (x_norm + options.parameter_tolerance):
            reason = "parameter_tolerance"
            break
    return state, reason, lam


def bundle_adjust(problem: BAProblem, options: BAOptions | None = None, *,
                  start_inlier: np.ndarray | None = None, workspace: Workspace | None = None) -> BAResult:
    """Refine cameras and points of ``problem`` (not modified); returns a :class:`BAResult`.

    The gauge is fixed as described in :mod:`dome_calib.ba.gauge`; parameters with ``problem.free`` False stay
    bit-identical. Per-iteration progress goes to the ``dome_calib.ba.solver`` logger at INFO level.

    ``start_inlier`` (M,) bool: a warm start, the inliers of an earlier solve of the same observations from
    which ``problem`` starts (e.g. the same problem with other parameters free). The robust first stage, whose
    job is to find the basin and expose the gross outliers, is then skipped: the schedule starts with the
    final loss on those inliers (to ``first_stage_function_tolerance`` when outlier rounds follow) and the
    outlier rounds re-judge every observation as usual (stopping as soon as a round changes almost none).
    The damping starts at ``options.initial_lambda`` as in a cold start: the earlier solve's last damping is far
    too small for a problem with other parameters free (measured on the panel dome: 6 rejected steps, 30 % more
    reduced systems, for the same minimum).

    ``workspace``: where the solver keeps its large arrays (:class:`dome_calib.ba.schur.Workspace`; default a new one
    for this solve): hand the same one to a series of solves of one problem to reuse them across the series.
    Example:
        >>> result = bundle_adjust(problem, BAOptions(loss="huber", loss_scale_px=2.0))
        >>> bundle = result.problem.to_bundle(seq="160906_band1")
    """
    options = options or BAOptions()
    if start_inlier is not None and np.shape(start_inlier) != (problem.n_observations,):
        raise ValueError(f"start_inlier has shape {np.shape(start_inlier)}, the problem has "
                         f"{problem.n_observations} observations")
    # small BLAS calls: one thread (see dome_calib.ba.blas); the big Cholesky takes more
    with blas_threads(1):
        return _bundle_adjust(problem, options, start_inlier, Workspace() if workspace is None else workspace)


def solution_uncertainty(result: BAResult, *, n_threads: int = 2, workspace: Workspace | None = None
                         ) -> CameraUncertainty:
    """The camera uncertainties of a solve's solution (what ``BAOptions.compute_uncertainty`` adds to it), for
    a result computed without them: the same reduced system at ``result.problem`` over its used observations
    (its large arrays in ``workspace``, e.g. the one the solves used)."""
    p = result.problem
    st = build_structure(p.camera_index, p.point_index, result.inlier, p.free & ~result.gauge.held, p.n_points,
                         workspace)
    with blas_threads(1):
        return camera_uncertainty(p, st, result.sigma_px, n_threads=n_threads, gauge=result.gauge)


def _bundle_adjust(problem: BAProblem, options: BAOptions, start_inlier: np.ndarray | None, workspace: Workspace
                   ) -> BAResult:
    t0 = time.perf_counter()
    gauge: Gauge = choose_gauge(problem, mode=options.gauge, reference_camera=options.gauge_reference_camera,
                                scale_camera=options.gauge_scale_camera)
    # inner constraints: the gauge's parameters stay free in the solve and are held only for the uncertainties
    free = problem.free if gauge.inner else problem.free & ~gauge.held
    state = _State(camera_params=problem.camera_params.copy(), points_cm=problem.points_cm.copy())
    M = problem.n_observations
    warm = start_inlier is not None
    inlier = np.asarray(start_inlier, dtype=bool).copy() if warm else np.ones(M, dtype=bool)
    rounds = options.outlier_rounds
    st = build_structure(problem.camera_index, problem.point_index, inlier, free, problem.n_points, workspace)
    # stage 0: cold, the robust loss on everything until the basin is found; warm (in the basin, gross outliers
    # known), the final loss on the given inliers. Both to the first stage's looser tolerance when rounds follow
    # (they re-judge and converge it; measured on the panel dome's warm lens-model solve: 24 iterations, not 28)
    loss, scale = (options.final_loss, options.final_loss_scale_px) if warm else (options.loss, options.loss_scale_px)
    ftol = options.first_stage_function_tolerance if rounds else options.function_tolerance
    state, reason, lam = _levenberg_marquardt(
        problem, state, st, options, loss=LossKind(loss), scale=scale, ftol=ftol, stage=0, lam=options.initial_lambda,
        inner=gauge.inner, until_outliers_settle=bool(rounds) and options.first_stage_stops_when_outliers_settle)
    reasons = [reason]
    threshold_px = None
    final_stage = partial(_levenberg_marquardt, problem, loss=LossKind(options.final_loss),
                          scale=options.final_loss_scale_px, ftol=options.function_tolerance, inner=gauge.inner)
    rnd = 1
    while rnd <= rounds:
        r_all = residuals(state.camera_params, state.points_cm, problem.camera_index, problem.point_index,
                          problem.uv_px, n_threads=options.n_threads)
        new_inlier, threshold_px = _outlier_verdicts(r_all, st, options, judged=inlier)
        changed = int(np.sum(new_inlier != inlier))
        logger.info("ba outliers round %d: threshold %.3f px, %d of %d observations rejected (%d changed)", rnd,
                    threshold_px, int((~new_inlier).sum()), M, changed)
        # round 1 always runs: the solve never ends on the first stage's loose tolerance or robust loss
        if changed <= options.outlier_change_tolerance * M and rnd > 1:
            if reason != "capped":
                break
            # settled at a round's first step: converge that round, then judge again (converged, its residuals
            # can still move observations across the threshold)
            state, reason, lam = final_stage(state, st, options, stage=rnd - 1, lam=lam)
            reasons.append(reason)
            continue
        inlier = new_inlier
        st = build_structure(problem.camera_index, problem.point_index, inlier, free, problem.n_points, workspace)
        cap = options.intermediate_round_iterations if rnd < rounds and options.intermediate_round_iterations else None
        state, reason, lam = final_stage(state, st, options, stage=rnd, lam=lam, max_iterations=cap)
        reasons.append(reason)
        rnd += 1
    refined = problem.copy()
    refined.camera_params = state.camera_params
    refined.points_cm = state.points_cm
    if gauge.inner:  # statistics and uncertainties with the gauge held (7 fewer unknowns, a regular system)
        st = build_structure(problem.camera_index, problem.point_index, inlier, problem.free & ~gauge.held,
                             problem.n_points, workspace)
    result = camera_statistics(refined, st, inlier, gauge=gauge, iterations=state.iterations,
                               termination=reasons, outlier_threshold_px=threshold_px)
    if options.compute_uncertainty:
        result.uncertainty = camera_uncertainty(refined, st, result.sigma_px, n_threads=options.n_threads,
                                                gauge=gauge)
    result.time_s = time.perf_counter() - t0
    logger.info("ba done: %d iterations, rms %.4f px, %d inliers, %.1f s", len(state.iterations), result.rms_px,
                int(inlier.sum()), result.time_s)
    return result
