"""Issue 37: what a capture or a prior can hold that used to calibrate as if nothing were wrong: a prior in metres,
an EXIF-rotated image, a file manager's copy, a camera not named PP_NN, a listed scene missing on disk. Each is read
right or refused in one line naming the file, before any work (the SfM and BA are the stand-ins of
tests/test_calibrate.py)."""
from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

import dome_calib.pipeline.full as pipeline
from dome_calib.bundle import Bundle, Camera
from dome_calib.bundle_io import write_bundle
from dome_calib.errors import CaptureError, DomeCalibError

from .report_data import NO_PLOTS
from .test_calibrate import capture, stand_in_stages  # noqa: F401  (fixtures)


def _options(**kw):
    return pipeline.CalibrateOptions(progress=None, report=NO_PLOTS, **kw)  # no test here reads a plot


def _in_metres(bundle: Bundle) -> Bundle:
    cams = {n: Camera(name=c.name, type=c.type, resolution=c.resolution, K=c.K, dist=c.dist, R=c.R,
                      t_cm=c.t_cm / 100.0, panel=c.panel, node=c.node) for n, c in bundle.cameras.items()}
    return Bundle(seq=bundle.seq, cameras=cams, calib_data_source="another tool, in metres")


# ------------------------------------------------------------------------------------------ prior in metres
@pytest.mark.parametrize("scale, unit", [(0.01, "metres"), (10.0, "millimetres")])
def test_a_prior_in_metres_or_millimetres_is_refused_saying_which(tmp_path, capture, stand_in_stages, scale, unit):
    cap, truth = capture
    prior = _in_metres(truth) if scale == 0.01 else Bundle(seq="mm", cameras={
        n: Camera(name=c.name, type=c.type, resolution=c.resolution, K=c.K, dist=c.dist, R=c.R, t_cm=c.t_cm * 10,
                  panel=c.panel, node=c.node) for n, c in truth.cameras.items()})
    write_bundle(prior, tmp_path / "prior")
    with pytest.raises(DomeCalibError, match=f"--prior {tmp_path / 'prior'}: .* t looks like {unit}"):
        pipeline.run_calibration(cap, tmp_path / "out", _options(prior=tmp_path / "prior"))
    assert stand_in_stages == {"sfm": 0, "ba": 0}
    assert not (tmp_path / "out").exists()


def test_a_prior_in_cm_still_calibrates(tmp_path, capture, stand_in_stages):
    cap, truth = capture
    write_bundle(truth, tmp_path / "prior")
    pipeline.run_calibration(cap, tmp_path / "out", _options(prior=tmp_path / "prior"))
    assert stand_in_stages["sfm"] == 1


@pytest.mark.parametrize("command", ["kinect", "triangulate", "pointcloud"])
def test_a_bundle_in_metres_is_refused_by_the_commands_that_place_things_in_the_world(tmp_path, capture, command,
                                                                                       dome_calib_cli):
    _, truth = capture
    write_bundle(_in_metres(truth), tmp_path / "m")
    det = tmp_path / "det.json"
    det.write_text("{}")
    for kind in ("ir", "color"):  # a Kinect folder as find_sensor_frames lists it (the images are not read first)
        (tmp_path / "kinect" / "KINECTNODE4").mkdir(parents=True, exist_ok=True)
        (tmp_path / "kinect" / "KINECTNODE4" / f"{kind}_0000.png").write_bytes(b"")
    args = {"kinect": ["kinect", tmp_path / "kinect", "--bundle", tmp_path / "m", "-o", tmp_path / "o"],
            "triangulate": ["triangulate", det, "--bundle", tmp_path / "m", "-o", tmp_path / "o"],
            "pointcloud": ["pointcloud", "--bundle", tmp_path / "m", "--time-ms", "0", "--depth", tmp_path,
                           "-o", tmp_path / "o.ply"]}[command]
    done = dome_calib_cli(*args)
    assert done.returncode == 1
    assert "t looks like metres" in done.stderr, done.stderr


# ------------------------------------------------------------------------------------------ EXIF orientation
def _png_with_orientation(image: np.ndarray, orientation: int) -> bytes:
    """The PNG of ``image`` with an eXIf chunk whose Orientation tag (0x0112) is ``orientation`` (3: turn 180)."""
    ok, buf = cv2.imencode(".png", image)
    data = buf.tobytes()
    tiff = (b"MM\x00\x2a" + struct.pack(">I", 8) + struct.pack(">H", 1)
            + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack(">I", 0))
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    at = data.index(b"IDAT") - 4
    return data[:at] + chunk + data[at:]


def test_an_exif_rotated_image_is_read_as_the_sensor_saw_it(tmp_path):
    from projector.features import FeatureOptions, extract_image

    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur((rng.random((240, 320)) * 255).astype(np.uint8), (0, 0), 2.0)
    image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX)
    plain, turned = tmp_path / "01_01.png", tmp_path / "01_02.png"
    cv2.imwrite(str(plain), image)
    turned.write_bytes(_png_with_orientation(image, 3))
    assert np.array_equal(cv2.imread(str(turned), cv2.IMREAD_GRAYSCALE), image[::-1, ::-1])  # OpenCV's default
    options = FeatureOptions(min_features=1)
    a = extract_image(("01_01", str(plain), options))
    b = extract_image(("01_02", str(turned), options))
    assert a.failure is None and len(a.keypoints) > 50
    np.testing.assert_array_equal(b.keypoints, a.keypoints)  # the same pixels, not turned 180 degrees


