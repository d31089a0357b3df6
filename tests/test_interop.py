"""Export / import round trips (every camera's projection and rays over the whole image), and the peers' own
readers: pycolmap, aniposelib's CameraGroup.load, Pose2Sim's retrieve_calib_params, OpenCV's FileStorage for
EasyMocap."""
from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from dome_calib.ownership import RECORD
from dome_calib.bundle import Bundle, Camera, CameraType
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.camera import COLMAP_PIXEL_OFFSET_PX
from dome_calib.interop.common import PANOPTIC_FROM_UP
from dome_calib.interop.common import ExportOptions, ImportOptions
from dome_calib.interop.convert import export_bundle, import_calibration
from dome_calib.interop.registry import EXPORT_FORMATS, IMPORT_FORMATS
from dome_calib.layout import nominal_dome
from dome_calib.panoptic_io import read_calibration

from .conftest import REAL_CALIBRATION
from .interop_helpers import gaps_px, pixels, world_points_cm

ROUND_TRIP_TOL_PX = 1e-6
#: Drawn cameras reach what no real one does (15 m away, a 180 deg turn, f = 200 px, the principal point at a
#: sixth of the image): float64 through metres, the format's up axis and a rotation vector at pi leave up to
#: 1.06e-6 px there (Pose2Sim, found by a draw); a real dome's 520 cameras stay within ROUND_TRIP_TOL_PX.
MUTATED_TOL_PX = 1e-5
OUT = {"colmap": "model", "aniposelib": "calibration.toml", "pose2sim": "Calib.toml", "easymocap": "easymocap",
       "nerfstudio": "transforms.json"}
#: The formats that go both ways.
BOTH_WAYS = [f for f in EXPORT_FORMATS if f in IMPORT_FORMATS]


@pytest.fixture(scope="module")
def real_bundle(tmp_path_factory) -> Path:
    cameras, source = read_calibration(REAL_CALIBRATION)
    folder = tmp_path_factory.mktemp("real") / "bundle"
    write_bundle(Bundle(seq="160906_band1", cameras=cameras, calib_data_source=source), folder)
    return folder


@pytest.fixture(scope="module")
def synthetic_bundle(tmp_path_factory) -> Path:
    """The nominal full dome: 521 cameras (480 VGA, 31 HD, 10 Kinect colour), distortion with k3."""
    folder = tmp_path_factory.mktemp("synth") / "bundle"
    write_bundle(nominal_dome("full", seed=3), folder)
    return folder


def round_trip(bundle_folder: Path, fmt: str, work: Path, export: ExportOptions | None = None,
               unit: str | None = None, **import_kw):
    """Export then import; returns (original bundle, imported bundle, export result)."""
    result = export_bundle(bundle_folder, fmt, work / OUT[fmt], export or ExportOptions())
    import_unit = unit if unit is not None else (result.unit if fmt == "colmap" else None)
    import_calibration(work / OUT[fmt], fmt, work / "back", ImportOptions(unit=import_unit, **import_kw))
    return load_bundle(bundle_folder), load_bundle(work / "back"), result


def worst_gaps(original: Bundle, again: Bundle) -> tuple[float, float]:
    assert list(again.cameras) == list(original.cameras)  # same names, same order
    assert [c.resolution for c in again.cameras.values()] == [c.resolution for c in original.cameras.values()]
    proj, rays = gaps_px(list(original.cameras.values()), list(again.cameras.values()))
    return float(proj.max()), float(rays.max())


@pytest.mark.parametrize("fmt", BOTH_WAYS)
def test_round_trip_real_calibration(real_bundle, tmp_path, fmt):
    original, again, result = round_trip(real_bundle, fmt, tmp_path)
    proj, rays = worst_gaps(original, again)
    print(f"{fmt}: round trip of the real 520 cameras: projection {proj:.2e} px, rays {rays:.2e} px")
    assert len(again.cameras) == 520
    assert proj < ROUND_TRIP_TOL_PX and rays < ROUND_TRIP_TOL_PX
    assert {c.type for c in again.cameras.values()} == {CameraType.VGA, CameraType.HD, CameraType.KINECT_COLOR}
    assert result.corner_shift_px == {}  # nothing dropped: k3 too (Pose2Sim's reader takes 5 terms)


@pytest.mark.parametrize("fmt", BOTH_WAYS)
def test_round_trip_synthetic_full_dome(synthetic_bundle, tmp_path, fmt):
    original, again, _ = round_trip(synthetic_bundle, fmt, tmp_path)
    proj, rays = worst_gaps(original, again)
    print(f"{fmt}: round trip of the synthetic 521 cameras: projection {proj:.2e} px, rays {rays:.2e} px")
    assert len(again.cameras) == 521
    assert proj < ROUND_TRIP_TOL_PX and rays < ROUND_TRIP_TOL_PX


