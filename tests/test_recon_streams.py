"""Interpolating 2D tracks of streams with different rates to universal times, and triangulating across them."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from dome_calib.bundle import FRAME_TIME_TOLERANCE_MS, SyncTable
from dome_calib.errors import OptionsError
from dome_calib.recon.errors import ReconError
from dome_calib.recon.project import view_set
from dome_calib.synth.skeleton import MIRROR19, clock_table, skeleton_cm, synthetic_tracks
from dome_calib.recon.streams import (
    InterpolationOptions,
    StreamTracks,
    group_by_stream,
    interpolate_stream,
    stream_of_camera,
    triangulate_streams,
)

from .recon_helpers import real_bundle


def _linear_tracks(table: SyncTable) -> StreamTracks:
    """One camera, one joint moving linearly in the image: u = 100 + 0.5 px/ms * t, v = 200 - 0.25 px/ms * t."""
    t = table.univ_time_ms
    uv = np.stack([100 + 0.5 * t, 200 - 0.25 * t], axis=-1)[:, None, None, :]
    return StreamTracks(stream="hd", table=table, cameras=["00_00"], frame_index=table.index.copy(),
                        uv_px=uv, conf=np.ones((len(t), 1, 1)))


def test_interpolation_is_exact_for_linear_motion_and_empty_outside_the_span():
    table = clock_table(Fraction(30000, 1001), start_ms=0.0, duration_ms=1000.0, offset_ms=7.3)
    tracks = _linear_tracks(table)
    times = np.array([table.univ_time_ms[0] - 1.0, 100.0, 123.456, table.univ_time_ms[5], 990.0,
                      table.univ_time_ms[-1] + 0.5])
    uv, conf = interpolate_stream(tracks, times)
    inside = slice(1, 5)
    np.testing.assert_allclose(uv[inside, 0, 0, 0], 100 + 0.5 * times[inside], atol=1e-9)
    np.testing.assert_allclose(uv[inside, 0, 0, 1], 200 - 0.25 * times[inside], atol=1e-9)
    assert conf[[0, 5], 0, 0].tolist() == [0.0, 0.0] and np.isnan(uv[[0, 5]]).all()


def test_a_time_nanoseconds_off_a_frame_takes_that_frame_alone_next_to_a_missed_detection():
    """A 100 Hz grid hits frame times only up to float rounding (a few ns on a ~1e7 ms timeline): within
    FRAME_TIME_TOLERANCE_MS the frame is taken alone, so a missed detection in the neighbouring frame does not drop
    the joint; beyond the tolerance the neighbour is needed (and the joint is dropped) as before."""
    table = clock_table(Fraction(25), start_ms=36_000_000.0, duration_ms=400.0)
    linear, f = _linear_tracks(table), 4
    conf = linear.conf.copy()
    conf[[f - 1, f + 1]] = np.nan  # missed detections on both sides of frame f
    tracks = StreamTracks(stream="vga", table=table, cameras=linear.cameras, frame_index=linear.frame_index,
                          uv_px=linear.uv_px, conf=conf)
    t_f = table.univ_time_ms[f]
    off_ms = np.array([-3e-6, 3e-6, -0.9 * FRAME_TIME_TOLERANCE_MS, 0.9 * FRAME_TIME_TOLERANCE_MS])
    uv, conf = interpolate_stream(tracks, t_f + off_ms)
    assert conf[:, 0, 0].tolist() == [1.0] * 4
    np.testing.assert_allclose(uv[:, 0, 0, 0], 100 + 0.5 * t_f, atol=1e-9)  # frame f's detection, no blend
    uv, conf = interpolate_stream(tracks, t_f + np.array([-2.0, 2.0]) * FRAME_TIME_TOLERANCE_MS)
    assert conf[:, 0, 0].tolist() == [0.0, 0.0]  # beyond the tolerance the missed neighbour is needed
    # the same at the ends of the table: a few ns outside the span is the end frame, further out is nothing
    i0, i1, w0, w1 = table.bracket(table.univ_time_ms[[0, -1]] + np.array([-3e-6, 3e-6]))
    assert (w0[0], w1[0], i0[0]) == (1.0, 0.0, table.index[0]) and (w0[1], w1[1], i1[1]) == (0.0, 1.0, table.index[-1])
    w = table.bracket(table.univ_time_ms[[0, -1]] + np.array([-2.0, 2.0]) * FRAME_TIME_TOLERANCE_MS)[3]
    assert np.isnan(w).all()


def test_nearest_mode_takes_the_closer_frame():
    table = clock_table(Fraction(25), start_ms=0.0, duration_ms=400.0)
    tracks = _linear_tracks(table)
    t0, t1 = table.univ_time_ms[2], table.univ_time_ms[3]
    times = np.array([t0 + 0.3 * (t1 - t0), t0 + 0.7 * (t1 - t0)])
    uv, conf = interpolate_stream(tracks, times, mode="nearest")
    np.testing.assert_allclose(uv[:, 0, 0, 0], 100 + 0.5 * np.array([t0, t1]), atol=1e-9)
    assert conf[:, 0, 0].tolist() == [1.0, 1.0]
    with pytest.raises(OptionsError, match="max_gap_frames 0.5: expected a finite number >= 1"):
        InterpolationOptions(max_gap_frames=0.5)
    with pytest.raises(ValueError):
        InterpolationOptions(mode="cubic")


def test_dropped_frames_widen_the_gap_and_wide_gaps_are_not_bridged():
    table = clock_table(Fraction(30), start_ms=0.0, duration_ms=1000.0, dropped=[10, 20, 21])
    tracks = _linear_tracks(table)
    period = 1000.0 / 30
    k0 = table.univ_time_ms[0]
    times = np.array([k0 + 10.4 * period, k0 + 20.5 * period])
    uv, conf = interpolate_stream(tracks, times)
    # One dropped frame: bracketed by its neighbours (gap of 2 periods) and still exact for linear motion.
    assert conf[0, 0, 0] == 1.0
    np.testing.assert_allclose(uv[0, 0, 0, 0], 100 + 0.5 * times[0], atol=1e-9)
    # Two dropped frames: a gap of 3 periods is wider than max_gap_frames = 2.5.
    assert conf[1, 0, 0] == 0.0
    uv, conf = interpolate_stream(tracks, times, max_gap_frames=3.5)
    assert conf[1, 0, 0] == 1.0


def test_a_frame_without_detection_is_needed_only_if_it_has_weight():
    table = clock_table(Fraction(25), start_ms=0.0, duration_ms=400.0)
    tracks = _linear_tracks(table)
    tracks.conf[3] = 0.0
    t3, t4 = table.univ_time_ms[3], table.univ_time_ms[4]
    _, conf = interpolate_stream(StreamTracks(stream="hd", table=table, cameras=["00_00"],
                                              frame_index=tracks.frame_index, uv_px=tracks.uv_px, conf=tracks.conf),
                                 np.array([t4, 0.5 * (t3 + t4), t3]))
    assert conf[:, 0, 0].tolist() == [1.0, 0.0, 0.0]


def test_a_stream_holding_no_frame_gives_nothing():
    """A stream whose detections do not reach the times (OpenPose run on part of its frames): no detection, no
    IndexError; the same brackets serve the unlabelled people (recon.people.resample)."""
    table = clock_table(Fraction(25), start_ms=0.0, duration_ms=400.0)
    tracks = _linear_tracks(table)
    none = StreamTracks(stream="hd", table=table, cameras=["00_00"], frame_index=tracks.frame_index[:0],
                        uv_px=tracks.uv_px[:0], conf=tracks.conf[:0])
    uv, conf = interpolate_stream(none, table.univ_time_ms[2:5] + 3.0)
    assert uv.shape == (3, 1, 1, 2) and np.isnan(uv).all() and not conf.any()


def test_streams_of_cameras_and_missing_tables():
    bundle = real_bundle(n_vga=10)
    assert stream_of_camera(bundle, "01_01")[0] == "vga"
    assert stream_of_camera(bundle, "00_05")[0] == "hd"
    assert stream_of_camera(bundle, "50_10")[0] == "KINECTNODE10"
    det = {"00_00": (np.array([120, 121]), np.zeros((2, 19, 2)), np.ones((2, 19))),
           "00_01": (np.array([121, 122]), np.ones((2, 19, 2)), np.ones((2, 19)))}
    (hd,) = group_by_stream(bundle, det)
    assert hd.frame_index.tolist() == [120, 121, 122] and hd.cameras == ["00_00", "00_01"]
    assert hd.conf[:, 0, 0].tolist() == [1.0, 1.0, 0.0] and hd.conf[:, 1, 0].tolist() == [0.0, 1.0, 1.0]
    del bundle.sync.kinect_color["KINECTNODE3"]
    with pytest.raises(ReconError, match="KINECTNODE3.*ksynctables_test.json"):
        stream_of_camera(bundle, "50_03")


def test_all_streams_interpolated_beat_vga_only_and_time_matters():
    bundle = real_bundle(n_vga=60, start_ms=1000.0, duration_ms=1200.0, seed=3)
    views = view_set(bundle)
    tracks = synthetic_tracks(bundle, sorted(bundle.cameras), seed=4)
    vga_times = bundle.sync.streams["vga"].univ_time_ms
    times = vga_times[(vga_times > 1100) & (vga_times < 2100)]
    truth = skeleton_cm(times)
    mpjpe = {}
    for name, streams in (("vga", [s for s in tracks if s.stream == "vga"]), ("all", tracks)):
        seq = triangulate_streams(views, streams, times)
        assert np.isfinite(seq.X_cm).all()
        mpjpe[name] = np.linalg.norm(seq.X_cm - truth, axis=-1).mean() * 10.0
    assert mpjpe["all"] < mpjpe["vga"] < 3.0
    # Nearest frames instead of interpolation: the HD and Kinect cameras see the body up to half a frame late.
    seq = triangulate_streams(views, tracks, times, interpolation=InterpolationOptions(mode="nearest"))
    assert np.linalg.norm(seq.X_cm - truth, axis=-1).mean() * 10.0 > 1.2 * mpjpe["all"]
    # Between VGA frames (HD times) the interpolated streams still reconstruct the moving body.
    hd_times = bundle.sync.streams["hd"].univ_time_ms
    hd_times = hd_times[(hd_times > 1100) & (hd_times < 1500)]
    seq = triangulate_streams(views, tracks, hd_times)
    assert np.linalg.norm(seq.X_cm - skeleton_cm(hd_times), axis=-1).mean() * 10.0 < 3.0
    # A sync table 20 ms off (HD) spoils it: the times really are used.
    hd = next(s for s in tracks if s.stream == "hd")
    hd.table = SyncTable(index=hd.table.index, univ_time_ms=hd.table.univ_time_ms + 20.0)
    seq = triangulate_streams(views, [hd], times[2:-2])
    assert np.linalg.norm(seq.X_cm - truth[2:-2], axis=-1).mean() * 10.0 > 10.0


def test_skeleton_is_a_body():
    X = skeleton_cm(np.linspace(0, 4000, 50))
    assert X.shape == (50, 19, 3)
    assert np.all(X[..., 1] < 0.5) and np.all(X[:, [8, 14], 1] > -30)  # above the floor, ankles near it
    assert np.all(MIRROR19[MIRROR19] == np.arange(19))
    upper_arm = np.linalg.norm(X[:, 4] - X[:, 3], axis=-1)
    assert np.all((upper_arm > 20) & (upper_arm < 45))
