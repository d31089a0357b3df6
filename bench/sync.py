"""Benchmark of `timecode sync` on synthetic sessions: every frame's universal-time error against truth.

Run: .venv/bin/python bench/sync.py [--duration 20] [--per-frame]
Prints one JSON object per line: per session and stream the error statistics (and, with --per-frame, every
frame's error in microseconds), the aim (VGA and HD: under 10 us RMS) or, for Kinect streams, the bound the
simulated timestamp jitter sets; and peer figures in the same run, as ratios:
- VGA: our piecewise clock fit vs. a fit-free chain (each VGA frame's own decoded LTC start, HD tick by linear
  interpolation between decoded HD frame starts);
- Kinect: our drift-aware device-clock fit vs. an offset-only device clock (no drift).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from timecode.sync.pipeline import sync_session  # noqa: E402
from timecode.sync.session import load_session  # noqa: E402
from dome_calib.synth.sync_session import SynthSessionOptions, SynthTruth, make_session  # noqa: E402
from timecode.sync.tables import SyncResult, hd_univ_ms  # noqa: E402

AIM_VGA_HD_RMS_US = 10.0


def sessions(duration_s: float) -> dict[str, SynthSessionOptions]:
    return {
        "clean_48k_snr30": SynthSessionOptions(seed=1, duration_s=duration_s, dropped_frames=3),
        "hard_48k_snr10_kinect_snr15_jumps_midnight_df_restart": SynthSessionOptions(
            seed=2, duration_s=duration_s, snr_db=10.0, kinect_snr_db=15.0, vga_start="23:59:50:00",
            hd_start="23:59:50;00", vga_drift_ppm=48.0, hd_drift_ppm=-49.0, vga_jump_at_s=duration_s * 0.3,
            hd_jump_at_s=duration_s * 0.7, restart_at_s=duration_s * 0.5, dropped_frames=4, hd_timecode_every=0,
            n_kinects=3, kinect_missing_audio=("KINECTNODE3",)),
        "kinect_jitter_1ms_44k1": SynthSessionOptions(
            seed=3, duration_s=duration_s, sample_rate=44100, hd_rate="29.97", hd_start="10:00:00:00",
            kinect_frame_jitter_us=1000.0, kinect_block_jitter_us=2000.0),
    }


def _fit_free_vga(result: SyncResult, vga_ticks: np.ndarray) -> np.ndarray:
    """Universal time of VGA ticks with no clock model: own decoded start, HD tick interpolated between frames."""
    v, h = result.vga, result.hd
    pos = np.searchsorted(v.ticks, vga_ticks)
    pos = np.clip(pos, 0, v.ticks.size - 1)
    sample = np.where(v.ticks[pos] == vga_ticks, v.start_samples[pos], np.nan)
    return hd_univ_ms(h, np.interp(sample, h.start_samples, h.ticks.astype(float)))


def _stats(err_us: np.ndarray) -> dict:
    e = err_us[np.isfinite(err_us)]
    return {"err_rms_us": float(np.sqrt(np.mean(e**2))), "err_median_abs_us": float(np.median(np.abs(e))),
            "err_max_abs_us": float(np.max(np.abs(e)))}


def run(name: str, opts: SynthSessionOptions, per_frame: bool) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        truth: SynthTruth = make_session(tmp, opts)
        session = load_session(tmp)
        t0 = time.perf_counter()
        result = sync_session(tmp)
        seconds = time.perf_counter() - t0
    print(json.dumps({"bench": "sync", "session": name, "audio_s": opts.duration_s, "sample_rate": opts.sample_rate,
                      "snr_db": opts.snr_db, "decode_and_fit_s": round(seconds, 2),
                      "vga_events": [e["kind"] for e in result.vga.events],
                      "hd_events": [e["kind"] for e in result.hd.events], "flagged": result.flagged}))
    tables = dict(result.tables.streams)
    tables.update({f"{n}/color": t for n, t in result.tables.kinect_color.items()})
    tables.update({f"{n}/depth": t for n, t in result.tables.kinect_depth.items()})
    for key, table in tables.items():
        if not np.array_equal(table.index, truth.index[key]):
            raise SystemExit(f"{name}/{key}: table indices differ from truth")
        err_us = (table.univ_time_ms - truth.univ_ms[key]) * 1e3
        line = {"bench": "sync", "session": name, "stream": key, "frames": int(err_us.size), **_stats(err_us)}
        if "/" not in key:
            line["aim_rms_us"] = AIM_VGA_HD_RMS_US
            line["meets_aim"] = line["err_rms_us"] < AIM_VGA_HD_RMS_US
            if key == "vga":
                st = session.streams["vga"]
                ticks = st.index - st.ref_index[0] + result.vga.count_to_tick(st.ref_count[0])[0]
                peer = _stats((_fit_free_vga(result, ticks) - truth.univ_ms[key]) * 1e3)
                line["fit_free_err_rms_us"] = peer["err_rms_us"]
                line["ratio_ours_over_fit_free"] = line["err_rms_us"] / peer["err_rms_us"]
        else:
            node = key.split("/")[0]
            jit = truth.jitter_us[key]
            nd = session.kinects[node]
            x = nd.block_device_time_100ns.astype(float)
            fr = getattr(nd, key.split("/")[1]).device_time_100ns.astype(float)
            sb = opts.kinect_block_jitter_us
            var_fit = sb**2 * (1 / x.size + (fr - x.mean()) ** 2 / np.sum((x - x.mean()) ** 2))
            line["frame_jitter_rms_us"] = float(np.sqrt(np.mean(jit**2)))
            line["jitter_bound_rms_us"] = float(np.sqrt(np.mean(jit**2) + np.mean(var_fit)))
            line["meets_aim"] = line["err_rms_us"] < 1.2 * line["jitter_bound_rms_us"]
            kc = result.kinect[node]
            y = hd_univ_ms(result.hd, kc.audio.sample_to_tick(nd.block_first_sample.astype(float)) + kc.tick_offset)
            off = np.median(y - x * 1e-4)  # offset-only peer: the same block times, slope fixed to nominal
            peer = _stats((fr * 1e-4 + off - truth.univ_ms[key]) * 1e3)
            line["offset_only_err_rms_us"] = peer["err_rms_us"]
            line["ratio_ours_over_offset_only"] = line["err_rms_us"] / peer["err_rms_us"]
        if per_frame:
            line["index"] = table.index.tolist()
            line["errors_us"] = [round(float(v), 3) for v in err_us]
        print(json.dumps(line))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of audio per session")
    ap.add_argument("--per-frame", action=argparse.BooleanOptionalAction, default=True,
                    help="print every frame's error (default on)")
    args = ap.parse_args()
    for name, opts in sessions(args.duration).items():
        run(name, opts, args.per_frame)


if __name__ == "__main__":
    main()
