"""Import of a real Pose2Sim calibration (Qualisys, 4 phone cameras): Pose2Sim's own 3D result, reprojected
through the imported bundle, lands on the OpenPose detections it was triangulated from."""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from dome_calib.interop.common import PANOPTIC_FROM_UP, ImportOptions
from dome_calib.interop.convert import export_bundle, import_calibration

from .interop_helpers import BODY_25B, WORLD_FROM_TRC_AXES, pixels, read_openpose_person, read_trc

DATA = Path(__file__).parent / "data" / "pose2sim_balancing"
CALIB = DATA / "calibration" / "Calib_qualisys.toml"
TRC = DATA / "pose2sim_result" / "S00_P00_T01_BalancingTrial_0-100.trc"
#: Pose2Sim triangulated without undistorting (Config.toml: undistort_points = false) and drops cameras beyond its
#: reprojection threshold, so its points sit a few pixels off any one camera: a median under 25 px (1.3 % of the
#: 1920 px image height) is "on the detections"; a wrong axis map or unit is hundreds of pixels off.
MEDIAN_LIMIT_PX = 25.0


def medians_px(bundle, axes=WORLD_FROM_TRC_AXES, scale_cm=100.0, frame_shift=0) -> dict[str, tuple[float, int]]:
    """Camera -> (median pixel distance between the reprojected TRC markers and the detections, pairs used)."""
    frame_numbers, names, markers = read_trc(TRC)
    # the calibration's z-up world, turned to ours as the import turns it; TRC frame n holds frame index n - 1
    world_cm = markers[..., axes] * scale_cm @ PANOPTIC_FROM_UP["+z"].T
    joints = [BODY_25B[n] for n in names]
    out = {}
    for cam_name, cam in bundle.cameras.items():
        detected = read_openpose_person(DATA / "pose" / f"cam{cam_name[-2:]}_json", f"cam{cam_name[-2:]}", 100)
        index = np.clip(frame_numbers - 1 + frame_shift, 0, 99)
        seen = detected[index][:, joints, :2]
        uv = pixels(cam, world_cm.reshape(-1, 3)).reshape(seen.shape)
        dist = np.linalg.norm(uv - seen, axis=-1)
        out[cam_name] = (float(np.nanmedian(dist)), int(np.isfinite(dist).sum()))
    return out


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    out = tmp_path_factory.mktemp("p2s") / "bundle"
    import_calibration(CALIB, "pose2sim", out, ImportOptions(seq="balancing"))
    return load_bundle(out)


def test_the_imported_cameras_are_pose2sims(imported):
    assert list(imported.cameras) == ["cam_01", "cam_02", "cam_03", "cam_04"]
    cam = imported.cameras["cam_01"]
    assert cam.resolution == (1088, 1920)
    assert cam.K[0, 0] == 1681.244873046875 and cam.dist[4] == 0.0
    assert np.allclose(cam.t_cm, [32.11048899999996, 95.63320600000009, 289.07130499999996], atol=1e-12)
    centres = np.array([c.center_cm for c in imported.cameras.values()])
    assert np.all(centres[:, 1] < -50)  # the phones stand above the lab floor: up is -y, as in our world


def test_pose2sims_result_reprojects_onto_the_detections(imported):
    medians = medians_px(imported)
    for name, (median, pairs) in medians.items():
        print(f"{name}: median {median:.2f} px over {pairs} marker detections")
        assert pairs > 1900
        assert median < MEDIAN_LIMIT_PX, name


def test_the_axis_map_is_the_one_the_data_confirms(imported):
    """TRC is y-up: reading it as the calibration's z-up world, or in mm, misses by hundreds of pixels; and TRC frame
    n is detection frame n - 1 (a shift of one frame either way fits worse: the subject sways slowly)."""
    unmapped = medians_px(imported, axes=[0, 1, 2])
    assert min(m for m, _ in unmapped.values()) > 10 * MEDIAN_LIMIT_PX
    in_mm = medians_px(imported, scale_cm=0.1)
    assert min(m for m, _ in in_mm.values()) > 10 * MEDIAN_LIMIT_PX
    total = {shift: sum(m for m, _ in medians_px(imported, frame_shift=shift).values()) for shift in (-1, 0, 1)}
    assert min(total, key=total.get) == 0


