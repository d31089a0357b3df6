"""dome_calib.synth.group_eval: the multi-person figures on bodies made with known errors, the group truth file and
the reconstruct output read back."""
from __future__ import annotations

import json

import numpy as np
import pytest

from dome_calib.body3d_scene import scene_json
from dome_calib.recon.people.bodies import Bodies
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.group_eval import MATCH_CM, judge_group, load_group_truth, match_bodies, read_bodies
from dome_calib.synth.group_session import truth_document

STEP_MS = 100.0


def _truth(T: int = 12, P: int = 3, seed: int = 0):
    """(times_ms (T,), X_cm (T, P, 19, 3), present (T, P)): P skeletons 1 m apart walking along x at 1 m/s;
    person 2 present at t = 0, 1 and 9..11 only."""
    rng = np.random.default_rng(seed)
    times = np.arange(T) * STEP_MS
    shape = rng.normal(0.0, 20.0, (P, 19, 3))
    X = shape[None] + np.arange(P)[None, :, None, None] * np.array([0.0, 0.0, 100.0]) \
        + (times * 0.1)[:, None, None, None] * np.array([1.0, 0.0, 0.0])
    present = np.ones((T, P), dtype=bool)
    if P > 2:
        present[2:9, 2] = False
    X[~present] = np.nan
    return times, X, present


def test_judge_group_counts_known_errors():
    times, X, present = _truth()
    T = len(times)
    ids, bodies = [], []
    for t in range(T):
        b_ids, b_X = [], []
        b0 = X[t, 0] + np.array([1.0, 0.0, 0.0])  # 1 cm off everywhere; joint 5 never reconstructed
        b0[5] = np.nan
        b_ids.append(0), b_X.append(b0)
        if t != 3:  # person 1 missed once, and renamed 1 -> 2 from t = 6 (100 ms after its last match: a switch)
            b_ids.append(1 if t < 6 else 2), b_X.append(X[t, 1])
        if present[t, 2]:  # person 2: id 5, then absent 800 ms (> the tracker's 500 ms), back as id 6: by design
            b_ids.append(5 if t < 2 else 6), b_X.append(X[t, 2])
        if 2 <= t <= 6:  # a false body 3 m away for 5 consecutive times
            b_ids.append(7), b_X.append(X[t, 0] + 300.0)
        if t in (9, 10):  # another for 2
            b_ids.append(8), b_X.append(X[t, 1] - 300.0)
        ids.append(np.array(b_ids)), bodies.append(np.array(b_X))
    oracle_X = X + np.array([0.0, 2.0, 0.0])  # 2 cm off everywhere
    seen = np.full(present.shape, 10)
    seen[0, 1] = 3  # person 1 seen by 3 views at t = 0: not in the 8-view figure
    g = judge_group(times, ids, bodies, X, present, oracle_X, seen, max_missed_ms=500.0)
    n0, n1, n2 = 18 * T, 19 * (T - 1), 19 * 5  # joints both reconstructed per person (errors 1, 0, 0 cm)
    assert g["mpjpe_cm"] == pytest.approx(n0 / (n0 + n1 + n2), abs=1e-3)
    assert g["oracle_mpjpe_cm"] == pytest.approx(2.0, abs=1e-9)
    assert g["ratio"] == pytest.approx(g["mpjpe_cm"] / 2.0, abs=2e-3)
    assert g["true_body_frames"] == 2 * T + 5 and g["matched_body_frames"] == 2 * T + 5 - 1
    assert g["true_body_frames_8views"] == 2 * T + 5 - 1
    assert g["found_8views"] == pytest.approx((2 * T + 5 - 2) / (2 * T + 5 - 1), abs=1e-4)  # the miss at t = 3
    assert g["oracle_found_8views"] == 1.0
    assert g["times"] == T and g["times_all_found"] == T - 1
    assert g["false_body_frames"] == 7 and g["false_bodies_gt3"] == 1
    assert g["id_switches"] == 1 and g["new_id_after_long_gap"] == 1
    assert g["id_switches_per_1000"] == pytest.approx(1000.0 / (2 * T + 4), abs=1e-3)
    assert g["body_frames"] == sum(len(i) for i in ids)


