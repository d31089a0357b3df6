"""The body volume (occlusion) and the OpenPose-like detector of dome_calib.synth: hand-built occlusions, a brute-force
occlusion check, failure rates over many frames, OpenPose JSON round trips, determinism per camera."""
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.bundle import Bundle
from dome_calib.recon.body_models import JOINT_NAMES, to_joints19
from dome_calib.recon.project import view_set
from dome_calib.synth.body_volume import (_FACE, _FACE_MIN_COS, CAPSULE_RADIUS_CM, INSIDE_MARGIN_CM, RAY_STOP_CM,
                                          _capsule_hit, capsules_cm, occluded_joints, occluders, segment_distance2)
from dome_calib.synth.detector import (DetectionCounts, DetectorError, DetectorModel, openpose_file_name, shared_clock,
                                       synth_detections, write_openpose_folder)
from dome_calib.synth.detector_reference import truth_track
from dome_calib.synth.group import GroupOptions, GroupTruth, PersonPlan, make_group

from .recon_helpers import real_bundle

TORSO = [0, 2, 3, 9, 6, 12]  # neck, body centre, shoulders, hips


def _standing(*spots):
    """People standing at (x, z, facing_rad) spots."""
    plans = tuple(PersonPlan(id=i, role="talk", waypoints_cm=((x, z),), facing_rad=f) for i, (x, z, f) in
                  enumerate(spots))
    return GroupTruth(ids=list(range(len(plans))), plans=plans, start_ms=0.0, duration_ms=1000.0)


def test_a_person_between_camera_and_another_hides_the_right_joints():
    camera = np.array([[0.0, -120.0, -400.0]])
    facing_camera = -math.pi / 2  # forward = -z
    X, _ = _standing((0.0, 0.0, facing_camera), (0.0, -120.0, facing_camera)).joints_cm(np.zeros(1))
    occ = occluded_joints(camera, X[0])
    assert occ[0, 0, TORSO].all()  # the one behind: torso hidden by the blocker
    assert not occ[0, 1, TORSO + [1, 15, 17]].any()  # the blocker itself faces the camera, all seen
    by_self, by_others = occluders(camera, X[0])
    assert by_others[0, 0, TORSO].all() and not by_others[0, 1].any()  # who hides: the other one
    assert np.array_equal(by_self | by_others, occ) and not by_self[0, 0, TORSO].any()
    # Moving the blocker aside reveals them.
    X, _ = _standing((0.0, 0.0, facing_camera), (150.0, -120.0, facing_camera)).joints_cm(np.zeros(1))
    occ = occluded_joints(camera, X[0])
    assert not occ[0, 0, TORSO + [1, 15, 17, 16, 18]].any()
    # An absent blocker hides nothing and is not tested.
    X, _ = _standing((0.0, 0.0, facing_camera), (0.0, -120.0, facing_camera)).joints_cm(np.zeros(1))
    occ = occluded_joints(camera, X[0], np.array([True, False]))
    assert not occ[0, 0, TORSO].any() and not occ[0, 1].any()


def test_self_occlusion_from_behind_and_from_the_side():
    X, _ = _standing((0.0, 0.0, -math.pi / 2)).joints_cm(np.zeros(1))  # facing -z; its right is -x
    behind, front = np.array([0.0, -120.0, 400.0]), np.array([0.0, -120.0, -400.0])
    right_side = np.array([-400.0, -120.0, 0.0])
    occ = occluded_joints(np.stack([behind, front, right_side]), X[0])[:, 0]
    by_self, by_others = occluders(np.stack([behind, front, right_side]), X[0])
    assert np.array_equal(by_self[:, 0], occ) and not by_others.any()  # alone: every hidden joint is its own doing
    assert occ[0, [1, 15, 17]].all() and not occ[1, [1, 15, 17, 16, 18]].any()  # face from behind / front
    assert not occ[0, [0, 3, 9, 6, 12]].any()  # shoulders, hips and neck are seen from behind
    assert occ[2, [3, 6, 16]].all()  # from its right: left shoulder, hip and ear hidden by the body
    assert not occ[2, [9, 12, 18]].any()


