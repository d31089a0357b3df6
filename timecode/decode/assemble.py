"""One channel's edges -> decoded frames: bits, sync words, labels, rate, continuity, frames at the edges of the
audio, frame times from the bit clock.

Frames at the edges of the audio (the file starts or ends inside a frame, or the LTC stops after one):

- A run of edges that ends on the mid-bit edge of a 1 lacks only the edge that closes that bit; when the bit is
  the last of a sync word, the frame is complete but for its closing edge (its opening edge in reverse play),
  whose time the bit clock extrapolates (``bits.with_virtual_edges``). This holds wherever the run ends.
- A frame whose sync word is in the audio but which starts before the file's first sample (forward play; ends
  after its last sample in reverse play), so that its first bits (its last ones in reverse) are not read, has
  the label of the next frame minus one (the previous one in reverse play, whose label is one higher): accepted
  when every label bit that was read agrees with it. Its missing bits are those of that label and, for flags
  and user bits, of that neighbour (``bits_missing`` says how many), and its start time is extrapolated. Only
  at the file's edges: a frame whose first bits are lost inside the audio (a dropout, a splice) is not
  reported, since its start would be extrapolated into audio that is not its own.
"""
from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from timecode.decode.bits import EdgeStream, edge_stream, find_frames, with_virtual_edges
from timecode.decode.bitclock import fit_frame_times
from timecode.decode.continuity import continuity, detect_rate, rate_contradiction, rate_evidence
from timecode.errors import TimecodeError
from timecode.frame import bgf_bits, pack_bits, unpack_bits
from timecode.labels import frames_to_labels, labels_to_frames, labels_valid
from timecode.rates import FrameRate
from timecode.decode.result import ChannelDecode

#: Frame bits that carry the label (BCD digits) and the drop-frame and colour-frame flags.
LABEL_BITS = np.array([*range(0, 4), 8, 9, 10, 11, *range(16, 20), *range(24, 27), *range(32, 36), *range(40, 43),
                       *range(48, 52), 56, 57])


class RateMismatchError(TimecodeError, ValueError):
    """A requested frame rate that the LTC bit stream contradicts."""


def decode_edges(t: npt.NDArray[np.float64], rising: npt.NDArray[np.bool_], amplitude: npt.NDArray[np.float32],
                 sample_rate: int, *, impulse: npt.NDArray[np.bool_] | None = None, n_samples: int | None = None,
                 channel: int = 0, rate: FrameRate | None = None, ac_coupling_hz: float = 0.0,
                 impulse_tau_samples: float = 0.0, n_nonfinite: int = 0,
                 edge_margin_samples: float = 3.0) -> ChannelDecode:
    """Frames from one channel's sorted edge times (samples; ``n_samples`` of audio, for the edge frames).

    ``rate`` None detects the rate; a given rate that the bit stream contradicts raises RateMismatchError.
    An edge within ``edge_margin_samples`` of either end of the audio (its transition may be cut, and the
    smoothing reaches past the end) counts for the bits but not for the bit clock, like an edge outside.
    """
    impulse = np.zeros(len(t), bool) if impulse is None else impulse
    empty = ChannelDecode(channel=channel, sample_rate=sample_rate, rate=rate, n_edges=len(t),
                          ac_coupling_hz=ac_coupling_hz, impulse_tau_samples=impulse_tau_samples,
                          n_nonfinite=n_nonfinite)
    if len(t) > 1:
        # two edges closer than a tenth of the shortest half-bit cannot both be LTC (block seams)
        close = np.diff(t) < 0.1 * sample_rate / (2 * 2760.0)
        if close.any():
            drop = np.concatenate([[False], close]) | np.concatenate([close, [False]])
            t, rising, amplitude, impulse = t[~drop], rising[~drop], amplitude[~drop], impulse[~drop]
    es = edge_stream(t, rising, sample_rate)
    if es is None:
        return empty
    es = with_virtual_edges(es)
    if n_samples is not None:
        es.virtual |= (es.t < edge_margin_samples) | (es.t > n_samples - 1 - edge_margin_samples)
    raw = find_frames(es)
    fields = unpack_bits(raw.bits)
    complete = np.flatnonzero((raw.missing == 0) & fields.sync_ok & fields.bcd_ok)
    n_found = len(complete)
    hmsf, bits = fields.hmsf[complete], fields.bits[complete]
    start_e, end_e, reverse = raw.start_edge[complete], raw.end_edge[complete], raw.reverse[complete]
    if len(hmsf) == 0:
        empty.n_rejected = n_found
        return empty
    period = np.abs(es.t[end_e] - es.t[start_e])
    contiguous = np.concatenate([(end_e[:-1] == start_e[1:]) & (reverse[:-1] == reverse[1:]), [False]])
    if rate is None:
        rate = detect_rate(hmsf, bits[:, 10].astype(bool), period, contiguous, sample_rate, es.t[start_e])
    else:
        why = rate_contradiction(rate, rate_evidence(hmsf, bits[:, 10].astype(bool), period, contiguous,
                                                     sample_rate, es.t[start_e]))
        if why:
            raise RateMismatchError(f"channel {channel}: the LTC is not {rate} fps: {why}")
    valid = labels_valid(hmsf, rate)
    complete, hmsf, bits, start_e, end_e, reverse, period = (
        a[valid] for a in (complete, hmsf, bits, start_e, end_e, reverse, period))
    counts = labels_to_frames(hmsf, rate)
    mid = (es.t[start_e] + es.t[end_e]) / 2
    keep, disc = continuity(counts, reverse, mid, period, rate.frames_per_day)
    rows = complete[keep]
    counts, disc = counts[keep], disc[keep]
    frame_bits = raw.bits[rows]
    n_rejected = n_found - len(rows)
    if len(rows) == 0:
        empty.rate, empty.n_rejected = rate, n_rejected
        return empty
    rows, counts, disc, frame_bits = _add_edge_frames(raw, es, rows, counts, disc, frame_bits, rate, sample_rate,
                                                      n_samples)
    return _timed(raw, es, rows, counts, disc, frame_bits, rate, amplitude, impulse, channel=channel,
                  sample_rate=sample_rate, n_edges=len(t), n_rejected=n_rejected, ac_coupling_hz=ac_coupling_hz,
                  impulse_tau_samples=impulse_tau_samples, n_nonfinite=n_nonfinite)


