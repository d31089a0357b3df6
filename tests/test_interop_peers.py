"""Each format judged by its peer's own code: Pose2Sim's calib_qca_fun (Qualisys), caliscope's CameraArray
(to_toml / from_toml), Blender itself (bpy) on our script; and, where the peer cannot be installed here (nerfstudio
and EasyMocap need torch; Kalibr needs ROS), its code followed as read, with the file and commit named."""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from dome_calib.bundle import Bundle, Camera
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.interop.common import CM_PER_UNIT, PANOPTIC_FROM_UP, ExportOptions, ImportOptions, InteropError
from dome_calib.interop.convert import export_bundle, import_calibration
from dome_calib.panoptic_io import read_calibration

from .conftest import REAL_CALIBRATION
from .interop_helpers import (calib_intri_extri, dlt_columns, dlt_pixels, gaps_px, in_cam0_frame, kalibr_camchain,
                              nerfstudio_round_trip, pixels, projection_gap_worst_px, world_points_cm)

QCA = Path(__file__).parent / "data" / "pose2sim_qualisys" / "Calib.qca.txt"
ZUP_M = PANOPTIC_FROM_UP["+z"] / 100.0  # our point (cm, row vector) @ ZUP_M: the same point in a z-up world, m


def _gap_to_pose2sim_px(cams: list[Camera], converted: tuple, their_world=lambda X_cm: X_cm @ ZUP_M, dist=None,
                        ours=lambda cam: cam) -> float:
    """Worst px, over each camera's grid of world points, between our camera and the one a Pose2Sim converter
    returned (its ``(ret, C, S, D, K, R, T)``), projected by OpenCV in Pose2Sim's world (``their_world``: our points,
    cm, there); each image size checked. ``dist``: the distortion OpenCV is given per camera (default Pose2Sim's D);
    ``ours``: the camera of ours it is compared with."""
    _, _, S, D, K, R, T = converted
    worst = 0.0
    for i, cam in enumerate(cams):
        assert list(cam.resolution) == [int(v) for v in S[i]]
        X_cm = world_points_cm(cam)
        uv, _ = cv2.projectPoints(their_world(X_cm), np.asarray(R[i], float), np.asarray(T[i], float),
                                  np.asarray(K[i], float), np.asarray(D[i] if dist is None else dist[i], float))
        worst = max(worst, float(np.abs(uv.reshape(-1, 2) - pixels(ours(cam), X_cm)).max()))
    return worst


@pytest.fixture(scope="module")
def real(tmp_path_factory) -> tuple[Path, Bundle]:
    cameras, source = read_calibration(REAL_CALIBRATION)
    folder = tmp_path_factory.mktemp("real") / "bundle"
    write_bundle(Bundle(seq="band1", cameras=cameras, calib_data_source=source), folder)
    return folder, load_bundle(folder)


# ------------------------------------------------------------------------------------------------- nerfstudio
@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_nerfstudio_maps_our_cameras_back_where_they_are(real, tmp_path, unit):
    """Through nerfstudio's dataparser and back (dataparser_transforms): every real camera within 1e-6 cm of ours,
    at every --unit. The file we wrote before (applied_scale = 0.01, lengths in m) came back 178 cm off: the
    dataparser divides its centring offset by applied_scale too."""
    folder, bundle = real
    export_bundle(folder, "nerfstudio", tmp_path / "transforms.json", ExportOptions(unit=unit))
    names, back = nerfstudio_round_trip(tmp_path / "transforms.json")
    centres_cm = back[:, :3, 3] * CM_PER_UNIT[unit]
    ours = np.array([bundle.cameras[n].center_cm for n in names])
    worst_cm = float(np.linalg.norm(centres_cm - ours, axis=1).max())
    R_back = np.stack([bundle.cameras[n].R for n in names]) @ back[:, :3, :3]  # ~I
    worst_rad = float(np.abs(R_back - np.eye(3)).max())
    print(f"nerfstudio, --unit {unit}: cameras back within {worst_cm:.2e} cm, {worst_rad:.1e} rad")
    assert worst_cm < 1e-6 and worst_rad < 1e-9
    if unit == "m":  # the old file: applied_scale said the world was scaled by 0.01
        doc = json.loads((tmp_path / "transforms.json").read_text())
        (tmp_path / "old.json").write_text(json.dumps(doc | {"applied_scale": 0.01}))
        names, back = nerfstudio_round_trip(tmp_path / "old.json")
        off = np.linalg.norm(back[:, :3, 3] - ours, axis=1)  # its poses came back in cm
        print(f"with applied_scale 0.01: {np.median(off):.0f} cm off")
        assert np.median(off) > 100


