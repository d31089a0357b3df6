"""The body over time of a whole session: what it holds measured once, then the fit in windows fixed by the
session's own time index (on an executor), so that no result depends on how the per-frame work was cut.

1. :func:`session_priors`: each track's bone lengths (the median, in 0.01 cm steps, over all its times where both
   joints had ``bone_min_views`` inlier views; a limb or trunk bone never measured so is inferred from the body's
   size: :func:`infer_unmeasured_bones`) and each camera's pixel noise (the median of its detections' distances
   to the per-frame joints, from the histogram the per-frame tallies summed over every time:
   :attr:`~dome_calib.recon.people.agreement.CameraAgreement.noise`, / 1.177, a 2D Gaussian's median radius in units
   of its per-axis sigma). Both are read from integer steps: no choice rests on the last bits of a float.
2. :func:`time_windows`: windows of W times starting at multiples of W of the session's time index, each fitted with
   M context times on both sides and put out for its own W times only. M is the smoother's reach
   (:func:`margin_times`), W = ``window_margins`` x M.
3. :func:`refine_session`: each window reads its detections again (the bodies keep only the index of each view's
   assigned detection: the full dome's detections of an hour would not fit in memory, 78 MB per 100 times), fits
   (:func:`~dome_calib.recon.people.temporal.refine_tracks`), lets the depth witness judge the joints it placed,
   and tallies its verdicts on its own times (each time counted once).

**The reach.** The motion prior (white-noise acceleration of spectral density q, a cubic smoothing spline) weighs a
joint measured with per-axis noise sigma every dt seconds like a kernel smoother of bandwidth
``h = (sigma^2 dt / q)^(1/4)`` whose weights fall as ``exp(-|t| / (sqrt(2) h))`` (Silverman 1984, the equivalent
kernel of a smoothing spline). A window's cut edge moves a time ``d`` seconds inside it by at most the edge's own
error times that factor; with sigma = ``max_sigma_cm`` (no joint put out is less sure) and the slowest joint's q (the
trunk's), the influence falls to ``window_edge_influence`` after ``sqrt(2) h ln(1 / influence)`` seconds. A joint
that no view saw for a while is carried across the gap by the motion alone; it is put out only within
``(3 max_sigma^2 / q)^(1/3)`` seconds of its last measurement (its variance ``q d^3 / 3`` then exceeds max_sigma^2),
which the margin adds: M = ceil((sqrt(2) h ln(1 / influence) + (3 max_sigma^2 / q)^(1/3)) / dt), dt the session's
median time step. At 30 fps with the defaults: 32 times (1.06 s); windows of 192 own times.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dome_calib import ties
from dome_calib.recon.body_models import BONE_LENGTH_CM, MIRROR19
from dome_calib.recon.people.agreement import NOISE_BIN_PX, CameraAgreement, tally_verdicts
from dome_calib.recon.people.bodies import Bodies, Observations, observations_of
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.resample import gather_people
from dome_calib.recon.people.sources import FileSource, InMemorySource
from dome_calib.recon.people.temporal import BONE_A, BONE_B, SessionPriors, TemporalOptions, refine_tracks
from dome_calib.recon.project import ViewSet

#: A 2D Gaussian's median radius in units of its per-axis sigma: sqrt(2 ln 2).
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
#: Bone lengths are measured in these steps (cm).
BONE_STEP_CM = 0.01
#: Each bone's left/right mirror in BONE_LENGTH_CM's order (itself for the midline and cross bones).
BONE_MIRROR = np.array([next(f for f, (c, d) in enumerate(zip(BONE_A, BONE_B))
                             if {MIRROR19[a], MIRROR19[b]} == {c, d}) for a, b in zip(BONE_A, BONE_B)])
#: The face's joints: a detector puts the nose, eyes and ears where its own conventions say (BONE_LENGTH_CM's neck to
#: nose, 20 cm, is 15.5 on the synthetic body), so their bones neither tell a body's size nor are inferred from it.
FACE19 = ("nose", "l_eye", "r_eye", "l_ear", "r_ear")
#: The bones a body's size is read from, and that may be inferred from it: the limbs' and the trunk's.
SIZE_BONES = np.array([a not in FACE19 and b not in FACE19 for a, b in BONE_LENGTH_CM])
#: A body's size is read from this many of its size bones at least (a bone and its mirror count once).
MIN_SIZE_BONES = 3
#: A camera's noise is measured from this many of its detections at least (else the other cameras' median).
MIN_NOISE_RECORDS = 30
#: The noise of every camera when none has enough detections (px).
DEFAULT_NOISE_PX = 3.0


def noise_px_of(hist: np.ndarray, min_noise_px: float) -> np.ndarray:
    """(V, bins) counts of each camera's scaled distances (:attr:`CameraAgreement.noise`) -> (V,) pixel noise:
    the median bin's centre / 1.177, at least ``min_noise_px``; a camera with fewer than MIN_NOISE_RECORDS
    detections gets the median of the others'."""
    n = hist.sum(1)
    k = np.argmax(np.cumsum(hist, axis=1) >= (n[:, None] + 1) // 2, axis=1)
    noise = np.maximum((k + 0.5) * NOISE_BIN_PX / RAYLEIGH_MEDIAN, min_noise_px)
    measured = n >= MIN_NOISE_RECORDS
    fill = float(np.median(noise[measured])) if measured.any() else DEFAULT_NOISE_PX
    return np.where(measured, noise, fill)


def bone_lengths(bodies: list[Bodies], min_views: int) -> tuple[np.ndarray, np.ndarray]:
    """Each track's bone lengths over all its times: (K,) track ids, (K, E) cm (NaN: no time where both joints had
    ``min_views`` inlier views). The median of the lengths rounded to BONE_STEP_CM (of the two middle ones, their
    mean), a bone's and its left/right mirror's lengths together (:data:`BONE_MIRROR`): a person's left and right
    bones are one length to about a centimetre, and each side alone may rest on a few frames (the left thigh of
    Pose2Sim's balancing trial on 3 of 99, 37.8 cm against the right's 41.2 on 8; Pose2Sim's own triangulation: 41.6
    and 41.5), which the fit then held at 1.5 cm over the whole session."""
    ids = np.concatenate([b.ids for b in bodies] + [np.zeros(0, np.int64)])
    X = np.concatenate([b.X_cm for b in bodies] + [np.zeros((0, 19, 3))])
    n_inl = np.concatenate([b.n_inliers for b in bodies] + [np.zeros((0, 19), np.int64)])
    track_ids = np.unique(ids)
    E = len(BONE_A)
    out = np.full((len(track_ids), E), np.nan)
    length = np.linalg.norm(X[:, BONE_A] - X[:, BONE_B], axis=-1)  # (BF, E)
    good = (n_inl[:, BONE_A] >= min_views) & (n_inl[:, BONE_B] >= min_views) & np.isfinite(length)
    track = np.searchsorted(track_ids, ids)
    for e in range(E):
        sides = np.unique([e, BONE_MIRROR[e]])  # a bone and its left/right mirror: one length
        t = np.concatenate([track[good[:, x]] for x in sides])
        steps = np.concatenate([ties.quantize(length[good[:, x], x], BONE_STEP_CM) for x in sides])
        order = np.lexsort((steps, t))
        t, steps = t[order], steps[order]
        start = np.searchsorted(t, np.arange(len(track_ids)))
        count = np.bincount(t, minlength=len(track_ids))
        have = count > 0
        lo = start + (count - 1) // 2
        hi = start + count // 2
        out[have, e] = 0.5 * (steps[lo[have]] + steps[hi[have]]) * BONE_STEP_CM
    return track_ids, out


def infer_unmeasured_bones(bone_cm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, E) bone lengths (:func:`bone_lengths`; NaN: never measured) -> the same with each unmeasured limb or trunk
    bone (:data:`SIZE_BONES`) put at the body's size x its nominal length (BONE_LENGTH_CM), and (K, E) bool: which
    were inferred. The body's size: the median of measured / nominal over its measured size bones (a bone and its
    mirror once), when it has MIN_SIZE_BONES of them; in BONE_STEP_CM steps.

    Why: a bone is measured only where both joints had ``bone_min_views`` inlier views (two views always agree), so
    a joint that only two cameras see has no bone, and nothing holds it along their rays but those two views. On
    the demo's tiny dome a crouching person's ankles are inside the image of two cameras only, 10 degrees apart: a
    few pixels of detector bias there put the ankles 10 cm off along the rays and the shin at 55 cm (45.8 true)."""
    nominal = np.array(list(BONE_LENGTH_CM.values()))
    once = SIZE_BONES & (np.arange(len(nominal)) <= BONE_MIRROR)  # mirrors share one length: count one of each
    ratio = np.where(once, bone_cm / nominal, np.nan)
    count = np.isfinite(ratio).sum(1)
    with np.errstate(all="ignore"):
        size = np.where(count >= MIN_SIZE_BONES, np.nanmedian(np.where(count[:, None] > 0, ratio, 1.0), axis=1),
                        np.nan)
    inferred = SIZE_BONES & np.isnan(bone_cm) & np.isfinite(size)[:, None]
    guess = np.round(size[:, None] * nominal / BONE_STEP_CM) * BONE_STEP_CM
    return np.where(inferred, guess, bone_cm), inferred


def session_priors(bodies: list[Bodies], cameras: CameraAgreement, options: TemporalOptions) -> SessionPriors:
    """The whole session's tracked bodies and per-frame tallies -> what every window holds (module docstring)."""
    track_ids, bone_cm = bone_lengths(bodies, options.bone_min_views)
    bone_cm, inferred = infer_unmeasured_bones(bone_cm)
    return SessionPriors(track_ids=track_ids, bone_cm=bone_cm, bone_inferred=inferred,
                         noise_px=noise_px_of(cameras.noise, options.min_noise_px))


