"""One body per person over time (dome_calib.recon.people.temporal) on the few-camera rig (dome_calib.synth.rig, the
detector whose errors last): better than per frame against the truth, bones held, a swap in one view outvoted,
joints placed where the per-frame triangulation left them out, window edges that do not show."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dome_calib.recon.body_models import BONE_LENGTH_CM, JOINTS19
from dome_calib.errors import OptionsError
from dome_calib.recon.people.chunks import reconstruct_people_chunked
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people
from dome_calib.recon.people.sources import people_streams
from dome_calib.recon.people.temporal import TemporalOptions, within_probability
from dome_calib.recon.people.agreement import NOISE_BIN_PX, NOISE_BINS
from dome_calib.recon.people.bodies import Bodies, Observations
from dome_calib.recon.people.windows import bone_lengths, margin_times, noise_px_of, time_windows
from dome_calib.recon.project import view_set
from dome_calib.synth.detector import DetectorModel, synth_detections
from dome_calib.synth.group_eval import match_bodies
from dome_calib.synth.rig import GROUP_MARGIN_MS, RigOptions, few_camera_rig, rig_group

OPTIONS = PeopleOptions()
PER_FRAME = dataclasses.replace(OPTIONS, temporal=TemporalOptions(enabled=False))


@pytest.fixture(scope="module")
def rig():
    bundle = few_camera_rig(RigOptions(seed=0, duration_ms=3700.0 + GROUP_MARGIN_MS + 100.0))
    truth = rig_group(bundle, n_people=3, seed=3)
    det = synth_detections(bundle, truth, model=DetectorModel(seed=3))  # errors that last, as OpenPose's
    table = bundle.sync.streams["hd"]
    span = (table.univ_time_ms >= truth.start_ms) & (table.univ_time_ms <= truth.start_ms + truth.duration_ms)
    X, present = truth.joints_cm(table.univ_time_ms[span])
    return bundle, det, table.univ_time_ms[span], X, present


def _run(bundle, det, times, options, chunked=False):
    streams = people_streams(bundle, det)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    if chunked:
        return reconstruct_people_chunked(views, streams, times, options)
    return reconstruct_people(views, streams, times, options)


def _matched(seq, X, present):
    return match_bodies([b.ids for b in seq.bodies], [b.X_cm for b in seq.bodies], X, present)[1]


def test_better_than_per_frame_and_bones_held(rig):
    bundle, det, times, X, present = rig
    body = _matched(_run(bundle, det, times, OPTIONS), X, present)
    frame = _matched(_run(bundle, det, times, PER_FRAME), X, present)
    e_body, e_frame = np.linalg.norm(body - X, axis=-1), np.linalg.norm(frame - X, axis=-1)
    both = np.isfinite(e_body) & np.isfinite(e_frame)
    assert e_body[both].mean() < 0.75 * e_frame[both].mean()  # the aim: >= 25 % lower MPJPE
    assert np.isfinite(e_body).sum() >= np.isfinite(e_frame).sum()  # joints left out per frame are placed
    a, b = (np.array([JOINTS19.index(n) for n in pair]) for pair in zip(*BONE_LENGTH_CM))
    spread = lambda Y: np.nanmean(np.nanstd(np.linalg.norm(Y[:, :, a] - Y[:, :, b], axis=-1), axis=0))  # noqa
    assert spread(body) < 0.5 * spread(frame)  # cm over time, per person and bone


def test_a_swap_in_one_view_is_outvoted(rig):
    """Camera 00_00 swaps the left and right arm of everyone for 12 frames in a row (a detector's persistent
    error): the body keeps its wrists, and the swapped detections are counted as outvoted for that camera."""
    bundle, det, times, X, present = rig
    arm = [JOINTS19.index(n) for n in ("l_elbow", "l_wrist", "r_elbow", "r_wrist")]
    swapped = {c: dict(frames) for c, frames in det.items()}
    frames = sorted(det["00_00"])[40:52]
    for f in frames:
        kp = swapped["00_00"][f].copy()
        kp[:, arm] = kp[:, [arm[2], arm[3], arm[0], arm[1]]]
        swapped["00_00"][f] = kp
    clean = _run(bundle, det, times, OPTIONS)
    seq = _run(bundle, swapped, times, OPTIONS)
    table = bundle.sync.streams["hd"]
    k = np.isin(table.index[np.searchsorted(table.univ_time_ms, times)], frames)
    wrists = [JOINTS19.index("l_wrist"), JOINTS19.index("r_wrist")]
    err = np.linalg.norm(_matched(seq, X, present) - X, axis=-1)[:, :, wrists]
    err_clean = np.linalg.norm(_matched(clean, X, present) - X, axis=-1)[:, :, wrists]
    # as without the swap (2.5 cm there; its worst wrist, 20 cm, is one the detector itself lost)
    assert np.nanmean(err[k]) < np.nanmean(err_clean[k]) + 0.3 and np.nanmax(err[k]) <= np.nanmax(err_clean[k]) + 1.0
    cam = seq.cameras.names.index("00_00")
    more = seq.cameras.outvoted[cam] - clean.cameras.outvoted[cam]
    n_swapped = sum(int((det["00_00"][f][:, arm, 2] > 0).sum()) for f in frames)  # arm joints the camera detected
    # most of them: a left joint seen edge-on projects within a few pixels of its right partner, and stays in
    assert more >= 0.6 * n_swapped


def test_window_edges_do_not_show_and_chunks_change_nothing(rig):
    """The body over time in windows of one margin (the smoother's reach: 4 windows here) against one window over
    everything: every joint within 0.01 cm (measured: 4e-5, the solver's tolerance), the same joints put out, and
    the step across each window edge as in the single window. Chunks of 30 times (per frame) change nothing (1e-3
    cm: bone lengths and camera noise are measured once over the whole session)."""
    bundle, det, times, X, present = rig
    one = _matched(_run(bundle, det, times, dataclasses.replace(OPTIONS, temporal=TemporalOptions(
        window_margins=10_000))), X, present)
    small = TemporalOptions(window_margins=1)
    windows = time_windows(times, small)
    assert len(windows) >= 3
    cut = _matched(_run(bundle, det, times, dataclasses.replace(OPTIONS, temporal=small)), X, present)
    np.testing.assert_array_equal(np.isnan(cut), np.isnan(one))
    assert np.nanmax(np.abs(cut - one)) < 0.01
    for _, start, _, _ in windows[1:]:
        step_cut = np.linalg.norm(cut[start] - cut[start - 1], axis=-1)
        step_one = np.linalg.norm(one[start] - one[start - 1], axis=-1)
        assert np.nanmax(np.abs(step_cut - step_one)) < 0.01
    whole = _run(bundle, det, times, OPTIONS)
    chunked = _run(bundle, det, times, dataclasses.replace(OPTIONS, chunk_times=30), chunked=True)
    for a, b in zip(whole.bodies, chunked.bodies):
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_allclose(a.X_cm, b.X_cm, atol=1e-3)


class _HalfSpaceWitness:
    """A depth witness (duck-typed :class:`~dome_calib.recon.people.depth_witness.DepthWitness`) that sees through
    every joint above a height: the joints the body over time places there must go too."""

    def __init__(self, max_height_cm: float) -> None:
        self.max_height_cm = max_height_cm

    def keep(self, X_cm: np.ndarray, time_ms: float) -> np.ndarray:
        return ~(-X_cm[..., 1] > self.max_height_cm)  # y down: height is -y; NaN joints kept (no verdict)


def test_the_depth_witness_has_the_last_word_on_placed_joints(rig):
    bundle, det, times, X, present = rig
    streams = people_streams(bundle, det)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    seq = reconstruct_people(views, streams, times, OPTIONS, depth=_HalfSpaceWitness(120.0))
    heights = np.concatenate([-b.X_cm[..., 1].ravel() for b in seq.bodies])
    heights = heights[np.isfinite(heights)]
    assert len(heights) > 1000 and heights.max() <= 120.0
    for b in seq.bodies:  # a dropped joint is missing everywhere: c = -1, no inlier views
        gone = ~np.isfinite(b.X_cm).all(-1)
        assert (b.confidence[gone] == -1).all() and (b.n_inliers[gone] == 0).all()


def test_confidence_is_a_probability_and_options_refuse_nonsense():
    assert within_probability(5.0, np.array([1e-3]))[0] == pytest.approx(1.0)
    # chi distribution with 3 degrees of freedom: P(|e| < sigma) = 0.1987, P(|e| < 2 sigma) = 0.7385
    np.testing.assert_allclose(within_probability(5.0, np.array([5.0, 2.5])), [0.198748, 0.738536], atol=1e-5)
    for bad in (dict(iterations=0), dict(robust_k=0.0), dict(bone_sigma_cm=float("nan")), dict(max_sigma_cm=-1.0)):
        with pytest.raises(OptionsError):
            TemporalOptions(**bad)


def test_windows_tile_the_session_from_the_smoothers_reach():
    """M is the smoother's reach in time steps (the docs' derivation: 32 at 29.97 fps, 28 at 25 fps with the
    defaults); the windows' own spans start at multiples of W = 6 M and tile the session; each is fitted with M more
    times on both sides, within the session."""
    hd = np.arange(1000) * 1001 / 30  # ms
    vga = np.arange(1000) * 40.0
    assert margin_times(hd, TemporalOptions()) == 32 and margin_times(vga, TemporalOptions()) == 28
    assert margin_times(hd, TemporalOptions(window_edge_influence=0.1)) < 32  # less reach asked, less margin
    for T in (1, 5, 191, 192, 193, 1000):
        windows = time_windows(hd[:T], TemporalOptions())
        own = np.concatenate([np.arange(a, b) for _, a, b, _ in windows])
        np.testing.assert_array_equal(own, np.arange(T))
        for lo, a, b, hi in windows:
            assert a % 192 == 0 and lo == max(0, a - 32) and hi == min(T, b + 32)


def _bodies(ids, lengths_cm, n_inliers=3):
    """One body per time: joints on a line so that the neck-nose bone has the given length."""
    out = []
    for i, L in zip(ids, lengths_cm):
        X = np.zeros((1, 19, 3))
        X[0, :, 0] = np.arange(19) * 10.0
        X[0, JOINTS19.index("nose"), 0] = X[0, JOINTS19.index("neck"), 0] + L
        out.append(Bodies(X_cm=X, confidence=np.ones((1, 19)), n_inliers=np.full((1, 19), n_inliers),
                          n_views=np.array([4]), ids=np.array([i])))
    return out


def test_bone_lengths_are_medians_in_steps_over_the_whole_track():
    e = [tuple(b) for b in BONE_LENGTH_CM].index(("neck", "nose"))
    ids, L = bone_lengths(_bodies([4, 4, 4, 4, 9], [20.004, 20.0149, 19.99, 30.0, 11.0]), 3)
    np.testing.assert_array_equal(ids, [4, 9])
    assert L[0, e] == pytest.approx(20.005)  # steps 2000, 2001, 1999, 3000 -> (2000 + 2001) / 2 x 0.01 cm
    assert L[1, e] == pytest.approx(11.0)
    assert np.isnan(bone_lengths(_bodies([1], [20.0], n_inliers=2), 3)[1][0, e])  # too few inlier views: no bone


def test_camera_noise_from_the_summed_histogram():
    """The median bin's centre / 1.177 (a 2D Gaussian's median radius in sigmas); a camera with fewer than 30
    detections takes the others' median."""
    rng = np.random.default_rng(0)
    hist = np.zeros((3, NOISE_BINS), np.int64)
    for v, sigma in enumerate((2.0, 4.0)):
        r = np.hypot(*rng.normal(scale=sigma, size=(2, 20_000)))
        hist[v] = np.bincount((r / NOISE_BIN_PX).astype(int), minlength=NOISE_BINS)[:NOISE_BINS]
    hist[2, 40] = 10  # 10 detections only
    noise = noise_px_of(hist, 0.5)
    np.testing.assert_allclose(noise[:2], [2.0, 4.0], rtol=0.02)
    assert noise[2] == np.median(noise[:2])


