"""Bundle files: exact round trips of the real Panoptic files, validation messages, the M_color convention."""
from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.ownership import RECORD
from dome_calib.bundle import FRAME_TIME_TOLERANCE_MS, Bundle, KinectSensor, SyncTable, SyncTables

from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.errors import BundleFormatError
from dome_calib.panoptic_io import M_COLOR_CONVENTION, read_calibration, read_kcalibration

from .conftest import REAL_CALIBRATION, REAL_KCALIBRATION


def _sync() -> SyncTables:
    vga = SyncTable(index=np.arange(100, 112), univ_time_ms=1000.0 + 40.0 * np.arange(12) + 0.0123)
    hd = SyncTable(index=np.arange(5, 15), univ_time_ms=1001.5 + 1001.0 / 30.0 * np.arange(10))
    k = SyncTable(index=np.array([0, 1, 3]), univ_time_ms=np.array([990.25, 1023.6, 1090.3]))
    return SyncTables(streams={"vga": vga, "hd": hd}, kinect_color={"KINECTNODE1": k}, kinect_depth={"KINECTNODE1": k})


def _real_bundle(seq: str = "160906_band1") -> Bundle:
    cameras, source = read_calibration(REAL_CALIBRATION)
    return Bundle(seq=seq, cameras=cameras, calib_data_source=source, kinect=read_kcalibration(REAL_KCALIBRATION),
                  sync=_sync())


def test_real_calibration_round_trip_is_exact(tmp_path):
    original = json.loads(REAL_CALIBRATION.read_text())
    write_bundle(_real_bundle(), tmp_path)
    again = load_bundle(tmp_path)
    rewritten = json.loads((tmp_path / "calibration_160906_band1.json").read_text())
    assert len(again.cameras) == 520
    by_name = {c["name"]: c for c in rewritten["cameras"]}
    for cam in original["cameras"]:  # every number identical, field by field
        for field in ("type", "resolution", "panel", "node", "K", "distCoef", "R", "t"):
            assert by_name[cam["name"]][field] == cam[field], (cam["name"], field)
    assert [c["name"] for c in rewritten["cameras"]] == [c["name"] for c in original["cameras"]]
    write_bundle(again, tmp_path / "second")
    assert (tmp_path / "second" / "calibration_160906_band1.json").read_text() == (
        tmp_path / "calibration_160906_band1.json").read_text()


def test_written_file_reads_like_the_real_one(tmp_path):
    write_bundle(_real_bundle(), tmp_path)
    text = (tmp_path / "calibration_160906_band1.json").read_text()
    real = REAL_CALIBRATION.read_text()
    first_camera = real[: real.index("\t\t},")]
    assert text.startswith(first_camera)  # same layout: tabs, one matrix row per line, compact numbers


def test_kinect_and_sync_round_trip(tmp_path):
    bundle = _real_bundle()
    write_bundle(bundle, tmp_path)
    again = load_bundle(tmp_path)
    assert list(again.kinect.sensors) == [f"KINECTNODE{i}" for i in range(1, 11)]
    for name, s in bundle.kinect.sensors.items():
        t = again.kinect.sensors[name]
        for field in ("K_depth", "dist_depth", "K_color", "dist_color", "M_depth", "M_color", "M_world2sensor"):
            np.testing.assert_array_equal(getattr(t, field), getattr(s, field), err_msg=f"{name}.{field}")
        assert t.extra == s.extra
    np.testing.assert_array_equal(again.kinect.M_world2vga, bundle.kinect.M_world2vga)
    for stream in ("vga", "hd"):
        np.testing.assert_array_equal(again.sync.streams[stream].univ_time_ms, bundle.sync.streams[stream].univ_time_ms)
        np.testing.assert_array_equal(again.sync.streams[stream].index, bundle.sync.streams[stream].index)
    np.testing.assert_array_equal(again.sync.kinect_depth["KINECTNODE1"].index, [0, 1, 3])
    assert json.loads((tmp_path / "kcalibration_160906_band1.json").read_text())["convention"] == M_COLOR_CONVENTION