def margin_times(times_ms: np.ndarray, options: TemporalOptions) -> int:
    """M, the smoother's reach in time steps of the session (module docstring)."""
    steps = np.diff(np.asarray(times_ms, dtype=float))
    steps = steps[steps > 0]
    if not len(steps):
        return 1
    dt_s = float(np.median(steps)) / 1000.0
    q = float(np.min(options.spectral_density()))
    sigma2 = options.max_sigma_cm ** 2
    h_s = (sigma2 * dt_s / q) ** 0.25
    reach_s = math.sqrt(2.0) * h_s * math.log(1.0 / options.window_edge_influence) + (3.0 * sigma2 / q) ** (1 / 3)
    return max(1, math.ceil(reach_s / dt_s))


def time_windows(times_ms: np.ndarray, options: TemporalOptions) -> list[tuple[int, int, int, int]]:
    """The windows of a session of T times: (lo, start, stop, hi) time indices, own times [start, stop) at multiples
    of W, fitted over [lo, hi) (M more on both sides, within the session)."""
    T = len(times_ms)
    M = margin_times(times_ms, options)
    W = options.window_margins * M
    return [(max(0, s - M), s, min(s + W, T), min(T, s + W + M)) for s in range(0, T, W)]


@dataclass(frozen=True)
class WindowTask:
    """What one window's task gets (picklable): the cameras, where its detections are, the fitted span's times and
    tracked bodies, its own times [own_start, own_stop) within them, the session's priors."""

    index: int
    views: ViewSet
    source: InMemorySource | FileSource
    times_ms: np.ndarray
    bodies: list[Bodies]
    own_start: int
    own_stop: int
    priors: SessionPriors
    options: TemporalOptions
    max_gap_frames: float
    batch_times: int
    depth: DepthWitness | None
    ties: object | None = None  # the patches' part motions on the fitted span's times (JointTies), or None


