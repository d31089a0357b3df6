"""The optical flow's forward-backward check with ``lk_fb_strict`` (issue 49): the backward flow never starts at its
own answer (the points it must return to), for every caller of ``seed._lk``: it starts at the forward's end moved back by the guess's
displacement, or at the forward's end without a guess; the caller's guess is not written; a point whose true
motion the forward flow gets wrong by several pixels fails the check (a backward flow started at the answer passed
these: it converged there at once)."""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from dome_calib.recon.patches import seed as seed_mod
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.seed import optical_flow

SHIFT = np.array([4.0, -3.0])  # the true motion, px
STRICT = PatchOptions(lk_fb_strict=True)


def _pair() -> tuple[np.ndarray, np.ndarray]:
    """A smooth random texture and the same translated by SHIFT (320 x 240)."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.uniform(0, 255, (240, 320)).astype(np.float32), (0, 0), 2.0)
    base = cv2.normalize(base, None, 20, 235, cv2.NORM_MINMAX)
    M = np.array([[1.0, 0.0, SHIFT[0]], [0.0, 1.0, SHIFT[1]]], np.float32)
    return base.astype(np.uint8), cv2.warpAffine(base, M, (320, 240), flags=cv2.INTER_CUBIC).astype(np.uint8)


P0 = np.stack(np.meshgrid(np.arange(40.0, 290.0, 20.0), np.arange(40.0, 210.0, 20.0)), -1).reshape(-1, 2)


@pytest.mark.parametrize("guess", [None, "prediction", "position"])
def test_the_backward_flow_starts_off_its_answer(monkeypatch, guess):
    """The backward call's initial points: the forward's end (no guess), else the forward's end moved back by the
    guess's displacement; never the points themselves where the forward moved off its start."""
    src, dst = _pair()
    g = {None: None, "prediction": P0 + SHIFT + [0.7, -0.4], "position": P0 + [6.0, 1.0]}[guess]
    calls = []
    real = cv2.calcOpticalFlowPyrLK

    def spy(prev, nxt, pts, init, **kw):
        start = None if init is None else np.array(init, copy=True)
        out = real(prev, nxt, pts, init, **kw)
        calls.append((np.array(pts, copy=True), start, np.array(out[0], copy=True)))
        return out

    monkeypatch.setattr(seed_mod.cv2, "calcOpticalFlowPyrLK", spy)
    q, _ = optical_flow(src, dst, P0, STRICT, guess=g, levels=1)
    (a, _, b), (b_in, start, _) = calls
    assert np.array_equal(b_in, b)
    want = b if g is None else b - (np.float32(g).reshape(-1, 1, 2) - a)
    assert np.array_equal(start, want.astype(np.float32))
    moved = np.linalg.norm((b - (a if g is None else np.float32(g).reshape(-1, 1, 2))).reshape(-1, 2), axis=1) > 0.1
    assert moved.any()
    assert not np.any(np.all(start.reshape(-1, 2)[moved] == a.reshape(-1, 2)[moved], axis=1))


@pytest.mark.parametrize("strict", [False, True])
def test_the_callers_guess_is_not_written(strict):
    """OpenCV writes its result into the initial-flow array: the flow works on a copy."""
    src, dst = _pair()
    g = np.ascontiguousarray(P0 + SHIFT + [1.0, 0.5], dtype=np.float32)
    kept = g.copy()
    optical_flow(src, dst, P0, PatchOptions(lk_fb_strict=strict), guess=g, levels=1, predicted=True)
    assert np.array_equal(g, kept)


@pytest.mark.parametrize("points, guess_error, levels", [
    ([[280.0, 130.0]], None, 0),  # no guess, no pyramid: the forward stops at a wrong minimum
    ([[90.0, 70.0], [160.0, 130.0], [80.0, 170.0], [270.0, 110.0]], [8.0, -5.0], 1),  # a prediction 9.4 px off
])
def test_a_forward_flow_wrong_by_several_px_fails_the_check(points, guess_error, levels):
    """Points whose forward flow ends more than 3 px from their true motion fail the check (the check started at
    the answer passed each of these)."""
    src, dst = _pair()
    p0 = np.array(points)
    g = None if guess_error is None else p0 + SHIFT + guess_error
    q, ok = optical_flow(src, dst, p0, STRICT, guess=g, levels=levels)
    assert np.all(np.linalg.norm(q - p0 - SHIFT, axis=1) > 3.0)
    assert not ok.any()


def test_a_right_flow_passes_the_check():
    """The check is not a rejection of everything: the flow started at the true motion passes it."""
    src, dst = _pair()
    q, ok = optical_flow(src, dst, P0, STRICT, guess=P0 + SHIFT, levels=1)
    assert ok.all() and np.abs(q - P0 - SHIFT).max() < 0.1


def test_the_flow_has_one_place():
    """The rule lives in ``seed._lk``: no other code of the package calls OpenCV's Lucas-Kanade."""
    pkg = Path(seed_mod.__file__).resolve().parents[2]
    calls = {str(p.relative_to(pkg)): len(re.findall(r"calcOpticalFlowPyrLK\(", p.read_text()))
             for p in pkg.rglob("*.py")}
    assert {k: n for k, n in calls.items() if n} == {"recon/patches/seed.py": 2}