# -------------------------------------------------------------------------------------------------- EasyMocap
def test_easymocaps_own_calibration_output_imports(real, tmp_path):
    """EasyMocap's calib_intri writes no H_ / W_ (its read_camera takes them only when present): the import takes
    the size from the images beside the files (images/<camera>/, EasyMocap's layout) or --image-size, and says
    which when it has neither. The cameras then project as EasyMocap reads them (6 decimals: to 1e-2 px)."""
    _, bundle = real
    names = ["00_00", "00_12", "01_01", "05_17"]
    calib_intri_extri(tmp_path / "emc", bundle, names)
    with pytest.raises(InteropError, match=r"intri\.yml: camera 00_00: H_00_00/W_00_00: missing .*--image-size"):
        import_calibration(tmp_path / "emc", "easymocap", tmp_path / "b")
    assert not (tmp_path / "b").exists()
    for n in names:
        (tmp_path / "emc" / "images" / n).mkdir(parents=True)
        w, h = bundle.cameras[n].resolution
        cv2.imwrite(str(tmp_path / "emc" / "images" / n / "000000.jpg"), np.zeros((h, w, 3), np.uint8))
    import_calibration(tmp_path / "emc", "easymocap", tmp_path / "b")
    again = load_bundle(tmp_path / "b")
    assert list(again.cameras) == names
    assert [c.resolution for c in again.cameras.values()] == [bundle.cameras[n].resolution for n in names]
    proj, _ = gaps_px([bundle.cameras[n] for n in names], list(again.cameras.values()))
    print(f"EasyMocap's calib_intri / calib_extri files (6 decimals) imported: {proj.max():.2e} px")
    assert proj.max() < 1e-2
    import_calibration(tmp_path / "emc", "easymocap", tmp_path / "b2", ImportOptions(image_size=(640, 480)))
    assert {c.resolution for c in load_bundle(tmp_path / "b2").cameras.values()} == {(640, 480)}


def test_easymocap_export_is_z_up_as_easymocaps_world(real, tmp_path):
    """EasyMocap's world is z up: its 3D scene (zju3dv/EasyMocap ``config/vis3d/o3d_scene.yml`` @ e6ea2c50) puts the
    ground at z = 0 spanning x and y and the capture volume from z = 0 to 2 m. Exported by default, our floor (y =
    0) is at z = 0 and every camera of the dome is above it (z > 0)."""
    folder, bundle = real
    result = export_bundle(folder, "easymocap", tmp_path / "emc")
    assert result.world_up == "+z"
    extri = cv2.FileStorage(str(tmp_path / "emc" / "extri.yml"), cv2.FILE_STORAGE_READ)
    centres = []
    for n, cam in bundle.cameras.items():
        R, T = extri.getNode(f"Rot_{n}").mat(), extri.getNode(f"T_{n}").mat()
        centres.append((-R.T @ T).ravel())
    centres = np.array(centres)
    ours = np.array([c.center_cm for c in bundle.cameras.values()])
    assert np.allclose(centres[:, 2], -ours[:, 1] / 100.0, atol=1e-9)  # height above our floor
    assert centres[:, 2].min() > 0.0


