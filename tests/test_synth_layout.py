"""The synthetic dome layout: counts, names, geometry and intrinsics against the real dome's statistics."""
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from dome_calib.bundle import CameraType

from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.camera import max_valid_radius2, project
from dome_calib.layout import DOME_CENTRE_CM, nominal_dome, select_preset
from dome_calib.synth.dome import dome_from_calibration, projectors

REAL = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"


@pytest.fixture(scope="module")
def full():
    return nominal_dome("full", seed=0)


def test_full_counts_and_names(full):
    counts = Counter(c.type for c in full.cameras.values())
    assert counts == {CameraType.VGA: 480, CameraType.HD: 31, CameraType.KINECT_COLOR: 10}
    assert {f"{p:02d}_{n:02d}" for p in range(1, 21) for n in range(1, 25)} <= set(full.cameras)
    assert {f"00_{i:02d}" for i in range(31)} | {f"50_{i:02d}" for i in range(1, 11)} <= set(full.cameras)


def test_geometry_like_real_dome(full):
    C = np.array([c.center_cm for c in full.of_type("vga").values()])
    assert -300 < C[:, 1].min() < -280 and -80 < C[:, 1].max() < -60  # real: -295 .. -69 cm
    assert abs(np.linalg.norm(C, axis=1).mean() - 326) < 10  # real |C| 326 cm
    for cam in full.cameras.values():
        R = cam.R
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        # dome centre projects near the image centre (aim jitter 8 cm at ~2.7 m: < 6 deg)
        axis_to_centre = DOME_CENTRE_CM - cam.center_cm
        cos = (R[2] @ axis_to_centre) / np.linalg.norm(axis_to_centre)
        assert cos > np.cos(np.radians(8))
        assert R[1] @ np.array([0, 1, 0]) > 0.5  # image down is world down (y down)
    kin = full.of_type("kinect-color")
    heights = sorted(round(-c.center_cm[1]) for c in kin.values())
    assert heights == [100] * 5 + [260] * 5


def test_intrinsics_like_real(full):
    vga = np.array([c.intr for c in full.of_type("vga").values()])
    dist = np.array([c.dist for c in full.of_type("vga").values()])
    assert abs(vga[:, 0].mean() - 745.4) < 0.5 and vga[:, 0].std() < 3
    assert abs(dist[:, 0].mean() + 0.321) < 0.005
    hd = np.array([c.intr[0] for c in full.of_type("hd").values()])
    assert 1300 < hd.mean() < 1650
    kin = np.array([c.intr[0] for c in full.of_type("kinect-color").values()])
    assert abs(kin.mean() - 1054.7) < 5
    all_dist = np.array([c.dist for c in full.cameras.values()])
    corner_r2 = np.array([((c.resolution[0] / c.intr[0]) ** 2 + (c.resolution[1] / c.intr[1]) ** 2) / 4 * 1.3
                          for c in full.cameras.values()])
    assert np.all(max_valid_radius2(all_dist) > corner_r2)  # the lens is monotonic over every image


def test_seed_determinism_and_preset_subset(full):
    again = nominal_dome("full", seed=0)
    other = nominal_dome("full", seed=1)
    assert np.array_equal(again.cameras["05_07"].K, full.cameras["05_07"].K)
    assert not np.array_equal(other.cameras["05_07"].K, full.cameras["05_07"].K)
    tiny = nominal_dome("tiny", seed=0)
    assert len(tiny.cameras) == 16
    assert {t: len(tiny.of_type(t)) for t in ("vga", "hd", "kinect-color")} == {"vga": 8, "hd": 5, "kinect-color": 3}
    for name, cam in tiny.cameras.items():
        assert np.array_equal(cam.R, full.cameras[name].R)
    assert 55 <= len(nominal_dome("panel", seed=0).cameras) <= 65


def test_from_real_calibration_and_roundtrip(tmp_path):
    b = dome_from_calibration(REAL, "panel")
    assert sum(c.type == CameraType.VGA for c in b.cameras.values()) == 48
    write_bundle(b, tmp_path)
    back = load_bundle(tmp_path)
    assert sorted(back.cameras) == sorted(b.cameras)
    np.testing.assert_allclose(back.cameras["01_01"].R, b.cameras["01_01"].R, atol=1e-9)


def test_tiny_cameras_see_dome_centre():
    b = nominal_dome("tiny", seed=0)
    s = b.stacked()
    p = project(DOME_CENTRE_CM[None], s["R"], s["t_cm"], s["intr"], s["dist"])
    assert p.in_image(s["resolution"]).all()


def test_projectors_aim_at_tent():
    projs = projectors(seed=0)
    assert len(projs) == 5
    for p in projs.values():
        x = p.R @ np.array([0.0, -95.0, 0.0]) + p.t_cm
        uv = (p.K @ x)[:2] / x[2]
        assert x[2] > 0 and np.all(np.abs(uv - np.array(p.resolution) / 2) < 100)


def test_select_preset_rejects_missing_panels():
    from dome_calib.errors import DomeCalibError

    with pytest.raises(DomeCalibError, match="panel"):
        select_preset({}, "tiny")


def test_as_built_dome_is_the_design_camera_set_but_not_the_design():
    from dome_calib.rotation import rotation_angle_deg
    from dome_calib.synth.dome import AS_BUILT_CENTER_SIGMA_CM, as_built_dome

    design = nominal_dome("panel", seed=0)
    built = as_built_dome("panel", seed=0)
    assert sorted(built.cameras) == sorted(design.cameras)
    moved = np.array([built.cameras[n].center_cm - design.cameras[n].center_cm for n in design.cameras])
    assert 0.7 * AS_BUILT_CENTER_SIGMA_CM < np.sqrt(np.mean(moved ** 2)) < 1.3 * AS_BUILT_CENTER_SIGMA_CM  # cm
    turned = [rotation_angle_deg(built.cameras[n].R, design.cameras[n].R) for n in design.cameras]
    assert np.median(turned) > 1.0  # deg: another aim and roll draw
    again = as_built_dome("panel", seed=0)
    for n, c in built.cameras.items():
        np.testing.assert_array_equal(c.t_cm, again.cameras[n].t_cm)
        np.testing.assert_allclose(c.R @ c.R.T, np.eye(3), atol=1e-12)