def test_occlusion_equals_brute_force():
    truth = make_group(GroupOptions(n_people=8, scenario="mixed", seed=3))
    X, present = truth.joints_cm(np.array([2200.0]))
    X, present = X[0], present[0]
    bundle = real_bundle(n_vga=30, kinect=False, sync=False)
    C = view_set(bundle).center_cm
    fast = occluded_joints(C, X, present)
    # Brute force: every ray against every capsule of every present person.
    A, B, r = capsules_cm(X)
    P = len(X)
    ray_end = X[None] - RAY_STOP_CM * (X[None] - C[:, None, None]) / np.linalg.norm(
        X[None] - C[:, None, None], axis=-1, keepdims=True)  # (V, P, 19, 3)
    V = len(C)
    shape = (V, P, 19, P, 12)
    p1 = np.broadcast_to(C[:, None, None, None, None], shape + (3,)).reshape(-1, 3)
    q1 = np.broadcast_to(ray_end[:, :, :, None, None], shape + (3,)).reshape(-1, 3)
    p2 = np.broadcast_to(A[None, None, None], shape + (3,)).reshape(-1, 3)
    q2 = np.broadcast_to(B[None, None, None], shape + (3,)).reshape(-1, 3)
    hit = (segment_distance2(p1, q1, p2, q2) < np.broadcast_to(r ** 2, shape).reshape(-1)).reshape(shape)
    own_inside = np.zeros((P, 19, P, 12), dtype=bool)
    for p in range(P):
        for k in range(12):  # point to capsule axis
            d = B[p, k] - A[p, k]
            t = np.clip((X[p] - A[p, k]) @ d / (d @ d), 0.0, 1.0)
            dist = np.linalg.norm(X[p] - A[p, k] - t[:, None] * d, axis=-1)
            own_inside[p, :, p, k] = dist < CAPSULE_RADIUS_CM[k] + INSIDE_MARGIN_CM
    hit &= ~own_inside[None] & present[None, None, None, :, None]
    slow = hit.any(axis=(3, 4))
    head = 0.5 * (X[:, 16] + X[:, 18])
    for k, j in enumerate(_FACE):
        n = X[:, j] - head
        to_cam = C[:, None] - X[None, :, j]
        cos = np.sum(n * to_cam, -1) / np.linalg.norm(n, axis=-1) / np.linalg.norm(to_cam, axis=-1)
        slow[:, :, j] |= cos < _FACE_MIN_COS[k]
    slow &= present[None, :, None]
    assert 0.15 < slow[:, present].mean() < 0.7
    assert np.array_equal(fast, slow), np.argwhere(fast != slow)[:5]


def test_segment_distance_and_capsule_hit():
    rng = np.random.default_rng(0)
    p1, q1, p2, q2 = (rng.normal(size=(4000, 3)) * 30 for _ in range(4))
    d2 = segment_distance2(p1, q1, p2, q2)
    s = np.linspace(0, 1, 401)
    a = p1[:, None] + s[None, :, None] * (q1 - p1)[:, None]
    b = p2[:, None] + s[None, :, None] * (q2 - p2)[:, None]
    for i in range(0, 4000, 200):  # dense sampling bounds the true distance from above
        dense = np.min(np.linalg.norm(a[i][:, None] - b[i][None], axis=-1))
        assert math.sqrt(d2[i]) <= dense + 1e-9 and dense - math.sqrt(d2[i]) < 0.2
    # parallel segments
    assert segment_distance2(np.zeros((1, 3)), np.array([[10.0, 0, 0]]), np.array([[5.0, 3, 0]]),
                             np.array([[20.0, 3, 0]]))[0] == pytest.approx(9.0)
    rad2 = rng.uniform(1, 900, size=(4000, 1))
    d1, d2v, r = q1 - p1, (q2 - p2)[:, None], (p1 - p2)[:, None]
    hit = _capsule_hit(tuple(d1.T), np.sum(d1 * d1, -1), tuple(np.moveaxis(r, -1, 0)), np.sum(r * r, -1),
                       np.sum(d2v * r, -1), tuple(np.moveaxis(d2v, -1, 0)), np.sum(d2v * d2v, -1), rad2)[:, 0]
    clear = np.abs(d2 - rad2[:, 0]) > 1e-6 * rad2[:, 0]
    assert np.array_equal(hit[clear], (d2 < rad2[:, 0])[clear])