@pytest.mark.parametrize(("fmt", "export_unit", "import_kw"), [
    ("colmap", "mm", {"unit": "mm"}),
    ("aniposelib", "cm", {"unit": "squares", "square_size_mm": 10.0}),  # 1 square of 10 mm = 1 cm
    ("nerfstudio", "cm", {}),
])
def test_units_and_names_are_applied_both_ways(synthetic_bundle, tmp_path, fmt, export_unit, import_kw):
    names = {"00_00": "hd_first", "01_01": "vga_first"}
    export = ExportOptions(unit=export_unit, names=names, binary=False)
    if fmt == "aniposelib":  # a foreign aniposelib file does not name its unit: drop ours
        result = export_bundle(synthetic_bundle, fmt, tmp_path / "a.toml", export)
        text = (tmp_path / "a.toml").read_text().replace(f'unit = "{result.unit}"\n', "")
        (tmp_path / OUT[fmt]).write_text(text)
        import_calibration(tmp_path / OUT[fmt], fmt, tmp_path / "back",
                           ImportOptions(names={v: k for k, v in names.items()}, **import_kw))
        original, again = load_bundle(synthetic_bundle), load_bundle(tmp_path / "back")
    else:
        original, again, _ = round_trip(synthetic_bundle, fmt, tmp_path, export,
                                        names={v: k for k, v in names.items()}, **import_kw)
    assert max(worst_gaps(original, again)) < ROUND_TRIP_TOL_PX


camera_strategy = st.fixed_dictionaries({
    "quat": st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1),
    "t_cm": st.tuples(*[st.floats(-2000, 2000)] * 3),
    "f_px": st.floats(200, 3000), "aspect": st.floats(0.98, 1.02),
    "c_frac": st.tuples(st.floats(0.3, 0.7), st.floats(0.3, 0.7)),
    "k": st.tuples(st.floats(-0.4, 0.1), st.floats(-0.05, 0.2), st.floats(-1e-3, 1e-3), st.floats(-1e-3, 1e-3),
                   st.sampled_from([0.0, -0.05, 0.03])),
    "size": st.sampled_from([(640, 480), (1920, 1080), (1088, 1920)]),
})


def _camera(name: str, d: dict) -> Camera:
    w, h = d["size"]
    f = d["f_px"]
    K = np.array([[f, 0, d["c_frac"][0] * w], [0, f * d["aspect"], d["c_frac"][1] * h], [0, 0, 1.0]])
    return Camera(name=name, type=CameraType.VGA, resolution=(w, h), K=K, dist=np.array(d["k"], dtype=float),
                  R=Rotation.from_quat(d["quat"]).as_matrix(), t_cm=np.array(d["t_cm"]), panel=0, node=0)


def _lens_is_monotonic(d: dict) -> bool:
    """Whether the radial distortion keeps growing out to the farthest image corner, as a real lens does:
    d/dr [r (1 + k1 r^2 + k2 r^4 + k3 r^6)] > 0.2. Beyond its turning point the model folds the image back onto
    itself, and any round trip there is as ill-conditioned as the fold (a 1e-10 rad rotation becomes 1e-6 px)."""
    w, h = d["size"]
    cx, cy = d["c_frac"][0] * w, d["c_frac"][1] * h
    r_max = max(np.hypot(max(cx, w - cx) / d["f_px"], max(cy, h - cy) / (d["f_px"] * d["aspect"])), 1e-9)
    k1, k2, _, _, k3 = d["k"]
    r2 = np.linspace(0.0, 1.0, 512) ** 2 * r_max ** 2
    return bool(np.all(1 + 3 * k1 * r2 + 5 * k2 * r2 ** 2 + 7 * k3 * r2 ** 3 > 0.2))


@settings(max_examples=15, deadline=None)
@given(cams=st.lists(camera_strategy, min_size=1, max_size=12), fmt=st.sampled_from(BOTH_WAYS))
@example(cams=[{"quat": (0.0, 0.18336263487508497, 0.96875, 0.0), "t_cm": (0.0, 1512.25, 0.0), "f_px": 200.0,
                "aspect": 1.0, "c_frac": (0.6875, 0.3125), "k": (0.0, 0.0, 0.0, 0.0, 0.03), "size": (1920, 1080)}],
         fmt="pose2sim")  # the draw that left 1.06e-6 px (MUTATED_TOL_PX)
