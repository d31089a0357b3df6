"""Decoded frames as a table for people, CSV or JSON (what ``timecode decode`` prints), for one file or many.

Columns: ``file`` (the audio file), ``channel`` (0 = first), ``label`` (HH:MM:SS:FF, ``;`` before the frames in
drop-frame), ``dir`` (fwd/rev), ``start_samples`` and ``end_samples`` (sub-sample time of the edges opening bit 0
and closing bit 79, samples from the start of the file), ``start_s`` (start / sample rate), ``user_bits``
(8 hex digits, user group 8 first), ``flags`` (DF drop frame, CF colour frame, B0/B1/B2 binary group flags,
P! polarity bit wrong, IMP read from an impulse train, XS/XE start/end edge extrapolated), ``level_dbfs``,
``jitter_us`` (RMS of edge times around the local bit clock; small = clean), ``disc`` (``*``: the label does not
follow the previous frame: start, jump or re-jam), ``reading`` (square or impulses), ``extrapolated`` (start,
end or empty: which edge is not in the audio), ``bits_missing`` (bits of a frame cut by the file's start or end).
"""
from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from enum import StrEnum

import numpy as np

from timecode.decode.result import EXTRAPOLATED, ChannelDecode

#: One decoded file: its name as given and its channels.
FileDecode = tuple[str, Sequence[ChannelDecode]]


class OutputFormat(StrEnum):
    TABLE = "table"
    CSV = "csv"
    JSON = "json"


COLUMNS = ("file", "channel", "label", "frame_number", "direction", "start_samples", "end_samples", "start_s",
           "user_bits", "drop_frame", "color_frame", "bgf0", "bgf1", "bgf2", "parity_ok", "level_dbfs",
           "jitter_us", "discontinuity", "reading", "extrapolated", "bits_missing")


def _rows(ch: ChannelDecode, source: str) -> list[dict]:
    labels = ch.label_strings()
    fs = float(ch.sample_rate)
    out = []
    for i in range(len(ch)):
        out.append({
            "file": source, "channel": ch.channel, "label": labels[i], "frame_number": int(ch.frame_numbers[i]),
            "direction": "reverse" if ch.reverse[i] else "forward",
            "start_samples": round(float(ch.start_samples[i]), 4), "end_samples": round(float(ch.end_samples[i]), 4),
            "start_s": round(float(ch.start_samples[i]) / fs, 9), "user_bits": f"{int(ch.user_bits[i]):08x}",
            "drop_frame": bool(ch.drop_frame[i]), "color_frame": bool(ch.color_frame[i]),
            "bgf0": bool(ch.bgf[i, 0]), "bgf1": bool(ch.bgf[i, 1]), "bgf2": bool(ch.bgf[i, 2]),
            "parity_ok": bool(ch.parity_ok[i]), "level_dbfs": round(float(ch.level_dbfs[i]), 2),
            "jitter_us": None if np.isnan(ch.jitter_us[i]) else round(float(ch.jitter_us[i]), 3),
            "discontinuity": bool(ch.discontinuity[i]), "reading": "impulses" if ch.impulses[i] else "square",
            "extrapolated": EXTRAPOLATED[int(ch.extrapolated[i])].value, "bits_missing": int(ch.bits_missing[i]),
        })
    return out


def channel_summary(ch: ChannelDecode) -> str:
    """One line per channel: rate, frame count, first/last label, rejected frames, AC coupling, impulses, edge
    frames, NaN samples."""
    gaps = f", {ch.n_nonfinite} NaN/inf samples read as gaps" if ch.n_nonfinite else ""
    if len(ch) == 0:
        return (f"channel {ch.channel}: no LTC frames ({ch.n_edges} transitions, {ch.n_rejected} rejected "
                f"frames{gaps})")
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
    n_imp = int(ch.impulses.sum())
    if n_imp:
        extra.append(f"{n_imp} read from impulses (input time constant {ch.impulse_tau_samples:.2f} samples)")
    n_x = int((ch.extrapolated > 0).sum())
    if n_x:
        extra.append(f"{n_x} with an edge extrapolated")
    tail = f", {', '.join(extra)}" if extra else ""
    return (f"channel {ch.channel}: {ch.rate} fps, {len(ch)} frames {labels[0]} .. {labels[-1]}, "
            f"{n_disc} segment(s), median jitter {np.nanmedian(ch.jitter_us):.2f} us{tail}{gaps}")


