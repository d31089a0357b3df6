"""Track a patch cloud from its seed time, one reference-stream frame at a time, backward or forward.

One step, from reference time ``t`` to ``t'``, for each of the at most ``track_views`` cameras that saw a patch at
``t`` chosen by :func:`best_views` (the most face-on, spread in direction; ``track_views`` 0: every camera that saw
it):

1. **the camera's own frames** (its stream's sync table, :func:`dome_calib.recon.streams.frame_brackets`: the one
   place where a stream is brought to universal time): ``t`` lies between frames ``a`` and ``a+`` (weight ``w``
   of ``a+``; in travel order). The patch's three points are projected at ``t`` (``p``); if ``w > 0`` the flow
   ``d`` from ``a`` to ``a+`` at ``p`` places them at ``p - w d`` in frame ``a`` and ``p + (1 - w) d`` in ``a+``, so
   that the camera's track, interpolated linearly to ``t`` as every stream is, passes through the projection;
2. **optical flow** (pyramidal Lucas-Kanade, forward-backward checked) carries the points through the camera's
   frames up to the two frames around ``t'``, and the track is interpolated linearly to ``t'`` the same way
   (for a reference-stream camera both weights are 0 or 1: one flow step, the CVPR 2014 method itself); with
   ``lk_predict``, from a patch's second step on, each flow starts at the point's predicted motion (its last
   step's 3D velocity projected at the frames' times) with ``lk_levels_predicted`` pyramid levels;
3. **triangulation** of each point from the cameras it was tracked in (robust, inliers within
   ``triangulation_px``), then the MAP visibility at ``t'`` in **every** camera (:mod:`.visibility`; a camera the
   patch was not flown in has no motion term), then the points triangulated again from the visible tracked
   cameras alone (if at least two).

A plane point that cannot be triangulated moves with the centre. A patch ends when its centre cannot be
triangulated, fewer than ``min_visible`` cameras see it, or a plane point's distance to the centre changed by more
than ``max_stretch`` in the step; then its plane points are put back at ``axis_cm`` from the centre, orthogonal
(:func:`square_up`: the patch is a rigid square whose plane the points give). Every operation is per patch (optical flow per point,
triangulation per point with draws keyed by its own pixels, one cut whose labels do not depend on the other
graphs), and positions are quantised to 2^-10 cm after each step: tracking any subset of a cloud gives its patches
bit for bit what tracking the whole cloud gives them.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dome_calib.bundle import SyncTable
from dome_calib.recon.patches.frames import FrameSource, patch_axes, project_one
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.motion import bone_carry
from dome_calib.recon.patches.occlusion import PART_RADIUS_CM, BodyPrior
from dome_calib.recon.patches.parts import bone_segments, nearest_part
from dome_calib.recon.patches.seed import optical_flow
from dome_calib.recon.patches.visibility import Frames, Visibility, estimate_visibility, off_seed
from dome_calib.recon.patches.warp import seed_to_now, warp_px, warped_flow
from dome_calib.recon.project import ViewSet, project_view
from dome_calib.recon.streams import frame_brackets, frame_period_ms
from dome_calib.recon.triangulate import TriangulationOptions, triangulate
from dome_calib import ties

logger = logging.getLogger(__name__)

#: Patch positions are rounded to multiples of this after every step (cm): no later choice rests on last bits.
POSITION_QUANTUM_CM = 2.0 ** -10
#: A camera's frame within this of a reference time (ms) is at that very time (the reference stream's cameras).
SAME_TIME_MS = 0.5
#: Streams' brackets wider than this many nominal periods are not bridged (as the skeleton stages).
MAX_GAP_FRAMES = 2.5


@dataclass(frozen=True)
class Clock:
    """One camera's frames: its stream's table and the frame indices the source holds (increasing)."""

    table: SyncTable
    frames: np.ndarray

    def times(self) -> np.ndarray:
        return self.table.times_of(self.frames)


@dataclass(frozen=True)
class CloudTrack:
    """One cloud over its reference times (T, travel order from the seed): X_cm (N, T, 3, 3) (NaN: ended);
    visible, photometric (N, T, V) bool; alive (N, T); carried (N, T) bool or None: the patch was kept at that time
    by its part's motion alone (``refind_carry_steps``: predicted, not measured; not alive there, no position, no
    view)."""

    times_ms: np.ndarray
    X_cm: np.ndarray
    visible: np.ndarray
    photometric: np.ndarray
    alive: np.ndarray
    carried: np.ndarray | None = None
    # (N,) int8: the rule that ended each patch (END_CAUSES; 0: not ended); a diagnosis of run_cloud's tracks
    # (bench/patch_ends.py), not kept in PatchTrajectories
    ended: np.ndarray | None = None


#: Why a patch ended at a step (:attr:`CloudTrack.ended`, an index into this; "" not ended), in the order the rules
#: are applied: its centre's flow kept in fewer than two of its flown views ("flow") or kept in two or more with no
#: two agreeing within ``triangulation_px`` ("triangulation"); seen by fewer than ``min_visible`` cameras after the
#: MAP cut because fewer than that many are in the image and faced ("unseen_geometry"), or are once the people's
#: occlusion is taken out ("unseen_body"), or the cut labelled the candidates "not visible" where one of them had a
#: failed flow in the motion term ("unseen_flow") or none had ("unseen_photo"); a plane point's distance changed
#: ("stretched"); off its seed appearance ("slid").
END_CAUSES = ("", "flow", "triangulation", "unseen_geometry", "unseen_body", "unseen_flow", "unseen_photo",
              "stretched", "slid")


def end_causes(lost: np.ndarray, unseen: np.ndarray, stretched: np.ndarray, slid: np.ndarray, tracked: np.ndarray,
               vis: Visibility, motion: np.ndarray, o: PatchOptions) -> np.ndarray:
    """(N,) int8: the :data:`END_CAUSES` index of each patch ended at a step by the rules' masks (N,), ``tracked``
    (N, 3, V) the step's flows, ``vis`` the step's visibility and ``motion`` (N, V) its motion term."""
    out = np.zeros(len(lost), np.int8)
    code = {c: np.int8(i) for i, c in enumerate(END_CAUSES)}
    out[lost] = np.where(tracked[lost, 0].sum(axis=1) < 2, code["flow"], code["triangulation"])
    hidden = vis.hidden if vis.hidden is not None else np.zeros_like(vis.candidate)
    shown = (vis.candidate | hidden).sum(axis=1) >= o.min_visible
    by_flow = (vis.candidate & np.isinf(motion)).any(axis=1)
    out[unseen] = np.select([~shown[unseen], vis.candidate[unseen].sum(axis=1) < o.min_visible, by_flow[unseen]],
                            [code["unseen_geometry"], code["unseen_body"], code["unseen_flow"]], code["unseen_photo"])
    out[stretched], out[slid] = code["stretched"], code["slid"]
    return out


def quantise_cm(X: np.ndarray) -> np.ndarray:
    return np.rint(X / POSITION_QUANTUM_CM) * POSITION_QUANTUM_CM


def judged_frames(clocks: list[Clock], t_ms: float) -> Frames:
    """Each camera's frame nearest ``t_ms`` among those it holds, and its time offset (-1 / 0 if none within half
    a nominal period)."""
    frame, offset = np.full(len(clocks), -1, np.int64), np.zeros(len(clocks))
    for v, c in enumerate(clocks):
        if len(c.frames) == 0:
            continue
        times = c.times()
        i = ties.argmin_first(np.abs(times - t_ms), ties.TIME_QUANTUM_MS)
        if abs(times[i] - t_ms) <= 0.5 * frame_period_ms(c.table) + 1e-6:
            frame[v], offset[v] = c.frames[i], times[i] - t_ms
    return Frames(frame=frame, offset_ms=offset, t_ms=float(t_ms))


def _bracket(clock: Clock, t_ms: float, forward: bool) -> tuple[int, int, float] | None:
    """(behind, ahead, weight of ahead) positions into ``clock.frames`` around ``t_ms`` in travel order."""
    b = frame_brackets(clock.table, clock.frames, np.array([t_ms]), max_gap_frames=MAX_GAP_FRAMES)
    if not (b.usable[0] and b.has0[0] and b.has1[0]):
        return None
    if forward:
        return int(b.pos0[0]), int(b.pos1[0]), float(b.w1[0])
    return int(b.pos1[0]), int(b.pos0[0]), float(b.w0[0])


#: Predicts where a camera's points (M, 2) are at a universal time (ms): (M, 2) pixels (:func:`track_cloud`).
Predictor = Callable[[float], np.ndarray]


def predicted_motion(predict: Predictor, t_i: float, t_j: float, o: PatchOptions) -> tuple[np.ndarray, np.ndarray]:
    """The predicted image motion (M, 2) of a camera's points from its frame at ``t_i`` to the one at ``t_j`` (0
    where the prediction is not finite) and each point's pyramid levels (M,): ``lk_levels_predicted``, or
    ``lk_levels`` where the predicted motion is at least ``lk_levels_full_px`` (if that is not 0)."""
    shift = predict(t_j) - predict(t_i)
    shift = np.where(np.all(np.isfinite(shift), axis=1, keepdims=True), shift, 0.0)
    levels = np.full(len(shift), o.lk_levels_predicted, np.int64)
    if o.lk_levels_full_px > 0:
        # quantised before the comparison: no choice rests on last bits
        levels[ties.at_least(np.linalg.norm(shift, axis=1), o.lk_levels_full_px, ties.FLOW_QUANTUM_PX)] = o.lk_levels
    return shift, levels


def _flow_step(source: FrameSource, name: str, clock: Clock, i: int, j: int, p: np.ndarray, o: PatchOptions,
               predict: Predictor | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) from frame position i to j of one camera -> ((M, 2), (M,) ok). With ``predict``: each point's
    flow starts at ``p`` plus its predicted motion between the two frames' times, with its own pyramid levels
    (:func:`predicted_motion`; one call per level count)."""
    if i == j:
        return p.copy(), np.ones(len(p), bool)
    a = source.gray(name, int(clock.frames[i]))
    b = source.gray(name, int(clock.frames[j]))
    if predict is None:
        return optical_flow(a, b, p, o)
    t = clock.table.times_of(clock.frames[[i, j]])
    shift, levels = predicted_motion(predict, float(t[0]), float(t[1]), o)
    q, ok = np.empty((len(p), 2)), np.zeros(len(p), bool)
    for lv in np.unique(levels):
        rows = np.flatnonzero(levels == lv)
        q[rows], ok[rows] = optical_flow(a, b, p[rows], o, guess=p[rows] + shift[rows], levels=int(lv),
                                         predicted=True)
    return q, ok