@pytest.fixture(scope="module")
def scene():
    bundle = real_bundle(n_vga=12, start_ms=0.0, duration_ms=4000.0)
    truth = make_group(GroupOptions(n_people=8, scenario="mixed", seed=2))
    cams = sorted(bundle.of_type("vga"))[:12] + sorted(bundle.of_type("hd"))[::3]
    return bundle, truth, cams


def test_detector_rates_and_failure_modes(scene):
    """The rates the detector reports (DetectionCounts) are the set ones, on 8 people in the dome."""
    bundle, truth, cams = scene
    model = DetectorModel(seed=1, miss_base=0.05, swap_lr=0.05, swap_limb=0.1, neighbour_limb=0.3,
                          false_people_per_view=0.2, conf_above_1=0.01)
    counts = DetectionCounts()
    det, ids = synth_detections(bundle, truth, cameras=cams, model=model, counts=counts, with_ids=True)
    r = counts.rates()
    assert abs(r["miss_visible"] - model.miss_base) < 0.012  # episodes: fewer independent draws than joints
    assert abs(r["miss_hidden"] - model.miss_occluded) < 0.05
    assert r["miss_border_zone"] > r["miss_visible"] + 0.1  # misses rise at the border
    assert abs(r["swap_whole"] - 0.05) < 0.015 and abs(r["swap_limb"] - 0.1) < 0.025
    assert counts.neighbour_eligible > 500 and abs(r["neighbour_limb"] - 0.3) < 0.06
    assert 0.1 < r["false_people_per_view"] <= 0.2 + 0.04
    assert abs(r["confidence_above_1"] - 0.01) < 0.003
    assert counts.people_cut > 1000 and 0.5 < r["cut_people_detected"] < 1.0  # truncated people still detected
    # Confidence follows visibility: another person's hidden joints that are detected have low confidence.
    vga = [c for c in cams if bundle.cameras[c].type == "vga"][:6]
    table = bundle.sync.streams["vga"]
    frames = np.array(sorted(det[vga[0]]))
    conf = {False: [], True: []}
    for person in truth.ids:
        t = truth_track(bundle, truth, {c: det[c] for c in vga}, ids, frames, table.times_of(frames), 40.0,
                        person=person)
        seen = t.kp[..., 2] > 0
        conf[False] += t.kp[..., 2][seen & ~t.hidden].tolist()
        conf[True] += t.kp[..., 2][seen & t.hidden].tolist()
    assert np.median(conf[True]) + 0.25 < np.median(conf[False])
    # Without truncation, a person cut by the border is not detected at all.
    counts2 = DetectionCounts()
    synth_detections(bundle, truth, cameras=cams[:4], model=DetectorModel(truncate_border=False), counts=counts2)
    assert counts2.people_cut > 0 and counts2.people_cut_detected == 0


def test_detections_per_camera_are_deterministic(scene):
    """A camera's detections do not depend on the other cameras, on the span asked for (its errors start at the
    anchor 1 s before the group), or on the seed of another run; a span before the anchor is refused."""
    bundle, truth, cams = scene
    model = DetectorModel(seed=9)
    alone = synth_detections(bundle, truth, cameras=["00_05"], model=model)
    many = synth_detections(bundle, truth, cameras=["00_05", cams[0], "50_03"], model=model,
                            univ_time_ms=(1000.0, 3000.0))
    assert set(many["00_05"]) < set(alone["00_05"]) and len(many["00_05"]) > 50
    for f, d in many["00_05"].items():
        assert np.array_equal(d, alone["00_05"][f])
    other = synth_detections(bundle, truth, cameras=["00_05"], model=DetectorModel(seed=10))
    assert any(not np.array_equal(d, other["00_05"][f]) for f, d in alone["00_05"].items())
    # Each stream at its own frames: VGA, HD and Kinect frame indices come from their own sync tables.
    for cam, stream in (("00_05", "hd"), (cams[0], "vga")):
        table = bundle.sync.streams[stream]
        t = table.times_of(np.array(sorted(many[cam])))
        assert np.all((t >= 1000.0) & (t <= 3000.0))
    kin = bundle.sync.kinect_color["KINECTNODE3"]
    assert set(many["50_03"]) == set(kin.index[(kin.univ_time_ms >= 1000.0) & (kin.univ_time_ms <= 3000.0)].tolist())
    with pytest.raises(DetectorError, match="before the group"):
        synth_detections(bundle, truth, cameras=["00_05"], univ_time_ms=(truth.start_ms - 1500.0, 100.0))