def test_round_trip_of_mutated_cameras(cams, fmt):
    """Any rotation, position, focal, principal point and distortion whose lens is physical (monotonic out to
    the image corners), 1-12 cameras (order and > 10 names)."""
    assume(all(_lens_is_monotonic(d) for d in cams))
    names = [f"cam_{i}" for i in range(len(cams))]  # cam_10 sorts before cam_2 as a string
    bundle = Bundle(seq="h", cameras={n: _camera(n, d) for n, d in zip(names, cams)})
    with tempfile.TemporaryDirectory() as tmp:
        write_bundle(bundle, Path(tmp) / "b")
        original, again, _ = round_trip(Path(tmp) / "b", fmt, Path(tmp))
        assert worst_gaps(original, again)[0] < MUTATED_TOL_PX
        assert list(again.cameras) == list(original.cameras)  # the bundle file's order (type, then name)


# ------------------------------------------------------------------------------------------ the peers' own readers
@pytest.mark.parametrize("binary", [True, False])
def test_pycolmap_reads_the_model_and_projects_like_us(real_bundle, tmp_path, binary):
    export_bundle(real_bundle, "colmap", tmp_path / "model", ExportOptions(unit="m", binary=binary))
    assert sorted(p.name for p in (tmp_path / "model").iterdir() if p.name != RECORD) == sorted(
        f"{k}.{'bin' if binary else 'txt'}" for k in ("cameras", "images", "points3D", "rigs", "frames"))
    rec = pycolmap.Reconstruction(str(tmp_path / "model"))
    bundle = load_bundle(real_bundle)
    assert rec.num_rigs() == 1 and rec.num_frames() == 1 and rec.num_images() == 520
    assert rec.rigs[1].num_sensors() == 520
    names = [rec.images[i].name for i in sorted(rec.images)]
    assert names == [f"{n}.png" for n in bundle.cameras]
    worst = 0.0
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        cam = bundle.cameras[image.name.removesuffix(".png")]
        X_cm = world_points_cm(cam)
        X_cam_m = image.cam_from_world() * (X_cm / 100.0)
        uv = rec.cameras[image.camera_id].img_from_cam(X_cam_m) - COLMAP_PIXEL_OFFSET_PX
        worst = max(worst, float(np.abs(uv - pixels(cam, X_cm)).max()))
        assert rec.cameras[image.camera_id].model.name == ("FULL_OPENCV" if cam.dist[4] else "OPENCV")
    print(f"pycolmap vs our model, 520 real cameras: {worst:.2e} px")
    assert worst < ROUND_TRIP_TOL_PX


@pytest.mark.parametrize("which", ["real", "synthetic"])
def test_aniposelib_loads_every_camera_in_our_order_and_projects_like_us(real_bundle, synthetic_bundle, tmp_path,
                                                                         which):
    from aniposelib.cameras import CameraGroup

    folder = real_bundle if which == "real" else synthetic_bundle
    export_bundle(folder, "aniposelib", tmp_path / "calibration.toml")  # mm, the default
    group = CameraGroup.load(str(tmp_path / "calibration.toml"))
    bundle = load_bundle(folder)
    assert [c.get_name() for c in group.cameras] == list(bundle.cameras)
    assert len(group.cameras) == (520 if which == "real" else 521)
    assert group.metadata["unit"] == "mm"
    worst = 0.0
    for peer, cam in zip(group.cameras, bundle.cameras.values()):
        X_cm = world_points_cm(cam)
        uv = peer.project(X_cm * 10.0).reshape(-1, 2)
        worst = max(worst, float(np.abs(uv - pixels(cam, X_cm)).max()))
    print(f"aniposelib vs our model, {len(group.cameras)} {which} cameras: {worst:.2e} px")
    assert worst < ROUND_TRIP_TOL_PX