def test_assigned_records_against_plain_numpy():
    """The compiled reading of a window's detections: every (body, view, joint) with a detection, in that order,
    confidences clipped to 1, and per (body, joint) the ``strongest`` most confident (1e-4 steps, ties: the lower
    view) marked, as plain numpy finds them."""
    from dome_calib.recon.people.compiled import assigned_records

    rng = np.random.default_rng(4)
    T, V, N, B, K = 3, 40, 4, 7, 5
    kp = rng.uniform(0, 500, (T, V, N, 19, 3)).astype(np.float32)
    kp[..., 2] = np.where(rng.random((T, V, N, 19)) < 0.3, 0.0, rng.choice([0.5, 0.7, 1.02], (T, V, N, 19)))
    time_of = rng.integers(0, T, B)
    A = np.where(rng.random((B, V)) < 0.2, -1, rng.integers(0, N, (B, V))).astype(np.int16)
    body, view, joint, uv, conf, strong = assigned_records(kp, time_of, A, K)
    b, v = np.nonzero(A >= 0)
    det = kp[time_of[b], v, A[b, v]]
    q, j = np.nonzero(det[..., 2] > 0)
    np.testing.assert_array_equal(body, b[q])
    np.testing.assert_array_equal(view, v[q])
    np.testing.assert_array_equal(joint, j)
    np.testing.assert_array_equal(uv, det[q, j, :2])
    np.testing.assert_array_equal(conf, np.minimum(det[q, j, 2], 1.0))
    for bb in range(B):
        for jj in range(19):
            mine = np.flatnonzero((body == bb) & (joint == jj))
            order = np.lexsort((view[mine], -np.round(conf[mine].astype(float) * 1e4)))  # confidence, then view
            expected = np.zeros(len(mine), bool)
            expected[order[:K]] = True
            np.testing.assert_array_equal(strong[mine], expected)


