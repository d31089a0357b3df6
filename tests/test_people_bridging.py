"""A tracked person through thin evidence (dome_calib.recon.people.bridging): times where a person shows few views
only part of his body, between times where he is tracked."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dome_calib.recon.body_models import JOINTS19
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.bridging import GapPredictions, gap_batches, gap_predictions
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people
from dome_calib.recon.people.sources import people_streams
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.people.tracking import TrackingOptions
from dome_calib.recon.project import view_set

from .people_helpers import group_detections, group_joints_cm
from .recon_helpers import real_bundle

#: What the thin views show of the person (his face, neck and right arm, as next to a panel): view A all 7 joints,
#: B the first 4, C the last 4, D the 2 first and 2 last. Every pair shares at most 4 (A with each other), so the
#: pair hypotheses' common joints add up to 12, below the association's cluster floor (15); every joint is in 2 or
#: 3 of the views, so 7 joints can be triangulated.
THIN = [JOINTS19.index(n) for n in ("nose", "l_eye", "r_eye", "neck", "r_shoulder", "r_elbow", "r_wrist")]
SHOWN = {"A": THIN, "B": THIN[:4], "C": THIN[3:], "D": THIN[:2] + THIN[5:]}
GAP = slice(8, 14)  # the reference (VGA) times where person 0 is thin


@pytest.fixture(scope="module")
def thin_person():
    """3 people walking, seen by 24 VGA and 31 HD cameras (noise, misses, swaps); at 6 VGA times in the middle
    person 0 is seen only by 4 VGA cameras and only as SHOWN (in the HD cameras not at all then)."""
    bundle = real_bundle(kinect=False, n_vga=24, start_ms=1000.0, duration_ms=900.0, seed=4)
    cams = sorted(n for n, c in bundle.cameras.items() if c.type in ("vga", "hd"))
    people, labels = group_detections(bundle, cams, 3, seed=5, false_people=0.0, swap=0.0, miss=0.0)
    vga = bundle.sync.streams["vga"]
    times = vga.univ_time_ms[2:-2]
    gap_frames = [int(f) for f in vga.index[2:-2][GAP]]
    t0, t1 = times[GAP][0] - 50.0, times[GAP][-1] + 50.0  # HD frames that bracket the thin times
    vcams = [c for c in cams if bundle.cameras[c].type == "vga"]
    # the thin views: VGA cameras that see all of person 0's SHOWN joints at every thin time
    full_view = [c for c in vcams if all(np.any(labels[c][f] == 0) and np.all(
        people[c][f][labels[c][f] == 0][0][THIN, 2] > 0) for f in gap_frames)]
    assert len(full_view) >= 4
    shown = dict(zip(full_view[:4], SHOWN.values()))
    for c in cams:
        if bundle.cameras[c].type == "vga":
            frames = gap_frames
        else:
            table = bundle.sync.streams["hd"]
            frames = [int(f) for f, t in zip(table.index, table.univ_time_ms) if t0 <= t <= t1]
        for f in frames:
            if f not in people[c]:
                continue
            rows, lab = people[c][f], labels[c][f]
            mine = lab == 0
            if c in shown:
                hide = np.ones(19, bool)
                hide[shown[c]] = False
                rows = rows.copy()
                rows[np.ix_(mine, hide)] = 0.0
            else:
                rows, lab = rows[~mine], lab[~mine]
            people[c][f], labels[c][f] = rows, lab
    return bundle, cams, people, times


def _found(seq, truth):
    """(T, P) distance (cm) of each true person's nearest body (inf: none), (T, P) its id, and the bodies per time."""
    T, P = truth.shape[:2]
    err, ids = np.full((T, P), np.inf), np.full((T, P), -1)
    for k, b in enumerate(seq.bodies):
        for X, i in zip(b.X_cm, b.ids):
            d = np.nanmean(np.linalg.norm(X[None] - truth[k], axis=-1), axis=-1)
            p = int(np.argmin(d))
            if d[p] < err[k, p]:
                err[k, p], ids[k, p] = d[p], i
    return err, ids, [len(b.ids) for b in seq.bodies]