def test_our_reconstruction_stage_on_the_imported_bundle_agrees_with_pose2sims_result(imported):
    """The imported bundle feeds dome_calib.recon's triangulation (Pose2Sim's settings: 15 px reprojection
    threshold, likelihood above 0.3) and gives back Pose2Sim's own points: the median within 3 cm (Pose2Sim's 15 px
    gate at the cameras' ~3.5 m and 1680 px focal length), nine in ten within 10 cm (the two differ in how they drop
    views: RANSAC here, Pose2Sim's worst-camera-out loop there; and Pose2Sim interpolates gaps)."""
    from dome_calib.recon.project import view_set
    from dome_calib.recon.triangulate import TriangulationOptions, triangulate

    frame_numbers, names, markers = read_trc(TRC)
    pose2sim_cm = markers[..., WORLD_FROM_TRC_AXES] * 100.0 @ PANOPTIC_FROM_UP["+z"].T
    views = view_set(imported)
    joints = [BODY_25B[n] for n in names]
    detections = np.stack([read_openpose_person(DATA / "pose" / f"cam{n[-2:]}_json", f"cam{n[-2:]}", 100)
                           [frame_numbers - 1][:, joints] for n in views.names], axis=2)  # (F, J, V, 3)
    tri = triangulate(views, detections[..., :2].reshape(-1, len(views.names), 2),
                      detections[..., 2].reshape(-1, len(views.names)),
                      TriangulationOptions(inlier_threshold_px=15.0, min_confidence=0.3))
    gap_cm = np.linalg.norm(tri.X_cm - pose2sim_cm.reshape(-1, 3), axis=1)
    print(f"ours vs Pose2Sim: {np.isfinite(gap_cm).sum()}/{gap_cm.size} points, median {np.nanmedian(gap_cm):.2f} cm, "
          f"90th percentile {np.nanpercentile(gap_cm, 90):.2f} cm")
    assert np.isfinite(gap_cm).mean() > 0.9
    assert np.nanmedian(gap_cm) < 3.0 and np.nanpercentile(gap_cm, 90) < 10.0


# ------------------------------------------------------------------------- Pose2Sim's own code on our Calib.toml
def _ring_cameras(n: int = 12) -> dict[str, dict]:
    """``cam1`` .. ``camN``: 1920x1080 cameras on a 4 m ring, 2 m up, aimed at (0, 0, 1) m of a z-up world, each
    with its own focal length and distortion (Pose2Sim's 4 terms), so that swapping two of them shows."""
    cams = {}
    for i in range(n):
        a = 2 * np.pi * i / n
        centre = np.array([4.0 * np.cos(a), 4.0 * np.sin(a), 2.0])
        z = np.array([0.0, 0.0, 1.0]) - centre
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])  # rows: camera axes in the world (y down in the image)
        f = 1300.0 + 15.0 * i
        cams[f"cam{i + 1}"] = {"S": [1920.0, 1080.0], "K": np.array([[f, 0, 955.0 + i], [0, f, 541.0 - i], [0, 0, 1]]),
                               "D": np.array([-0.08 - 0.004 * i, 0.03, 2e-4, -1e-4]),
                               "R": cv2.Rodrigues(R)[0].ravel(), "T": -R @ centre}
    return cams


def _person_m(frames: int, seed: int = 7) -> np.ndarray:
    """(frames, 17, 3) COCO_17 joints of one made-up person swaying near the centre, metres, z up."""
    rng = np.random.default_rng(seed)
    base = np.concatenate([rng.uniform(-0.25, 0.25, (17, 2)), rng.uniform(0.1, 1.7, (17, 1))], axis=1)
    sway = 0.2 * np.sin(np.linspace(0, np.pi, frames))[:, None, None] * np.array([1.0, 0.5, 0.0])
    return base[None] + sway