def test_m_color_convention_maps_depth_into_color():
    """M_color = sensor_from_color: a point known in depth coordinates lands where the colour camera sees it."""
    rng = np.random.default_rng(0)
    from dome_calib.rotation import rotvec_to_matrix

    color_from_depth = np.eye(4)
    color_from_depth[:3, :3] = rotvec_to_matrix(np.array([0.002, -0.01, 0.004]))
    color_from_depth[:3, 3] = [-0.052, 0.0003, 0.0011]
    M_depth = np.diag([-1.0, -1.0, 1.0, 1.0])  # sensor_from_depth, as in the real file
    M_color = M_depth @ np.linalg.inv(color_from_depth)  # sensor_from_color
    s = KinectSensor(name="KINECTNODE1", K_depth=np.eye(3), dist_depth=np.zeros(5), depth_size=(512, 424),
                     K_color=np.eye(3), dist_color=np.zeros(5), color_size=(1920, 1080), M_depth=M_depth,
                     M_color=M_color, M_world2sensor=np.eye(4))
    X_depth = np.append(rng.normal(0, 1, 3), 1.0)
    np.testing.assert_allclose(s.color_from_depth @ X_depth, color_from_depth @ X_depth, atol=1e-12)
    # the real file read with this convention gives the Kinect v2 baseline: colour camera ~5.2 cm along x
    real = read_kcalibration(REAL_KCALIBRATION)
    for sensor in real.sensors.values():
        baseline_cm = 100 * np.linalg.norm(sensor.color_from_depth[:3, 3])
        assert 4.5 < baseline_cm < 6.0


def test_atomic_write_leaves_old_file_when_formatting_fails(tmp_path):
    bundle = _real_bundle()
    write_bundle(bundle, tmp_path)
    before = (tmp_path / "calibration_160906_band1.json").read_text()
    broken = copy.deepcopy(bundle)
    broken.cameras["01_01"].t_cm[0] = np.nan
    with pytest.raises(ValueError):
        write_bundle(broken, tmp_path)
    assert (tmp_path / "calibration_160906_band1.json").read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [RECORD, "calibration_160906_band1.json", "kcalibration_160906_band1.json", "synctables_160906_band1.json",
         "ksynctables_160906_band1.json"])


def test_more_than_ten_cameras_keep_their_names(tmp_path):
    write_bundle(_real_bundle(), tmp_path)
    again = load_bundle(tmp_path)
    for name in ("01_01", "01_10", "01_02", "00_00", "00_30", "50_10"):
        np.testing.assert_array_equal(again.cameras[name].K, _real_bundle().cameras[name].K)


# --- validation: each bad file names the field ---------------------------------------------------------------


def _write_variant(tmp_path: Path, mutate) -> Path:
    data = json.loads(REAL_CALIBRATION.read_text())
    data["cameras"] = data["cameras"][:12]
    mutate(data["cameras"])
    folder = tmp_path / "bad"
    folder.mkdir()
    (folder / "calibration_bad.json").write_text(json.dumps(data))
    return folder


def _set(i, field, value):
    def mutate(cams):
        cams[i][field] = value
    return mutate