# --------------------------------------------------------------------------------------------------- Qualisys
@pytest.mark.parametrize("binning", [1, 2])
def test_qualisys_reads_as_pose2sims_calib_qca_fun(binning):
    """The Qualisys file of Pose2Sim's demo, read by Pose2Sim's own calib_qca_fun (pose2sim 0.10.49, its
    binning_factor) and by our import: same cameras in the same order and sizes, projecting alike within 1e-6 px over
    the image (Pose2Sim's result is in metres in the lab's z-up world; ours in cm, turned to y down) once its
    distortion terms are ours: Pose2Sim divides them by 64 and by the binning, we read them as written, on the
    evidence of the cameras' own checkerboard images (tests/test_interop_qualisys_evidence.py)."""
    from Pose2Sim.calibration import calib_qca_fun

    converted = calib_qca_fun(str(QCA), binning_factor=binning)
    C, D = converted[1], converted[3]
    from dome_calib.interop.convert import read_foreign

    bundle, unit = read_foreign(QCA, "qualisys", ImportOptions(binning=binning))
    assert unit == "mm" and list(bundle.cameras) == C
    cams = list(bundle.cameras.values())
    for i, cam in enumerate(cams):
        np.testing.assert_allclose(cam.dist[:4], np.asarray(D[i], dtype=float) * 64 * binning, rtol=1e-12)
    worst = _gap_to_pose2sim_px(cams, converted, dist=[cam.dist[:4] for cam in cams])
    print(f"Qualisys .qca.txt: ours vs Pose2Sim's calib_qca_fun: {worst:.2e} px")
    assert worst < 1e-6


def test_qualisys_import_matches_the_calibration_pose2sim_made_from_it(tmp_path):
    """The demo's Calib_qualisys.toml is Pose2Sim's conversion of this .qca.txt: both imports give the same
    cameras (names cam01 / cam_01 aside; the toml's distortion terms are Pose2Sim's, 1/64 of the file's)."""
    from dataclasses import replace

    from dome_calib.interop.convert import read_foreign

    toml = Path(__file__).parent / "data" / "pose2sim_balancing" / "calibration" / "Calib_qualisys.toml"
    a, _ = read_foreign(QCA, "qualisys", ImportOptions())
    b, _ = read_foreign(toml, "pose2sim", ImportOptions())
    for ca, cb in zip(a.cameras.values(), b.cameras.values()):
        np.testing.assert_allclose(ca.dist[:4], cb.dist[:4] * 64, rtol=1e-6)
    b.cameras.update({n: replace(c, dist=ca.dist) for (n, c), ca in zip(b.cameras.items(), a.cameras.values())})
    proj, rays = gaps_px(list(a.cameras.values()), list(b.cameras.values()))
    print(f"Qualisys vs Pose2Sim's toml of it: {proj.max():.2e} px")
    assert proj.max() < 1e-3  # the toml keeps 16 digits of Pose2Sim's float arithmetic


# -------------------------------------------------------------------------------------------------- Caliscope
def test_caliscope_camera_array_written_and_read_by_caliscope(real, tmp_path):
    """Real cameras written by caliscope's own CameraArray.to_toml (in a z-up world, m), imported by us, and read
    back by caliscope's CameraArray.from_toml: our cameras project as OpenCV does on what caliscope read."""
    from caliscope.cameras.camera_array import CameraArray, CameraData

    _, bundle = real
    names = [n for n in bundle.cameras if n.startswith(("00_", "50_"))] + list(bundle.cameras)[:40]
    array = CameraArray({i: CameraData(cam_id=i, size=bundle.cameras[n].resolution,
                                       matrix=bundle.cameras[n].K.copy(), distortions=bundle.cameras[n].dist.copy(),
                                       rotation=bundle.cameras[n].R @ PANOPTIC_FROM_UP["+z"],
                                       translation=bundle.cameras[n].t_cm / 100.0)
                         for i, n in enumerate(names)})
    array.to_toml(tmp_path / "camera_array.toml")
    import_calibration(tmp_path, "caliscope", tmp_path / "b")  # a folder: its camera_array.toml
    again = load_bundle(tmp_path / "b")
    assert list(again.cameras) == [f"cam_{i}" for i in range(len(names))]
    theirs = CameraArray.from_toml(tmp_path / "camera_array.toml")
    worst = 0.0
    for i, cam in enumerate(again.cameras.values()):
        c = theirs.cameras[i]
        X_cm = world_points_cm(cam)
        uv, _ = cv2.projectPoints(X_cm @ ZUP_M, cv2.Rodrigues(c.rotation)[0], c.translation, c.matrix,
                                  c.distortions)
        worst = max(worst, float(np.abs(uv.reshape(-1, 2) - pixels(cam, X_cm)).max()))
        assert tuple(c.size) == cam.resolution
    print(f"caliscope's CameraArray vs our import, {len(names)} real cameras: {worst:.2e} px")
    assert worst < 1e-6