def _session(tmp_path, calib_file, cams: dict[str, dict], joints_m: np.ndarray):
    """A Pose2Sim project: Config.toml (its demo's, single person, COCO_17, undistorted points, no C3D),
    calibration/<calib_file>, pose/camN_json/camN.FFFF.json projected with OpenCV from each camera's own
    parameters."""
    import json

    import rtoml

    demo = Path(importlib.util.find_spec("Pose2Sim").origin).parent / "Demo_SinglePerson" / "Config.toml"
    config = rtoml.load(demo)
    project = tmp_path / "project"
    (project / "calibration").mkdir(parents=True)
    config["project"].update(project_dir=str(project), frame_range="all")
    config["pose"]["pose_model"] = "COCO_17"
    config["triangulation"].update(undistort_points=True, make_c3d=False, interpolation="none")
    rtoml.dump(config, project / "Config.toml")
    (project / "calibration" / "Calib.toml").write_bytes(Path(calib_file).read_bytes())
    for name, c in cams.items():
        folder = project / "pose" / f"{name}_json"
        folder.mkdir(parents=True)
        for f, joints in enumerate(joints_m):
            uv, _ = cv2.projectPoints(joints, c["R"], c["T"], c["K"], c["D"])
            keypoints = np.concatenate([uv.reshape(-1, 2), np.full((len(joints), 1), 0.9)], axis=1)
            (folder / f"{name}.{f:04d}.json").write_text(json.dumps(
                {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": keypoints.ravel().tolist()}]}))
    return config, project


def _triangulated_m(config, project, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose2Sim's triangulate_all on the project; its TRC (y up, m) back in the calibration's z-up world, and the
    truth of the joints it holds (COCO_17's tree in Pose2Sim's skeletons.py names 13 of the 17)."""
    from anytree import PreOrderIter
    from Pose2Sim.skeletons import COCO_17
    from Pose2Sim.triangulation import triangulate_all

    cwd = Path.cwd()
    try:
        os.chdir(project)
        triangulate_all(config)
    finally:
        os.chdir(cwd)
    (trc,) = (project / "pose-3d").glob("*.trc")
    _, names, markers = read_trc(trc)
    ids = {node.name: node.id for node in PreOrderIter(COCO_17) if node.id is not None}
    return markers[..., WORLD_FROM_TRC_AXES], truth[:, [ids[n] for n in names]]


@pytest.fixture(scope="module")
def ring_calib(tmp_path_factory) -> tuple[Path, dict[str, dict]]:
    """cam1 .. cam12 written by Pose2Sim's own toml_write."""
    from Pose2Sim.calibration import toml_write

    cams = _ring_cameras()
    path = tmp_path_factory.mktemp("ring") / "Calib_ring.toml"
    toml_write(str(path), list(cams), [c["S"] for c in cams.values()], [c["D"] for c in cams.values()],
               [c["K"] for c in cams.values()], [c["R"] for c in cams.values()], [c["T"] for c in cams.values()])
    return path, cams


def test_import_then_export_keeps_the_files_camera_order(ring_calib, tmp_path):
    """cam1 .. cam12 come back as cam1 .. cam12 (they came back cam1, cam10, cam11, cam12, cam2, ... when the bundle
    writer sorted them), read by Pose2Sim's own retrieve_calib_params."""
    from Pose2Sim.common import retrieve_calib_params

    path, cams = ring_calib
    import_calibration(path, "pose2sim", tmp_path / "b", ImportOptions(seq="ring"))
    assert list(load_bundle(tmp_path / "b").cameras) == list(cams)
    export_bundle(tmp_path / "b", "pose2sim", tmp_path / "Calib.toml")
    import rtoml

    assert [k for k in rtoml.load(tmp_path / "Calib.toml") if k != "metadata"] == list(cams)
    params = retrieve_calib_params(tmp_path / "Calib.toml")
    for i, c in enumerate(cams.values()):
        assert np.allclose(params["K"][i], c["K"], rtol=0, atol=1e-9)
        assert np.allclose(params["T"][i], c["T"], rtol=0, atol=1e-12)


def test_a_pose2sim_session_with_our_calibration_pairs_each_camera_with_its_detections(ring_calib, tmp_path):
    """Pose2Sim's own triangulation (triangulate_all, undistorted points) of detections projected into cam1 ..
    cam12, with the calibration imported and exported by us: every joint within 0.1 mm of the truth. With the
    tables in the order the bundle writer used to give them (cam1, cam10, cam11, ...), the same run pairs cameras
    with other cameras' detections and misses by metres or triangulates nothing."""
    path, cams = ring_calib
    import_calibration(path, "pose2sim", tmp_path / "b", ImportOptions(seq="ring"))
    export_bundle(tmp_path / "b", "pose2sim", tmp_path / "Calib.toml")
    truth = _person_m(12)
    config, project = _session(tmp_path / "ours", tmp_path / "Calib.toml", cams, truth)
    found, held = _triangulated_m(config, project, truth)
    gap_mm = np.linalg.norm(found - held, axis=-1) * 1000
    print(f"Pose2Sim with our Calib.toml: worst joint {gap_mm.max():.2e} mm")
    assert gap_mm.max() < 0.1

    import rtoml

    doc = rtoml.load(tmp_path / "Calib.toml")
    sorted_doc = {k: doc[k] for k in sorted(k for k in doc if k != "metadata")} | {"metadata": doc["metadata"]}
    rtoml.dump(sorted_doc, tmp_path / "Calib_sorted.toml")
    config, project = _session(tmp_path / "sorted", tmp_path / "Calib_sorted.toml", cams, truth)
    found, held = _triangulated_m(config, project, truth)
    scrambled_m = np.linalg.norm(found - held, axis=-1)
    print(f"Pose2Sim with the name-sorted tables: median joint {np.nanmedian(scrambled_m):.2f} m off, "
          f"{np.isnan(scrambled_m).mean():.0%} not triangulated")
    assert not np.nanmedian(scrambled_m) < 0.1


def test_pose2sims_own_reader_takes_all_five_distortion_terms(tmp_path):
    """The real 520 cameras exported for Pose2Sim and read by Pose2Sim's retrieve_calib_params: 5 terms each, and
    OpenCV on what it read (its z-up metres) projects as our cameras within 1e-6 px (k3 used to be dropped: 20-34 px
    at the real HD cameras' corners, bench/interop.py)."""
    from Pose2Sim.common import retrieve_calib_params

    from dome_calib.bundle import Bundle
    from dome_calib.bundle_io import write_bundle
    from dome_calib.panoptic_io import read_calibration

    from .conftest import REAL_CALIBRATION
    from .interop_helpers import world_points_cm

    cameras, source = read_calibration(REAL_CALIBRATION)
    write_bundle(Bundle(seq="band1", cameras=cameras, calib_data_source=source), tmp_path / "real")
    export_bundle(tmp_path / "real", "pose2sim", tmp_path / "Calib.toml")
    params = retrieve_calib_params(tmp_path / "Calib.toml")
    bundle = load_bundle(tmp_path / "real")
    assert len(params["dist"]) == 520 and all(d.shape == (5,) for d in params["dist"])
    worst = 0.0
    for i, cam in enumerate(bundle.cameras.values()):
        X_cm = world_points_cm(cam)
        uv, _ = cv2.projectPoints(X_cm @ PANOPTIC_FROM_UP["+z"] / 100.0, params["R"][i], params["T"][i],
                                  params["K"][i], params["dist"][i])
        worst = max(worst, float(np.abs(uv.reshape(-1, 2) - pixels(cam, X_cm)).max()))
    print(f"Pose2Sim's retrieve_calib_params + OpenCV vs our model, 520 real cameras: {worst:.2e} px")
    assert worst < 1e-6


def test_a_camera_table_without_name_is_named_by_its_key(tmp_path):
    """Pose2Sim's retrieve_calib_params never reads ``name`` (it takes the tables in order): a Calib.toml whose
    tables have none is Pose2Sim's all the same; each camera is named by its table's key."""
    import tomllib

    import tomli_w
    from Pose2Sim.common import retrieve_calib_params

    doc = tomllib.loads(CALIB.read_text())
    for key, table in doc.items():
        if isinstance(table, dict) and key != "metadata":
            table.pop("name", None)
    path = tmp_path / "Calib_noname.toml"
    path.write_text(tomli_w.dumps(doc))
    theirs = retrieve_calib_params(path)  # Pose2Sim reads it (rtoml: a Path, not its text)
    bundle = import_calibration(path, "pose2sim", tmp_path / "b", ImportOptions())
    loaded = load_bundle(tmp_path / "b")
    assert list(loaded.cameras) == [k for k, v in doc.items() if isinstance(v, dict) and k != "metadata"]
    assert len(theirs["K"]) == len(loaded.cameras) and bundle is not None
    for K, cam in zip(theirs["K"], loaded.cameras.values()):
        np.testing.assert_allclose(cam.K, K)


def test_export_a_camera_subset(tmp_path, dome_calib_cli):
    """``export --cameras``: only those cameras, in the bundle's order, read back by Pose2Sim's own reader; a camera
    the bundle lacks is one line, nothing written."""
    import tomllib

    from Pose2Sim.common import retrieve_calib_params

    import_calibration(CALIB, "pose2sim", tmp_path / "b", ImportOptions())
    run = dome_calib_cli("export", str(tmp_path / "b"), "--to", "pose2sim", "-o", str(tmp_path / "Calib.toml"),
                         "--cameras", "cam_04,cam_02")
    assert run.returncode == 0, run.stderr
    doc = tomllib.loads((tmp_path / "Calib.toml").read_text())
    assert [k for k, v in doc.items() if isinstance(v, dict) and k != "metadata"] == ["cam_02", "cam_04"]
    theirs = retrieve_calib_params(tmp_path / "Calib.toml")
    full = load_bundle(tmp_path / "b")
    for K, name in zip(theirs["K"], ("cam_02", "cam_04")):
        np.testing.assert_allclose(K, full.cameras[name].K)
    run = dome_calib_cli("export", str(tmp_path / "b"), "--to", "pose2sim", "-o", str(tmp_path / "none.toml"),
                         "--cameras", "cam_09")
    assert run.returncode == 1 and "no camera 'cam_09'" in run.stderr and not (tmp_path / "none.toml").exists()