def _flags(r: dict) -> str:
    return " ".join(n for n, on in (("DF", r["drop_frame"]), ("CF", r["color_frame"]), ("B0", r["bgf0"]),
                                    ("B1", r["bgf1"]), ("B2", r["bgf2"]), ("P!", not r["parity_ok"]),
                                    ("IMP", r["reading"] == "impulses"),
                                    ("XS", r["extrapolated"] in ("start", "both")),
                                    ("XE", r["extrapolated"] in ("end", "both"))) if on)


def format_table(files: Sequence[FileDecode]) -> str:
    """Fixed-width table with a summary line per channel (and a ``# file`` line per file when there are many)."""
    lines = []
    head = (f"{'ch':>2} {'label':<11} {'dir':<3} {'start_samples':>16} {'end_samples':>16} {'start_s':>12} "
            f"{'user_bits':<8} {'flags':<12} {'dBFS':>6} {'jit_us':>7} disc")
    for source, channels in files:
        if len(files) > 1:
            lines.append(f"# file {source}")
        for ch in channels:
            lines.append(f"# {channel_summary(ch)}")
        lines.append(head)
        for ch in channels:
            for r in _rows(ch, source):
                jit = "-" if r["jitter_us"] is None else f"{r['jitter_us']:.2f}"
                lines.append(
                    f"{r['channel']:>2} {r['label']:<11} {'rev' if r['direction'] == 'reverse' else 'fwd':<3} "
                    f"{r['start_samples']:>16.4f} {r['end_samples']:>16.4f} {r['start_s']:>12.6f} "
                    f"{r['user_bits']:<8} {_flags(r) or '-':<12} {r['level_dbfs']:>6.1f} {jit:>7} "
                    f"{'*' if r['discontinuity'] else ''}")
    return "\n".join(lines) + "\n"


def format_csv(files: Sequence[FileDecode]) -> str:
    """One row per frame of every file and channel, with a ``file`` column."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for source, channels in files:
        for ch in channels:
            w.writerows(_rows(ch, source))
    return buf.getvalue()


def _file_doc(source: str, channels: Sequence[ChannelDecode]) -> dict:
    return {"file": source, "channels": [{
        "channel": ch.channel, "sample_rate": ch.sample_rate, "rate": str(ch.rate) if ch.rate else None,
        "fps": f"{ch.rate.fps.numerator}/{ch.rate.fps.denominator}" if ch.rate else None,
        "n_frames": len(ch), "n_rejected": ch.n_rejected, "ac_coupling_hz": round(ch.ac_coupling_hz, 2),
        "impulse_tau_samples": round(ch.impulse_tau_samples, 3), "n_nonfinite": ch.n_nonfinite,
        "frames": [{k: v for k, v in r.items() if k not in ("channel", "file")} for r in _rows(ch, source)],
    } for ch in channels]}


TIME_CONVENTION = ("start_samples/end_samples: sub-sample time of the edge opening bit 0 / closing bit 79, in "
                   "samples from the first sample of the file (0.0 = first sample); an edge outside the audio "
                   "('extrapolated') is timed by the bit clock of the frame's other edges")


def format_json(files: Sequence[FileDecode], failed: Sequence[tuple[str, str]] = (), batch: bool = False) -> str:
    """One file: ``{"file", "time_convention", "channels"}``; several (``batch``): ``{"time_convention",
    "files": [{"file", "channels"}], "failed": [{"file", "error"}]}``."""
    if not batch:
        ((source, channels),) = files
        doc = {"file": source, "time_convention": TIME_CONVENTION, **{k: v for k, v in _file_doc(
            source, channels).items() if k != "file"}}
    else:
        doc = {"time_convention": TIME_CONVENTION, "files": [_file_doc(s, c) for s, c in files],
               "failed": [{"file": s, "error": e} for s, e in failed]}
    return json.dumps(doc, indent=1) + "\n"


def render(files: Sequence[FileDecode], fmt: OutputFormat, failed: Sequence[tuple[str, str]] = (),
           batch: bool = False) -> str:
    if fmt == OutputFormat.CSV:
        return format_csv(files)
    if fmt == OutputFormat.JSON:
        return format_json(files, failed, batch)
    return format_table(files)
