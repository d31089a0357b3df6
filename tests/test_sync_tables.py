"""Universal time of every frame (timecode.sync.tables) against the truth of synthetic sessions.

The decoder is replaced here by the encoder's exact frame starts plus 1 us of noise, so these tests isolate
the clock logic; tests/test_sync_cli.py runs the real decoder end to end.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from timecode.sync.clock import FrameStarts
from timecode.sync.match import frames_at, match_hd_to_kinect
from timecode.sync.session import load_session
from dome_calib.synth.sync_session import SynthSessionOptions, make_session
from timecode.sync.tables import SyncError, SyncOptions, build_sync

VGA_HD_RMS_US = 10.0  # the sync aim: VGA-HD offsets within 10 us RMS
FRAME_NOISE_US = 1.0  # decoder-like timing noise added to the exact frame starts


def _decoded(tmp_path: Path, **kw):
    """A synthetic session, loaded, with decoder-like frame starts of every LTC channel."""
    o = SynthSessionOptions(duration_s=4.0, **kw)
    truth = make_session(tmp_path, o)
    session = load_session(tmp_path)
    rng = np.random.default_rng(7)

    def frames(key: str, rate, fs: float) -> FrameStarts:
        count, start = truth.ltc_frames[key]
        return FrameStarts(count=count, start_samples=start + rng.normal(0, FRAME_NOISE_US * 1e-6 * fs, start.size),
                           sample_rate=fs, fps=rate.fps, frames_per_day=rate.frames_per_day, source=key)

    ltc = session.ltc
    kinect = {n: frames(n, ltc.hd_rate, o.kinect_sample_rate) if n not in o.kinect_missing_audio else "no audio"
              for n in session.kinects}
    return session, truth, frames("vga", ltc.vga_rate, o.sample_rate), frames("hd", ltc.hd_rate, o.sample_rate), kinect


def _run(tmp_path: Path, options: SyncOptions | None = None, **kw):
    session, truth, vga, hd, kinect = _decoded(tmp_path, **kw)
    return build_sync(session, vga, hd, kinect, options), truth


def _errors_us(result, truth) -> dict[str, tuple[float, float]]:
    """Per stream: (RMS error vs truth, RMS of the simulated timestamp jitter), microseconds."""
    tables = dict(result.tables.streams)
    tables.update({f"{n}/color": t for n, t in result.tables.kinect_color.items()})
    tables.update({f"{n}/depth": t for n, t in result.tables.kinect_depth.items()})
    out = {}
    for key, table in tables.items():
        np.testing.assert_array_equal(table.index, truth.index[key])
        err = (table.univ_time_ms - truth.univ_ms[key]) * 1e3
        out[key] = (float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(truth.jitter_us[key] ** 2))))
    return out


def _check_accuracy(result, truth) -> None:
    for key, (rms, jitter) in _errors_us(result, truth).items():
        if "/" in key:  # Kinect: limited by the simulated timestamp jitter (plus the block-fit offset)
            assert rms < 1.3 * jitter + 60.0, key
        else:
            assert rms < VGA_HD_RMS_US, key


def test_clean_session_meets_accuracy_aims(tmp_path):
    result, truth = _run(tmp_path)
    _check_accuracy(result, truth)
    assert result.flagged == {}
    names = [s.name for s in result.summaries]
    assert names[:2] == ["vga", "hd"] and "KINECTNODE2/depth" in names
    vga = result.summaries[0]
    expected = ((1 - 17e-6) / (1 + 23e-6) - 1) * 1e6  # VGA period on the HD timeline, from the simulated drifts
    assert abs(vga.drift_ppm - expected) < 1.0


def test_dropped_frames_keep_their_indices(tmp_path):
    result, truth = _run(tmp_path, dropped_frames=5)
    for key in ("vga", "hd"):
        gaps = np.flatnonzero(np.diff(truth.index[key]) > 1)
        assert gaps.size >= 1
        t = result.tables.streams[key]
        # the frame after a gap is timed as its own index, not as the next in the list
        period_ms = 40.0 if key == "vga" else 1001 / 30
        for g in gaps:
            n_missing = truth.index[key][g + 1] - truth.index[key][g]
            assert abs(t.univ_time_ms[g + 1] - t.univ_time_ms[g] - n_missing * period_ms) < 0.01
    _check_accuracy(result, truth)


def test_vga_timecode_jump(tmp_path):
    result, truth = _run(tmp_path, vga_jump_at_s=2.0, vga_jump_frames=54321)
    assert [e["kind"] for e in result.vga.events] == ["jump"]
    _check_accuracy(result, truth)


def test_hd_timecode_jump_keeps_universal_time_continuous(tmp_path):
    result, truth = _run(tmp_path, hd_jump_at_s=2.0, hd_jump_frames=-40000)
    assert [e["kind"] for e in result.hd.events] == ["jump"]
    assert np.all(np.diff(result.tables.streams["hd"].univ_time_ms) > 0)
    _check_accuracy(result, truth)


def test_midnight_wrap(tmp_path):
    result, truth = _run(tmp_path, vga_start="23:59:58:00", hd_start="23:59:58;00")
    assert [e["kind"] for e in result.hd.events] == ["midnight"]
    hd = result.tables.streams["hd"].univ_time_ms
    assert hd[0] < 86_400_000 < hd[-1]  # universal time runs on past 24 h instead of wrapping
    _check_accuracy(result, truth)


@pytest.mark.parametrize("hd_rate,hd_start", [("29.97df", "10:09:58;00"), ("29.97", "10:09:58:00")])
def test_hd_drop_frame_and_non_drop(tmp_path, hd_rate, hd_start):
    result, truth = _run(tmp_path, hd_rate=hd_rate, hd_start=hd_start)
    assert result.hd.events == []  # 10:10:00 (no drop) and the DF skips at 10:09:59->10:10:00 are continuous
    _check_accuracy(result, truth)


def test_recording_restart(tmp_path):
    result, truth = _run(tmp_path, restart_at_s=1.9)
    assert len(result.vga.audio) == 2 and len(result.hd.audio) == 2
    _check_accuracy(result, truth)


def test_kinect_without_audio_is_flagged_or_an_error(tmp_path):
    result, truth = _run(tmp_path, kinect_missing_audio=("KINECTNODE2",))
    assert list(result.flagged) == ["KINECTNODE2"] and "no audio" in result.flagged["KINECTNODE2"]
    assert "KINECTNODE2" not in result.tables.kinect_color and "KINECTNODE1" in result.tables.kinect_depth
    _check_accuracy(result, truth)
    with pytest.raises(SyncError, match="^KINECTNODE2: no audio"):
        _run(tmp_path / "strict", SyncOptions(strict_kinect=True), kinect_missing_audio=("KINECTNODE2",))


def test_hd_to_kinect_matching_against_truth(tmp_path):
    result, truth = _run(tmp_path)
    hd_idx = truth.index["hd"][10:-10]
    t_hd = truth.univ_ms["hd"][10:-10]
    for node in ("KINECTNODE1", "KINECTNODE2"):
        m = match_hd_to_kinect(result.tables, hd_idx, node)
        for kind, fm in (("color", m.color), ("depth", m.depth)):
            key = f"{node}/{kind}"
            dt_true = truth.univ_ms[key][None, :] - t_hd[:, None]
            best = np.argmin(np.abs(dt_true), axis=1)
            clear = np.sort(np.abs(dt_true), axis=1)[:, 1] - np.abs(dt_true[np.arange(best.size), best]) > 2.0
            # wherever the true nearest frame is not a near tie (2 ms), the tables pick it, and say by how much
            np.testing.assert_array_equal(fm.index[clear], truth.index[key][best][clear])
            pos = np.searchsorted(truth.index[key], fm.index)  # the matched frame's true time difference ...
            dt_matched = truth.univ_ms[key][pos] - t_hd
            assert np.all(np.abs(fm.dt_ms - dt_matched) < 1.0)  # ... is what the API says, within jitter (ms)
            assert fm.within.all()
    with pytest.raises(KeyError, match="KINECTNODE9"):
        match_hd_to_kinect(result.tables, hd_idx, "KINECTNODE9")
    at = frames_at(result.tables, float(truth.univ_ms["vga"][5]))
    assert int(at["vga"].index) == truth.index["vga"][5] and abs(float(at["vga"].dt_ms)) < 0.01


def test_streams_that_do_not_overlap(tmp_path):
    session, truth, vga, hd, kinect = _decoded(tmp_path, n_kinects=1)
    session.streams["vga"].index = session.streams["vga"].index + 25 * 60  # frames a minute after the recording
    with pytest.raises(SyncError, match="^stream vga: no frame within the LTC recording"):
        build_sync(session, vga, hd, kinect)
    session.streams["vga"].index = session.streams["vga"].index - 25 * 60 + 50  # the last 2 s hang over the end
    with pytest.raises(SyncError, match=r"^stream vga: 4\d frames lie up to 1\.\d+ s outside"):
        build_sync(session, vga, hd, kinect, SyncOptions(max_extrapolation_s=0.1))
    kinect["KINECTNODE1"].count[:] = (kinect["KINECTNODE1"].count + 9000) % hd.frames_per_day  # another hour
    result = build_sync(session, vga, hd, kinect)
    assert "do not overlap" in result.flagged["KINECTNODE1"]


def test_kinect_device_clock_reset_splits_the_fit(tmp_path):
    session, truth, vga, hd, kinect = _decoded(tmp_path, n_kinects=1)
    node = session.kinects["KINECTNODE1"]
    reset = node.block_device_time_100ns[node.block_device_time_100ns.size // 2]
    for arr in (node.block_device_time_100ns, node.color.device_time_100ns, node.depth.device_time_100ns):
        arr[arr >= reset] += 47 * 10**7  # the device clock leaps 47 s forward mid-session
    result = build_sync(session, vga, hd, kinect)
    assert len(result.kinect["KINECTNODE1"].device) == 2
    _check_accuracy(result, truth)


def test_kinect_audio_losing_blocks(tmp_path):
    """A Kinect drops 23 audio blocks (368 ms): its LTC fit restarts, the device-time fit runs straight through."""
    result, truth = _run(tmp_path, kinect_audio_gap_at_s=2.0)
    for node in ("KINECTNODE1", "KINECTNODE2"):
        kc = result.kinect[node]
        assert [e["kind"] for e in kc.audio.events] == ["restart"] and len(kc.audio.audio) == 2
        assert len(kc.device) == 1
    _check_accuracy(result, truth)
