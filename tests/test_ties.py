"""No choice rests on the last bits of a float: every tie-sensitive choice gives the same answer when its
inputs move by 1e-12 (what another CPU's BLAS and SIMD kernels do), and equal-by-design values go by name."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dome_calib.ba.gauge import choose_gauge
from dome_calib.ba.problem import BAProblem
from dome_calib.layout import all_nominal_cameras, nominal_dome, select_preset
from dome_calib.ties import argmax_first, order_by, quantize
from projector.consistency import changed_cameras
from projector.pairs import PairOptions, pairs_from_prior, spread_subset

JITTER = 1e-12  # relative: far above float noise on one machine, far below anything physical


def _jittered(cameras: dict, seed: int) -> dict:
    """Every camera's centre and rotation moved by ~1e-12 relative (random signs), as another CPU might."""
    rng = np.random.default_rng(seed)
    out = {}
    for n, c in cameras.items():
        R = c.R * (1.0 + JITTER * rng.choice([-1.0, 1.0], size=(3, 3)))
        center = c.center_cm * (1.0 + JITTER * rng.choice([-1.0, 1.0], size=3))
        out[n] = dataclasses.replace(c, R=R, t_cm=-R @ center)
    return out


@pytest.fixture(scope="module")
def design():
    return all_nominal_cameras(seed=0)


def test_quantised_order_breaks_equal_values_by_name():
    values = np.array([2.0, 1.0 + 3e-16, 1.0, 1.0 - 2e-16])  # "equal" values, last bits apart
    assert order_by(values, ["d", "c", "b", "a"], 1e-9) == [3, 2, 1, 0]  # a, b, c by name, then d
    assert argmax_first(np.array([1.0, 3.0 - 1e-15, 3.0]), 1e-9) == 1
    assert quantize([0.25, -1.0], 0.5).tolist() == [0, -2]
    with pytest.raises(ValueError):
        quantize([np.nan], 1.0)


@pytest.mark.parametrize("preset", ["tiny", "panel"])
def test_preset_camera_set_survives_last_bit_changes(design, preset):
    expected = select_preset(design, preset)
    for seed in range(8):
        assert select_preset(_jittered(design, seed), preset) == expected


def test_tiny_preset_has_equal_by_design_candidates(design):
    """The guard above means something: the design has distance ties that only the name can break."""
    centre = np.mean([c.center_cm for n, c in design.items() if n.startswith("01_")], axis=0)
    d = np.array([np.linalg.norm(design[f"01_{k:02d}"].center_cm - centre) for k in range(7, 25)])
    q = quantize(d, 1e-4)
    assert len(np.unique(q)) < len(q)  # several outer-ring cameras at one distance


def test_prior_pairs_survive_last_bit_changes():
    cams = nominal_dome("panel", seed=0).cameras  # 60 cameras: prior-based, not exhaustive
    names = sorted(cams)
    options = PairOptions(samples_per_sphere=300)
    expected = pairs_from_prior(cams, names, options)
    assert len(expected) > len(names)
    for seed in range(3):
        assert pairs_from_prior(_jittered(cams, seed), names, options) == expected


def test_spread_subset_survives_last_bit_changes(design):
    names = sorted(n for n in design if n.startswith(("01_", "02_", "03_")))
    expected = spread_subset(design, names, 10)
    for seed in range(8):
        assert spread_subset(_jittered(design, seed), names, 10) == expected


def test_changed_cameras_does_not_depend_on_input_order():
    """Equal bad-pair fractions: the verdict goes by name, not by the order pairs arrived in."""
    errors = {("a", "b"): 5.0, ("a", "c"): 0.1, ("b", "c"): 0.1, ("c", "d"): 0.1, ("b", "d"): 0.1}
    forward = changed_cameras(errors, bad_px=1.0)
    backward = changed_cameras(dict(reversed(list(errors.items()))), bad_px=1.0)
    assert list(forward.changed) == list(backward.changed)


def test_gauge_choice_survives_last_bit_changes():
    cams = nominal_dome("tiny", seed=0).cameras
    rng = np.random.default_rng(0)
    X = rng.normal([0.0, -95.0, 0.0], 30.0, size=(50, 3))
    names = sorted(cams)
    cam_index = np.repeat(np.arange(len(names)), len(X))
    point_index = np.tile(np.arange(len(X)), len(names))
    uv = np.zeros((len(cam_index), 2))

    def gauge_of(cameras):
        problem = BAProblem.from_cameras(cameras, {"scene_01": X}, camera_index=cam_index, point_index=point_index,
                                         uv_px=uv, camera_names=names)
        g = choose_gauge(problem)
        return g.reference_camera, g.scale_camera, g.scale_component

    expected = gauge_of(cams)
    for seed in range(4):
        assert gauge_of(_jittered(cams, seed)) == expected