def _time_at(es: EdgeStream, pos: int) -> float:
    """Time of the edge at half-bit position ``pos`` (it exists: a bit boundary of a decoded frame)."""
    return float(es.t[min(int(np.searchsorted(es.pos, pos)), len(es.pos) - 1)])


def _add_edge_frames(raw, es: EdgeStream, rows, counts, disc, frame_bits, rate: FrameRate, sample_rate: int,
                     n_samples: int | None):
    """Partial frames at the file's edges (module docstring) inserted beside their neighbours."""
    if n_samples is None:
        return rows, counts, disc, frame_bits
    bit_len = 2 * es.half_bit_samples
    by_start = {int(e): k for k, e in enumerate(raw.start_edge[rows])}
    i0, i1, i2 = bgf_bits(rate.is_25_layout)
    add = []
    for p in np.flatnonzero(raw.missing > 0):
        k = by_start.get(int(raw.end_edge[p]))
        if k is None or raw.reverse[rows[k]] != raw.reverse[p]:
            continue
        miss = int(raw.missing[p])
        # the frame starts before the first sample (after the last one in reverse play), half a bit's slack
        if raw.reverse[p]:  # the last bit read is frame bit `miss`, closed at start_pos - 2 miss
            at_edge = _time_at(es, int(raw.start_pos[p]) - 2 * miss) + miss * bit_len > n_samples - 0.5 * bit_len
        else:  # the first bit read is frame bit `miss`, opened at start_pos + 2 miss
            at_edge = _time_at(es, int(raw.start_pos[p]) + 2 * miss) - miss * bit_len < 0.5 * bit_len
        if not at_edge:
            continue
        nb = frame_bits[k]
        count = int((counts[k] - 1) % rate.frames_per_day)
        ub = int(unpack_bits(nb[None]).user_bits[0])
        expect = pack_bits(frames_to_labels([count], rate), is_25_layout=rate.is_25_layout, user_bits=ub,
                           drop_frame=bool(nb[10]), color_frame=bool(nb[11]),
                           bgf=(bool(nb[i0]), bool(nb[i1]), bool(nb[i2])))[0]
        seen = raw.known[p][LABEL_BITS]
        if np.any(raw.bits[p][LABEL_BITS][seen] != expect[LABEL_BITS][seen]):
            continue
        add.append((k, p, count, np.where(raw.known[p], raw.bits[p], expect).astype(np.uint8)))
    if not add:
        return rows, counts, disc, frame_bits
    rows, counts, disc, frame_bits = list(rows), list(counts), list(disc), list(frame_bits)
    for k, p, count, fb in sorted(add, key=lambda a: -a[0]):  # from the end, so indices stay valid
        at = k if not raw.reverse[p] else k + 1  # forward: before its next frame; reverse: after its previous
        if not raw.reverse[p]:
            disc[k] = False  # the neighbour now follows it
        rows.insert(at, p)
        counts.insert(at, count)
        disc.insert(at, not raw.reverse[p])
        frame_bits.insert(at, fb)
    return np.array(rows), np.array(counts, np.int64), np.array(disc, bool), np.array(frame_bits, np.uint8)