def flow_camera(source: FrameSource, name: str, clock: Clock, t0: float, t1: float, p: np.ndarray,
                o: PatchOptions, predict: Predictor | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) where the camera's track meets reference time t0 -> ((M, 2) where it meets t1, (M,) ok).
    ``predict``: where the points are predicted at a time (each flow step starts at the predicted motion, see
    :func:`_flow_step`); None: every flow starts where the point is."""
    forward = t1 > t0
    b0, b1 = _bracket(clock, t0, forward), _bracket(clock, t1, forward)
    M = len(p)
    if b0 is None or b1 is None:
        return np.full((M, 2), np.nan), np.zeros(M, bool)
    step = 1 if forward else -1
    a, a_next, w = b0
    known: dict[int, np.ndarray] = {}
    ok = np.ones(M, bool)
    if w >= 1.0:  # t0 is the ahead frame's own time
        known[a_next] = p
        last = a_next
    elif w > 0:
        q, good = _flow_step(source, name, clock, a, a_next, p, o, predict)
        d = q - p
        known[a], known[a_next] = p - w * d, p + (1 - w) * d
        ok &= good
        last = a_next
    else:
        known[a] = p
        last = a
    b, b_next, w1 = b1
    need = b_next if w1 > 0 else b
    while (need - last) * step > 0:
        q, good = _flow_step(source, name, clock, last, last + step, known[last], o, predict)
        known[last + step] = q
        ok &= good
        last += step
    if w1 >= 1.0:
        out = known[b_next]
    elif w1 == 0:
        out = known[b]
    else:
        out = (1 - w1) * known[b] + w1 * known[b_next]
    return out, ok


def refind_lost(source: FrameSource, name: str, clock: Clock, t0: float, t1: float, p: np.ndarray, q: np.ndarray,
                ok: np.ndarray, o: PatchOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lost point re-found from where its patch went (``PatchOptions.lk_refind``): patches (n, 3) of one camera,
    their points at t0 ``p`` (n, 3, 2), flown to t1 ``q`` (n, 3, 2), ``ok`` (n, 3). A point whose flow failed in a
    patch with another point tracked in this camera is flown again (:func:`flow_camera`), started at its own
    position moved by the mean image motion of its patch's tracked points there (the patch is a 6 cm square: its
    points move together), one prediction's pyramid levels, the same forward-backward check; kept where it passes.
    -> (q, ok, re-found (n, 3))."""
    some = ok.any(axis=1) & ~ok.all(axis=1)
    if not some.any() or t1 == t0:
        return q.copy(), ok.copy(), np.zeros(ok.shape, bool)
    n_ok = ok.sum(axis=1, keepdims=True)
    shift = np.where(ok[..., None], q - p, 0.0).sum(axis=1) / np.maximum(n_ok, 1)  # (n, 2)
    rows, cols = np.nonzero(some[:, None] & ~ok)
    start, move = p[rows, cols], shift[rows]
    return _fly_again(source, name, clock, t0, t1, q, ok, rows, cols, start,
                      lambda t_ms: start + move * ((t_ms - t0) / (t1 - t0)), o)