def test_a_bone_and_its_mirror_share_one_length():
    """A person's left and right bones are one length: measured on both sides' frames together. Pose2Sim's balancing
    trial measured the left thigh on 3 frames (37.8 cm) and the right on 8 (41.2); held apart, the left hip was
    pulled 4 cm towards the knee's end of a thigh too short."""
    e_l = [tuple(b) for b in BONE_LENGTH_CM].index(("l_hip", "l_knee"))
    e_r = [tuple(b) for b in BONE_LENGTH_CM].index(("r_hip", "r_knee"))
    bodies = []
    for left, right in [(37.8, 41.2)] * 3 + [(np.nan, 41.2)] * 5 + [(np.nan, 40.9)] * 3:
        X = np.zeros((1, 19, 3))
        X[0, :, 0] = np.arange(19) * 10.0
        X[0, JOINTS19.index("l_knee")] = X[0, JOINTS19.index("l_hip")] + [0.0, left, 0.0]
        X[0, JOINTS19.index("r_knee")] = X[0, JOINTS19.index("r_hip")] + [0.0, right, 0.0]
        bodies.append(Bodies(X_cm=X, confidence=np.ones((1, 19)), n_inliers=np.full((1, 19), 3),
                             n_views=np.array([4]), ids=np.array([0])))
    L = bone_lengths(bodies, 3)[1][0]
    assert L[e_l] == L[e_r] == pytest.approx(41.2)  # the median of 3 x 37.8, 8 x 41.2, 3 x 40.9