# ----------------------------------------------------------------------------------------------------- Kalibr
def test_kalibr_camchain_as_kalibr_writes_it(real, tmp_path):
    """A camera chain of real cameras (k3 left out: radtan has 4 terms) dumped as Kalibr's CameraChainParameters
    writes it (ethz-asl/kalibr ``kalibr_common/ConfigReader.py`` @ ea2791f0: ``yaml.dump`` of cam0, cam1, ... with
    ``T_cn_cnm1`` from ``setExtrinsicsLastCamToHere``; followed as read, no code copied): imported, every camera
    projects as the truth expressed in cam0's frame within 1e-6 px."""
    _, bundle = real
    cams = list(bundle.cameras.values())[::13]
    (tmp_path / "camchain.yaml").write_text(yaml.dump(kalibr_camchain(cams)))
    import_calibration(tmp_path / "camchain.yaml", "kalibr", tmp_path / "b")
    again = load_bundle(tmp_path / "b")
    assert list(again.cameras) == [f"cam{i}" for i in range(len(cams))]
    worst = projection_gap_worst_px(in_cam0_frame(cams), list(again.cameras.values()))
    print(f"Kalibr camchain of {len(cams)} real cameras: {worst:.2e} px")
    assert worst < 1e-6


# ---------------------------------------------------------------------------------------------------- Blender
_BPY_PROBE = """
import json, runpy, sys
import bpy
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector
runpy.run_path(sys.argv[1])
points = json.loads(open(sys.argv[2]).read())
out = {}
for name, pts in points.items():
    scene = bpy.data.scenes[name]
    obj = scene.camera
    assert obj.name == name, (obj.name, name)
    w, h = scene.render.resolution_x, scene.render.resolution_y
    uv = []
    for p in pts:
        v = world_to_camera_view(scene, obj, Vector(p))
        uv.append([v.x * w - 0.5, (1.0 - v.y) * h - 0.5])
    out[name] = uv
print("RESULT" + json.dumps(out))
"""