def window_observations(task: WindowTask) -> Observations:
    """The window's bodies' detections, read again from its source: the frames that bracket its times, once (read
    again per batch, the full dome's files would cost 44 % more: 3.5 frames of margin on both sides of every 16
    times); brought to its times and gathered ``batch_times`` at a time."""
    t = task.times_ms
    streams = task.source.chunk(float(t[0]), float(t[-1]), task.max_gap_frames)
    parts, row = [], 0
    for s in range(0, len(t), task.batch_times):
        sl = slice(s, min(s + task.batch_times, len(t)))
        kp = gather_people(streams, t[sl], task.max_gap_frames)
        parts.append(observations_of(kp, task.bodies[sl], row, strongest=task.options.max_views_per_joint))
        row += sum(len(b.ids) for b in task.bodies[sl])
    return Observations.concat(parts)


def run_window(task: WindowTask) -> tuple[int, list[Bodies], CameraAgreement]:
    """Executor task: one window fitted -> (index, the bodies of its own times, the verdicts on their detections)."""
    obs = window_observations(task)
    fit = refine_tracks(task.views, task.times_ms, task.bodies, obs, task.priors, task.options, ties=task.ties)
    own = slice(task.own_start, task.own_stop)
    bodies = fit.bodies[own]
    if task.depth is not None:  # the witness has the last word on the joints the body placed too
        for b, time_ms in zip(bodies, task.times_ms[own]):
            if len(b.ids):
                gone = ~task.depth.keep(b.X_cm, float(time_ms)) & np.isfinite(b.X_cm).all(-1)
                b.X_cm[gone], b.confidence[gone], b.n_inliers[gone] = np.nan, -1.0, 0
    mine = (fit.record_time >= task.own_start) & (fit.record_time < task.own_stop)
    verdicts = tally_verdicts(list(task.views.names), obs.view[mine], fit.residual_px[mine], fit.outvoted[mine],
                              fit.offset_px[mine])
    return task.index, bodies, verdicts


