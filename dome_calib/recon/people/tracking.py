"""Identity over time: the same person keeps the same id; people enter and leave; an id is never reused.

:func:`track_bodies` links the people of consecutive times by the Hungarian method
(``scipy.optimize.linear_sum_assignment``) on the median 3D joint distance between each track's predicted skeleton
(the whole body at constant velocity from its last two observations) and each body, gated: confirmed tracks
first, then tentative ones (seen fewer than ``min_track_frames`` times) with the bodies left. Confirmed tracks not
seen for ``max_missed_ms`` or ``max_missed_steps`` time steps (the median step of the times: a time-lapse rig's
frames 1 s apart keep their tracks), whichever is longer, end; tentative ones at their first miss; tracks shorter than ``min_track_frames`` are
dropped (a false body lasts a frame or two). Ids are given in order of first appearance (then creation order),
once.

:func:`smooth_track` is optional smoothing: a local linear least-squares fit over a centred window of the track's
own observation times. A linear fit reproduces any constant-velocity motion exactly (also at the ends of a track
and across uneven time steps), so it does not bias a moving joint; it lags only under acceleration (by
acceleration x window^2 / 6 at most in the middle of a track).

Tracking runs once over the whole session (long sessions too: see :mod:`~dome_calib.recon.people.chunks`).
"""
from __future__ import annotations

import numpy as np

from dome_calib import ties
from dome_calib.options import AtLeast, options
from dome_calib.recon.people.bodies import Bodies
from dome_calib.recon.people.matching import gated_assignment, skeleton_distance_cm
from dome_calib.schema import NonNegFinite, PosFinite


@options
class TrackingOptions:
    """gate_cm: a body continues a track if its median joint distance to the track's prediction is below
    ``gate_cm + gate_cm_per_s x elapsed``; max_missed_ms, max_missed_steps: a track unseen longer than the
    larger of max_missed_ms and max_missed_steps median time steps ends (the steps follow the frame rate: at 1
    frame per second 500 ms would end every track at once); min_track_frames: shorter tracks are dropped, and a
    track is tentative until seen this often (matched after the confirmed ones, ended by a single miss); a session
    of fewer times asks for all of them (:meth:`min_frames_for`: one snapshot keeps the people seen in it);
    smooth_half_window: half width (in observations) of the smoothing window, 0 = off; bridge_gaps: the times inside
    a track's gaps are searched again with its prediction (:mod:`~dome_calib.recon.people.bridging`)."""

    gate_cm: PosFinite = 40.0
    gate_cm_per_s: NonNegFinite = 100.0
    max_missed_ms: NonNegFinite = 500.0
    max_missed_steps: NonNegFinite = 2.5
    min_track_frames: AtLeast(1) = 3
    smooth_half_window: AtLeast(0) = 0
    bridge_gaps: bool = True

    def max_missed_for(self, times_ms: np.ndarray) -> float:
        """The gap (ms) that ends a confirmed track at these times: max(max_missed_ms, max_missed_steps x the
        median step between them)."""
        steps = np.diff(np.asarray(times_ms, dtype=float))
        steps = steps[steps > 0]
        return max(self.max_missed_ms, self.max_missed_steps * float(np.median(steps)) if len(steps) else 0.0)

    def min_frames_for(self, n_times: int) -> int:
        """The times a track needs to be kept in a session of ``n_times`` times: min_track_frames, or every time of
        a shorter session (a snapshot of 1 or 2 times has no longer track to ask for)."""
        return max(1, min(self.min_track_frames, int(n_times)))