def test_blender_renders_each_camera_as_our_pinhole(real, tmp_path):
    """Our script run by Blender itself (bpy 5.0): for each camera, its scene's camera projects world points
    (Blender's world_to_camera_view) where our camera without its lens distortion does, within Blender's 32-bit
    floats (~2e-3 px at 30 cm from the camera); the export states per camera what dropping the distortion moves at
    the corner."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("bpy (Blender as a Python module) is not installed: `make venv` installs it")
    folder, bundle = real
    names = [n for n in bundle.cameras if n.startswith("00_")][:8] + list(bundle.cameras)[:8] + ["50_01"]
    subset = Bundle(seq="subset", cameras={n: bundle.cameras[n] for n in names})
    write_bundle(subset, tmp_path / "subset")
    result = export_bundle(tmp_path / "subset", "blender", tmp_path / "dome.py")
    assert set(result.corner_shift_px) == set(names)
    points = {n: (world_points_cm(c) @ ZUP_M).tolist() for n, c in subset.cameras.items()}
    (tmp_path / "points.json").write_text(json.dumps(points))
    run = subprocess.run([sys.executable, "-c", _BPY_PROBE, str(tmp_path / "dome.py"), str(tmp_path / "points.json")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    uv = json.loads(run.stdout.split("RESULT", 1)[1])
    worst = 0.0
    for n, c in subset.cameras.items():
        pinhole = type(c)(**{**c.__dict__, "dist": np.zeros(5)})
        worst = max(worst, float(np.abs(np.array(uv[n]) - pixels(pinhole, world_points_cm(c))).max()))
    print(f"Blender (bpy) vs our pinhole, {len(names)} real cameras: {worst:.2e} px")
    assert worst < 5e-3  # 32-bit floats: 3e-7 m at 5 m from the origin is 1e-3 px at a point 30 cm away


# ------------------------------------------------------------------------------------------------------ Vicon
def _xcp(tmp_path: Path) -> tuple[Path, dict]:
    """A Vicon .xcp holding the real Pose2Sim trial's four cameras (lab z up, mm; the quaternion scalar last, a
    small radial term in VICON_RADIAL2's 4th and 5th numbers) and one marker camera, written from its calibration."""
    from scipy.spatial.transform import Rotation

    from dome_calib.interop.convert import read_foreign

    toml = Path(__file__).parent / "data" / "pose2sim_balancing" / "calibration" / "Calib_qualisys.toml"
    bundle, _ = read_foreign(toml, "pose2sim", ImportOptions(world_up="-y"))  # the lab's z-up world, kept
    rows = []
    for k, (name, cam) in enumerate(bundle.cameras.items()):
        q = Rotation.from_matrix(cam.R).as_quat()  # x, y, z, w
        centre_mm = -cam.R.T @ cam.t_cm * 10.0
        radial = f"0 0 0 {-0.02 * (k + 1):.4f} {0.01 * (k + 1):.4f}"
        rows.append(f'<Camera DEVICEID="{name}" TYPE="Vue video" SENSOR_SIZE="{cam.resolution[0]} '
                    f'{cam.resolution[1]}" PIXEL_ASPECT_RATIO="{cam.K[0, 0] / cam.K[1, 1]!r}"><KeyFrames><KeyFrame '
                    f'FOCAL_LENGTH="{cam.K[0, 0]!r}" PRINCIPAL_POINT="{cam.K[0, 2]!r} {cam.K[1, 2]!r}" '
                    f'ORIENTATION="{" ".join(repr(float(v)) for v in q)}" '
                    f'POSITION="{" ".join(repr(float(v)) for v in centre_mm)}" VICON_RADIAL2="{radial}" '
                    f'WORLD_ERROR="0.2"/></KeyFrames></Camera>')
    rows.append('<Camera DEVICEID="9" TYPE="Vantage" SENSOR_SIZE="2048 1088" PIXEL_ASPECT_RATIO="1"><KeyFrames>'
                '<KeyFrame FOCAL_LENGTH="1000" PRINCIPAL_POINT="1024 544" ORIENTATION="0 0 0 1" POSITION="0 0 3000" '
                'VICON_RADIAL="0 0" WORLD_ERROR="0.1"/></KeyFrames></Camera>')
    path = tmp_path / "calib.xcp"
    path.write_text('<?xml version="1.0"?>\n<Calibration>' + "".join(rows) + "</Calibration>\n")
    return path, bundle.cameras


def test_vicon_reads_as_pose2sims_calib_vicon_fun(tmp_path):
    """A Vicon .xcp read by Pose2Sim's own calib_vicon_fun (pose2sim 0.10.49) and by our import: the same video
    cameras in the same order and sizes (the marker camera left out by both), projecting alike within 1e-6 px over
    the image; and the cameras it was written from come back (their own distortion aside)."""
    from Pose2Sim.calibration import calib_vicon_fun

    from dome_calib.interop.convert import read_foreign

    path, written = _xcp(tmp_path)
    converted = calib_vicon_fun(str(path))
    bundle, unit = read_foreign(path, "vicon", ImportOptions())
    assert unit == "mm" and list(bundle.cameras) == converted[1] == list(written)
    for cam in bundle.cameras.values():
        np.testing.assert_allclose(cam.K, written[cam.name].K, rtol=1e-12)
    worst = _gap_to_pose2sim_px(list(bundle.cameras.values()), converted)
    print(f"Vicon .xcp: ours vs Pose2Sim's calib_vicon_fun: {worst:.2e} px")
    assert worst < 1e-6


