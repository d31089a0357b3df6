"""Quick recalibration (`calibrate --prior --only-changed`) on a synthetic scene database: keypoints are exact
projections (plus noise) of tent-like points into the CURRENT cameras, matches and verified two-view geometries
are written as matching would write them, and the prior is the calibration before two cameras were disturbed.
Checks the epipolar screening, the triangulation with known poses, the registration and the refinement against
the current truth, and that every other camera stays bit-identical to the prior."""
from __future__ import annotations

import dataclasses
import itertools
import json

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from dome_calib.bundle import Bundle

from dome_calib.bundle_io import write_bundle
from dome_calib.camera import intr_to_K, opencv_to_colmap_px, project
from dome_calib.compare import camera_error
from dome_calib.layout import nominal_dome
from dome_calib.reasons import ReasonCode
from projector.consistency import changed_cameras, pair_errors
from projector.database import add_image, image_name, write_features

from .report_data import NO_PLOTS  # the calibration test reads no plot

NOISE_PX = 0.2
#: Its own camera set (not a preset's): one panel's neighbourhood, as the quick path sees it on the dome, where
#: every camera has close partners.
CAMERAS = [f"01_{k:02d}" for k in range(1, 9)] + ["00_00", "00_01", "00_16", "50_04"]
MOVED, RELENSED = "01_03", "01_05"
BLANK = "01_08"  # in the prior, a blank image now


def _neighbourhood() -> Bundle:
    full = nominal_dome("full", seed=0)
    return Bundle(seq="prior", cameras={n: full.cameras[n] for n in CAMERAS})


def _disturbed(prior: Bundle) -> Bundle:
    """The dome now: MOVED shifted 3 cm and turned 1.1 deg, RELENSED with a 4 % shorter focal length."""
    now = dict(prior.cameras)
    c = now[MOVED]
    R = Rotation.from_rotvec([0.0, 0.02, 0.0]).as_matrix() @ c.R
    now[MOVED] = dataclasses.replace(c, R=R, t_cm=-R @ (c.center_cm + [3.0, 0.0, 0.0]))
    c = now[RELENSED]
    now[RELENSED] = dataclasses.replace(c, K=intr_to_K(c.intr * [0.96, 0.96, 1, 1]))
    return Bundle(seq="now", cameras=now)


def write_scene_database(path, current: Bundle, prior: Bundle, seed: int = 0, n_points: int = 3000) -> list[str]:
    """A scene database as features + matching would leave it (database cameras from the prior)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-70, -190, -70], [70, -10, 70], size=(n_points, 3))
    names = sorted(current.cameras)
    s = current.stacked(names)
    proj = project(X, s["R"], s["t_cm"], s["intr"], s["dist"])
    seen = proj.in_image(s["resolution"]) & proj.in_lens
    keypoint_of = np.full(seen.shape, -1)
    with pycolmap.Database.open(str(path)) as db:
        ids = {}
        for c, n in enumerate(names):
            visible = np.nonzero(seen[c])[0]
            keypoint_of[c, visible] = np.arange(len(visible))
            uv = opencv_to_colmap_px(proj.uv_px[c, visible] + rng.normal(0, NOISE_PX, (len(visible), 2)))
            kp = np.column_stack([uv, np.ones(len(uv)), np.zeros(len(uv))])
            ids[n] = add_image(db, image_name(n), prior.cameras[n])
            write_features(db, ids[n], kp, rng.integers(0, 255, (len(uv), 128), dtype=np.uint8))
        for (a, na), (b, nb) in itertools.combinations(enumerate(names), 2):
            both = np.nonzero(seen[a] & seen[b])[0]
            if len(both) < 30:
                continue
            m = np.column_stack([keypoint_of[a, both], keypoint_of[b, both]]).astype(np.uint32)
            db.write_matches(ids[na], ids[nb], m)
            tvg = pycolmap.TwoViewGeometry()
            tvg.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            tvg.inlier_matches = m
            db.write_two_view_geometry(ids[na], ids[nb], tvg)
    return names


def _matched_scene(tmp_path, current: Bundle, prior: Bundle, seed: int):
    """The quick path's stage ``match`` as :func:`write_scene_database` leaves it (no images on disk)."""
    import dome_calib.pipeline.quick as quick

    db = tmp_path / "scene_01" / "database.db"
    db.parent.mkdir()
    names = write_scene_database(db, current, prior, seed=seed)
    return quick.MatchedScene(scene="scene_01", database=db, image_dir=tmp_path, cameras=names, failures={},
                              pairs=0, verified_pairs=0, inlier_matches=0, seconds={})