def _fly_again(source: FrameSource, name: str, clock: Clock, t0: float, t1: float, q: np.ndarray, ok: np.ndarray,
               rows: np.ndarray, cols: np.ndarray, start: np.ndarray, predict: Predictor, o: PatchOptions
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lost points (``rows``, ``cols``) of ``q`` (n, 3, 2) / ``ok`` (n, 3) flown again from ``start`` with the
    prediction ``predict`` (:func:`flow_camera`), kept where they pass -> (new q, new ok, re-found (n, 3)): the one
    re-flight of :func:`refind_lost` and :func:`refind_from_body`."""
    q, ok, found = q.copy(), ok.copy(), np.zeros(ok.shape, bool)
    r, good = flow_camera(source, name, clock, t0, t1, start, o, predict)
    q[rows[good], cols[good]] = r[good]
    ok[rows[good], cols[good]] = True
    found[rows[good], cols[good]] = True
    return q, ok, found


def body_prediction(X: np.ndarray, J0: np.ndarray, J1: np.ndarray, o: PatchOptions) -> np.ndarray:
    """Patches (n, 3, 3) at t0 -> where the body over time carries them at t1 (n, 3, 3), NaN where it cannot: each
    patch's part at t0 (:func:`~.parts.nearest_part`: the capsule of :data:`~.occlusion.PART_RADIUS_CM` whose
    surface is nearest its centre, within ``seed_depth_window_cm``, how far the skeleton seeds take the real
    surface to lie from it) and that bone's move from t0 to t1 (:func:`~.motion.bone_carry`); ``J0``, ``J1``
    (P, 19, 3) the people at t0 and t1 (:meth:`BodyPrior.at`, the same people in the same order)."""
    out = np.full(X.shape, np.nan)
    if len(X) == 0 or len(J0) == 0 or len(J1) != len(J0):
        return out
    person, bone = nearest_part(X[:, 0], J0, PART_RADIUS_CM, o.seed_depth_window_cm)
    on = np.flatnonzero(person >= 0)
    if len(on):
        (A0, B0), (A1, B1) = bone_segments(J0), bone_segments(J1)
        pb = (person[on], bone[on])
        out[on] = bone_carry(X[on], A0[pb], B0[pb], A1[pb], B1[pb])
    return out


def refind_from_body(source: FrameSource, views: ViewSet, v: int, clock: Clock, t0: float, t1: float,
                     X: np.ndarray, X_pred: np.ndarray, p: np.ndarray, q: np.ndarray, ok: np.ndarray,
                     need: np.ndarray, o: PatchOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A centre lost in a view re-found from the part's motion (``PatchOptions.refind_from_body``): patches (n, 3)
    of camera ``v``, at t0 ``X`` (n, 3, 3) in the world and ``p`` (n, 3, 2) in the image, flown to t1 ``q`` (n, 3,
    2), ``ok`` (n, 3); ``X_pred`` (n, 3, 3) where the body over time carries them at t1 (:func:`body_prediction`;
    NaN: no part). In each patch of ``need`` (n,) whose centre's flow failed, each lost point with a prediction is
    flown again (:func:`flow_camera`), started at its position moved by its predicted image motion (the points
    moved linearly in the world from ``X`` to ``X_pred`` between the frames' times, projected), the prediction's
    pyramid levels, the same forward-backward check; kept where it passes -> (q, ok, re-found (n, 3)). The flow's
    window and levels are ``refind_window_px`` and ``refind_levels`` where set (:func:`refind_flow_options`)."""
    has = np.all(np.isfinite(X_pred), axis=(1, 2))
    rows, cols = np.nonzero((need & ~ok[:, 0] & has)[:, None] & ~ok)
    if not len(rows) or t1 == t0:
        return q.copy(), ok.copy(), np.zeros(ok.shape, bool)
    start, X_a, X_b = p[rows, cols], X[rows, cols], X_pred[rows, cols]
    return _fly_again(source, views.names[v], clock, t0, t1, q, ok, rows, cols, start,
                      lambda t_ms: project_view(views, v, X_a + (X_b - X_a) * ((t_ms - t0) / (t1 - t0)))[0],
                      refind_flow_options(o))


