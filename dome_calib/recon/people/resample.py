"""Unlabelled people of every camera brought to universal times (the first step of a batch).

Each camera's detections are at its own stream's frame times. At a universal time t the two bracketing frames of
the stream are used (:func:`~dome_calib.recon.streams.frame_brackets`, the one implementation that the single-person
:func:`~dome_calib.recon.streams.interpolate_stream` reads too): the people of frame f0 and frame f1 are matched to
each other in 2D (:func:`~dome_calib.recon.people.matching.greedy_match` on the mean pixel distance of their common
joints, gated relative to the person's size) and each matched pair is interpolated joint by joint (``w0 * a + w1 *
b``; a joint seen in one frame only is kept if that frame is the nearer one). People found in one frame only are kept
if that frame is the nearer one. This is 2D tracking over one frame step: local, stateless (chunks of time are
independent) and linear in cameras; the identity over longer spans is kept in 3D
(:mod:`dome_calib.recon.people.tracking`). A time that coincides with a frame needs no matching. A stream holding no
frame near the times (OpenPose run on part of a stream's frames only) gives nobody there.
"""
from __future__ import annotations

import numpy as np

from dome_calib import ties
from dome_calib.recon.people.matching import greedy_match
from dome_calib.recon.people.sources import PeopleStream
from dome_calib.recon.streams import Brackets, frame_brackets


def _person_size_px(kp: np.ndarray) -> np.ndarray:
    """(..., 19, 3) -> (...,) diagonal of the bounding box of the detected joints (0 if fewer than 2)."""
    have = kp[..., 2] > 0
    big = np.float32(1e9)
    lo = np.where(have[..., None], kp[..., :2], big).min(axis=-2)
    hi = np.where(have[..., None], kp[..., :2], -big).max(axis=-2)
    return np.where(have.sum(-1) >= 2, np.linalg.norm(hi - lo, axis=-1), 0.0)


def interpolate_people(stream: PeopleStream, univ_time_ms: np.ndarray, *, max_gap_frames: float = 2.5,
                       match_gate: float = 0.25, min_gate_px: float = 15.0) -> np.ndarray:
    """People of one stream at (T,) universal times -> (T, V_s, N_out, J, 3) (empty slots have c = 0; J = 19, or
    19 + extra joints after them: the matching, the slots' order and their count read the first 19 only, so the
    joints19 of a stream with extras come out as those of the stream without).

    match_gate: two frames' people match if their mean joint distance is below ``match_gate`` x the person's
    bounding-box diagonal (at least ``min_gate_px``). Outside the table's span, across gaps wider than
    ``max_gap_frames`` nominal periods, or where the stream holds neither frame there are no people.
    """
    t = np.asarray(univ_time_ms, dtype=float)
    br = frame_brackets(stream.table, stream.frame_index, t, max_gap_frames=max_gap_frames)
    w1 = br.w1
    near_a = w1 <= 0.5
    # the nearer frame of each time (one gather: the full dome's VGA times sit on their frames), both only where mixed
    out = Brackets.take(stream.kp, np.where(near_a, br.pos0, br.pos1), np.where(near_a, br.has0, br.has1))
    out[~br.usable] = 0.0
    mix = br.usable & (w1 > 0) & (w1 < 1)
    if not mix.any():
        return out
    a = Brackets.take(stream.kp, br.pos0[mix], br.has0[mix])  # (M, V, N, 19, 3)
    b = Brackets.take(stream.kp, br.pos1[mix], br.has1[mix])
    wb = w1[mix].astype(np.float32)  # (M,)
    near = wb <= 0.5
    a19, b19 = a[..., :19, :], b[..., :19, :]
    both = (a19[:, :, :, None, :, 2] > 0) & (b19[:, :, None, :, :, 2] > 0)  # (M, V, N, N, 19)
    dist = np.linalg.norm(a19[:, :, :, None, :, :2] - b19[:, :, None, :, :, :2], axis=-1)
    n_common = both.sum(-1)
    cost = np.where(n_common >= 3, np.where(both, dist, 0).sum(-1) / np.maximum(n_common, 1), np.inf)
    gate = np.maximum(match_gate * _person_size_px(a19), min_gate_px)[..., None]
    match = greedy_match(cost, gate, ties.DETECTION_DISTANCE_QUANTUM_PX)  # (M, V, N)
    M, V, N = match.shape
    bm = np.take_along_axis(b, np.maximum(match, 0)[..., None, None], axis=2)
    matched = match >= 0
    ja, jb = a[..., 2] > 0, bm[..., 2] > 0  # (M, V, N, 19)
    w = wb[:, None, None, None, None]
    interp = (1 - w) * a + w * bm
    interp[..., 2] = np.minimum(a[..., 2], bm[..., 2])
    near5 = near[:, None, None, None, None]
    near4 = near[:, None, None, None]
    joint = np.where((ja & jb)[..., None], interp,
                     np.where((ja & near4)[..., None], a, np.where((jb & ~near4)[..., None], bm, 0)))
    slots_a = np.where(matched[..., None, None], joint, np.where(near5, a, 0))
    used_b = np.zeros((M, V, N), bool)
    mi, vi, ni = np.nonzero(matched)
    used_b[mi, vi, match[mi, vi, ni]] = True
    slots_b = np.where((~used_b & ~near[:, None, None])[..., None, None], b, 0)
    merged = np.concatenate([slots_a, slots_b], axis=2)  # (M, V, 2N, 19, 3)
    full = np.zeros((len(t), V, 2 * N) + stream.kp.shape[-2:], dtype=np.float32)
    full[:, :, :N] = out
    full[mix] = merged
    filled = (full[..., :19, 2] > 0).any(-1)
    order = np.argsort(~filled, axis=2, kind="stable")
    full = np.take_along_axis(full, order[..., None, None], axis=2)
    keep = max(int(filled.sum(axis=2).max()), 1)
    return full[:, :, :keep]


def gather_people(streams: list[PeopleStream], times_ms: np.ndarray, max_gap_frames: float) -> np.ndarray:
    """All streams' people at the times -> (T, V, N, J, 3) (views in stream order, empty slots c = 0; J: the
    streams', 19 or 19 + extra joints)."""
    parts = [interpolate_people(s, times_ms, max_gap_frames=max_gap_frames) for s in streams]
    N = max(p.shape[2] for p in parts)
    out = np.zeros((len(times_ms), sum(p.shape[1] for p in parts), N) + parts[0].shape[-2:], dtype=np.float32)
    v = 0
    for p in parts:  # each stream's views in place (no padded copy, then a concatenated one)
        out[:, v: v + p.shape[1], : p.shape[2]] = p
        v += p.shape[1]
    return out