# ------------------------------------------------------------------------------------------------------ bioCV
def test_biocv_reads_as_pose2sims_calib_biocv_fun(tmp_path):
    """A bioCV calibration folder (one .calib text file per camera) written from the real Pose2Sim trial's cameras,
    read by Pose2Sim's own calib_biocv_fun (pose2sim 0.10.49) and by our import: the same cameras in the same order
    (cam_00 ..), sizes, projecting alike within 0.01 px over the image (measured 2e-3 px: Pose2Sim reads K and [R | t]
    as float32)."""
    from Pose2Sim.calibration import calib_biocv_fun

    from dome_calib.interop.convert import read_foreign

    toml = Path(__file__).parent / "data" / "pose2sim_balancing" / "calibration" / "Calib_qualisys.toml"
    source, _ = read_foreign(toml, "pose2sim", ImportOptions(world_up="-y"))  # the lab's world kept
    folder = tmp_path / "biocv"
    folder.mkdir()
    for k, cam in enumerate(source.cameras.values()):
        rows = [f"{cam.resolution[0]}", f"{cam.resolution[1]}"] + [" ".join(repr(float(v)) for v in r) for r in cam.K]
        rows += [""] + [" ".join(repr(float(v)) for v in (*cam.R[i], cam.t_cm[i] * 10.0)) for i in range(3)]
        rows += ["0 0 0 1", "", " ".join(repr(float(v)) for v in (-0.01 * (k + 1), 0.002, 0.0001, -0.0002))]
        (folder / f"{k:02d}.calib").write_text("\n".join(rows) + "\n")
    converted = calib_biocv_fun(sorted(folder.glob("*.calib")))
    bundle, unit = read_foreign(folder, "biocv", ImportOptions())
    assert unit == "mm" and list(bundle.cameras) == converted[1] == [f"cam_{k:02d}" for k in range(4)]
    worst = _gap_to_pose2sim_px(list(bundle.cameras.values()), converted)
    print(f"bioCV .calib: ours vs Pose2Sim's calib_biocv_fun: {worst:.2e} px")
    assert worst < 1e-2


# ------------------------------------------------------------------------------------------------------ easyWand
def _balancing_cameras():
    from dome_calib.interop.convert import read_foreign

    toml = Path(__file__).parent / "data" / "pose2sim_balancing" / "calibration" / "Calib_qualisys.toml"
    source, _ = read_foreign(toml, "pose2sim", ImportOptions(world_up="-y"))  # the lab's world kept
    return list(source.cameras.values())


def test_easywand_dlt_reads_as_the_dlt_projects(tmp_path, caplog):
    """easyWand's *_dltCoefs.csv (11 rows, a column per camera, pixels from the bottom left) made from the real
    Pose2Sim trial's 4 cameras (1088 x 1920, their distortion left out: a DLT is linear), in mm: our import projects
    as the DLT's own formula (argus_gui's dlt_inverse) within 1e-6 px over the image, and gives back the cameras'
    K, R and t. The image size is needed (the file does not hold it); a skew is dropped and said."""
    from dome_calib.interop.convert import read_foreign

    cams = _balancing_cameras()
    W, H = cams[0].resolution
    L = dlt_columns(cams, H)
    path = tmp_path / "trial_dltCoefs.csv"
    np.savetxt(path, L, delimiter=",", fmt="%.17g")
    bundle, unit = read_foreign(path, "easywand", ImportOptions(image_size=(W, H), unit="mm", world_up="-y"))
    assert unit == "mm" and list(bundle.cameras) == ["cam_01", "cam_02", "cam_03", "cam_04"]
    worst = 0.0
    for k, (cam, src) in enumerate(zip(bundle.cameras.values(), cams)):
        assert tuple(cam.resolution) == (W, H) and not cam.dist.any()
        X_cm = world_points_cm(cam)
        worst = max(worst, float(np.abs(dlt_pixels(L[:, k], X_cm * 10.0, H) - pixels(cam, X_cm)).max()))
        np.testing.assert_allclose(cam.K, src.K, rtol=1e-9)
        np.testing.assert_allclose(cam.R, src.R, atol=1e-9)
        np.testing.assert_allclose(cam.t_cm, src.t_cm, atol=1e-6)
    print(f"easyWand DLT: ours vs the DLT's own projection: {worst:.2e} px")
    assert worst < 1e-6
    np.savetxt(path, dlt_columns(cams, H, skew_px=2.0), delimiter=",", fmt="%.17g")
    with caplog.at_level("WARNING"):
        read_foreign(path, "easywand", ImportOptions(image_size=(W, H), unit="mm"))
    assert "skew 2 px is dropped" in caplog.text