def refind_flow_options(o: PatchOptions) -> PatchOptions:
    """The options :func:`refind_from_body`'s re-flight flies with: ``o`` with its window ``refind_window_px`` and
    its predicted levels ``refind_levels`` where set (``o`` itself where neither is: the same bits)."""
    if o.refind_window_px == 0 and o.refind_levels < 0:
        return o
    return dataclasses.replace(o, lk_window_px=o.refind_window_px or o.lk_window_px,
                               lk_levels_predicted=o.lk_levels_predicted if o.refind_levels < 0 else o.refind_levels,
                               lk_levels_full_px=o.lk_levels_full_px if o.refind_levels < 0 else 0.0)


#: Patches triangulated per call: the robust triangulation's arrays are (points, cameras, hypotheses) and outgrow
#: the caches (full dome, 6000 patches per call: 1.99 ms per patch, 1.41 in chunks of 1000, 1.17 of 500, 1.12 of
#: 250); each point's result is its own (the same bits in any chunks).
TRIANGULATE_CHUNK = 256


def _triangulate_points(views: ViewSet, uv: np.ndarray, conf: np.ndarray, o: PatchOptions) -> np.ndarray:
    """(N, 3, V, 2) pixels, (N, 3, V) conf -> (N, 3, 3) points (NaN where a point has fewer than 2 inliers)."""
    N, _, V = conf.shape
    out = np.full((N, 3, 3), np.nan)
    for lo in range(0, N, TRIANGULATE_CHUNK):
        n = len(conf[lo:lo + TRIANGULATE_CHUNK])
        tri = triangulate(views, uv[lo:lo + n].reshape(n * 3, V, 2), conf[lo:lo + n].reshape(n * 3, V),
                          TriangulationOptions(inlier_threshold_px=o.triangulation_px, min_views=2),
                          few_views=o.track_views)
        out[lo:lo + n] = tri.X_cm.reshape(n, 3, 3)
    return out


def _triangulate_again(views: ViewSet, uv: np.ndarray, tracked: np.ndarray, use: np.ndarray, X_tri: np.ndarray,
                       o: PatchOptions) -> np.ndarray:
    """:func:`_triangulate_points` of ``uv`` (N, 3, V, 2) in the views ``use`` (N, 3, V), given ``X_tri``, the same
    points triangulated in the views ``tracked``: a patch whose views did not change (every tracked view still
    visible: most of them) keeps ``X_tri``'s points, which are the same bits (a point's triangulation depends on its
    own pixels and views only); the others are triangulated again."""
    again = X_tri.copy()
    changed = np.flatnonzero(np.any(use != tracked, axis=(1, 2)))
    if len(changed):
        again[changed] = _triangulate_points(views, uv[changed], use[changed].astype(float), o)
    return again


def square_up(X: np.ndarray, axis_cm: float) -> np.ndarray:
    """Patches (N, 3, 3) -> the same centre and plane with the plane points back at ``axis_cm``, orthogonal."""
    u, v, _ = patch_axes(X[:, 0], X[:, 1], X[:, 2])
    return np.stack([X[:, 0], X[:, 0] + axis_cm * u, X[:, 0] + axis_cm * v], 1)