def test_a_detection_far_from_the_others_does_not_pull_the_body(rig):
    """One camera's joint 10 sigma from where three others agree (as one phone's left hip in Pose2Sim's balancing
    trial, 40-55 px off), at every time: the body stays where the three put it. Cauchy's weight let it pull with
    0.8 sigma, most of an inlier's: 1.7 px off in the other views here, 5 cm on that trial."""
    from dome_calib.recon.kernel import camera_table
    from dome_calib.recon.people.bodies import Observations
    from dome_calib.recon.people.compiled import distances_px
    from dome_calib.recon.people.temporal import SessionPriors, refine_tracks
    from dome_calib.recon.project import project_points

    bundle, _, _, X, present = rig
    views = view_set(bundle, sorted(bundle.cameras)[:4])
    T, sigma_px = 12, 3.0
    body = X[0, np.flatnonzero(present[0])[0]]  # (19, 3) a true body, standing still
    uv = project_points(views, body).uv_px  # (4, 19, 2)
    j = JOINTS19.index("l_hip")
    t, v, jj = (a.ravel() for a in np.meshgrid(np.arange(T), np.arange(4), np.arange(19), indexing="ij"))
    obs_uv = uv[v, jj].astype(np.float32)
    obs_uv[(v == 0) & (jj == j)] += [10.0 * sigma_px, 0.0]
    obs = Observations(row=t.astype(np.int32), view=v.astype(np.int16), joint=jj.astype(np.int8), uv_px=obs_uv,
                       conf=np.full(len(t), 0.8, np.float32), strong=np.ones(len(t), bool))
    bodies = [Bodies(X_cm=body[None].copy(), confidence=np.ones((1, 19)), n_inliers=np.full((1, 19), 4),
                     n_views=np.array([4]), ids=np.array([0])) for _ in range(T)]
    priors = SessionPriors(track_ids=np.array([0]), bone_cm=np.full((1, len(BONE_LENGTH_CM)), np.nan),
                           noise_px=np.full(4, sigma_px))
    fit = refine_tracks(views, np.arange(T) * 40.0, bodies, obs, priors)
    P = np.stack([b.X_cm[0, j] for b in fit.bodies])
    off = distances_px(P[:, None].repeat(4, 1).reshape(-1, 3), np.arange(4 * T), np.tile(np.arange(4), T),
                       np.tile(uv[:, j], (T, 1)), camera_table(views)).reshape(T, 4)
    assert off[:, 1:].max() < 0.3, off  # Cauchy: 1.74 px
    assert fit.outvoted[(obs.view == 0) & (obs.joint == j)].all()