@pytest.mark.parametrize("text, options, message", [
    ("1,2\n" * 10, {"image_size": (10, 10)}, "rows: expected a list of 11 lists"),
    ("1,2\n" * 10 + "1\n", {"image_size": (10, 10)}, "rows of [1, 2] columns"),
    ("1,x\n" * 11, {"image_size": (10, 10)}, "line 1: 'x' is not a number"),
    ("1,2\n" * 11, {}, "give --image-size"),
    ("0,0\n" * 11, {"image_size": (10, 10)}, "column 1 (cam_01): its 3 x 3 part is singular")])
def test_easywand_bad_files_one_line(tmp_path, text, options, message):
    from dome_calib.interop.convert import read_foreign

    path = tmp_path / "x_dltCoefs.csv"
    path.write_text(text)
    with pytest.raises(InteropError) as err:
        read_foreign(path, "easywand", ImportOptions(unit="mm", **options))
    assert message in str(err.value) and "\n" not in str(err.value) and str(path) in str(err.value)


# ---------------------------------------------------------------------------------------------------- OpenCap
# Pose2Sim turns OpenCap's world (its vertical board's, y down) by Rz(pi) Rx(-pi/2): its world point is A @ ours.
OPENCAP_TO_POSE2SIM = np.diag([-1.0, -1.0, 1.0]) @ np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])


def _opencap_pickles(folder: Path, cams, protocol: int = 4) -> None:
    """OpenCap's camera files as its saveCameraParameters writes them (pickled dict of arrays, t in mm)."""
    import pickle

    folder.mkdir()
    for k, cam in enumerate(cams):
        d = {"imageSize": np.array([[cam.resolution[1]], [cam.resolution[0]]]), "intrinsicMat": cam.K.copy(),
             "distortion": cam.dist.reshape(1, 5).copy(), "rotation": cam.R.copy(),
             "translation": (cam.t_cm * 10.0).reshape(3, 1), "rotation_EulerAngles": np.zeros((3, 1))}
        (folder / f"cam{k}.pickle").write_bytes(pickle.dumps(d, protocol=protocol))


def test_opencap_reads_as_pose2sims_calib_opencap_fun(real, tmp_path):
    """OpenCap .pickle files written for 6 real Panoptic cameras (HD, with k3), read by Pose2Sim's own
    calib_opencap_fun (pose2sim 0.10.49) and by our import: same order (cam_00 ..), sizes; Pose2Sim's cameras see its
    turned world (A X, m) as ours see X (cm) within 1e-6 px over the image, against ours without k3 (Pose2Sim drops
    it: ours keeps it)."""
    from Pose2Sim.calibration import calib_opencap_fun

    from dome_calib.interop.convert import read_foreign

    cams = [c for n, c in real[1].cameras.items() if n.startswith("00_")][:6]
    assert any(abs(c.dist[4]) > 0 for c in cams)
    folder = tmp_path / "opencap"
    _opencap_pickles(folder, cams)
    converted = calib_opencap_fun(sorted(folder.glob("*.pickle")))
    bundle, unit = read_foreign(folder, "opencap", ImportOptions())
    assert unit == "mm" and list(bundle.cameras) == converted[1] == [f"cam_{k:02d}" for k in range(6)]
    assert [cam.dist[4] for cam in bundle.cameras.values()] == [c.dist[4] for c in cams]  # k3 kept
    worst = _gap_to_pose2sim_px(list(bundle.cameras.values()), converted,
                                their_world=lambda X_cm: X_cm @ OPENCAP_TO_POSE2SIM.T / 100.0,
                                ours=lambda cam: Camera(**{**cam.__dict__, "dist": np.array([*cam.dist[:4], 0.0])}))
    print(f"OpenCap .pickle: ours vs Pose2Sim's calib_opencap_fun: {worst:.2e} px")
    assert worst < 1e-6