def test_match_gate_is_mean_joint_distance():
    times, X, present = _truth(T=1, P=1)
    near = X[0, 0] + np.array([0.0, MATCH_CM - 0.5, 0.0])
    far = X[0, 0] + np.array([0.0, MATCH_CM + 0.5, 0.0])
    for body, want in ((near, 4), (far, -1)):
        match_id, ours, unmatched = match_bodies([np.array([4])], [body[None]], X, present)
        assert match_id[0, 0] == want
        assert (unmatched == {}) == (want == 4) and np.isfinite(ours).all() == (want == 4)
    # Hungarian, not greedy: two people 15 cm apart (same shape); body A is 5 cm from person 0 and 10 cm from
    # person 1, body B 8 cm from person 0 and 23 cm from person 1: greedy would give A to person 0 and lose person 1
    S = X[0, 0]
    two = np.stack([S, S + np.array([0.0, 0.0, 15.0])])[None]
    A, B = S + np.array([0.0, 0.0, 5.0]), S + np.array([0.0, 0.0, -8.0])
    match_id, ours, _ = match_bodies([np.array([10, 11])], [np.stack([A, B])], two, np.ones((1, 2), dtype=bool))
    assert match_id.tolist() == [[11, 10]]
    np.testing.assert_array_equal(ours[0, 1], A)


def test_group_truth_and_bodies_read_back(tmp_path):
    truth = make_group(GroupOptions(n_people=7, scenario="mixed", start_ms=0.0, duration_ms=3000.0, seed=1))
    times = np.arange(0.0, 3000.0, 40.0)
    doc = truth_document(truth, times, np.arange(len(times)) + 100, stream="vga",
                         options=GroupOptions(n_people=7, scenario="mixed", duration_ms=3000.0, seed=1))
    doc["options"] = {"body_model": "BODY_25"}
    (tmp_path / "group_truth.json").write_text(json.dumps(doc))
    g = load_group_truth(tmp_path / "group_truth.json")
    X, present = truth.joints_cm(times)
    assert g.ids.tolist() == list(range(7)) and g.body_model == "BODY_25" and g.scenario == "mixed"
    assert g.frames.tolist() == (np.arange(len(times)) + 100).tolist()
    np.testing.assert_array_equal(g.present, present)
    assert not present.all()  # the leaver is gone before the end
    np.testing.assert_allclose(g.X_cm[present], X[present], atol=1e-3)  # 3 decimals in the file
    assert np.isnan(g.X_cm[~present]).all()
    # bodies written as reconstruct writes them, read back in frame order with missing joints NaN
    out = tmp_path / "people"
    out.mkdir()
    written = {}
    for frame in (9, 10, 100):
        k = frame % 7
        Xb = X[k, :2].copy()
        conf = np.full((2, 19), 0.5)
        conf[1, 4] = -1.0
        b = Bodies(X_cm=Xb, confidence=conf, n_inliers=np.full((2, 19), 3), n_views=np.array([3, 3]),
                   ids=np.array([frame, 1]))
        scene = scene_json(frame * 40.0, b.ids, b.X_cm, b.confidence, b.n_inliers, "vga_25")
        (out / f"body3DScene_{frame:08d}.json").write_text(json.dumps(scene))
        written[frame] = Xb
    frames, t_ms, ids, bodies = read_bodies(out)
    assert frames.tolist() == [9, 10, 100] and t_ms.tolist() == [360.0, 400.0, 4000.0]
    for f, i, B in zip(frames, ids, bodies):
        assert sorted(i.tolist()) == sorted([1, int(f)])
        by_id = dict(zip(i.tolist(), B))
        np.testing.assert_allclose(by_id[int(f)], written[f][0], atol=1e-4)
        assert np.isnan(by_id[1][4]).all() and np.isfinite(np.delete(by_id[1], 4, axis=0)).all()