def _timed(raw, es: EdgeStream, rows, counts, disc, frame_bits, rate: FrameRate, amplitude, impulse, *,
           channel: int, sample_rate: int, **summary) -> ChannelDecode:
    """The result: fields of each frame's bits, and its start and end from the local bit clock."""
    fields = unpack_bits(frame_bits)
    start_e, end_e, reverse = raw.start_edge[rows], raw.end_edge[rows], raw.reverse[rows]
    start_pos, end_pos = raw.start_pos[rows], es.pos[end_e]
    # clock-fit segments: never across a discontinuity (runs are already apart in position)
    seg = np.cumsum(disc) - 1
    p_lo, p_hi = np.minimum(start_pos, end_pos), np.maximum(start_pos, end_pos)
    nseg = int(seg[-1]) + 1
    seg_lo = np.full(nseg, np.iinfo(np.int64).max)
    seg_hi = np.full(nseg, np.iinfo(np.int64).min)
    np.minimum.at(seg_lo, seg, p_lo)
    np.maximum.at(seg_hi, seg, p_hi)
    real = np.flatnonzero(~es.virtual)
    if real.size < 2:  # nothing to time by (a frame's worth of edges, all at the very ends): none are reported
        return ChannelDecode(channel=channel, sample_rate=sample_rate, rate=rate, **summary)
    j = np.clip(np.searchsorted(es.pos[real], start_pos), 1, len(real) - 1)
    before, after = real[j - 1], real[j]
    ref = np.where(np.abs(es.pos[before] - start_pos) <= np.abs(es.pos[after] - start_pos), before, after)
    start, end, rms = fit_frame_times(es.t, es.pos, ~es.virtual, start_pos, end_pos, ref, seg_lo[seg], seg_hi[seg],
                                      es.half_bit_samples)
    start_out = (start_e < 0) | es.virtual[np.maximum(start_e, 0)]
    end_out = es.virtual[end_e]
    i0, i1, i2 = bgf_bits(rate.is_25_layout)
    amp = amplitude[es.index[ref]].astype(np.float64)
    return ChannelDecode(
        channel=channel, sample_rate=sample_rate, rate=rate, labels=frames_to_labels(counts, rate),
        frame_numbers=counts, user_bits=fields.user_bits, drop_frame=frame_bits[:, 10].astype(bool),
        color_frame=frame_bits[:, 11].astype(bool), bgf=frame_bits[:, [i0, i1, i2]].astype(bool),
        parity_ok=fields.parity_ok, reverse=reverse, start_samples=start, end_samples=end,
        level_dbfs=20 * np.log10(np.maximum(amp, 1e-12)), jitter_us=rms / sample_rate * 1e6, discontinuity=disc,
        impulses=impulse[es.index[ref]], extrapolated=(start_out.astype(np.int8) + 2 * end_out.astype(np.int8)),
        bits_missing=raw.missing[rows], **summary,
    )


def pole_to_tau(poles: list[float]) -> float:
    """Time constant (samples) of the median fitted input pole a = exp(-1 / tau); 0 when none was fitted."""
    a = [p for p in poles if not math.isnan(p) and 0.0 < p < 1.0]
    return float(-1.0 / math.log(float(np.median(a)))) if a else 0.0


__all__ = ["LABEL_BITS", "RateMismatchError", "decode_edges", "pole_to_tau"]