def _stretched(X: np.ndarray, o: PatchOptions) -> np.ndarray:
    d = np.linalg.norm(X[:, 1:] - X[:, :1], axis=-1)  # (N, 2)
    return np.any(ties.above(np.abs(d / o.axis_cm - 1.0), o.max_stretch, ties.UNIT_QUANTUM), axis=1)


#: Patches whose flown views are chosen together (memory: chunk x cameras x 3 directions).
BEST_VIEWS_CHUNK = 1024


def best_views(views: ViewSet, X: np.ndarray, candidates: np.ndarray, k: int, spread_deg: float) -> np.ndarray:
    """The cameras each patch is tracked in: at most ``k`` of its ``candidates`` (N, V) (the cameras that saw it),
    chosen greedily, most face-on first: each pick maximises ``cos * min(1, angle / spread_deg)``, ``cos`` the
    cosine between the patch normal and the direction to the camera (0 if it faces away), ``angle`` the smallest
    angle at the patch between that direction and those already picked. A dense dome puts several cameras a few
    degrees apart: the spread keeps the picks from crowding one panel, which triangulates no better than one of
    them. Scores are quantised to 1e-6 and ties go to the first camera; every patch's pick depends on its own row
    only. ``k`` 0, or a patch with at most ``k`` candidates: all of them. -> (N, V) bool."""
    N, V = candidates.shape
    if k <= 0 or N == 0:
        return candidates.copy()
    many = candidates.sum(1) > k
    chosen = np.where(many[:, None], False, candidates)
    todo = np.flatnonzero(many)
    centers = views.center_cm
    for lo in range(0, len(todo), BEST_VIEWS_CHUNK):  # (n, C, 3) directions per chunk: a cloud's would not fit
        rows = todo[lo:lo + BEST_VIEWS_CHUNK]
        # each patch's candidates first, in camera order (C columns: the most any of them has; the rest padding,
        # never picked: a candidate scores >= 0), so a dome's patch is scored in its ~120 cameras, not all 521
        cols = np.argsort(~candidates[rows], axis=1, kind="stable")[:, :int(candidates[rows].sum(1).max())]
        Xr = X[rows]
        _, _, normal = patch_axes(Xr[:, 0], Xr[:, 1], Xr[:, 2])
        d = centers[cols] - Xr[:, None, 0]  # (n, C, 3)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        face = np.clip(np.sum(d * normal[:, None], axis=-1), 0.0, 1.0)
        gap = np.ones(cols.shape)
        avail = np.take_along_axis(candidates[rows], cols, axis=1)
        sub = np.arange(len(rows))
        for _ in range(k):
            j, _ = ties.argmax_where(face * gap, avail, ties.VIEW_COSINE_QUANTUM)
            chosen[rows, cols[sub, j]] = True
            avail[sub, j] = False
            if spread_deg > 0:
                cos_j = np.clip(np.sum(d * d[sub, j][:, None], axis=-1), -1.0, 1.0)
                gap = np.minimum(gap, np.degrees(np.arccos(cos_j)) / spread_deg)
    return chosen


def has_spare_view(flown: np.ndarray, o: PatchOptions) -> np.ndarray:
    """(N,) the patches flown (``flown`` (N, V)) in more than ``min_visible`` cameras: a view to spare, so a
    doubtful view is not the patch's end (``view_lost_with_centre``, ``refind_from_body`` apply to the others)."""
    return flown.sum(axis=1) > o.min_visible


def motion_term(views: ViewSet, uv: np.ndarray, tracked: np.ndarray, flown: np.ndarray, slid_view: np.ndarray,
                X: np.ndarray, o: PatchOptions) -> np.ndarray:
    """The visibility's motion term of a step (N, V) px: where a patch was flown, its flow against its triangulated
    points ``X`` (N, 3, 3) reprojected (the largest over its points); a failed flow inf (3 sigmas); elsewhere NaN
    (no term; a view whose flow left the seed appearance is not triangulated, and judged without it). ``uv``
    (N, 3, V, 2) the flown points, ``tracked`` (N, 3, V) their flows' success, ``flown`` and ``slid_view`` (N, V).
    A failed flow is any of its points' (a view with a point lost is doubtful), except, with
    ``o.view_lost_with_centre``, for a patch with no view to spare (flown in at most ``min_visible`` cameras): there
    a failed flow is its centre's and the residual is over the points tracked (a plane point lost alone moves with
    the centre, as in the triangulation), so a lost plane point does not end the patch."""
    N, V = flown.shape
    centre_rule = np.zeros(N, bool) if not o.view_lost_with_centre else ~has_spare_view(flown, o)
    resid = np.full((N, V), np.nan)
    for v in np.flatnonzero(flown.any(0)):
        idx = np.flatnonzero(flown[:, v])
        proj = project_one(views, v, X[idx])[0]
        err = np.linalg.norm(uv[idx, :, v] - proj, axis=-1)
        # a failed point's pixels say nothing where the centre rule holds
        err = np.where(tracked[idx, :, v] | ~centre_rule[idx, None], err, 0.0)
        resid[idx, v] = err.max(axis=1)
    flow_ok = np.where(centre_rule[:, None], tracked[:, 0], tracked.all(axis=1))
    return np.where(flow_ok, resid, np.where(flown & ~slid_view, np.inf, np.nan))