BAD_CALIBRATIONS = {
    "missing K": (lambda cams: cams[3].pop("K"), "camera 01_04: cameras[3].K: missing (expected a 3 x 3 camera matrix"),
    "K wrong shape": (_set(2, "K", [[745.0, 0, 320], [0, 745, 240]]),
                      "camera 01_03: cameras[2].K: expected a 3 x 3 camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
                      "(px, fx, fy > 0), got [[745.0, 0, 320], [0, 745, 240]]"),
    "t wrong shape": (_set(2, "t", [[1.0], [2.0]]), "camera 01_03: cameras[2].t: expected 3 numbers (flat, 3 x 1 or 1 x 3), "
                                                    "got [[1.0], [2.0]]"),
    "distCoef four": (_set(1, "distCoef", [0.1, 0.2, 0.0, 0.0]),
                      "camera 01_02: cameras[1].distCoef: expected a list of 5 finite numbers (or 5 x 1, 1 x 5)"),
    "NaN in t": (_set(0, "t", [[1.0], [float("nan")], [3.0]]), "camera 01_01: cameras[0].t[1]: expected a finite number "
                                                                ">= -1e+06 and <= 1e+06, got NaN"),
    "inf in R": (_set(0, "R", [[float("inf"), 0, 0], [0, 1, 0], [0, 0, 1]]),
                 "camera 01_01: cameras[0].R[0][0]: expected a finite number >= -2 and <= 2, got Infinity"),
    "R not orthonormal": (_set(5, "R", [[1.0, 0.01, 0], [0, 1, 0], [0, 0, 1]]),
                          "camera 01_06: cameras[5].R: not a rotation (|R R^T - I| = 0.01"),
    "R reflection": (_set(5, "R", [[-1.0, 0, 0], [0, 1, 0], [0, 0, 1]]), "camera 01_06: cameras[5].R: not a rotation "
                                                                         "(|R R^T - I| = 0, det = -1"),
    "negative focal": (_set(4, "K", [[-745.0, 0, 320], [0, 745, 240], [0, 0, 1]]),
                       "camera 01_05: cameras[4].K: focal length must be positive"),
    "duplicate name": (_set(7, "name", "01_01"), "camera 01_01: cameras[7].name: duplicate camera name"),
    "unknown type": (_set(8, "type", "thermal"), "camera 01_09: cameras[8].type: expected \"vga\" or \"hd\" or "
                                                 "\"kinect-color\", got \"thermal\""),
    "resolution float": (_set(9, "resolution", [640.5, 480]), "camera 01_10: cameras[9].resolution[0]: expected an "
                                                              "integer >= 1 and <= 100000, got 640.5"),
    "resolution three": (_set(9, "resolution", [640, 480, 3]), "camera 01_10: cameras[9].resolution: expected a list of "
                                                               "2 integers"),
    "resolution zero": (_set(9, "resolution", [0, 480]), "camera 01_10: cameras[9].resolution[0]: expected an integer "
                                                         ">= 1"),
    "name missing": (lambda cams: cams[10].pop("name"), "cameras[10].name: missing (expected a plain name (no '/'))"),
}


@pytest.mark.parametrize("case", sorted(BAD_CALIBRATIONS))
def test_bad_calibration_names_file_camera_and_field(tmp_path, case):
    mutate, expected = BAD_CALIBRATIONS[case]
    folder = _write_variant(tmp_path, mutate)
    with pytest.raises(BundleFormatError) as err:
        load_bundle(folder)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(str(folder / "calibration_bad.json"))
    assert expected in message


def _write_sync(tmp_path: Path, sync: dict) -> Path:
    folder = tmp_path / "b"
    folder.mkdir()
    shutil.copy(REAL_CALIBRATION, folder / "calibration_s.json")
    (folder / "synctables_s.json").write_text(json.dumps(sync))
    return folder


@pytest.mark.parametrize(
    ("sync", "expected"),
    [
        ({"vga": {"index": [0, 1, 2], "univ_time": [0.0, 40.0]}}, "vga.univ_time: 2 times for 3 indices"),
        ({"vga": {"index": [0, 1, 2], "univ_time": [0.0, 40.0, 40.0]}}, "vga.univ_time[2]: time does not increase at frame index 2"),
        ({"hd": {"index": [0, 1], "univ_time": [0.0, float("nan")]}}, "hd.univ_time[1]: expected a finite number, got NaN"),
        ({"hd": {"index": [0, 2, 1], "univ_time": [0.0, 1.0, 2.0]}}, "hd.index[2]: frame indices must be increasing"),
        ({"hd": {"univ_time": [0.0]}}, "hd.index: missing"),
    ],
)
def test_bad_sync_tables_name_the_field(tmp_path, sync, expected):
    folder = _write_sync(tmp_path, sync)
    with pytest.raises(BundleFormatError, match="synctables_s.json") as err:
        load_bundle(folder)
    assert expected in str(err.value)