def test_kinect_and_depth_readers_ignore_exif_orientation(tmp_path):
    from dome_calib.kinect.detect import read_gray

    image = np.zeros((48, 64), np.uint8)
    image[:8, :8] = 255
    path = tmp_path / "color_0.png"
    path.write_bytes(_png_with_orientation(image, 3))
    np.testing.assert_array_equal(read_gray(path, (64, 48), "colour"), image)


# ------------------------------------------------------------------------------------------ names and copies
def _pattern_png(path: Path, seed: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), (np.random.default_rng(seed).random((48, 64)) * 255).astype(np.uint8))


@pytest.mark.parametrize("listed", [True, False], ids=["capture.json", "no capture.json"])
def test_a_file_managers_copy_is_refused_naming_it(tmp_path, capture, stand_in_stages, listed):
    cap, _ = capture
    scene = cap / "scenes" / "scene_01"
    _pattern_png(scene / "01_01.png", 1)
    (scene / "01_01 (1).png").write_bytes((scene / "01_01.png").read_bytes())
    if not listed:
        (cap / "capture.json").unlink()
    with pytest.raises(CaptureError, match=r"01_01 \(1\).png: '01_01 \(1\)' is not a camera name"):
        pipeline.run_calibration(cap, tmp_path / "out", _options())
    assert stand_in_stages == {"sfm": 0, "ba": 0}


def test_two_cameras_with_the_same_picture_are_refused_naming_both(tmp_path, capture, stand_in_stages):
    cap, _ = capture
    scene = cap / "scenes" / "scene_01"
    _pattern_png(scene / "01_01.png", 1)
    _pattern_png(scene / "01_03.png", 3)
    (scene / "01_02.png").write_bytes((scene / "01_01.png").read_bytes())
    with pytest.raises(CaptureError, match=r"01_02.png: the same picture as .*01_01.png"):
        pipeline.run_calibration(cap, tmp_path / "out", _options())
    assert stand_in_stages == {"sfm": 0, "ba": 0}


def test_blank_images_alike_are_not_copies(tmp_path, capture, stand_in_stages):
    cap, _ = capture
    for n in ("01_01", "01_02"):
        cv2.imwrite(str(cap / "scenes" / "scene_01" / f"{n}.png"), np.zeros((48, 64), np.uint8))
    pipeline.run_calibration(cap, tmp_path / "out", _options())  # the feature stage reports blank images
    assert stand_in_stages["sfm"] == 1


@pytest.mark.parametrize("name", ["hd-main", "00_31", "21_01", "50_11", "1_01"])
def test_a_camera_not_named_pp_nn_is_refused_with_how_to_name_it(tmp_path, capture, stand_in_stages, name):
    cap, _ = capture
    (cap / "capture.json").unlink()
    _pattern_png(cap / "scenes" / "scene_01" / f"{name}.png", 5)
    with pytest.raises(CaptureError, match=f"{name}.png: '{name}' is not a camera name .*HD 00_00..00_30"):
        pipeline.run_calibration(cap, tmp_path / "out", _options())
    assert stand_in_stages == {"sfm": 0, "ba": 0}


def test_an_image_of_a_camera_capture_json_does_not_list_is_refused(tmp_path, capture, stand_in_stages):
    cap, _ = capture
    _pattern_png(cap / "scenes" / "scene_01" / "07_07.png", 7)
    with pytest.raises(CaptureError, match="07_07.png: camera 07_07 is not among the cameras of .*capture.json"):
        pipeline.run_calibration(cap, tmp_path / "out", _options())


def test_a_listed_scene_missing_on_disk_is_one_line_naming_it(tmp_path, capture, stand_in_stages, dome_calib_cli):
    cap, _ = capture
    meta = json.loads((cap / "capture.json").read_text())
    meta["scenes"].append("scene_02")
    (cap / "capture.json").write_text(json.dumps(meta))
    done = dome_calib_cli("calibrate", cap, "-o", tmp_path / "out")
    assert done.returncode == 1
    assert done.stderr.strip() == (f"dome-calib: error: {cap / 'capture.json'} lists scene 'scene_02' but "
                                   f"{cap / 'scenes' / 'scene_02'} is missing: copy the scene there or remove it "
                                   "from the list")
    assert stand_in_stages == {"sfm": 0, "ba": 0}


def test_compare_against_a_reference_in_metres_is_refused(tmp_path, capture, dome_calib_cli):
    _, truth = capture
    write_bundle(truth, tmp_path / "cm")
    write_bundle(_in_metres(truth), tmp_path / "m")
    done = dome_calib_cli("compare", tmp_path / "cm", tmp_path / "m")
    assert done.returncode == 1 and f"{tmp_path / 'm'}: " in done.stderr and "t looks like metres" in done.stderr
    done = dome_calib_cli("compare", tmp_path / "m", tmp_path / "cm")  # an estimate in any scale: aligned
    assert done.returncode == 0, done.stderr