@pytest.mark.parametrize("body_model, naming", [("BODY_25", "openpose"), ("COCO_18", "dotted"),
                                                ("BODY_25B", "openpose"), ("PANOPTIC19", "dotted")])
def test_openpose_files_read_back_the_same_pixels(scene, tmp_path, body_model, naming):
    bundle, truth, _ = scene
    det = synth_detections(bundle, truth, cameras=["00_01", "50_02"], univ_time_ms=(500.0, 800.0),
                           model=DetectorModel(false_people_per_view=0.5, seed=2))
    out = write_openpose_folder(tmp_path / "det", det, body_model=body_model, naming=naming)
    assert sorted(p.name for p in out.iterdir()) == ["00_01", "50_02"]
    n = 0
    for cam, frames in det.items():
        assert len(list((out / cam).iterdir())) == len(frames)
        for f, people in frames.items():
            doc = json.loads((out / cam / openpose_file_name(cam, f, naming)).read_text())
            assert doc["version"] == 1.3
            assert all(p["person_id"] == [-1] and p["face_keypoints_2d"] == [] for p in doc["people"])
            kp = np.array([p["pose_keypoints_2d"] for p in doc["people"]], dtype=float).reshape(
                len(doc["people"]), len(JOINT_NAMES[body_model]), 3)
            back = to_joints19(kp, body_model)
            direct = [k for k, name in enumerate(JOINT_NAMES["PANOPTIC19"]) if name in JOINT_NAMES[body_model]]
            assert np.array_equal(back[:, direct], np.where(people[:, direct, 2:] > 0, people[:, direct], 0.0))
            n += len(people)
    assert n > 10
    assert openpose_file_name("00_01", 42) == "00_01_000000000042_keypoints.json"
    assert openpose_file_name("00_01", 42, "dotted") == "00_01.0042.json"