def _with_twin(views, name: str, degrees: float):
    """The view set plus a twin of camera ``name`` turned ``degrees`` about the vertical through the world origin
    (the rig's centre): two views of everything in the middle that are nearly parallel."""
    from dome_calib.recon.project import ViewSet
    from dome_calib.rotation import rotvec_to_matrix

    i = views.index_of([name])
    turn = rotvec_to_matrix(np.array([0.0, np.radians(degrees), 0.0]))  # the y axis is vertical in the dome
    R = np.concatenate([views.R, views.R[i] @ turn.T])
    return ViewSet(names=list(views.names) + [name + "_twin"], R=R, t_cm=np.concatenate([views.t_cm, views.t_cm[i]]),
                   intr=np.concatenate([views.intr, views.intr[i]]), dist=np.concatenate([views.dist, views.dist[i]]),
                   resolution=np.concatenate([views.resolution, views.resolution[i]]))


def test_a_joint_two_close_views_see_is_held_by_the_bone_the_body_size_gives(rig):
    """The ankles seen by two cameras 10 degrees apart only (the demo's tiny dome sees a crouching person's ankles
    so), each detection 4 px off in opposite directions: no frame has them in 3 inlier views, so the shin is never
    measured, and before, nothing held the ankle along the two rays (10 cm off, the shin 10 cm long on the tiny
    dome). The shin is now the body's size x its nominal length (``infer_unmeasured_bones``), held loosely; the face
    bones are neither read nor inferred."""
    from dome_calib.recon.people.temporal import SessionPriors, refine_tracks
    from dome_calib.recon.people.windows import SIZE_BONES, infer_unmeasured_bones
    from dome_calib.recon.project import project_points
    from dome_calib.recon.triangulate import triangulate

    bundle, _, _, X, present = rig
    views = _with_twin(view_set(bundle, sorted(bundle.cameras)[:4]), "00_00", 10.0)
    V, T, sigma_px = 5, 12, 5.0  # the HD and Kinect cameras of the tiny dome: 5.3-6.2 px
    body = X[0, np.flatnonzero(present[0])[0]]
    uv = project_points(views, body).uv_px  # (5, 19, 2)
    ankles = [JOINTS19.index("l_ankle"), JOINTS19.index("r_ankle")]
    seen = np.ones((V, 19), bool)
    seen[1:4, ankles] = False  # 00_00 and its twin only
    det = uv.copy()
    det[0, ankles, 0] += 4.0
    det[4, ankles, 0] -= 4.0
    tri = triangulate(views, det.transpose(1, 0, 2), np.where(seen.T, 0.9, 0.0))
    assert np.all(tri.n_inliers[ankles] == 2)
    before = np.linalg.norm(tri.X_cm[ankles] - body[ankles], axis=-1)
    assert before.min() > 5.0, before  # two views 10 degrees apart: 4 px put the ankle this far along the rays
    bodies = [Bodies(X_cm=tri.X_cm[None].copy(), confidence=np.ones((1, 19)),
                     n_inliers=np.where(seen.sum(0) >= 4, 5, 2)[None], n_views=np.array([V]), ids=np.array([0]))
              for _ in range(T)]
    t, v, j = (a.ravel() for a in np.meshgrid(np.arange(T), np.arange(V), np.arange(19), indexing="ij"))
    on = seen[v, j]
    obs = Observations(row=t[on].astype(np.int32), view=v[on].astype(np.int16), joint=j[on].astype(np.int8),
                       uv_px=det[v[on], j[on]].astype(np.float32), conf=np.full(on.sum(), 0.9, np.float32),
                       strong=np.ones(on.sum(), bool))
    ids, L = bone_lengths(bodies, 3)
    shin = [tuple(b) for b in BONE_LENGTH_CM].index(("l_knee", "l_ankle"))
    assert np.isnan(L[0, shin])  # never measured
    filled, inferred = infer_unmeasured_bones(L)
    assert inferred[0, shin] and not inferred[0, ~SIZE_BONES].any()
    true_shin = np.linalg.norm(body[JOINTS19.index("l_knee")] - body[JOINTS19.index("l_ankle")])
    assert abs(filled[0, shin] - true_shin) < 3.0, (filled[0, shin], true_shin)

    def ankle_error(bone_cm, inferred):
        priors = SessionPriors(track_ids=ids, bone_cm=bone_cm, noise_px=np.full(V, sigma_px), bone_inferred=inferred)
        fit = refine_tracks(views, np.arange(T) * 40.0, bodies, obs, priors)
        return np.linalg.norm(fit.bodies[T // 2].X_cm[0, ankles] - body[ankles], axis=-1)

    assert ankle_error(L, None).min() > 5.0  # the old rule: no shin, the ankles where the two rays put them
    assert ankle_error(filled, inferred).max() < 3.0


def test_an_extra_joints_depth_is_unheld_by_two_close_views_only(rig):
    """Which extra joints move with their anchor: those two views only see (two always agree) whose rays meet at less
    than 30 degrees (8 here; the tiny dome's 10); not two views 64 degrees apart (two of the few-camera rig's, as
    the real Pose2Sim trial's 55-130: there moving the feet with the ankles put them farther from the cameras that
    agree), nor three views."""
    from dome_calib.recon.people.extras import depth_unheld

    bundle, _, _, X, present = rig
    views = _with_twin(view_set(bundle, sorted(bundle.cameras)[:4]), "00_00", 10.0)
    point = X[0, np.flatnonzero(present[0])[0], JOINTS19.index("l_ankle")]
    inliers = np.zeros((4, 5), bool)
    inliers[0, [0, 4]] = True  # 00_00 and its twin, 10 degrees
    inliers[1, [0, 1]] = True  # two of the rig's cameras
    inliers[2, [0, 1, 4]] = True  # three views
    inliers[3, [0]] = True  # one view: not triangulated
    np.testing.assert_array_equal(depth_unheld(views, np.tile(point, (4, 1)), inliers, 3), [True, False, False, False])


def test_an_extra_joint_moves_with_its_anchor():
    """A foot seen by the same two near-parallel views as its ankle shares the ankle's error along their rays (the
    same camera's bias, the same person): the extra joint is put at the body's ankle + its offset from the ankle
    triangulated from the same views. Before, a crouching synthetic person's feet were 6-10 cm off per frame where
    its ankles, fitted over time, were 1-2 cm off."""
    from dome_calib.recon.people.extras import on_its_anchor

    body_ankle = np.array([[[0.0, 90.0, 0.0]], [[np.nan] * 3]])  # (2 bodies, 1 anchor, 3); the second's missing
    X_anchor = np.array([[[0.0, 80.0, 6.0]], [[0.0, 80.0, 6.0]]])  # the ankle from the toe's two views alone
    toe = X_anchor + [[[15.0, 3.0, 1.0]]]
    out = on_its_anchor(toe, X_anchor, body_ankle)
    np.testing.assert_allclose(out[0, 0], [15.0, 93.0, 1.0])
    np.testing.assert_array_equal(out[1], toe[1])  # no body ankle: as triangulated
    np.testing.assert_array_equal(on_its_anchor(toe, np.full_like(toe, np.nan), body_ankle), toe)


@pytest.mark.slow
def test_a_crouching_persons_ankles_and_feet_on_the_tiny_dome(tmp_path):
    """The two people of ``bench/pose2sim_pipeline.py --two-people`` (tiny dome, scenario crouch, BODY_25 with feet):
    person 1's ankles are inside two cameras' images only (10 degrees apart). Before, its ankles came out 10.6 / 4.4
    cm from the truth (median; the shin never measured) and its feet 6-12 cm; now within 3 cm, every other joint as
    before (within 2 cm)."""
    from dome_calib.bundle_io import write_bundle
    from dome_calib.recon.people.commands import people_options, reconstruct_folder
    from dome_calib.skeletons.scenes import read_people
    from dome_calib.synth.detector import feet_detections
    from dome_calib.synth.dome import as_built_dome
    from dome_calib.synth.group import GroupOptions, make_group
    from dome_calib.synth.openpose_write import write_openpose_folder
    from dome_calib.synth.skeleton import feet_cm, synthetic_sync

    bundle = as_built_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=5000.0, seed=0)
    write_bundle(bundle, tmp_path / "bundle")
    truth = make_group(GroupOptions(n_people=2, start_ms=500.0, duration_ms=4000.0, scenario="crouch", seed=1))
    det, ids = synth_detections(bundle, truth, with_ids=True)
    write_openpose_folder(tmp_path / "det", det, body_model="BODY_25", extras=feet_detections(bundle, truth, det, ids))
    reconstruct_folder(tmp_path / "det", tmp_path / "bundle", tmp_path / "people", body_model="BODY_25",
                       options=people_options())
    people = read_people(tmp_path / "people")
    X, _ = truth.joints_cm(people.times_ms)
    for track in people.tracks.values():
        gap = [np.nanmedian(np.linalg.norm(track.X_cm[:, 2] - X[track.rows, p, 2], axis=-1)) for p in range(2)]
        p = int(np.argmin(gap))
        true = np.concatenate([X[track.rows, p], feet_cm(X[track.rows, p])], axis=1)
        err = np.nanmedian(np.linalg.norm(track.X_cm - true, axis=-1), axis=0)  # (25,) per joint
        assert err.max() < 4.5, dict(zip(people.joints, err.round(1)))
        assert err[[JOINTS19.index("l_ankle"), JOINTS19.index("r_ankle")]].max() < 3.0
        if p == 1:
            assert err[19:].max() < 3.0, err[19:]  # the feet