@pytest.fixture
def scene(tmp_path):
    prior = _neighbourhood()
    current = _disturbed(prior)
    db = tmp_path / "scene_01" / "database.db"
    db.parent.mkdir()
    names = write_scene_database(db, current, prior)
    return prior, current, db, names


def test_epipolar_screening_flags_exactly_the_disturbed_cameras(scene):
    prior, current, db, _ = scene
    same = changed_cameras(pair_errors(db, current.cameras))
    assert same.changed == {}  # the truth explains every pair: nothing flagged
    errors = pair_errors(db, prior.cameras)
    verdict = changed_cameras(errors)
    assert sorted(verdict.changed) == [MOVED, RELENSED]
    good = [e for (a, b), e in errors.items() if MOVED not in (a, b) and RELENSED not in (a, b)]
    assert max(good) < 0.5  # px: feature noise only
    assert np.median([e for (a, b), e in errors.items() if MOVED in (a, b)]) > 2.0  # px: a 1.1 deg turn


def test_greedy_verdict_clears_neighbours_of_a_disturbed_group():
    """A camera whose partners are mostly disturbed has mostly bad pairs, yet is not flagged once they are."""
    err = {("a", "b"): 9.0, ("a", "c"): 9.0, ("b", "c"): 9.0, ("a", "x"): 9.0, ("b", "x"): 9.0, ("c", "x"): 9.0,
           ("x", "y"): 0.1, ("y", "z"): 0.1, ("x", "z"): 0.1}
    verdict = changed_cameras(err, bad_px=1.0)
    assert sorted(verdict.changed) == ["a", "b", "c"]  # x had 3 of 5 pairs bad


def test_quick_recalibration_reestimates_only_the_changed(tmp_path, scene, monkeypatch):
    import dome_calib.pipeline.full as pipeline
    import dome_calib.pipeline.quick as quick
    from dome_calib.bundle_io import load_bundle

    prior, current, db, names = scene
    cap = tmp_path / "capture"
    (cap / "scenes" / "scene_01").mkdir(parents=True)
    (cap / "capture.json").write_text(json.dumps({"scenes": ["scene_01"], "cameras": names}))
    matched = quick.MatchedScene(scene="scene_01", database=db, image_dir=cap / "scenes" / "scene_01", cameras=names,
                                 failures={BLANK: "blank image (grey-level std 0.0 < 3.0)"}, pairs=0,
                                 verified_pairs=0, inlier_matches=0, seconds={})
    monkeypatch.setattr(quick, "match_first_scene", lambda *a, **k: matched)
    prior_dir = write_bundle(prior, tmp_path / "prior")
    out = tmp_path / "quick"
    result = pipeline.run_calibration(cap, out, pipeline.CalibrateOptions(prior=prior_dir, only_changed=True, report=NO_PLOTS))
    assert sorted(result.changes) == [MOVED, RELENSED]
    bundle = load_bundle(out)
    for n in prior.cameras:
        if n not in (MOVED, RELENSED):
            np.testing.assert_array_equal(bundle.cameras[n].t_cm, prior.cameras[n].t_cm)
            np.testing.assert_array_equal(bundle.cameras[n].K, prior.cameras[n].K)
    for n in (MOVED, RELENSED):  # the prior's frame: no alignment needed
        e = camera_error(bundle.cameras[n], current.cameras[n])
        assert e.center_cm < 0.3 and e.rotation_deg < 0.05 and e.focal_pct < 0.5, (n, e)
    assert ReasonCode.INTRINSICS_CHANGED in [r.code for r in result.changes[RELENSED].reasons]
    assert ReasonCode.INTRINSICS_CHANGED not in [r.code for r in result.changes[MOVED].reasons]
    np.testing.assert_array_equal(bundle.cameras[MOVED].K, prior.cameras[MOVED].K)  # a moved camera keeps its lens
    assert f"{MOVED}: residual" in pipeline.format_result(result)
    unchecked = [row for row in result.to_check if row.name == BLANK]  # in the prior, blank image now
    assert unchecked and unchecked[0].reasons[0].code == ReasonCode.NOT_CHECKED
    assert "not checked against the prior: no usable image" in unchecked[0].reasons[0].text
    assert BLANK in bundle.cameras and BLANK not in result.changes


