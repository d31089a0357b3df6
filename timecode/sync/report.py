"""The sync report (``report/sync.json`` of a bundle) and the per-stream summary the CLI prints."""
from __future__ import annotations

from timecode.sync.clock import AudioSegment, ChannelClock, LineFit
from timecode.sync.tables import SyncResult, pair_models

UNIVERSAL_TIME = ("milliseconds on the HD LTC timeline: (label count of the first locked HD LTC frame + HD clock "
                  "frames since) * 1000 / hd_fps; continues through timecode jumps and past midnight")


def _segment(seg: AudioSegment, clock: ChannelClock) -> dict:
    nominal = clock.sample_rate / float(clock.fps)
    us = 1e6 / clock.sample_rate
    return {"tick_first": seg.tick_first, "tick_last": seg.tick_last, "sample_first": seg.sample_first,
            "sample_last": seg.sample_last, "samples_per_frame": seg.samples_per_tick,
            "drift_ppm_vs_audio": (seg.samples_per_tick / nominal - 1) * 1e6, "n_frames": seg.fit.n_points,
            "n_outliers": seg.fit.n_outliers, "residual_rms_us": seg.fit.residual_rms * us,
            "residual_max_us": seg.fit.residual_max * us}


def channel_report(clock: ChannelClock) -> dict:
    """One LTC channel: decoded frames, misreads, outliers, drift against its audio clock, fits per segment."""
    return {"source": clock.source, "fps": str(clock.fps), "sample_rate": clock.sample_rate,
            "n_decoded": clock.n_decoded, "n_misread": clock.n_misread, "n_outliers": clock.n_outliers,
            "drift_ppm_vs_audio": clock.drift_ppm, "residual_rms_us": clock.residual_rms_us,
            "events": sorted(clock.events, key=lambda e: e["tick"]),
            "label_segments": [{"count_first": s.count_first, "tick_first": s.tick_first, "tick_last": s.tick_last}
                               for s in clock.labels],
            "segments": [_segment(s, clock) for s in clock.audio]}


def _device(fit: LineFit, span: tuple[int, int]) -> dict:
    return {"device_time_first_100ns": span[0], "device_time_last_100ns": span[1], "univ_ms_at_ref": fit.y_ref,
            "device_time_ref_100ns": fit.x_ref, "ms_per_100ns": fit.slope, "drift_ppm": (fit.slope / 1e-4 - 1) * 1e6,
            "n_blocks": fit.n_points, "n_outliers": fit.n_outliers, "residual_rms_us": fit.residual_rms * 1e3,
            "residual_max_us": fit.residual_max * 1e3}


def sync_report(result: SyncResult) -> dict:
    """Everything about the fits, JSON-ready: channels, VGA-HD pair models, Kinect device clocks, streams."""
    kinect: dict[str, dict] = {}
    for name, kc in result.kinect.items():
        kinect[name] = {"status": "synced", "audio": channel_report(kc.audio), "hd_tick_offset": kc.tick_offset,
                        "device_clock": [_device(f, s) for f, s in zip(kc.device, kc.spans)]}
    for name, why in result.flagged.items():
        kinect[name] = {"status": "not synced", "reason": why}
    return {
        "seq": result.seq,
        "universal_time": UNIVERSAL_TIME,
        "drift_convention": "drift_ppm = (measured frame period / nominal period - 1) * 1e6 on the reference clock",
        "channels": {"vga": channel_report(result.vga), "hd": channel_report(result.hd)},
        "vga_on_universal_time": pair_models(result.vga, result.hd),
        "kinect": kinect,
        "streams": {s.name: {"n_frames": s.n_frames, "first_ms": s.first_ms, "last_ms": s.last_ms,
                             "drift_ppm": s.drift_ppm, "residual_rms_us": s.residual_rms_us,
                             "n_outliers": s.n_outliers} for s in result.summaries},
        "notes": result.notes,
    }


def summary_lines(result: SyncResult) -> list[str]:
    """A fixed-width table a technician reads: per stream frames, span, drift, residual RMS; then problems."""
    lines = [f"{'stream':<20} {'frames':>7} {'first (ms)':>14} {'span (s)':>9} {'drift ppm':>10} {'resid RMS us':>13}"]
    for s in result.summaries:
        lines.append(f"{s.name:<20} {s.n_frames:>7d} {s.first_ms:>14.3f} {(s.last_ms - s.first_ms) / 1e3:>9.3f} "
                     f"{s.drift_ppm:>10.2f} {s.residual_rms_us:>13.2f}")
    for clock in (result.vga, result.hd):
        for e in sorted(clock.events, key=lambda e: e["tick"]):
            doubt = " (labels jump there too: later times rest on them)" if e.get("doubtful") else ""
            lines.append(f"note: {clock.source}: {e['kind']} at sample {e['sample']:.0f}{doubt}")
        if clock.n_misread or clock.n_outliers:
            lines.append(f"note: {clock.source}: {clock.n_misread} misread frames dropped, "
                         f"{clock.n_outliers} outliers rejected")
    lines += [f"note: {n}" for n in result.notes]
    for name, why in result.flagged.items():
        lines.append(f"NOT SYNCED: {name}: {why}")
    return lines