def test_feet_share_their_ankle_s_error_and_go_where_body_25_has_them(scene, tmp_path):
    """BODY_25's feet for the synthetic detector (which draws joints19 only): each foot joint is its ankle's
    detection moved by the true foot's offset from the true ankle, so it lies as far from the true foot as the ankle
    from the true ankle; absent with the ankle and for false people; the detections themselves are unchanged; the
    OpenPose files carry them where BODY_25 has them, the other joints as before."""
    from dome_calib.recon.body_models import EXTRA_JOINTS, JOINTS19
    from dome_calib.recon.project import project_points
    from dome_calib.recon.streams import stream_of_camera
    from dome_calib.synth.detector import feet_detections
    from dome_calib.synth.skeleton import FEET, feet_cm

    bundle, truth, _ = scene
    cams, span = ["00_01", "50_02"], (500.0, 800.0)
    model = DetectorModel(false_people_per_view=0.5, seed=2)
    det, ids = synth_detections(bundle, truth, cameras=cams, univ_time_ms=span, model=model, with_ids=True)
    plain = synth_detections(bundle, truth, cameras=cams, univ_time_ms=span, model=model)
    feet = feet_detections(bundle, truth, det, ids)
    assert list(EXTRA_JOINTS["BODY_25"]) == list(FEET)
    la, ra = JOINTS19.index("l_ankle"), JOINTS19.index("r_ankle")
    checked = 0
    for cam in cams:
        table = stream_of_camera(bundle, cam)[1]  # 50_02: a Kinect's colour camera
        for f, people in det[cam].items():
            np.testing.assert_array_equal(people, plain[cam][f])  # the detector's draws are untouched
            assert feet[cam][f].shape == (len(people), 6, 3)
            false = ids[cam][f] < 0
            assert not feet[cam][f][false].any()
            t = table.univ_time_ms[np.searchsorted(table.index, f)]
            X = truth.joints_cm(np.array([t]))[0][0]
            for k in np.flatnonzero(~false):
                p = list(truth.ids).index(ids[cam][f][k])
                true_uv = project_points(view_set(bundle, [cam]), np.vstack([X[p], feet_cm(X[p])])).uv_px[0]
                for e, ankle in enumerate([la] * 3 + [ra] * 3):
                    if people[k, ankle, 2] > 0:
                        assert feet[cam][f][k, e, 2] == people[k, ankle, 2]
                        np.testing.assert_allclose(feet[cam][f][k, e, :2] - true_uv[19 + e],
                                                   people[k, ankle, :2] - true_uv[ankle], atol=2e-3)
                        checked += 1
                    else:
                        assert not feet[cam][f][k, e].any()
    assert checked > 100
    out = write_openpose_folder(tmp_path / "det", det, body_model="BODY_25", extras=feet)
    for f in sorted(det["00_01"])[:3]:
        doc = json.loads((out / "00_01" / openpose_file_name("00_01", f)).read_text())
        kp = np.array([p["pose_keypoints_2d"] for p in doc["people"]], float).reshape(-1, 25, 3)
        np.testing.assert_allclose(kp[:, [JOINT_NAMES["BODY_25"].index(n) for n in FEET]], feet["00_01"][f])
        np.testing.assert_array_equal(to_joints19(kp, "BODY_25"), np.where(det["00_01"][f][..., 2:] > 0,
                                                                            det["00_01"][f], 0.0))


def test_without_sync_tables_all_cameras_share_one_clock(scene):
    bundle, truth, _ = scene
    plain = Bundle(seq="plain", cameras={n: bundle.cameras[n] for n in ("00_01", "01_01")})
    det = synth_detections(plain, truth, univ_time_ms=(0.0, 400.0))
    assert sorted(det["00_01"]) == sorted(det["01_01"]) == list(range(11)) == shared_clock(0.0, 400.0).index.tolist()


def test_bad_input():
    bundle = real_bundle(n_vga=2, kinect=False, sync=True)
    truth = make_group(GroupOptions(n_people=2))
    with pytest.raises(DetectorError, match="no camera named '99_99'"):
        synth_detections(bundle, truth, cameras=["99_99"])
    with pytest.raises(DetectorError, match="50_01.*KINECTNODE1"):
        bundle.sync.kinect_color.pop("KINECTNODE1")
        synth_detections(bundle, truth, cameras=["50_01"])
    with pytest.raises(DetectorError, match="swap_lr=1.5"):
        DetectorModel(swap_lr=1.5)
    with pytest.raises(DetectorError, match="naming 'x'"):
        write_openpose_folder("/nonexistent/never", {}, naming="x")