def track_bodies(times_ms: np.ndarray, bodies: list[np.ndarray],
                 options: TrackingOptions | None = None) -> list[np.ndarray]:
    """Ids of the bodies of each time.

    Args: times_ms (T,) increasing; bodies[t] (P_t, 19, 3) cm (NaN = joint missing).
    Returns: ids[t] (P_t,) int: 0, 1, ... in order of first appearance; -1 for bodies of dropped short tracks.
    """
    options = options or TrackingOptions()
    max_missed_ms = options.max_missed_for(times_ms)
    min_frames = options.min_frames_for(len(times_ms))
    track_of = [np.full(len(b), -1, dtype=np.int64) for b in bodies]
    last_X: list[np.ndarray] = []
    last_t: list[float] = []
    vel: list[np.ndarray] = []
    seen: list[int] = []
    active: list[int] = []
    prev_t = -np.inf
    for k, (t, X) in enumerate(zip(np.asarray(times_ms, dtype=float), bodies)):
        # confirmed tracks survive gaps up to max_missed_ms; a tentative one (seen fewer than min_track_frames
        # times) ends as soon as it misses a time
        active = [i for i in active if t - last_t[i] <= max_missed_ms
                  and (seen[i] >= min_frames or last_t[i] >= prev_t)]
        prev_t = t
        P = len(X)
        # confirmed tracks first, then tentative ones with the bodies left (a one-frame false body next to a
        # person cannot take the person's track)
        for group in ([i for i in active if seen[i] >= min_frames],
                      [i for i in active if seen[i] < min_frames]):
            free = np.flatnonzero(track_of[k] < 0)
            if not group or not len(free):
                continue
            pred = np.stack([last_X[i] + vel[i] * (t - last_t[i]) for i in group])
            cost = skeleton_distance_cm(pred, X[free])
            gate = options.gate_cm + options.gate_cm_per_s * 1e-3 * np.array([t - last_t[i] for i in group])
            step = ties.SKELETON_DISTANCE_QUANTUM_CM
            for r, c in zip(*gated_assignment(cost, ties.below(cost, gate[:, None], step), step)):
                track_of[k][free[c]] = group[r]
        for c in range(P):
            i = track_of[k][c]
            if i < 0:
                i = len(last_X)
                track_of[k][c] = i
                last_X.append(X[c].copy())
                last_t.append(t)
                vel.append(np.zeros((19, 3)))
                seen.append(1)
                active.append(i)
                continue
            seen[i] += 1
            dt = t - last_t[i]
            v = (X[c] - last_X[i]) / dt if dt > 0 else np.zeros((19, 3))
            # one velocity for the whole body (median over joints): a joint's own velocity from two noisy positions
            # would throw the prediction off by the noise again at every step
            have = np.isfinite(v).all(-1)
            vel[i] = np.broadcast_to(np.median(v[have], axis=0) if have.any() else np.zeros(3), (19, 3)).copy()
            last_X[i] = np.where(np.isfinite(X[c]), X[c], last_X[i] + vel[i] * dt)
            last_t[i] = t
    n_tracks = len(last_X)
    length = np.bincount(np.concatenate([tr[tr >= 0] for tr in track_of] + [np.zeros(0, np.int64)]),
                         minlength=n_tracks)
    keep = length >= min_frames
    new_id = np.full(n_tracks, -1, dtype=np.int64)
    new_id[keep] = np.arange(int(keep.sum()))  # creation order = order of first appearance
    return [np.where(tr >= 0, new_id[np.maximum(tr, 0)], -1) for tr in track_of]


def apply_tracks(times_ms: np.ndarray, bodies: list[Bodies], options: TrackingOptions) -> list[Bodies]:
    """Ids by :func:`track_bodies`; bodies of dropped tracks removed."""
    ids = track_bodies(np.asarray(times_ms, dtype=float), [b.X_cm for b in bodies], options)
    return [b.take(i >= 0, i[i >= 0]) for b, i in zip(bodies, ids)]


def smooth_tracks(times_ms: np.ndarray, bodies: list[Bodies], half_window: int) -> list[Bodies]:
    """Optional smoothing of every track of tracked bodies (:func:`smooth_track`; ``half_window`` 0: unchanged)."""
    if half_window <= 0:
        return bodies
    times = np.asarray(times_ms, dtype=float)
    out = [b.take(np.arange(len(b.ids))) for b in bodies]
    for tid in sorted({int(x) for b in out for x in b.ids}):
        where = [(k, int(np.flatnonzero(b.ids == tid)[0])) for k, b in enumerate(out) if np.any(b.ids == tid)]
        X = np.stack([out[k].X_cm[p] for k, p in where])
        Xs = smooth_track(times[[k for k, _ in where]], X, half_window)
        for (k, p), x in zip(where, Xs):
            out[k].X_cm[p] = x
    return out


def smooth_track(times_ms: np.ndarray, X: np.ndarray, half_window: int) -> np.ndarray:
    """Local linear fit of one track: times (L,), X (L, 19, 3) (NaN = missing) -> (L, 19, 3).

    Each point is replaced by the value at its time of the least-squares line through the observations of its
    window (``half_window`` observations either side, fewer at the ends); joints missing at the point stay
    missing, and fits with fewer than 2 observations keep the point.
    """
    if half_window <= 0 or len(X) < 3:
        return X.copy()
    t = np.asarray(times_ms, dtype=float)
    out = X.copy()
    for k in range(len(t)):
        lo, hi = max(0, k - half_window), min(len(t), k + half_window + 1)
        dt = (t[lo:hi] - t[k])[:, None, None]
        Y = X[lo:hi]
        w = np.isfinite(Y).all(-1, keepdims=True)
        Yz = np.where(w, Y, 0.0)
        n, s1, s2 = w.sum(0), (w * dt).sum(0), (w * dt * dt).sum(0)
        m0, m1 = Yz.sum(0), (Yz * dt).sum(0)
        det = n * s2 - s1 * s1
        ok = (n >= 2) & (det > 1e-9) & np.isfinite(X[k]).all(-1, keepdims=True)
        intercept = (s2 * m0 - s1 * m1) / np.where(ok, det, 1.0)
        out[k] = np.where(ok, intercept, X[k])
    return out
