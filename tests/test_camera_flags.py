"""cameras.json's offset criterion (issue 51, "flags that hold when half the cameras are off"): a camera whose inlier
detections lie to one side of the body is flagged whatever the other cameras do; noise, a bias too small to matter
and a bias too few joints show are not."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.people.agreement import ERROR_BIN_PX, NOISE_BIN_PX, CameraAgreement, tally_verdicts
from dome_calib.recon.people.scene_io import camera_report, offset_words

HD = np.array([[1920, 1080]] * 5)


def tallies(shift_px: list[tuple[float, float]], n: int = 3000, sigma_px: float = 3.0, seed: int = 0,
            names: list[str] | None = None) -> CameraAgreement:
    """Five cameras' tallies (``names``: theirs, default 00_00 ... 00_04) as the body over time gives them: n inlier detections each, Gaussian noise of
    ``sigma_px`` per axis around ``shift_px`` (the camera's systematic offset), the noise histogram measured on the
    same detections, every camera's median error and share used alike enough for the relative criteria."""
    rng = np.random.default_rng(seed)
    names = names or [f"00_{k:02d}" for k in range(5)]
    view = np.repeat(np.arange(5), n)
    offset = rng.normal(0.0, sigma_px, (5 * n, 2)) + np.repeat(np.asarray(shift_px, float), n, axis=0)
    residual = np.hypot(offset[:, 0], offset[:, 1])
    a = CameraAgreement.empty(names)
    a.detected[:] = a.used[:] = 100
    a = a.with_verdicts(tally_verdicts(names, view, residual, np.zeros(5 * n, bool), offset))
    noise = rng.normal(0.0, sigma_px, (5, n, 2))
    for v in range(5):
        d = np.hypot(noise[v, :, 0], noise[v, :, 1])
        a.noise[v] += np.bincount((d / NOISE_BIN_PX).astype(np.int64), minlength=a.noise.shape[1])[:a.noise.shape[1]]
    return a


def test_two_of_five_cameras_shifted_are_flagged_and_no_other():
    """bench/camera_flags.py's case: two of five cameras turned by 1 deg put every joint ~16 and ~18 px to one
    side; their median errors (~16-18 px) are under 3 x the cameras' median and none is outvoted, so the relative
    and outvoted criteria flag nobody: the offset flags both, and says where their joints lie."""
    a = tallies([(-16.0, 0.0), (0.0, 18.0), (1.0, 0.5), (-2.0, 1.0), (0.5, -1.5)], sigma_px=6.0)
    report = camera_report(a, HD)
    assert report["flagged"] == ["00_00", "00_01"]
    assert report["notes"][0].startswith("camera 00_00: its joints lie 16 px to the left of where the others")
    assert "18 px down" in report["notes"][1]
    cam = report["cameras"]["00_00"]
    assert abs(cam["median_offset_px"][0] + 16.0) < 0.5 and abs(cam["median_offset_px"][1]) < 0.5
    assert cam["offset_joints"] == 3000 and cam["offset_z"] > 100
    assert report["cameras"]["00_02"]["median_offset_px"] is not None
    # without the image size the offset criterion is not applied: the verdict of the criteria before it (nobody:
    # every median error is under 3 x the cameras' median, nothing outvoted)
    assert camera_report(a)["flagged"] == [] and report["median_reprojection_px"] > 6


def test_a_small_bias_or_a_few_joints_do_not_flag():
    """A 3 px bias over thousands of joints is significant but below the floor (a share of the image diagonal);
    a 14 px bias over a hundred joints of a camera whose noise is ~25 px is above the floor but not significant."""
    report = camera_report(tallies([(3.0, 0.0)] + [(0.0, 0.0)] * 4), HD)
    assert report["flagged"] == [] and report["cameras"]["00_00"]["offset_z"] > 5
    few = tallies([(14.0, 0.0)] + [(0.0, 0.0)] * 4, n=100, sigma_px=6.0)
    few.noise[0] = 0
    few.noise[0, int(29.0 / NOISE_BIN_PX)] = 100  # its measured noise: 29 px median distance, 24.7 px per axis
    report = camera_report(few, HD)
    assert report["flagged"] == [] and report["cameras"]["00_00"]["offset_z"] < 5


def test_the_offset_tally_sums_over_chunks_in_any_order():
    """Each window tallies its own times: the sum over windows is the tally of the whole session."""
    rng = np.random.default_rng(1)
    names = ["a", "b"]
    view = rng.integers(0, 2, 1000)
    offset = rng.normal(0.0, 5.0, (1000, 2))
    offset[::97] = np.nan
    residual = np.hypot(offset[:, 0], offset[:, 1])
    out = rng.random(1000) < 0.1
    whole = tally_verdicts(names, view, residual, out, offset)
    parts = CameraAgreement.empty(names)
    for sl in (slice(600, 1000), slice(0, 250), slice(250, 600)):
        parts.add(tally_verdicts(names, view[sl], residual[sl], out[sl], offset[sl]))
    assert np.array_equal(parts.offset, whole.offset)
    ok = np.isfinite(residual) & ~out
    assert whole.offset[:, 0].sum() == ok.sum()
    med, n = whole.median_offset_px()
    assert np.allclose(med[0], np.median(offset[ok & (view == 0)], axis=0), atol=0.5)


def test_offset_words():
    assert offset_words(np.array([-16.2, 1.0])) == "16 px to the left"
    assert offset_words(np.array([9.0, -9.0])) == "13 px up and to the right"
    assert offset_words(np.array([0.0, 4.0])) == "4 px down"


def test_median_error_histogram_unchanged():
    """The offset tally rides beside the error histogram, which is as before."""
    a = tallies([(0.0, 0.0)] * 5, n=500)
    assert a.hist.sum() == 2500 and np.isfinite(a.median_px()).all()
    assert (a.median_px() < 3 * 3.0 + ERROR_BIN_PX).all()


def _verdicts_from_the_file(report: dict) -> tuple[list[str], dict[str, bool]]:
    """The flags recomputed from cameras.json's figures alone, as written (rounded)."""
    from dome_calib.recon.people.scene_io import MIN_JUDGED, OFFSET_Z, OUTVOTED_LIMIT
    rows = report["cameras"]
    meds = [r["median_reprojection_px"] for r in rows.values() if r["median_reprojection_px"] is not None]
    shares = [r["share_used"] for r in rows.values() if r["share_used"] is not None]
    offset, flagged = {}, []
    for name, r in rows.items():
        offset[name] = bool(r["offset_joints"] >= MIN_JUDGED and r["offset_z"] is not None and r["offset_z"] > OFFSET_Z
                            and r["offset_floor_px"] is not None
                            and float(np.hypot(*r["median_offset_px"])) > r["offset_floor_px"])
        bad = (r["median_reprojection_px"] is not None and r["median_reprojection_px"] > max(3.0 * float(
               np.median(meds)), 5.0)) or (r["share_used"] is not None and r["share_used"] < 0.5 * float(
               np.median(shares))) or (r["joints_judged"] >= MIN_JUDGED and r["outvoted_share"] > OUTVOTED_LIMIT)
        if bad or offset[name]:
            flagged.append(name)
    return flagged, offset


@pytest.mark.parametrize("sigma_px", [2.0, 6.0])
@pytest.mark.parametrize("bias_px", [0.0, 5.2, 5.6, 16.0])
def test_every_flag_follows_from_the_figures_as_written(bias_px, sigma_px):
    """A verdict never rests on more than the file says: the flags recomputed from cameras.json's own (rounded)
    figures are the report's, near the offset floor (7.7 px on a 1920 x 1080 image) and away from it."""
    a = tallies([(bias_px, bias_px), (0.0, 0.0), (1.0, 0.5), (-2.0, 1.0), (0.5, -1.5)], sigma_px=sigma_px)
    report = camera_report(a, HD)
    flagged, offset = _verdicts_from_the_file(report)
    assert flagged == report["flagged"]
    assert offset == {n: r["offset_flagged"] for n, r in report["cameras"].items()}