def test_bad_ksynctables_and_kcalibration_name_the_field(tmp_path):
    folder = _write_sync(tmp_path, {"vga": {"index": [0], "univ_time": [0.0]}})
    (folder / "ksynctables_s.json").write_text(json.dumps(
        {"kinect": {"color": {"KINECTNODE3": {"index": [0, 1], "univ_time": [5.0, 4.0]}}, "depth": {}}}))
    with pytest.raises(BundleFormatError, match=r"kinect.color.KINECTNODE3.univ_time\[1\]: time does not"):
        load_bundle(folder)
    (folder / "ksynctables_s.json").unlink()
    k = json.loads(REAL_KCALIBRATION.read_text())
    k["sensors"][2]["M_color"][0][0] = float("nan")
    (folder / "kcalibration_s.json").write_text(json.dumps(k))
    with pytest.raises(BundleFormatError, match=r"sensors\[2\].M_color\[0\]\[0\]: expected a finite number .*, got NaN"):
        load_bundle(folder)
    k = json.loads(REAL_KCALIBRATION.read_text())
    k["convention"] = "M_color = color_from_sensor"
    (folder / "kcalibration_s.json").write_text(json.dumps(k))
    with pytest.raises(BundleFormatError, match=r"convention: unknown convention"):
        load_bundle(folder)


def test_not_a_bundle(tmp_path):
    with pytest.raises(BundleFormatError, match="no calibration_<seq>.json"):
        load_bundle(tmp_path)
    (tmp_path / "calibration_x.json").write_text("{not json")
    with pytest.raises(BundleFormatError, match=r"calibration_x.json: not valid JSON"):
        load_bundle(tmp_path)


# --- sync lookup -----------------------------------------------------------------------------------------------


def test_sync_lookup_by_index_nearest_and_bracket():
    table = SyncTable(index=np.array([10, 11, 12, 14]), univ_time_ms=np.array([0.0, 40.0, 80.0, 160.0]))
    assert table.time_of(14) == 160.0
    with pytest.raises(KeyError, match="frame 13"):
        table.time_of(13)  # dropped frame: never guessed from the list position
    idx, dt = table.nearest(np.array([15.0, 25.0, 159.0]))
    np.testing.assert_array_equal(idx, [10, 11, 14])
    np.testing.assert_allclose(dt, [-15.0, 15.0, 1.0])
    i0, i1, w0, w1 = table.bracket(np.array([10.0, 100.0, -1.0]))
    np.testing.assert_array_equal(i0[:2], [10, 12])
    np.testing.assert_array_equal(i1[:2], [11, 14])
    np.testing.assert_allclose(w1[:2], [0.25, 0.25])
    np.testing.assert_allclose(w0[:2] + w1[:2], 1.0)
    assert np.isnan(w0[2]) and np.isnan(w1[2])


@settings(max_examples=60, deadline=None)
@given(start_ms=st.floats(0.0, 8.64e7), period_ms=st.floats(10.0, 50.0), k=st.integers(0, 9),
       off=st.floats(-0.99, 0.99), frac=st.floats(0.05, 0.95))
def test_bracket_takes_a_frame_alone_within_the_tolerance_and_interpolates_between(start_ms, period_ms, k, off, frac):
    """Property: a time within FRAME_TIME_TOLERANCE_MS of frame k gives frame k weight exactly 1 (anywhere on a
    day-long timeline, first and last frame included); a time well between two frames gets weights in (0, 1)
    summing to 1 that interpolate the time itself."""
    times = start_ms + period_ms * np.arange(10)
    table = SyncTable(index=np.arange(100, 110), univ_time_ms=times)
    i0, i1, w0, w1 = (np.asarray(v).item() for v in table.bracket(times[k] + off * FRAME_TIME_TOLERANCE_MS))
    assert {i0: w0, i1: w1}.get(100 + k) == 1.0 and min(w0, w1) == 0.0
    if k < 9:
        t = times[k] + frac * period_ms
        i0, i1, w0, w1 = (np.asarray(v).item() for v in table.bracket(t))
        assert (i0, i1) == (100 + k, 101 + k) and 0.0 < w1 < 1.0 and w0 + w1 == pytest.approx(1.0)
        assert w0 * times[k] + w1 * times[k + 1] == pytest.approx(t, abs=1e-6)


def test_atomic_write_gives_normal_permissions_and_leaves_nothing_on_error(tmp_path):
    import os

    from dome_calib.io_utils import atomic_path, atomic_write_text

    atomic_write_text(tmp_path / "a.json", "{}")
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o666 & ~mask
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "b.json") as tmp:
            tmp.write_text("half")
            raise RuntimeError("stop")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]
