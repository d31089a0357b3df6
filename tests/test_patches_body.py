"""The body over time refined with the parts' rigid motions (dome_calib.recon.patches.body): the ties as a term
of the temporal fit, absent without patches, and on the few-camera rig with patches on the true surface: lower
error, smoother."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dome_calib.recon.patches.body import JointTies, TIED_JOINTS, TieOptions, flag_joints, ties_from_patches
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people, refit_over_time
from dome_calib.recon.people.sources import InMemorySource, people_streams
from dome_calib.recon.people.temporal import TemporalOptions, _layout, refine_tracks
from dome_calib.recon.people.windows import WindowTask, session_priors, window_observations
from dome_calib.recon.project import view_set
from dome_calib.synth.detector import DetectorModel, synth_detections
from dome_calib.synth.group_eval import match_bodies
from dome_calib.synth.rig import GROUP_MARGIN_MS, RigOptions, few_camera_rig, rig_group
from dome_calib.synth.surface_patches import true_patches


def _bodies(X):
    """(T, P, 19, 3) -> one Bodies per time, ids 0..P-1."""
    P = X.shape[1]
    return [Bodies(X_cm=x.copy(), confidence=np.ones((P, 19)), n_inliers=np.full((P, 19), 3), n_views=np.full(P, 3),
                   ids=np.arange(P)) for x in X]


def _ties(X, times, rng, joints=(4, 5)):
    """Exact ties of random rigid motions carrying joints of track 1 from each time to the next."""
    out = []
    for k in range(len(times) - 1):
        q = rng.normal(size=3) * 0.1
        c, s = np.cos(q[0]), np.sin(q[0])
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        for j in joints:
            out.append((1, j, times[k], times[k + 1], R, X[k + 1, 1, j] - R @ X[k, 1, j], 0.5))
    cols = list(zip(*out))
    return JointTies(track_id=np.array(cols[0]), joint=np.array(cols[1]), from_ms=np.array(cols[2]),
                     to_ms=np.array(cols[3]), R=np.stack(cols[4]), t_cm=np.stack(cols[5]), sigma_cm=np.array(cols[6]))


def test_the_ties_term_is_their_cost():
    """H and b of the ties over a layout: the gradient H x - b vanishes where every tie holds, and
    0.5 x'Hx - b'x + c is half the cost sum |X(k+1) - R X(k) - t|^2 / sigma^2 at any x."""
    rng = np.random.default_rng(0)
    T = 6
    times = np.arange(T) * 33.0
    X = rng.normal(0, 50, (T, 2, 19, 3))
    bodies = _bodies(X)
    lay = _layout(bodies)
    ties = _ties(X, times, rng)
    H, b = ties.system(lay, times, bodies)
    P = np.zeros((lay.n_var, 3))
    P[lay.var[lay.var >= 0]] = np.stack([X[k, p] for k, p in zip(lay.bf_k, lay.bf_p)])[lay.var >= 0]
    assert np.abs(H @ P.ravel() - b.ravel()).max() < 1e-9
    x = rng.normal(0, 50, P.shape)
    rows = {(int(k), int(tr)): f for f, (k, tr) in enumerate(zip(lay.bf_k, lay.bf_track))}
    cost = 0.0
    for i in range(len(ties)):
        k0, k1 = int(np.searchsorted(times, ties.from_ms[i])), int(np.searchsorted(times, ties.to_ms[i]))
        i0, i1 = lay.var[rows[k0, 1], ties.joint[i]], lay.var[rows[k1, 1], ties.joint[i]]
        r = x[i1] - ties.R[i] @ x[i0] - ties.t_cm[i]
        cost += r @ r / ties.sigma_cm[i] ** 2
    x0 = P  # the quadratic's minimum (cost 0)
    assert 0.5 * x.ravel() @ H @ x.ravel() - b.ravel() @ x.ravel() - (
        0.5 * x0.ravel() @ H @ x0.ravel() - b.ravel() @ x0.ravel()) == pytest.approx(0.5 * cost, rel=1e-9)


def test_gap_variance_grows_with_the_ties_across_a_gap():
    rng = np.random.default_rng(1)
    T = 12
    times = np.arange(T) * 33.0
    X = rng.normal(0, 50, (T, 2, 19, 3))
    X[3:8, 1, 5] = np.nan  # wrist of track 1 missing at 5 times
    X[3:8, 0, 5] = np.nan  # and of track 0, which has no ties
    bodies = _bodies(X)
    lay = _layout(bodies)
    ties = _ties(np.nan_to_num(X), times, rng, joints=(5,))
    X0 = np.stack([bodies[k].X_cm[p] for k, p in zip(lay.bf_k, lay.bf_p)])
    base = np.full(lay.n_var, 1e6)
    q = np.full(19, 3e5)
    var = ties.gap_variance(lay, X0, times, bodies, base, q)
    v1 = var[lay.var[(lay.bf_track == 1), 5]]
    assert np.allclose(v1, 0.25 * np.array([0, 0, 0, 1, 2, 3, 2, 1, 0, 0, 0, 0]))  # sigma 0.5: 0.25 per step
    d = 0.033 * np.array([1, 2, 3, 2, 1])  # track 0 has no ties: the prior's own growth
    assert np.allclose(var[lay.var[(lay.bf_track == 0), 5]][3:8], 3e5 * d ** 3 / 3)
    # a step without a tie (4 -> 5) adds the prior's growth over its 33 ms (3.6 cm^2) to the side from time 2
    cut = ~((ties.joint == 5) & (ties.from_ms == times[4]))
    part = JointTies(*(getattr(ties, f)[cut] for f in JointTies.__dataclass_fields__))
    v2 = part.gap_variance(lay, X0, times, bodies, base, q)[lay.var[(lay.bf_track == 1), 5]]
    assert np.allclose(v2[[3, 4, 6, 7]], 0.25 * np.array([1, 2, 2, 1]))
    assert v2[5] == pytest.approx(0.75)  # from time 8: 3 tied steps (from time 2: 0.5 + 3.6)


def test_joint_ties_and_flags():
    assert TIED_JOINTS[0] == (2, 0) and set(TIED_JOINTS[1]) == {0, 1, 15, 16, 17, 18}
    with pytest.raises(Exception):
        TieOptions(floor_cm=0.0)
    d = np.zeros((2, 19, 3))
    d[1, 4] = [6.0, 0, 0]
    c = np.full((2, 19), 0.99)
    flags = flag_joints(d, np.zeros((2, 19, 3)), c)
    assert flags.sum() == 1 and flags[1, 4]
    c[1, 4] = 0.5  # the body is not sure there: no verdict
    assert not flag_joints(d, np.zeros((2, 19, 3)), c).any()


@pytest.fixture(scope="module")
def rig():
    """2 people on the few-camera rig for 1.5 s: the tracked bodies per frame, their detections, and patches on the
    true surface with the stream's error (the occluded limbs are bench/patches_body.py's)."""
    bundle = few_camera_rig(RigOptions(seed=1, duration_ms=1500.0 + GROUP_MARGIN_MS + 100.0))
    truth = rig_group(bundle, n_people=2, seed=1)
    table = bundle.sync.streams["hd"]
    times = table.univ_time_ms[(table.univ_time_ms >= truth.start_ms)][:45]
    det = synth_detections(bundle, truth, model=DetectorModel(seed=1))
    streams = people_streams(bundle, det)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    options = PeopleOptions()
    seq = reconstruct_people(views, streams, times, dataclasses.replace(options, temporal=TemporalOptions(
        enabled=False)))
    source = InMemorySource(streams)
    views = views.subset(source.cameras)
    priors = session_priors(seq.bodies, seq.cameras, options.temporal)
    task = WindowTask(index=0, views=views, source=source, times_ms=times, bodies=seq.bodies, own_start=0,
                      own_stop=len(times), priors=priors, options=options.temporal,
                      max_gap_frames=options.max_gap_frames, batch_times=options.batch_times, depth=None)
    obs = window_observations(task)
    X, present = truth.joints_cm(times)
    patches = true_patches(bundle, list(views.names), truth, times, 1, per_part=20)
    fit = lambda ties=None: refine_tracks(views, times, seq.bodies, obs, priors, options.temporal, ties=ties)  # noqa
    return fit, times, X, present, patches, (views, streams, options)


def _matched(res, X, present):
    return match_bodies([b.ids for b in res.bodies], [b.X_cm for b in res.bodies], X, present)


def test_no_ties_change_nothing(rig):
    fit, times, *_ = rig
    alone = fit()
    none = fit(_empty_ties())
    for a, b in zip(alone.bodies, none.bodies):
        assert np.array_equal(a.X_cm, b.X_cm, equal_nan=True) and np.array_equal(a.confidence, b.confidence)


def test_true_surface_motions_lower_the_error_and_the_jitter(rig):
    fit, times, X, present, (Pt, normal, alive, _, _), _ = rig
    alone = fit()
    body = _matched(alone, X, present)[1]
    ties, labels, motions = ties_from_patches(Pt, normal, alive, times, alone.bodies)
    assert len(ties) > 1000 and len(motions) > 500 and (labels.bone >= 0).mean() > 0.9
    withp = _matched(fit(ties), X, present)[1]
    both = np.isfinite(body).all(-1) & np.isfinite(withp).all(-1)
    e0, e1 = (np.linalg.norm(Y - X, axis=-1)[both] for Y in (body, withp))
    assert e1.mean() < 0.92 * e0.mean()  # measured: 1.31 -> 1.10 cm
    acc = lambda Y: Y[2:] - 2 * Y[1:-1] + Y[:-2]  # noqa: E731
    m3 = both[2:] & both[1:-1] & both[:-2]
    a0, a1 = (np.linalg.norm(acc(Y) - acc(X), axis=-1)[m3] for Y in (body, withp))
    assert a1.mean() < 0.5 * a0.mean()  # measured: 0.41 -> 0.05 cm per step^2


def _empty_ties() -> JointTies:
    return JointTies(track_id=np.zeros(0, np.int64), joint=np.zeros(0, np.int64), from_ms=np.zeros(0),
                     to_ms=np.zeros(0), R=np.zeros((0, 3, 3)), t_cm=np.zeros((0, 3)), sigma_cm=np.zeros(0))


def test_the_session_is_fitted_again_with_the_ties_in_its_windows(rig):
    """What `reconstruct --images` does after the patch stage: the body over time again from the same tracks, the
    ties carried to every window (windows of 4 margins cut these 45 times in several); no ties: the first pass to
    the bit."""
    _, times, X, present, (Pt, normal, alive, _, _), (views, streams, options) = rig
    options = dataclasses.replace(options, temporal=dataclasses.replace(options.temporal, window_margins=1))
    seq = reconstruct_people(views, streams, times, options)
    assert seq.tracked is not None
    again = refit_over_time(views, InMemorySource(streams), seq, options, _empty_ties())
    for a, b in zip(seq.bodies, again.bodies):
        assert np.array_equal(a.ids, b.ids) and np.array_equal(a.X_cm, b.X_cm, equal_nan=True)
    ties, _, _ = ties_from_patches(Pt, normal, alive, times, seq.bodies)
    refit = refit_over_time(views, InMemorySource(streams), seq, options, ties)
    body, withp = (match_bodies([b.ids for b in s.bodies], [b.X_cm for b in s.bodies], X, present)[1]
                   for s in (seq, refit))
    both = np.isfinite(body).all(-1) & np.isfinite(withp).all(-1)
    e0, e1 = (np.linalg.norm(Y - X, axis=-1)[both] for Y in (body, withp))
    assert e1.mean() < 0.92 * e0.mean(), (e0.mean(), e1.mean())  # measured: 1.26 -> 1.02 cm
    per_frame = dataclasses.replace(options, temporal=TemporalOptions(enabled=False))
    flat = reconstruct_people(views, streams, times, per_frame)
    assert flat.tracked is None and refit_over_time(views, InMemorySource(streams), flat, per_frame, ties) is flat