def test_quick_recalibration_with_nothing_changed_keeps_the_prior(tmp_path):
    import dome_calib.pipeline.quick as quick

    prior = _neighbourhood()
    matched = _matched_scene(tmp_path, prior, prior, seed=3)
    det = quick.detect_suspects(matched, prior)
    assert det.suspects == []
    est = quick.reestimate(matched, det, prior, tmp_path / "work")
    assert est.changed == [] and est.ba is None


def test_greedy_verdict_flags_a_group_that_moved_as_a_whole():
    """Panel p moved rigidly: its internal pairs stay good, each camera has only one bad pair of three, yet every
    pair leaving the panel is bad: the group is flagged, its neighbours (q, x) are not."""
    p, q = ["p1", "p2", "p3", "p4", "p5"], ["q1", "q2", "q3"]
    err = {pair: 0.1 for pair in itertools.combinations(p, 2)}
    err.update({pair: 0.1 for pair in itertools.combinations(q + ["x", "y"], 2)})
    err.update({(a, b): 9.0 for a, b in zip(p, q + ["x", "y"])})  # one pair each leaves the panel
    group_of = {n: 1 for n in p} | {n: 2 for n in q}
    alone = changed_cameras(err, bad_px=1.0)
    assert alone.changed == {}  # camera by camera, nothing looks changed
    verdict = changed_cameras(err, bad_px=1.0, group_of=group_of)
    assert sorted(verdict.changed) == p and verdict.changed_groups == {1: (1.0, 5)}
    few = {pair: e for pair, e in err.items() if pair not in (("p4", "x"), ("p5", "y"))}
    assert changed_cameras(few, bad_px=1.0, group_of=group_of).changed == {}  # 3 pairs leaving it: too few to judge


def test_rigidly_moved_panel_is_found_and_reestimated(tmp_path):
    """The eight panel-1 cameras moved together (2 cm and 1 deg about the panel's centre): their mutual pairs fit
    the prior, their pairs with the HD and Kinect cameras do not. All eight are found and re-estimated; the
    cameras off the panel keep the prior."""
    import dome_calib.pipeline.quick as quick

    prior = _neighbourhood()
    panel = [n for n in CAMERAS if n.startswith("01_")]
    centre = np.mean([prior.cameras[n].center_cm for n in panel], axis=0)
    turn = Rotation.from_rotvec([0.0, np.radians(1.0), 0.0]).as_matrix()
    now = dict(prior.cameras)
    for n in panel:
        c = now[n]
        R = c.R @ turn.T  # world turned about the panel centre, then shifted: a rigid motion of the panel
        C = centre + turn @ (c.center_cm - centre) + [2.0, 0.0, 0.0]
        now[n] = dataclasses.replace(c, R=R, t_cm=-R @ C)
    current = Bundle(seq="now", cameras=now)
    matched = _matched_scene(tmp_path, current, prior, seed=5)
    det = quick.detect_suspects(matched, prior)
    assert det.suspects == sorted(panel) and det.panels == [1]
    est = quick.reestimate(matched, det, prior, tmp_path / "work")
    assert sorted(est.changed) == sorted(panel)
    for n in panel:
        e = camera_error(est.ba.cameras[n], current.cameras[n])
        assert e.center_cm < 0.3 and e.rotation_deg < 0.05, (n, e)