def _as_numpy_1(data: bytes, protocol: int) -> bytes:
    """A pickle written by numpy 2 with the module names numpy 1.x writes (``numpy.core``): in text for protocols
    0-3, as length-prefixed strings in the one frame of a small protocol 4-5 pickle (its length mended)."""
    if protocol <= 3:
        return data.replace(b"numpy._core.", b"numpy.core.")
    assert data[2:3] == b"\x95" and int.from_bytes(data[3:11], "little") == len(data) - 11  # PROTO, one FRAME
    for old in (b"numpy._core.multiarray", b"numpy._core.numeric"):
        new = old.replace(b"._core", b".core")
        data = data.replace(b"\x8c" + bytes([len(old)]) + old, b"\x8c" + bytes([len(new)]) + new)
    return data[:3] + (len(data) - 11).to_bytes(8, "little") + data[11:]


def test_opencap_pickle_of_any_protocol_and_numpy_1_names_reads(real, tmp_path):
    """Protocols 0-5, and numpy 1.x's global names (``numpy.core.multiarray``), give the same cameras."""
    cams = list(real[1].cameras.values())[:1]
    got = []
    for p in range(6):
        _opencap_pickles(tmp_path / f"p{p}", cams, protocol=p)
        f = tmp_path / f"p{p}" / "cam0.pickle"
        f.write_bytes(_as_numpy_1(f.read_bytes(), p))
        assert b"numpy.core." in f.read_bytes() and b"numpy._core" not in f.read_bytes()
        from dome_calib.interop.opencap import read
        got.append(read(tmp_path / f"p{p}", ImportOptions()).cameras[0])
    for c in got:
        np.testing.assert_array_equal(c.K, got[0].K)
        np.testing.assert_array_equal(c.t, cams[0].t_cm * 10.0)


class _Payload:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        import os
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("protocol", [2, 4])
def test_opencap_pickle_naming_code_is_refused_unrun(tmp_path, protocol):
    """A pickle that would run os.system on pickle.load is refused with one line naming the file and the global,
    and the command is not run (its marker file does not appear)."""
    import pickle

    from dome_calib.interop.opencap import read

    folder = tmp_path / "opencap"
    folder.mkdir()
    marker = tmp_path / "ran"
    evil = folder / "cam0.pickle"
    evil.write_bytes(pickle.dumps({"imageSize": np.array([1080, 1920]), "x": _Payload(marker)}, protocol=protocol))
    with pytest.raises(InteropError) as exc:
        read(folder, ImportOptions())
    msg = str(exc.value)
    assert "\n" not in msg and str(evil) in msg and ("posix.system" in msg or "os.system" in msg), msg
    assert not marker.exists()


def test_opencap_schema_names_the_field(real, tmp_path):
    import pickle

    from dome_calib.interop.opencap import read

    folder = tmp_path / "opencap"
    _opencap_pickles(folder, list(real[1].cameras.values())[:1])
    f = folder / "cam0.pickle"
    d = pickle.loads(f.read_bytes())  # our own file, just written
    d["distortion"] = np.zeros((1, 3))
    f.write_bytes(pickle.dumps(d))
    with pytest.raises(InteropError, match=r"cam0\.pickle.*distortion"):
        read(folder, ImportOptions())