def test_opencv_filestorage_reads_the_easymocap_files_as_easymocap_does(real_bundle, tmp_path):
    """As EasyMocap's ``read_camera`` (mytools/camera_utils.py): K_, dist_, H_, W_, R_ (Rodrigues), T_ (m), in its
    z-up world (the export's default)."""
    export_bundle(real_bundle, "easymocap", tmp_path / "cal")
    intri = cv2.FileStorage(str(tmp_path / "cal" / "intri.yml"), cv2.FILE_STORAGE_READ)
    extri = cv2.FileStorage(str(tmp_path / "cal" / "extri.yml"), cv2.FILE_STORAGE_READ)
    node = intri.getNode("names")
    names = [node.at(i).string() for i in range(node.size())]
    bundle = load_bundle(real_bundle)
    assert names == list(bundle.cameras)
    worst = 0.0
    for name in names:  # as EasyMocap's read_camera: K_, dist_, H_, W_, R_ (Rodrigues) and T_ (m)
        cam = bundle.cameras[name]
        K, dist = intri.getNode(f"K_{name}").mat(), intri.getNode(f"dist_{name}").mat()
        assert dist.shape == (1, 5)
        assert (int(intri.getNode(f"W_{name}").real()), int(intri.getNode(f"H_{name}").real())) == cam.resolution
        rvec, T = extri.getNode(f"R_{name}").mat(), extri.getNode(f"T_{name}").mat()
        assert np.abs(cv2.Rodrigues(rvec)[0] - extri.getNode(f"Rot_{name}").mat()).max() < 1e-12
        X_cm = world_points_cm(cam)
        uv, _ = cv2.projectPoints(X_cm @ PANOPTIC_FROM_UP["+z"] / 100.0, rvec, T, K, dist)
        worst = max(worst, float(np.abs(uv.reshape(-1, 2) - pixels(cam, X_cm)).max()))
    print(f"OpenCV (EasyMocap's reading) vs our model, 520 real cameras: {worst:.2e} px")
    assert worst < ROUND_TRIP_TOL_PX


@pytest.mark.parametrize("up", ["+x", "-x", "+y", "+z", "-z"])
def test_world_up_turns_the_world_and_back(synthetic_bundle, tmp_path, up):
    """Exported with up = UP and imported saying so: our world again. Imported as kept: the same cameras in the
    turned world (a point X of ours is M^T X there)."""
    export = ExportOptions(world_up=up)
    original, again, result = round_trip(synthetic_bundle, "easymocap", tmp_path, export, world_up=up)
    assert result.world_up == up
    assert max(worst_gaps(original, again)) < ROUND_TRIP_TOL_PX
    import_calibration(tmp_path / OUT["easymocap"], "easymocap", tmp_path / "kept", ImportOptions(world_up="-y"))
    kept = load_bundle(tmp_path / "kept")
    M = PANOPTIC_FROM_UP[up]
    ours, theirs = list(original.cameras.values()), list(kept.cameras.values())
    X = world_points_cm(ours)
    assert np.abs(pixels(theirs, X @ M) - pixels(ours, X)).max() < ROUND_TRIP_TOL_PX
    up_axis = M.T @ np.array([0.0, -1.0, 0.0])  # our up, in the file's world
    assert np.allclose(up_axis, np.eye(3)[" xyz".index(up[1]) - 1] * (1 if up[0] == "+" else -1))


@pytest.mark.parametrize(("model", "params"), [
    ("SIMPLE_PINHOLE", [900.0, 330.2, 241.7]),
    ("PINHOLE", [900.0, 905.5, 330.2, 241.7]),
    ("SIMPLE_RADIAL", [900.0, 330.2, 241.7, -0.12]),
    ("RADIAL", [900.0, 330.2, 241.7, -0.12, 0.03]),
    ("OPENCV", [900.0, 905.5, 330.2, 241.7, -0.12, 0.03, 4e-4, -2e-4]),
    ("FULL_OPENCV", [900.0, 905.5, 330.2, 241.7, -0.12, 0.03, 4e-4, -2e-4, 0.01, 0.0, 0.0, 0.0]),
])
def test_colmap_models_written_by_pycolmap_import_as_pycolmap_projects(tmp_path, model, params):
    """A plain COLMAP model (one camera shared by three images, trivial rigs, text files): every image becomes a
    camera of ours that projects as pycolmap does (minus COLMAP's half pixel)."""
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=640, height=480, params=params, camera_id=1))
    rotations = Rotation.from_euler("xyz", [[0.1, -0.2, 0.05], [-0.3, 0.4, 0.2], [0.2, 0.1, -2.9]]).as_matrix()
    for i, R in enumerate(rotations, start=1):
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(R), np.array([0.1 * i, -0.2, 1.5 + i]))
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"frames/img{i}.jpg", camera_id=1, image_id=i),
                                         pose)
    (tmp_path / "model").mkdir()
    rec.write_text(str(tmp_path / "model"))
    import_calibration(tmp_path / "model", "colmap", tmp_path / "b", ImportOptions(unit="m"))
    bundle = load_bundle(tmp_path / "b")
    assert list(bundle.cameras) == ["frames_img1", "frames_img2", "frames_img3"]  # a camera name is a file name
    for image_id, (name, cam) in zip(sorted(rec.images), bundle.cameras.items()):
        X_cm = world_points_cm(cam)
        image = rec.images[image_id]
        uv = rec.cameras[1].img_from_cam(image.cam_from_world() * (X_cm / 100.0)) - COLMAP_PIXEL_OFFSET_PX
        assert np.abs(uv - pixels(cam, X_cm)).max() < ROUND_TRIP_TOL_PX, name