@pytest.mark.parametrize("temporal", [False, True])
def test_a_tracked_person_is_kept_where_his_evidence_is_thin(thin_person, temporal):
    """Without bridging, person 0 is lost at the 6 thin times (his pair hypotheses are below the cluster floor);
    with it he is there at every time, under the id he has before and after, within 5 cm of the truth, and no
    other body appears (3 bodies at every time)."""
    bundle, cams, people, times = thin_person
    views = view_set(bundle, cams)
    streams = people_streams(bundle, people)
    truth = group_joints_cm(times, 3, seed=5)
    options = PeopleOptions(temporal=TemporalOptions(enabled=temporal))
    off = dataclasses.replace(options, tracking=TrackingOptions(bridge_gaps=False))
    err, _, counts = _found(reconstruct_people(views, streams, times, off), truth)
    assert np.all(np.isinf(err[GAP, 0])) and np.all(np.isfinite(np.delete(err[:, 0], np.arange(len(times))[GAP])))
    seq = reconstruct_people(views, streams, times, options)
    err, ids, counts = _found(seq, truth)
    assert err.max() < 5.0, err.max(axis=0)
    assert counts == [3] * len(times)
    assert [len(set(ids[:, p])) for p in range(3)] == [1] * 3
    if not temporal:  # the gaps' times read and searched 2 at a time: the same bodies to the last bit
        again = reconstruct_people(views, streams, times, dataclasses.replace(options, batch_times=2))
        for a, b in zip(seq.bodies, again.bodies):
            np.testing.assert_array_equal(a.ids, b.ids)
            np.testing.assert_array_equal(a.X_cm, b.X_cm)
            np.testing.assert_array_equal(a.assigned, b.assigned)
        for tally in ("detected", "used", "hist", "noise"):
            np.testing.assert_array_equal(getattr(seq.cameras, tally), getattr(again.cameras, tally))


def test_gap_predictions_follow_the_tracker_motion():
    """A track seen at times 0 and 3 (not 1, 2) is predicted at 1 and 2 on the straight line between, a joint known
    on one side only carried by the body's displacement; the gate is the tracker's, from the nearer side."""
    X0 = np.zeros((19, 3))
    X0[:, 0] = np.arange(19)
    X3 = X0 + [30.0, 0.0, 0.0]
    X0[5] = np.nan  # joint 5 only seen after the gap
    one = lambda X: Bodies(X_cm=X[None], confidence=np.ones((1, 19)), n_inliers=np.full((1, 19), 3),
                           n_views=np.array([3]), ids=np.array([7]), assigned=np.zeros((1, 2), np.int16))
    none = Bodies(X_cm=np.zeros((0, 19, 3)), confidence=np.zeros((0, 19)), n_inliers=np.zeros((0, 19), np.int64),
                  n_views=np.zeros(0, np.int64), ids=np.zeros(0, np.int64), assigned=np.zeros((0, 2), np.int16))
    gaps = gap_predictions(np.array([0.0, 100.0, 200.0, 300.0]), [one(X0), none, none, one(X3)],
                           TrackingOptions(gate_cm=40.0, gate_cm_per_s=100.0))
    assert [g.k for g in gaps] == [1, 2] and all(g.ids.tolist() == [7] for g in gaps)
    np.testing.assert_allclose(gaps[0].X_cm[0, :, 0], np.arange(19) + 10.0)
    np.testing.assert_allclose(gaps[1].X_cm[0, :, 0], np.arange(19) + 20.0)
    np.testing.assert_allclose([g.gate_cm[0] for g in gaps], [50.0, 50.0])


def test_gaps_far_apart_are_read_apart():
    """The gaps' times go in batches within batch_times consecutive times (a file source reads what brackets a batch's
    span: gaps an hour apart are never read together)."""
    gaps = [GapPredictions(k=k, ids=np.zeros(1, np.int64), X_cm=np.zeros((1, 19, 3)), gate_cm=np.ones(1))
            for k in (3, 4, 18, 19, 40, 900)]
    assert [[g.k for g in b] for b in gap_batches(gaps, 16)] == [[3, 4, 18], [19], [40], [900]]