def test_group_session_read_back_by_the_reconstruct_reader(tmp_path):
    from dome_calib.recon.openpose_io import read_openpose_folder
    from dome_calib.synth.group_session import GroupSessionOptions, make_group_session

    bundle = real_bundle(n_vga=2, start_ms=0.0, duration_ms=4000.0)
    cams = ["00_02", "00_07", "50_01", sorted(bundle.of_type("vga"))[0]]
    options = GroupSessionOptions(group=GroupOptions(n_people=6, scenario="leave", start_ms=300.0,
                                                     duration_ms=3000.0, seed=1),
                                  detector=DetectorModel(seed=4), body_model="BODY_25B", cameras=cams)
    truth = make_group_session(tmp_path / "group", bundle, options)
    read = read_openpose_folder(tmp_path / "group" / "detections", body_model="BODY_25B", cameras=set(bundle.cameras))
    det = synth_detections(bundle, truth, cameras=cams, univ_time_ms=(300.0, 3300.0), model=DetectorModel(seed=4))
    assert sorted(read.people) == sorted(cams)
    for cam in cams:
        assert sorted(read.people[cam]) == sorted(det[cam])
        for f, people in det[cam].items():  # the peer's reader rebuilds neck and body centre as midpoints
            keep = [k for k in range(19) if k not in (0, 2)]
            np.testing.assert_array_equal(read.people[cam][f][:, keep], people[:, keep])
    doc = json.loads((tmp_path / "group" / "group_truth.json").read_text())
    assert doc["reference_stream"] == "vga" and doc["units"] == "cm" and doc["roles"]["0"] == "leave"
    vga = bundle.sync.streams["vga"]
    frames = [fr["frame"] for fr in doc["frames"]]
    np.testing.assert_allclose([fr["univ_time_ms"] for fr in doc["frames"]], vga.times_of(np.array(frames)),
                               atol=1e-4)
    X, present = truth.joints_cm(vga.times_of(np.array(frames)))
    for k, fr in enumerate(doc["frames"]):
        assert [b["id"] for b in fr["bodies"]] == [i for i in truth.ids if present[k, i]]
        for b in fr["bodies"]:
            np.testing.assert_allclose(b["joints19"], X[k, b["id"]], atol=1e-3)
    listed = [{b["id"] for b in fr["bodies"]} for fr in doc["frames"]]
    assert 0 in listed[0] and 0 not in listed[-1]  # the leaver leaves
    assert 0 < doc["detector"]["miss_hidden"] < 1


def test_product_session_with_a_group(tmp_path, monkeypatch):
    """The synthetic product session's group option: OpenPose folders of every synced colour camera and the truth,
    within the span all streams cover (the tent capture stubbed as in conftest's small_product_session)."""
    import dome_calib.synth.session as synth_session
    from dome_calib.bundle_io import load_bundle
    from dome_calib.recon.openpose_io import read_openpose_folder
    from dome_calib.synth.group_session import session_span_ms

    from .conftest import stub_capture

    monkeypatch.setattr(synth_session, "write_capture", stub_capture)
    root = tmp_path / "sess"
    synth_session.make_product_session(root, synth_session.SessionOptions(
        duration_s=2.0, kinect_sensors=("KINECTNODE4",), kinect_good_frames=4, kinect_blurred_frames=0,
        kinect_cut_off_frames=0, group_people=4))
    truth_bundle = load_bundle(root / "ground_truth")
    manifest = json.loads((root / "dome_session.json").read_text())
    assert manifest["parts"]["group"] == "group" and manifest["options"]["group_people"] == 4
    read = read_openpose_folder(root / "group" / "detections", body_model="BODY_25",
                                cameras=set(truth_bundle.cameras))
    colour = {n for n, c in truth_bundle.cameras.items() if c.type in ("vga", "hd")} | {"50_04"}
    assert set(read.people) == colour
    start, duration = session_span_ms(truth_bundle)
    doc = json.loads((root / "group" / "group_truth.json").read_text())
    times = [fr["univ_time_ms"] for fr in doc["frames"]]
    assert start <= min(times) and max(times) <= start + duration and len(times) > 20
    assert sum(len(p) for c in read.people.values() for p in c.values()) > 100


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-300.0, 300.0, allow_nan=False), min_size=12, max_size=12))
def test_segment_distance_properties(coords):
    """Symmetric in the two segments, blind to their direction, never above any sampled pair's distance."""
    p1, q1, p2, q2 = (np.array([coords[3 * k:3 * k + 3]]) for k in range(4))
    if min(np.linalg.norm(q1 - p1), np.linalg.norm(q2 - p2)) < 1e-3:
        return
    d = segment_distance2(p1, q1, p2, q2)[0]
    for other in (segment_distance2(p2, q2, p1, q1), segment_distance2(q1, p1, p2, q2),
                  segment_distance2(p1, q1, q2, p2)):
        assert other[0] == pytest.approx(d, rel=1e-6, abs=1e-6)
    s = np.linspace(0.0, 1.0, 101)[:, None]
    a, b = p1 + s * (q1 - p1), p2 + s * (q2 - p2)
    dense = np.min(np.sum((a[:, None] - b[None]) ** 2, axis=-1))
    assert d <= dense + 1e-6
