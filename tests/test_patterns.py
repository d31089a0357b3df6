"""Projector random patterns: seeded, distinct per projector, full contrast, rich in SIFT features at all scales."""

import cv2
import numpy as np
from hypothesis import given, settings, strategies as st
from typer.testing import CliRunner

from dome_calib.cli import app
from projector.patterns import PatternOptions, make_pattern, make_patterns, pattern_to_uint8

SMALL = PatternOptions(resolution=(640, 400))


def test_seeded_and_distinct():
    a = make_pattern(3, "P1", SMALL)
    assert a.shape == (400, 640) and a.dtype == np.float32
    assert np.array_equal(a, make_pattern(3, "P1", SMALL))
    pats = make_patterns(3, options=SMALL)
    assert sorted(pats) == ["P1", "P2", "P3", "P4", "P5"]
    flat = np.stack([p.ravel() for p in pats.values()])
    corr = np.corrcoef(flat)
    assert np.abs(corr[~np.eye(5, dtype=bool)]).max() < 0.05  # independent patterns
    assert not np.array_equal(a, make_pattern(4, "P1", SMALL))


def test_full_contrast_uniform_histogram():
    img = pattern_to_uint8(make_pattern(0, "P2", SMALL))
    hist = np.bincount(img.ravel(), minlength=256)
    assert img.min() == 0 and img.max() == 255
    assert hist[1:255].min() > 0.5 * hist[1:255].mean()  # ~uniform over 8 bits


def test_multiscale_energy():
    """Band energy in every octave from 4 to 64 px wavelength (not a single-frequency texture)."""
    p = make_pattern(0, "P3", SMALL).astype(float)
    spec = np.abs(np.fft.rfft2(p - p.mean())) ** 2
    fy = np.fft.fftfreq(p.shape[0])[:, None]
    fx = np.fft.rfftfreq(p.shape[1])[None, :]
    f = np.hypot(fx, fy)
    bands = [spec[(f >= 1 / (1.5 * w)) & (f < 1.5 / w)].sum() for w in (4, 8, 16, 32, 64)]
    assert min(bands) > 0.1 * max(bands)


def test_sift_features_at_two_scales():
    img = pattern_to_uint8(make_pattern(0, "P1"))
    sift = cv2.SIFT_create()
    crop = img[200:600, 300:900]
    assert len(sift.detect(crop)) > 3000
    half = cv2.resize(crop, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)  # a camera seeing it smaller
    assert len(sift.detect(half)) > 800


def test_patterns_cli(tmp_path):
    r = CliRunner().invoke(app, ["patterns", str(tmp_path), "--seed", "2", "--width", "320", "--height", "200"])
    assert r.exit_code == 0, r.output
    files = sorted(p.name for p in tmp_path.glob("*.png"))
    assert files == [f"pattern_P{i}.png" for i in range(1, 6)]
    img = cv2.imread(str(tmp_path / "pattern_P1.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (200, 320) and img.dtype == np.uint8
    expected = pattern_to_uint8(make_pattern(2, "P1", PatternOptions(resolution=(320, 200))))
    assert np.array_equal(img, expected)


def test_patterns_cli_bad_size(tmp_path, dome_calib_cli):
    r = dome_calib_cli("patterns", tmp_path, "--width", "10")
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == ["dome-calib: error: pattern size 10x800: expected 64..8192 pixels per side"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from([0.0, -0.0, 1.5, -1.5, 3e-38, -3e-38, np.inf, -np.inf, 7.0]) | st.floats(allow_nan=False, width=32),
                min_size=1, max_size=200), st.integers(0, 2**31))
def test_the_rank_order_is_numpys_stable_argsort(values, seed):
    """The patterns' rank normalisation keeps numpy's stable order exactly: ties (equal values, -0.0 and +0.0)
    by index, infinities and subnormals in place."""
    from projector.patterns import _stable_order

    x = np.asarray(values, np.float32)
    x = np.concatenate([x, np.random.default_rng(seed).permutation(x)])  # every value at least twice: ties
    np.testing.assert_array_equal(_stable_order(x.reshape(2, -1)), np.argsort(x, axis=None, kind="stable"))
