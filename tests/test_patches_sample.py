"""The patch stage's bilinear sampler (:func:`dome_calib.recon.patches.frames.sample`) against the plain remap of
one interleaved float32 map: the same bits for every shape, dtype and tail (issue 49, branch speed49)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from dome_calib.recon.patches import frames
from dome_calib.recon.patches.frames import sample, sample_windows


def remapped(gray: np.ndarray, uv_px: np.ndarray) -> np.ndarray:
    """The one-map rule: pixels cast to float32, padded outside the image to whole rows of the map."""
    uv = np.asarray(uv_px).astype(np.float32).reshape(-1, 2)
    n = len(uv)
    cols = min(n, frames._REMAP_COLS)
    rows = -(-n // cols)
    maps = np.full((rows * cols, 2), -100.0, np.float32)
    maps[:n] = uv
    maps = maps.reshape(rows, cols, 2)
    out = cv2.remap(gray, np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1]), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(-1)[:n].astype(np.float32).reshape(np.shape(uv_px)[:-1])


@pytest.mark.parametrize("shape", [(1, 2), (7, 49, 2), (4096, 2), (4097, 2), (3, 50, 49, 2)])
@pytest.mark.parametrize("image_dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("pixel_dtype", [np.float64, np.float32])
def test_sample_is_the_one_map_remap_bit_for_bit(shape, image_dtype, pixel_dtype):
    rng = np.random.default_rng(sum(shape))
    gray = cv2.GaussianBlur((rng.random((48, 64)) * 255).astype(np.float32), (0, 0), 1.0).astype(image_dtype)
    uv = rng.uniform(-3.0, 66.0, shape).astype(pixel_dtype)  # some outside the image: 0 there
    uv[..., 1] *= 0.75
    got = sample(gray, uv)
    want = remapped(gray, uv)
    assert got.dtype == np.float32 and got.shape == shape[:-1]
    assert np.array_equal(got, want)
    if got.size >= 49:  # the draw reaches both inside and outside the image
        assert np.any(got == 0.0) and np.any(got > 0.0)


def test_sample_of_no_points_is_empty():
    assert sample(np.zeros((4, 4), np.uint8), np.zeros((0, 49, 2))).shape == (0, 49)


@pytest.mark.parametrize("shape", [(1, 2), (48, 355, 2), (5, 2)])
def test_sample_windows_is_sample_of_the_summed_pixels(shape):
    rng = np.random.default_rng(len(shape))
    gray = (rng.random((48, 64)) * 255).astype(np.uint8)
    centres = rng.uniform(-5.0, 68.0, shape)
    centres[..., 1] *= 0.75
    centres[rng.random(shape[:-1]) < 0.2] = -100.0  # the sweep's depths outside a neighbour's image
    half = 3
    off = np.stack(np.meshgrid(np.arange(-half, half + 1), np.arange(-half, half + 1)), -1).reshape(-1, 2)
    got = sample_windows(gray, centres, off)
    assert got.shape == shape[:-1] + (len(off),) and got.dtype == np.float32
    assert np.array_equal(got, sample(gray, centres[..., None, :] + off))