def now_frames(frames: Frames) -> np.ndarray:
    """(V,) the cameras with a frame at the reference time itself."""
    return (frames.frame >= 0) & (np.abs(frames.offset_ms) < SAME_TIME_MS)


@dataclass
class SeedViews:
    """Where each patch's three points were in each camera that saw it at the seed (the reference stream's cameras,
    whose frames are at the seed time), and those frames: the appearance a drifting track is pulled back to."""

    uv: np.ndarray  # (N, 3, V, 2) float32, NaN where the camera has no seed view of the patch
    frame: np.ndarray  # (V,) the seed frame of each camera (-1: none at the seed time)
    gray: dict

    @classmethod
    def at_seed(cls, source: FrameSource, views: ViewSet, frames: Frames, X: np.ndarray, seen: np.ndarray
                ) -> SeedViews:
        N, V = seen.shape
        now = now_frames(frames)
        uv = np.full((N, 3, V, 2), np.nan, np.float32)
        for v in np.flatnonzero((seen & now[None]).any(0)):
            idx = np.flatnonzero(seen[:, v])
            uv[idx, :, v] = project_one(views, v, X[idx])[0]
        return cls(uv=uv, frame=np.where(now, frames.frame, -1), gray={})

    def realign(self, source: FrameSource, name: str, frames: Frames, v: int, idx: np.ndarray, q: np.ndarray,
                ok: np.ndarray, o: PatchOptions, now: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flown points ``q`` (n, 3, 2), ``ok`` (n, 3) of patches ``idx`` in camera ``v`` (``name``) at this step's
        time, aligned to their seed appearance -> ((3 n, 2) points, (3 n,) ok, (3 n,) rejected here): Lucas-Kanade
        from the camera's seed image at the seed pixels, ``anchor_levels`` pyramid levels above the image,
        started at the flown point,
        forward-backward checked; a point is moved there when within
        ``anchor_flow_px`` of the flown point; a point farther (the flow slid, or the view changed) is rejected in
        this camera when ``anchor_reject``, and one that could not be aligned too when ``anchor_reject_unaligned``
        (else it is kept as flown). Points without a seed view in ``v``, or a camera with
        no frame at this very time, are left as flown. With ``anchor_warp`` and ``now`` (n, 3, 2), the patches'
        current triplets projected in ``v``, the seed image is first warped by each patch's seed-to-now map
        (:mod:`.warp`) where that map moves the flow window's corners by more than ``anchor_warp_px``: the seed
        appearance as the patch's plane is seen now."""
        q, ok = q.reshape(-1, 2).copy(), ok.reshape(-1).copy()
        f = int(frames.frame[v])
        off = np.zeros(len(ok), bool)
        if self.frame[v] < 0 or not now_frames(frames)[v]:
            return q, ok, off
        p0 = self.uv[idx, :, v].reshape(-1, 2).astype(float)
        has = np.all(np.isfinite(p0), axis=1) & ok
        if not has.any():
            return q, ok, off
        if v not in self.gray:
            self.gray[v] = source.gray(name, int(self.frame[v]))
        gray = source.gray(name, f)
        start, guess = p0[has], q[has]
        warped = np.zeros(len(start), bool)  # the points whose seed square is warped first (anchor_warp)
        if o.anchor_warp and now is not None:
            A = np.repeat(seed_to_now(self.uv[idx, :, v], now.reshape(-1, 3, 2)), 3, axis=0)[has]
            warped = ties.above(warp_px(A, o.lk_window_px), o.anchor_warp_px, ties.FLOW_QUANTUM_PX)
        r, good = np.zeros((len(start), 2)), np.zeros(len(start), bool)
        if (~warped).any():
            r[~warped], good[~warped] = optical_flow(self.gray[v], gray, start[~warped], o, guess=guess[~warped],
                                                     levels=o.anchor_levels)
        if warped.any():
            r[warped], good[warped] = warped_flow(self.gray[v], gray, start[warped], A[warped], guess[warped], o)
        near = good & ties.at_most(np.linalg.norm(r - guess, axis=1), o.anchor_flow_px, ties.FLOW_QUANTUM_PX)
        rows = np.flatnonzero(has)
        q[rows[near]] = r[near]
        if o.anchor_reject:
            bad = ~near if o.anchor_reject_unaligned else good & ~near
            ok[rows[bad]] = False
            off[rows[bad]] = True
        return q, ok, off


def anchored(flown: np.ndarray, o: PatchOptions) -> np.ndarray:
    """(n,) the patches the anchor flow realigns this step, of ``flown`` (n, V) (their cameras flown): those flown
    in at least ``anchor_min_views`` cameras (0: every patch)."""
    return flown.sum(axis=1) >= o.anchor_min_views


def anchor(seed_of: SeedViews, source: FrameSource, name: str, frames: Frames, v: int, idx: np.ndarray,
           q: np.ndarray, ok: np.ndarray, p: np.ndarray, flown: np.ndarray, slid_view: np.ndarray, o: PatchOptions
           ) -> tuple[np.ndarray, np.ndarray]:
    """The anchor flow of one camera's flown points: ``q`` (3 n, 2), ``ok`` (3 n,) of patches ``idx`` in camera
    ``v``, ``p`` (3 n, 2) their triplets' projections before the step -> (q, ok) with the :func:`anchored` patches'
    points realigned (:meth:`SeedViews.realign`); ``slid_view[idx, v]`` set where a point was rejected."""
    a = anchored(flown[idx], o)
    if a.all():  # every patch: the call as it was
        q, ok, off = seed_of.realign(source, name, frames, v, idx, q.reshape(-1, 3, 2), ok.reshape(-1, 3), o, now=p)
        slid_view[idx, v] = off.reshape(-1, 3).any(axis=1)
        return q, ok
    q3, ok3 = q.reshape(-1, 3, 2).copy(), ok.reshape(-1, 3).copy()
    if a.any():
        qa, oka, off = seed_of.realign(source, name, frames, v, idx[a], q3[a], ok3[a], o,
                                       now=p.reshape(-1, 3, 2)[a].reshape(-1, 2))
        q3[a], ok3[a] = qa.reshape(-1, 3, 2), oka.reshape(-1, 3)
        slid_view[idx[a], v] = off.reshape(-1, 3).any(axis=1)
    return q3.reshape(-1, 2), ok3.reshape(-1)


def _predictor(views: ViewSet, v: int, X: np.ndarray, velocity: np.ndarray, t0: float) -> Predictor:
    """Points (M, 3) at reference time ``t0`` moving at ``velocity`` (M, 3) cm / ms, projected into view ``v`` at a
    time: the constant-velocity prediction each flow step starts from (``PatchOptions.lk_predict``)."""
    return lambda t_ms: project_view(views, v, X + velocity * (t_ms - t0))[0]


def seed_visibility(source: FrameSource, views: ViewSet, clocks: list[Clock], t_ms: float, X0: np.ndarray,
                    seen: np.ndarray, neighbours: np.ndarray, o: PatchOptions, body: BodyPrior | None = None
                    ) -> Visibility:
    """The visibility a cloud's tracks start from at its seed time (the same for both directions: computed once)."""
    X = quantise_cm(np.asarray(X0, dtype=float))
    return estimate_visibility(source, views, judged_frames(clocks, t_ms), X, np.zeros_like(X), seen, None,
                               neighbours, o, body)


def track_cloud(source: FrameSource, views: ViewSet, clocks: list[Clock], times_ms: np.ndarray, X0: np.ndarray,
                seen: np.ndarray, neighbours: np.ndarray, o: PatchOptions, start: Visibility | None = None,
                body: BodyPrior | None = None) -> CloudTrack:
    """Track N patches (X0 (N, 3, 3) at ``times_ms[0]``, the seed time; ``seen`` (N, V) the seed's cameras) over
    ``times_ms`` (T,), monotonic in either direction (see the module). ``start``: :func:`seed_visibility` of these
    arguments if already computed. ``body``: the people over time, occluders of the views with
    ``o.body_occlusion`` (:mod:`.occlusion`)."""
    N, V, T = len(X0), len(views.names), len(times_ms)
    X_out = np.full((N, T, 3, 3), np.nan)
    vis_out = np.zeros((N, T, V), bool)
    photo_out = np.zeros((N, T, V), bool)
    alive = np.zeros((N, T), bool)
    X = quantise_cm(np.asarray(X0, dtype=float))
    vis = start if start is not None else seed_visibility(source, views, clocks, float(times_ms[0]), X, seen,
                                                           neighbours, o, body)
    live = vis.visible.sum(1) >= o.min_visible
    # the seed appearance, where the patch was seen at the seed (seed_appearance_end)
    seed_look = vis.appearance.keep(vis.visible & live[:, None]) if o.seed_appearance_end else None
    if o.anchor_flow:
        seed_of = SeedViews.at_seed(source, views, judged_frames(clocks, times_ms[0]), X, vis.visible & live[:, None])
    velocity_last = None  # (N, 3, 3) each point's velocity over the last step (cm / ms): the flow's prediction
    # refind_carry_steps: the patches kept this step by their part's motion alone, how many steps in a row, and the
    # views each was last seen in (a carried patch is flown there at the next step: it was seen by none)
    carried, carry_run = np.zeros(N, bool), np.zeros(N, np.int64)
    carried_out, last_seen = np.zeros((N, T), bool), np.zeros((N, V), bool)
    ended = np.zeros(N, np.int8)  # the rule that ended each patch (END_CAUSES)
    for k in range(T):
        if k > 0:
            t0, t1 = float(times_ms[k - 1]), float(times_ms[k])
            X_prev = X
            uv = np.full((N, 3, V, 2), np.nan)
            tracked = np.zeros((N, 3, V), bool)
            was = vis_out[:, k - 1]
            if carried.any():
                was = np.where(carried[:, None], last_seen, was)
            flown = best_views(views, X, was & live[:, None], o.track_views, o.track_view_spread_deg)
            refound = 0  # points whose flow failed, re-found from their patch's motion (lk_refind)
            # refind_from_body: where the part's motion carries each patch with no view to spare (NaN: no part)
            by_body = np.full((N, 3, 3), np.nan)
            if o.refind_from_body and body is not None:
                bare = np.flatnonzero(live & ~has_spare_view(flown, o))
                by_body[bare] = body_prediction(X[bare], body.at(t0), body.at(t1), o)
            from_body = 0  # points whose flow failed, re-found from their part's motion (refind_from_body)
            slid_view = np.zeros((N, V), bool)  # flown, but a point rejected by its seed appearance (anchor_flow)
            frames1 = judged_frames(clocks, t1)
            for v, name in enumerate(views.names):
                idx = np.flatnonzero(flown[:, v])
                if len(idx) == 0:
                    continue
                p = project_view(views, v, X[idx].reshape(-1, 3))[0]
                predict = None
                if o.lk_predict and velocity_last is not None:
                    predict = _predictor(views, v, X[idx].reshape(-1, 3), velocity_last[idx].reshape(-1, 3), t0)
                q, ok = flow_camera(source, name, clocks[v], t0, t1, p, o, predict)
                if o.lk_refind:
                    q3, ok3, found = refind_lost(source, name, clocks[v], t0, t1, p.reshape(-1, 3, 2),
                                                 q.reshape(-1, 3, 2), ok.reshape(-1, 3), o)
                    q, ok = q3.reshape(-1, 2), ok3.reshape(-1)
                    refound += int(found.sum())
                if o.refind_from_body and body is not None:
                    need = np.all(np.isfinite(by_body[idx]), axis=(1, 2))
                    if (need & ~ok.reshape(-1, 3)[:, 0]).any():
                        q3, ok3, found = refind_from_body(source, views, v, clocks[v], t0, t1, X[idx], by_body[idx],
                                                          p.reshape(-1, 3, 2), q.reshape(-1, 3, 2),
                                                          ok.reshape(-1, 3), need, o)
                        q, ok = q3.reshape(-1, 2), ok3.reshape(-1)
                        from_body += int(found.sum())
                if o.anchor_flow:
                    q, ok = anchor(seed_of, source, name, frames1, v, idx, q, ok, p, flown, slid_view, o)
                uv[idx, :, v] = q.reshape(-1, 3, 2)
                tracked[idx, :, v] = ok.reshape(-1, 3)
            X_tri = _triangulate_points(views, uv, tracked.astype(float), o)
            X_new = X_tri
            centre = np.all(np.isfinite(X_new[:, 0]), axis=1)
            lost = live & ~centre
            # refind_carry_steps: a centre still lost with its part's motion known is carried by it (predicted)
            carriable = np.all(np.isfinite(by_body), axis=(1, 2)) & (carry_run < o.refind_carry_steps)
            carry = lost & carriable
            live &= centre
            # a plane point that cannot be triangulated moves with the centre
            moved = X_new[:, :1] - X[:, :1]
            X_new = np.where(np.isfinite(X_new), X_new, X + moved)
            X_new = quantise_cm(np.where(live[:, None, None], X_new, 0.0))
            velocity = (X_new - X) / (t1 - t0)
            motion = motion_term(views, uv, tracked, flown, slid_view, X_new, o)
            vis = estimate_visibility(source, views, frames1, X_new, velocity, was, motion, neighbours, o, body)
            use = vis.visible[:, None, :] & tracked
            again = _triangulate_again(views, uv, tracked, use, X_tri, o)
            redo = live & (use.sum(axis=2) >= 2).all(axis=1) & np.all(np.isfinite(again), axis=(1, 2))
            X = np.where(redo[:, None, None], quantise_cm(np.where(redo[:, None, None], again, 0.0)), X_new)
            unseen = live & (vis.visible.sum(1) < o.min_visible)
            stretched = live & ~unseen & _stretched(X, o)
            slid = (live & ~unseen & ~stretched & off_seed(vis, seed_look, o) if seed_look is not None
                    else np.zeros_like(live))
            live &= ~unseen & ~stretched & ~slid
            if o.carry_unseen:  # a patch whose views were lost is carried as one whose centre was
                carry |= unseen & carriable
            ended = np.where(ended > 0, ended, end_causes(lost & ~carry, unseen & ~carry, stretched, slid, tracked,
                                                          vis, motion, o))
            X = quantise_cm(square_up(X, o.axis_cm))
            if carry.any():
                X[carry] = quantise_cm(square_up(by_body[carry], o.axis_cm))
                live |= carry
            carried, carry_run = carry, np.where(carry, carry_run + 1, 0)
            velocity_last = (X - X_prev) / (t1 - t0)
            logger.debug("step %d: %d live; ended: %d centre not triangulated, %d seen by too few, %d stretched, "
                         "%d off their seed appearance; %d views off their seed appearance; %d points re-found, %d from the body; "
                         "%d carried by their part", k, live.sum(), lost.sum() - carry.sum(), unseen.sum(),
                         stretched.sum(), slid.sum(), slid_view.sum(), refound, from_body, carry.sum())
        vis_v: Visibility = vis
        seen = live & ~carried  # measured at this time (a carried patch is written nowhere)
        X_out[seen, k] = X[seen]
        vis_out[seen, k] = vis_v.visible[seen]
        photo_out[seen, k] = vis_v.photometric[seen]
        alive[:, k] = seen
        carried_out[:, k] = carried
        last_seen[seen] = vis_v.visible[seen]
        if not live.any():
            break
    return CloudTrack(times_ms=np.asarray(times_ms, dtype=float), X_cm=X_out, visible=vis_out,
                      photometric=photo_out, alive=alive, carried=carried_out, ended=ended)
