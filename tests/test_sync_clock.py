"""Clock models from LTC frame starts (timecode.sync.clock), on small synthetic arrays with known truth."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from timecode.labels import label_to_frames
from timecode.rates import RATE_25, RATE_29_97_DF
from timecode.sync.clock import ClockError, ClockFitOptions, FrameStarts, fit_channel_clock, restarts_of, robust_line

FS = 48000.0
NOISE_SAMPLES = 0.05  # ~1 us at 48 kHz, what the sub-sample decoder achieves


def _frames(n: int, *, rate=RATE_25, start="10:00:00:00", drift_ppm=30.0, offset=1234.5, seed=0) -> dict:
    rng = np.random.default_rng(seed)
    ticks = np.arange(n)
    period = FS / float(rate.fps) / (1 + drift_ppm * 1e-6)
    start_samples = offset + ticks * period + rng.normal(0, NOISE_SAMPLES, n)
    count = (label_to_frames(start, rate) + ticks) % rate.frames_per_day
    return {"ticks": ticks, "count": count, "start_samples": start_samples, "rate": rate, "period": period,
            "offset": offset}


def _fs(d: dict, keep=None) -> FrameStarts:
    keep = np.ones(d["count"].size, bool) if keep is None else keep
    return FrameStarts(count=d["count"][keep], start_samples=d["start_samples"][keep], sample_rate=FS,
                       fps=d["rate"].fps, frames_per_day=d["rate"].frames_per_day, source="test channel")


def test_robust_line_rejects_and_counts_outliers():
    rng = np.random.default_rng(1)
    x = np.arange(200.0)
    y = 3.0 + 0.5 * x + rng.normal(0, 0.01, x.size)
    y[[7, 50, 120]] += [5.0, -3.0, 1.0]
    fit = robust_line(x, y, sigma=6.0, floor=0.05)
    assert fit.n_outliers == 3 and not fit.inliers[[7, 50, 120]].any()
    assert abs(fit.slope - 0.5) < 1e-4 and abs(fit(0.0) - 3.0) < 0.01
    assert fit.residual_rms < 0.015


def test_clean_clock_fit_recovers_drift_and_offset():
    d = _frames(300, drift_ppm=-42.0)
    clock = fit_channel_clock(_fs(d))
    assert clock.events == [] and clock.n_misread == 0 and clock.n_outliers == 0
    assert abs(clock.drift_ppm - (1 / (1 - 42e-6) - 1) * 1e6) < 0.5  # ppm
    err_us = (clock.tick_to_sample(d["ticks"]) - (d["offset"] + d["ticks"] * d["period"])) / FS * 1e6
    assert np.sqrt(np.mean(err_us**2)) < 0.3  # the fit averages the 1 us frame noise
    assert 0.7 < clock.residual_rms_us < 1.4


def test_timecode_jump_keeps_ticks_running():
    d = _frames(400)
    d["count"][250:] = (d["count"][250:] + 7777) % RATE_25.frames_per_day  # generator re-jammed
    clock = fit_channel_clock(_fs(d))
    assert [e["kind"] for e in clock.events] == ["jump"] and clock.events[0]["tick"] == 250
    assert len(clock.labels) == 2 and len(clock.audio) == 1  # labels split, audio continuous
    np.testing.assert_array_equal(clock.ticks, d["ticks"])
    ticks, found = clock.count_to_tick(d["count"][[0, 249, 250, 399]])
    assert found.all() and ticks.tolist() == [0, 249, 250, 399]


def test_missing_and_misread_frames():
    d = _frames(300)
    keep = np.ones(300, bool)
    keep[[20, 21, 22, 150]] = False  # decoder lost these frames
    d["count"][100] = 12345  # a misread label: rejected, not taken for two jumps
    clock = fit_channel_clock(_fs(d, keep))
    assert clock.events == [] and clock.n_misread == 1
    assert 100 not in clock.ticks and 150 not in clock.ticks and 299 in clock.ticks


def test_midnight_wrap_is_not_a_jump():
    d = _frames(200, start="23:59:58:00")
    clock = fit_channel_clock(_fs(d))
    assert [e["kind"] for e in clock.events] == ["midnight"] and clock.events[0]["tick"] == 50
    assert len(clock.labels) == 1
    ticks, found = clock.count_to_tick(np.array([label_to_frames("23:59:59:24", RATE_25),
                                                 label_to_frames("00:00:00:00", RATE_25)]))
    assert found.all() and ticks.tolist() == [49, 50]


def test_drop_frame_minute_boundary_is_continuous():
    d = _frames(200, rate=RATE_29_97_DF, start="10:00:59;00")  # 10:01:00;00 and ;01 do not exist
    clock = fit_channel_clock(_fs(d))
    assert clock.events == [] and len(clock.labels) == 1
    t, found = clock.count_to_tick(label_to_frames("10:01:00;02", RATE_29_97_DF))
    assert found and int(t) == 30  # 30 frames after 10:00:59;00
    assert abs(float(clock.fps) - 30000 / 1001) < 1e-12


def test_recording_restart_bridged_by_labels():
    d = _frames(400)
    cut = 2 * 1920 * 50 + 777.25  # ~0.41 s of audio lost mid-frame after tick ~200
    lost = (d["start_samples"] > 200 * 1920) & (d["start_samples"] < 200 * 1920 + cut)
    d["start_samples"] = np.where(d["start_samples"] >= 200 * 1920 + cut, d["start_samples"] - cut, d["start_samples"])
    clock = fit_channel_clock(_fs(d, ~lost))
    assert [e["kind"] for e in clock.events] == ["restart"] and len(clock.audio) == 2
    np.testing.assert_array_equal(clock.ticks, d["ticks"][~lost])  # ticks bridged by the labels
    assert len(restarts_of(clock)) == 1
    for seg in clock.audio:  # each side keeps sub-microsecond timing
        assert seg.fit.residual_rms / FS * 1e6 < 1.5


def test_no_frames_and_never_locks_are_one_line_errors():
    empty = FrameStarts(count=np.zeros(0, np.int64), start_samples=np.zeros(0), sample_rate=FS, fps=Fraction(25),
                        frames_per_day=RATE_25.frames_per_day, source="ltc.wav channel 0 (VGA LTC)")
    with pytest.raises(ClockError, match=r"^ltc.wav channel 0 \(VGA LTC\): no LTC frames decoded"):
        fit_channel_clock(empty)
    d = _frames(60, seed=3)
    d["count"] = np.random.default_rng(3).integers(0, 10**6, 60)  # garbage labels: nothing consistent
    with pytest.raises(ClockError, match="never locks"):
        fit_channel_clock(_fs(d))


def test_splice_of_whole_frames_in_both_channels_is_a_restart():
    """Cutting exactly 10 frames out of a stereo recording looks like a label jump on each channel; seen at the same
    place on both channels it is a splice: ticks are bridged by the labels (10 frames), not by the audio (0)."""
    from timecode.sync.tables import fit_ltc_pair

    chans = []
    for seed, offset in ((0, 1234.5), (1, 777.25)):
        d = _frames(300, offset=offset, drift_ppm=0.0, seed=seed)
        cut = 150 * 1920 + 500.0
        lost = (d["start_samples"] > cut - 1920) & (d["start_samples"] < cut + 10 * 1920)
        d["start_samples"] = np.where(d["start_samples"] >= cut, d["start_samples"] - 10 * 1920, d["start_samples"])
        chans.append((d, _fs(d, ~lost)))
    alone = fit_channel_clock(chans[0][1])
    assert [e["kind"] for e in alone.events] == ["jump"]  # one channel alone cannot tell
    vga, hd = fit_ltc_pair(chans[0][1], chans[1][1], ClockFitOptions())
    for clock, (d, fs) in zip((vga, hd), chans):
        assert [e["kind"] for e in clock.events] == ["restart"] and len(clock.audio) == 2
        np.testing.assert_array_equal(clock.ticks, d["ticks"][np.isin(d["count"], fs.count)])


def test_the_line_is_the_exact_least_squares_line_without_lapack(monkeypatch):
    """A Kinect's device clock (x in 100 ns ~1e10, y in ms ~3.6e7) over 2 s to 40 s: the slope within 1e-15 of the
    least-squares slope in exact rational arithmetic, in means and sums only (the same bits on every CPU).
    np.linalg.lstsq (LAPACK) was 1.8e-12 off here, and its bits changed with OpenBLAS's kernels."""
    for name in ("lstsq", "solve", "svd", "pinv", "inv", "qr"):
        monkeypatch.setattr(np.linalg, name, lambda *a, **k: pytest.fail("LAPACK in a clock fit"))
    rng = np.random.default_rng(0)
    for trial in range(20):
        x = np.sort(rng.uniform(1e10, 1e10 + 2e7 * (trial + 1), 60)).round()
        y = 3.6e7 + 1.0000116e-4 * (x - x[0]) + rng.normal(scale=0.3, size=60)
        fit = robust_line(x, y, sigma=1e9, floor=1e9)  # no outliers: the plain least-squares line
        xs = [Fraction(v) - Fraction(fit.x_ref) for v in x]
        ys = [Fraction(v) for v in y]
        mx, my = sum(xs) / 60, sum(ys) / 60
        slope = sum((a - mx) * (b - my) for a, b in zip(xs, ys)) / sum((a - mx) ** 2 for a in xs)
        assert abs(Fraction(fit.slope) / slope - 1) < Fraction(1, 10**15)
        assert abs(Fraction(fit.y_ref) - (my - slope * mx)) < Fraction(1, 10**6)  # ms: 1 ns (the ulp at 3.6e7 is 7e-9)
