"""Decoded frames as a table for people, CSV or JSON (what ``timecode decode`` prints).

Columns: ``channel`` (0 = first), ``label`` (HH:MM:SS:FF, ``;`` before the frames in drop-frame),
``dir`` (fwd/rev), ``start_samples`` and ``end_samples`` (sub-sample time of the edges opening bit 0 and
closing bit 79, samples from the start of the file), ``start_s`` (start / sample rate), ``user_bits``
(8 hex digits, user group 8 first), ``flags`` (DF drop frame, CF colour frame, B0/B1/B2 binary group flags,
P! polarity bit wrong), ``level_dbfs``, ``jitter_us`` (RMS of edge times around the local bit clock;
small = clean), ``disc`` (``*``: the label does not follow the previous frame: start, jump or re-jam).
"""
from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from enum import StrEnum

import numpy as np

from timecode.result import ChannelDecode


class OutputFormat(StrEnum):
    TABLE = "table"
    CSV = "csv"
    JSON = "json"


COLUMNS = ("channel", "label", "frame_number", "direction", "start_samples", "end_samples", "start_s",
           "user_bits", "drop_frame", "color_frame", "bgf0", "bgf1", "bgf2", "parity_ok", "level_dbfs",
           "jitter_us", "discontinuity")


def _rows(ch: ChannelDecode) -> list[dict]:
    labels = ch.label_strings()
    fs = float(ch.sample_rate)
    out = []
    for i in range(len(ch)):
        out.append({
            "channel": ch.channel, "label": labels[i], "frame_number": int(ch.frame_numbers[i]),
            "direction": "reverse" if ch.reverse[i] else "forward",
            "start_samples": round(float(ch.start_samples[i]), 4), "end_samples": round(float(ch.end_samples[i]), 4),
            "start_s": round(float(ch.start_samples[i]) / fs, 9), "user_bits": f"{int(ch.user_bits[i]):08x}",
            "drop_frame": bool(ch.drop_frame[i]), "color_frame": bool(ch.color_frame[i]),
            "bgf0": bool(ch.bgf[i, 0]), "bgf1": bool(ch.bgf[i, 1]), "bgf2": bool(ch.bgf[i, 2]),
            "parity_ok": bool(ch.parity_ok[i]), "level_dbfs": round(float(ch.level_dbfs[i]), 2),
            "jitter_us": None if np.isnan(ch.jitter_us[i]) else round(float(ch.jitter_us[i]), 3),
            "discontinuity": bool(ch.discontinuity[i]),
        })
    return out


def channel_summary(ch: ChannelDecode) -> str:
    """One line per channel: rate, frame count, first/last label, rejected frames, AC coupling."""
    if len(ch) == 0:
        return f"channel {ch.channel}: no LTC frames ({ch.n_edges} transitions, {ch.n_rejected} rejected frames)"
    labels = ch.label_strings()
    n_disc = int(ch.discontinuity.sum())
    rev = int(ch.reverse.sum())
    extra = []
    if rev:
        extra.append(f"{rev} reverse")
    if ch.n_rejected:
        extra.append(f"{ch.n_rejected} rejected")
    if ch.ac_coupling_hz:
        extra.append(f"AC coupling ~{ch.ac_coupling_hz:.0f} Hz undone")
    tail = f", {', '.join(extra)}" if extra else ""
    return (f"channel {ch.channel}: {ch.rate} fps, {len(ch)} frames {labels[0]} .. {labels[-1]}, "
            f"{n_disc} segment(s), median jitter {np.nanmedian(ch.jitter_us):.2f} us{tail}")


def format_table(channels: Sequence[ChannelDecode]) -> str:
    """Fixed-width table with a summary line per channel."""
    lines = []
    head = (f"{'ch':>2} {'label':<11} {'dir':<3} {'start_samples':>16} {'end_samples':>16} {'start_s':>12} "
            f"{'user_bits':<8} {'flags':<12} {'dBFS':>6} {'jit_us':>7} disc")
    for ch in channels:
        lines.append(f"# {channel_summary(ch)}")
    lines.append(head)
    for ch in channels:
        for r in _rows(ch):
            flags = " ".join(n for n, on in (("DF", r["drop_frame"]), ("CF", r["color_frame"]), ("B0", r["bgf0"]),
                                             ("B1", r["bgf1"]), ("B2", r["bgf2"]), ("P!", not r["parity_ok"])) if on)
            jit = "-" if r["jitter_us"] is None else f"{r['jitter_us']:.2f}"
            lines.append(
                f"{r['channel']:>2} {r['label']:<11} {'rev' if r['direction'] == 'reverse' else 'fwd':<3} "
                f"{r['start_samples']:>16.4f} {r['end_samples']:>16.4f} {r['start_s']:>12.6f} {r['user_bits']:<8} "
                f"{flags or '-':<12} {r['level_dbfs']:>6.1f} {jit:>7} {'*' if r['discontinuity'] else ''}")
    return "\n".join(lines) + "\n"


def format_csv(channels: Sequence[ChannelDecode]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for ch in channels:
        w.writerows(_rows(ch))
    return buf.getvalue()


def format_json(channels: Sequence[ChannelDecode], source: str) -> str:
    doc = {
        "file": source,
        "time_convention": "start_samples/end_samples: sub-sample time of the edge opening bit 0 / closing bit 79, "
                           "in samples from the first sample of the file (0.0 = first sample)",
        "channels": [{
            "channel": ch.channel, "sample_rate": ch.sample_rate, "rate": str(ch.rate) if ch.rate else None,
            "fps": f"{ch.rate.fps.numerator}/{ch.rate.fps.denominator}" if ch.rate else None,
            "n_frames": len(ch), "n_rejected": ch.n_rejected, "ac_coupling_hz": round(ch.ac_coupling_hz, 2),
            "frames": [{k: v for k, v in r.items() if k != "channel"} for r in _rows(ch)],
        } for ch in channels],
    }
    return json.dumps(doc, indent=1) + "\n"


def render(channels: Sequence[ChannelDecode], fmt: OutputFormat, source: str) -> str:
    if fmt == OutputFormat.CSV:
        return format_csv(channels)
    if fmt == OutputFormat.JSON:
        return format_json(channels, source)
    return format_table(channels)