def refine_session(views: ViewSet, source: InMemorySource | FileSource, times_ms: np.ndarray, bodies: list[Bodies],
                   cameras: CameraAgreement, options: TemporalOptions, *, max_gap_frames: float, batch_times: int,
                   depth: DepthWitness | None = None, executor=None,
                   progress: Callable[[int], None] | None = None,
                   ties=None) -> tuple[list[Bodies], CameraAgreement]:
    """The tracked bodies of a whole session (ids >= 0, with their assigned detections) and its per-frame tallies ->
    the bodies over time and the tallies with the body's verdicts (module docstring). Windows run on ``executor``
    (``map``; None: in this process); ``progress(times_done)`` after each window. ``ties``: the patches' part
    motions (:class:`~dome_calib.recon.patches.body.JointTies`) as a further term; each window gets those between
    its fitted span's first and last time (None: absent, the fit unchanged to the bit)."""
    t = np.asarray(times_ms, dtype=float)
    if not options.enabled or not len(t):
        return bodies, cameras
    views = views.subset(source.cameras)  # the order of the tallies and of the detections' views
    priors = session_priors(bodies, cameras, options)
    tasks = [WindowTask(index=i, views=views, source=source, times_ms=t[lo:hi], bodies=bodies[lo:hi],
                        own_start=a - lo, own_stop=b - lo, priors=priors, options=options,
                        max_gap_frames=max_gap_frames, batch_times=batch_times, depth=depth,
                        ties=None if ties is None else ties.between(float(t[lo]), float(t[hi - 1])))
             for i, (lo, a, b, hi) in enumerate(time_windows(t, options))]
    results: dict[int, tuple[list[Bodies], CameraAgreement]] = {}
    for index, got, verdicts in (map if executor is None or len(tasks) <= 1 else executor.map)(run_window, tasks):
        results[index] = (got, verdicts)
        if progress is not None:
            progress(sum(len(r[0]) for r in results.values()))
    out: list[Bodies] = []
    verdicts = CameraAgreement.empty(list(views.names))
    for i in range(len(tasks)):
        out += results[i][0]
        verdicts.add(results[i][1])
    return out, cameras.with_verdicts(verdicts)
