"""The body over time with the patches' part motions against the body over time alone (issue 49 part 3).

Run: .venv/bin/python bench/patches_body.py [--rig fewcam,panel] [--people 3] [--seconds 4] [--seeds 1,2]
         [--occlusions 6] [--limbs arms,legs] [--stream FILE.npz] [--end-to-end]
         [--own-stream sweep,skeleton,both,auto [--frames 30] [--seed-every 20] [--patch-options seed_min_views=2]
         [--stream-cache DIR]]
         [--part-options crease_cm=0.5]

Setup per (rig, seed): the synthetic group (``fewcam``: the 5-camera HD rig of bench/fewcam.py, ``small_area``
group; ``panel``: the as-built dome's panel preset, VGA of panels 1-2 with their HD and Kinect colour cameras,
``conversation`` group), the OpenPose-like detector (errors that last) with, per person, ``--occlusions`` spans of
10 reference frames in which one limb end (wrist or ankle, with its elbow or knee) is removed from every camera (an
occluded limb). The people are reconstructed per frame and tracked (``reconstruct_people``, body over time off),
then the body over time is fitted once over the whole span (one window) without and with the ties of
:mod:`dome_calib.recon.patches.body`, both on the same tracks, detections and priors. ``--end-to-end``: the path of
``reconstruct --images`` after its patch stage instead: the body over time in the session's windows, then fitted
again from the same tracks with the ties (:func:`~dome_calib.recon.people.run.refit_over_time`).

The patches: by default :func:`dome_calib.synth.surface_patches.true_patches` samples the bodies' surfaces
(:mod:`dome_calib.synth.textured`): patch triplets (centre and two plane points 3 cm away) seeded every 20
reference frames on the outer surface where at least 2 cameras see them, each living 30 frames each way while seen
by 2 cameras, with the stream's measured error added (a constant offset and a random walk, a little worse than the
stream's: see that module); they are labelled by :func:`~dome_calib.recon.patches.parts.label_parts` with the body
over time alone (not the truth), and their motions fitted by :func:`~dome_calib.recon.patches.motion.part_motions`.
With ``--stream FILE`` (``--rig panel --people 2 --seeds 0``: bench/patches.py's setup, ``--save FILE``), the
patches are the stream's own, tracked in the rendered images, at its times. With ``--own-stream`` the stream's own
patches are tracked here, from the rendered images alone (no depth; :data:`OWN_CAMERAS`): one cloud at the
reference frame (a multiple of 20) nearest the span's middle, tracked ``--frames`` each way (the times judged;
``--seed-every N``: a cloud at every multiple of N in them, as ``reconstruct`` seeds every 20th frame),
seeded by the sweep, by ``seed_method="skeleton"`` with the body over time alone as the seeds' prior
(:func:`~dome_calib.recon.patches.stage.body_prior`, the joints no detection saw carried by their parents: what
``reconstruct --images --patch-seeds skeleton`` gives it), or both side by side; one row per seeding on the same
rendered frames (a patch not alive at the seed time has no true person or part) (``--patch-options``: PatchOptions fields; ``--part-options``: PartOptions fields of the labels).

With the stream's own patches each row has ``reach`` (:func:`reach`): per part the patches seeded on it, their
frames alive, how they are labelled, and why each occluded joint-time not recovered within 3 cm is missed (no
seed, seed dies, wrong label, no motion, tie too weak; "seed dies" split by whether the clouds around the time seeded
the part). ``--stream-cache DIR`` keeps each stream computed.

Prints one JSON object per line per (rig, seed) and method: MPJPE (cm, over the true joints both methods put out
and over those each puts out), joint acceleration error (cm/s^2: the mean norm of the second difference of the
joints against the truth's, over the times where both are out at the three times), the occluded spans' joints
recovered within 3 cm (share of the removed joint-times; and of those a tie reaches: a part with patches), the share
of removed joint-times put out at all, the
labels' accuracy, motions and ties, and the per-frame joints flagged wrong
(:func:`~dome_calib.recon.patches.body.flag_joints` with each method's body; precision and recall against the
per-frame joints more than 5 cm from the truth); then the ratios against the aims.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from dome_calib.recon.body_models import JOINTS19  # noqa: E402
from dome_calib.recon.patches.body import TIED_JOINTS, flag_joints, ties_from_patches  # noqa: E402
from dome_calib.recon.patches.motion import MotionOptions  # noqa: E402
from dome_calib.recon.people.run import PeopleOptions, reconstruct_people, refit_over_time  # noqa: E402
from dome_calib.recon.people.sources import InMemorySource, people_streams  # noqa: E402
from dome_calib.recon.people.temporal import TemporalOptions, refine_tracks  # noqa: E402
from dome_calib.recon.people.windows import WindowTask, session_priors, window_observations  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.recon.streams import stream_of_camera  # noqa: E402
from dome_calib.synth.dome import as_built_dome  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.rig import GROUP_MARGIN_MS, RigOptions, few_camera_rig, rig_group  # noqa: E402
from dome_calib.synth.skeleton import synthetic_sync  # noqa: E402
from dome_calib.synth.detector import DetectorModel, synth_detections  # noqa: E402
from dome_calib.synth.group_eval import match_bodies  # noqa: E402
from dome_calib.synth.surface_patches import true_patches  # noqa: E402
from dome_calib.synth.textured import TexturedScene, TextureOptions, nearest_surface_points  # noqa: E402
from dome_calib.recon.patches.model import PatchOptions  # noqa: E402
from dome_calib.recon.patches.parts import BONES, PartOptions  # noqa: E402
from dome_calib.recon.patches.run import patch_stream, reference_stream  # noqa: E402
from dome_calib.recon.patches.seed_skeleton import choose_seed_method  # noqa: E402
from dome_calib.recon.streams import cameras_by_stream  # noqa: E402
from dome_calib.recon.patches.stage import body_prior, reseed_clouds  # noqa: E402
from patches import GrayCache  # noqa: E402  (bench/patches.py: the rendered grey images kept once)

LIMBS = [(JOINTS19.index(a), JOINTS19.index(b)) for a, b in
         (("l_elbow", "l_wrist"), ("r_elbow", "r_wrist"), ("l_knee", "l_ankle"), ("r_knee", "r_ankle"))]


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


#: The shins' joints (knees and ankles): their own figures, ``shins`` in each row.
SHIN_JOINTS = [JOINTS19.index(j) for j in ("l_knee", "l_ankle", "r_knee", "r_ankle")]


def occlude(det, bundle, truth, times_ms, n_spans, seed, span_frames=10, limbs=None):
    """Remove one limb end and its middle joint of each person from every camera for ``span_frames`` reference
    frames, ``n_spans`` times per person at random starts (a detection is the person's whose true joints it lies
    nearest, mean pixel distance): -> (det, removed (T, P, 19) bool, the joint-times taken out of the truth)."""
    rng = np.random.default_rng([seed, 10])
    T = len(times_ms)
    Xt, present = truth.joints_cm(times_ms)
    removed = np.zeros(Xt.shape[:3], bool)
    spans = []  # (person, joints, t0_ms, t1_ms)
    dt = float(np.median(np.diff(times_ms)))
    for p in range(Xt.shape[1]):
        slots = np.arange(5, T - span_frames - 5, span_frames + 5)
        for s in np.sort(rng.choice(slots, min(n_spans, len(slots)), replace=False)):
            a, b = (limbs or LIMBS)[rng.integers(len(limbs or LIMBS))]
            removed[s:s + span_frames, p, [a, b]] = present[s:s + span_frames, p, None]
            spans.append((p, [a, b], times_ms[s] - 0.5 * dt, times_ms[s + span_frames - 1] + 0.5 * dt))
    out = {}
    for cam, frames in det.items():
        _, table = stream_of_camera(bundle, cam)
        views = view_set(bundle, [cam])
        out[cam] = {}
        for f, kp in frames.items():
            t = float(table.time_of(f))
            hit = [sp for sp in spans if sp[2] <= t <= sp[3]]
            if not hit or not len(kp):
                out[cam][f] = kp
                continue
            X, on = truth.joints_cm(np.array([t]))
            uv = project_points(views, X[0].reshape(-1, 3)).uv_px[0].reshape(-1, 19, 2)
            d = np.linalg.norm(kp[:, None, :, :2] - uv[None], axis=-1)  # (N, P, 19)
            w = kp[:, None, :, 2] > 0
            cost = np.where(w, d, 0).sum(-1) / np.maximum(w.sum(-1), 1)
            cost[:, ~on[0]] = np.inf
            owner = np.argmin(cost, axis=1)
            kp = kp.copy()
            for p, js, _, _ in hit:
                kp[np.ix_(owner == p, js)] = 0.0
            out[cam][f] = kp
    return out, removed


def single_window(views, streams, times, seq, options: PeopleOptions):
    """The tracked bodies of ``seq`` -> (fit without ties, fit(ties)): the body over time over all times at once."""
    tem = options.temporal
    source = InMemorySource(streams)
    views = views.subset(source.cameras)
    priors = session_priors(seq.bodies, seq.cameras, tem)
    task = WindowTask(index=0, views=views, source=source, times_ms=times, bodies=seq.bodies, own_start=0,
                      own_stop=len(times), priors=priors, options=tem, max_gap_frames=options.max_gap_frames,
                      batch_times=options.batch_times, depth=None)
    obs = window_observations(task)
    return lambda ties=None: refine_tracks(views, times, seq.bodies, obs, priors, tem, ties=ties)


def _scores(X_est, X, mask, dt_s):
    err = np.linalg.norm(X_est - X, axis=-1)
    acc_est = (X_est[2:] - 2 * X_est[1:-1] + X_est[:-2]) / dt_s ** 2
    acc = (X[2:] - 2 * X[1:-1] + X[:-2]) / dt_s ** 2
    acc_err = np.linalg.norm(acc_est - acc, axis=-1)
    m3 = mask[2:] & mask[1:-1] & mask[:-2]
    return err, acc_err, m3


def _matched_confidence(bodies, ids) -> np.ndarray:
    """(T, P, 19) the c of the bodies matched to the true people (NaN: none)."""
    out = np.full(ids.shape + (19,), np.nan)
    for t, b in enumerate(bodies):
        for p in np.flatnonzero(ids[t] >= 0):
            out[t, p] = b.confidence[int(np.flatnonzero(b.ids == ids[t, p])[0])]
    return out


def _on_tracks(bodies, ids, shape) -> np.ndarray:
    """(T, P, 19, 3) the joints of the given track ids (T, P) in ``bodies`` (NaN: none or missing)."""
    out = np.full(shape, np.nan)
    for t, b in enumerate(bodies):
        for p in np.flatnonzero(ids[t] >= 0):
            k = np.flatnonzero(b.ids == ids[t, p])
            if len(k):
                out[t, p] = b.X_cm[int(k[0])]
    return out


#: The stream's own patches tracked here (``--own-stream``): the cameras of bench/patches.py's panel (the first 24
#: VGA, 4 HD and 2 Kinect colour by name; HD and Kinect colour rendered at half size) or all of the few-camera rig's
#: HD (half size).
OWN_CAMERAS = {"panel": {"vga": 24, "hd": 4, "kinect-color": 2}, "fewcam": {"hd": 99}}


def own_patches(bundle, truth, rig: str, times: np.ndarray, f: int, frames: int, method: str, bodies: list,
                source, o: PatchOptions, done: dict, seed: int = 0, cache: str = "", every: int = 0,
                hidden_from: list | None = None, first: dict | None = None) -> dict:
    """The stream's own patches from images alone (no depth): one cloud at reference frame ``f`` tracked ``frames``
    each way, seeded by ``method`` (``sweep``; ``skeleton``: the body over time ``bodies`` at ``times`` as the
    seeds' depth prior, as ``reconstruct --images --patch-seeds skeleton`` does; ``both``: the two streams side by
    side, their patches concatenated, not thinned; with ``o.body_occlusion`` the body over time is the views'
    occluders, as ``reconstruct --images`` gives it) -> the arrays ``ties_from_patches`` takes and the truth's person
    and part of each patch (the true surface point nearest its centre at the seed time). ``hidden_from``: the body
    fitted with a first stream's ties, the prior of the joints no detection saw (``reseed_hidden``'s second pass:
    of the first streams ``first``, by seeding, the clouds whose seeds' prior it changes streamed again, the
    others kept: :func:`~dome_calib.recon.patches.stage.reseed_clouds`)."""
    by_type = {t: sorted(n for n, c in bundle.cameras.items() if str(c.type) == t) for t in OWN_CAMERAS[rig]}
    cams = [n for t, k in OWN_CAMERAS[rig].items() for n in by_type[t][:k]]
    prior = body_prior(times, bodies, times, hidden_from)  # what reconstruct --images gives the stage
    trajs = []
    for m in (("sweep", "skeleton") if method == "both" else (method,)):
        if m == "auto":  # reconstruct --images' default: the seeding the reference stream's geometry picks
            m = choose_seed_method(view_set(bundle, cameras_by_stream(bundle, cams)[0][reference_stream(bundle, cams)]
                                            )).method
        opts = hashlib.sha256(repr(sorted((k, v) for k, v in dataclasses.asdict(o).items() if k != "reseed_hidden"
                                          )).encode()).hexdigest()[:12]  # the options (main's keys)
        second = ("_reseed" + hashlib.sha256(b"".join(np.ascontiguousarray(b.X_cm).tobytes() for b in hidden_from)
                                             ).hexdigest()[:12] if hidden_from is not None else "")  # on its prior
        cached = os.path.join(cache, f"{rig}_{seed}_{m}_{f}_{frames}_{every}_{opts}{second}.pkl") if cache else ""
        if m not in done and cached and os.path.exists(cached):
            with open(cached, "rb") as fh:
                done[m] = pickle.load(fh)
        if m not in done:  # each seeding's stream computed once (``done``), "both" reuses them
            seed_frames = [g for g in range(f - frames, f + frames + 1) if g % every == 0] if every else [f]
            uses = m == "skeleton" or o.body_occlusion or o.refind_from_body

            def stream_of(at, m=m, uses=uses):
                return patch_stream(bundle, source, cams, (float(times[0]), float(times[-1])),
                                    dataclasses.replace(o, track_frames=frames, seed_method=m), seed_frames=at,
                                    body=prior if uses else None)
            if first is None:
                done[m] = stream_of(seed_frames)
            else:
                table = cameras_by_stream(bundle, cams)[1][reference_stream(bundle, cams)]
                done[m] = reseed_clouds(first[m], np.array(seed_frames),
                                        np.array([table.time_of(g) for g in seed_frames]),
                                        body_prior(times, bodies, times) if uses else None, prior, stream_of)
            if cached:
                with open(cached, "wb") as fh:
                    pickle.dump(done[m], fh)
        trajs.append(done[m])
    X = np.concatenate([t.X_cm for t in trajs])
    normal = np.concatenate([t.normal for t in trajs])
    alive = np.concatenate([t.alive for t in trajs])
    seed_t = np.concatenate([t.seed_time_ms for t in trajs])
    carried = np.concatenate([np.zeros(t.alive.shape, bool) if t.carried is None else t.carried for t in trajs])
    # a patch not alive at its seed time (a seed that did not survive the step to it) has no truth: -1, not the
    # part nearest the origin (which made 17 never-alive patches of the panel "left-shin seeds")
    person, part = np.full(len(X), -1), np.full(len(X), -1)
    tt = trajs[0].times_ms
    for t_seed in np.unique(seed_t):
        k = int(np.argmin(np.abs(tt - t_seed)))
        live = (seed_t == t_seed) & alive[:, k]
        sp = nearest_surface_points(truth, float(tt[k]), X[live, k, 0])
        person[live], part[live] = sp.person, sp.part
    return dict(X_cm=X, normal=normal, alive=alive, person=person, part=part, cameras=len(cams),
                seed_time_ms=seed_t, carried=carried,
                seeds=[int(sum(t.alive[t.seed_time_ms == ts, int(np.argmin(np.abs(tt - ts)))].sum()
                               for ts in np.unique(t.seed_time_ms))) for t in trajs])


def run(rig: str, n_people: int, seconds: float, seed: int, n_occ: int, stream: str = "",
        end_to_end: bool = False, limbs: list | None = None, own: tuple[str, ...] = (), frames: int = 30,
        patch_options: PatchOptions | None = None, part_options: PartOptions | None = None,
        cache: str = "", every: int = 0, motion_options: MotionOptions | None = None) -> list[dict]:
    if rig == "fewcam":
        bundle = few_camera_rig(RigOptions(seed=seed, duration_ms=1000.0 * seconds + GROUP_MARGIN_MS + 100.0))
        truth = rig_group(bundle, n_people=n_people, seed=seed)
        ref = "hd"
        start = truth.start_ms
    else:  # as bench/patches.py sets it up (its --save file can be the patches)
        bundle = as_built_dome("panel", seed=seed)
        bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=6000.0, seed=seed)
        truth = make_group(GroupOptions(n_people=n_people, scenario="conversation", start_ms=500.0,
                                        duration_ms=5000.0, seed=seed))
        ref = "vga"
        start = 2500.0 - 500.0 * seconds
    table = bundle.sync.streams[ref]
    span = (table.univ_time_ms >= start) & (table.univ_time_ms <= start + 1000.0 * seconds)
    times = table.univ_time_ms[span]
    saved = np.load(stream) if stream else None
    if saved is not None:
        times = saved["times_ms"]
    if own:  # one cloud at the reference frame (a multiple of 20) nearest the span's middle, as bench/patches.py
        f = int(table.index[int(np.searchsorted(table.univ_time_ms, start + 500.0 * seconds))])
        f -= f % 20
        times = table.times_of(np.arange(f - frames, f + frames + 1))
    det = synth_detections(bundle, truth, model=DetectorModel(seed=seed))
    det, removed = occlude(det, bundle, truth, times, n_occ, seed, limbs=limbs)
    streams = people_streams(bundle, det)
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    X, present = truth.joints_cm(times)
    options = PeopleOptions()
    cpu = time.process_time()
    if end_to_end:  # reconstruct's own path: the body over time in the session's windows, then again with the ties
        alone = reconstruct_people(views, streams, times, options)
        seq = alone.tracked
        fit = lambda ties: refit_over_time(views, InMemorySource(streams), alone, options, ties)  # noqa: E731
    else:
        seq = reconstruct_people(views, streams, times, dataclasses.replace(options, temporal=TemporalOptions(
            enabled=False)))
        fit = single_window(views, streams, times, seq, options)
        alone = fit()
    cpu_alone = time.process_time() - cpu
    # the truth's people as tracks (for the tied joint-times)
    ids, _, _ = match_bodies([b.ids for b in alone.bodies], [b.X_cm for b in alone.bodies], X, present)
    track_ids = np.array([np.bincount(ids[:, p][ids[:, p] >= 0]).argmax() if (ids[:, p] >= 0).any() else -1
                          for p in range(X.shape[1])])
    cams = list(views.names)
    dt_s = float(np.median(np.diff(times))) / 1000.0
    est = {}
    conf = {}
    mids, est["body_over_time"], _ = match_bodies([b.ids for b in alone.bodies], [b.X_cm for b in alone.bodies], X,
                                                  present)
    conf["body_over_time"] = _matched_confidence(alone.bodies, mids)
    if own:
        source = GrayCache(TexturedScene(bundle, truth, TextureOptions(seed=seed, scale={
            "vga": 1.0, "hd": 0.5, "kinect-color": 0.5}), cache_frames=3))
    rows, done = [], {}
    for how in (own or ("",)):
        cpu = time.process_time()
        extra, seed_t, carried = {}, None, None
        if how:
            po = patch_options or PatchOptions()
            got = own_patches(bundle, truth, rig, times, f, frames, how, alone.bodies, source,
                              dataclasses.replace(po, reseed_hidden=False), done, seed, cache, every)
            if po.reseed_hidden:  # the first stream's ties fit the body; the second stream is seeded from it
                first = _judge(rig, seed, n_people, stream, how, end_to_end, cams, times, X, present, removed,
                               alone, fit, track_ids, est, conf, seq, dt_s, *(got[k] for k in (
                                   "X_cm", "normal", "alive", "person", "part")), cpu_alone, 0.0, {}, part_options,
                               motion_options, got["seed_time_ms"], quiet=True, carried=got["carried"])
                extra["first_pass"] = {k: first[1][k] for k in ("occluded_within_3cm", "limb_end_seeds", "seeds")
                                       if k in first[1]}
                got = own_patches(bundle, truth, rig, times, f, frames, how, alone.bodies, source, po, {}, seed,
                                  cache, every, hidden_from=first[-1], first=done)
            Pt, normal, alive, t_person, t_part = (got[k] for k in ("X_cm", "normal", "alive", "person", "part"))
            extra.update(patch_cameras=got["cameras"], seeds=got["seeds"], seed_every=every)
            seed_t, carried = got["seed_time_ms"], got["carried"]
        elif saved is None:
            Pt, normal, alive, t_person, t_part = true_patches(bundle, cams, truth, times, seed)
        else:
            Pt, normal, alive, t_person, t_part = (saved[k] for k in ("X_cm", "normal", "alive", "person", "part"))
        cpu_patches = time.process_time() - cpu
        rows += _judge(rig, seed, n_people, stream, how, end_to_end, cams, times, X, present, removed, alone, fit,
                       track_ids, est, conf, seq, dt_s, Pt, normal, alive, t_person, t_part, cpu_alone,
                       cpu_patches, extra, part_options, motion_options, seed_t, carried=carried)[:-1]
    return rows


#: Why an occluded joint-time no tie reaches within 3 cm (:func:`reach`), in the order the stages come.
REACH_CAUSES = ("no_seed", "seed_dies", "wrong_label", "no_motion", "tie_too_weak", "tied_not_within_3cm")


def reach(removed, within, times, track_ids, tracks, lab, t_person, t_part, alive, motions, ties,
          seed_time_ms=None, carried=None) -> dict:
    """How far the patches reach each body part and why the occluded joint-times missed are missed.

    Per true part (summed over the people): the patches seeded on it (true part at the seed time), their frames
    alive (median), how many are labelled right, labelled another part, or left unlabelled, and the steps with a
    motion of it. Per occluded joint-time not recovered within 3 cm (``removed & ~within``, (T, P, 19)): the
    furthest stage any part carrying the joint (:data:`TIED_JOINTS`) reaches at either step touching that time:
    ``no_seed`` (no patch seeded on it), ``seed_dies`` (fewer than a motion's ``min_patches`` alive at both ends
    of the step), ``wrong_label`` (alive, but fewer than that labelled to it), ``no_motion`` (labelled, no fit),
    ``tie_too_weak`` (a motion whose tie's sigma passes ``max_sigma_cm``), ``tied_not_within_3cm``. With the
    patches' seed times (N,) (the stream's own clouds), ``seed_dies_by_seeding`` splits ``seed_dies``: the clouds
    nearest the time on either side (at or before, after) seeded at least ``min_patches`` on a part carrying the
    joint, which ended before it (``seeded_then_ended``), or fewer (``too_few_seeded``). With the stream's
    ``carried`` (N, T) (a patch kept by its part's motion at that time, not measured: ``refind_carry_steps``),
    ``seed_dies_carried`` counts the ``seed_dies`` where at least ``min_patches`` of the part were alive or carried
    at both ends of a step touching the time (kept by the carry, not found again)."""
    need = MotionOptions().min_patches
    T, P = removed.shape[:2]
    lab_track = np.where(lab.bone >= 0, tracks[np.maximum(lab.person, 0)], -1)
    track_pos = {int(t): i for i, t in enumerate(tracks)}
    moved = {(int(p), int(b), int(k)) for p, b, k in zip(motions.person, motions.bone, motions.step)}
    tied = {(int(tr), int(j), float(a)) for tr, j, a in zip(ties.track_id, ties.joint, ties.from_ms)}
    parts = {}
    for b, (name, _, _) in enumerate(BONES):
        on = t_part == b
        life = alive[on].sum(1)
        right = on & (lab_track == np.where(t_person >= 0, track_ids[np.maximum(t_person, 0)], -2)) & (lab.bone == b)
        parts[name] = {"seeds": int(on.sum()), "frames_alive_median": float(np.median(life)) if on.any() else None,
                       "right": int(right.sum()), "other_part": int((on & (lab.bone >= 0) & ~right).sum()),
                       "unlabelled": int((on & (lab.bone < 0)).sum()),
                       "steps_moved": int(sum(1 for (_, bb, _) in moved if bb == b))}
    causes = {c: 0 for c in REACH_CAUSES}
    by_seeding = {"seeded_then_ended": 0, "too_few_seeded": 0}
    n_carried = 0
    kept = None if carried is None else alive | carried
    if seed_time_ms is not None:  # each patch's cloud as an index into times
        cloud = np.abs(np.asarray(seed_time_ms)[:, None] - np.asarray(times)[None, :]).argmin(1)
        clouds = np.unique(cloud)
    by_joint: dict[str, dict[str, int]] = {}
    for k, p, j in zip(*np.nonzero(removed & ~within)):
        tr = int(track_ids[p])
        best = 0
        for b in [b for b, js in enumerate(TIED_JOINTS) if j in js]:
            mine = (t_person == p) & (t_part == b)
            if mine.any():
                best = max(best, 1)
            for s in (k - 1, k):
                if s < 0 or s + 1 >= T:
                    continue
                both = alive[:, s] & alive[:, s + 1]
                if (mine & both).sum() < need:
                    continue
                best = max(best, 2)
                if (mine & both & (lab_track == tr) & (lab.bone == b)).sum() < need:
                    continue
                best = max(best, 3)
                if tr < 0 or (track_pos.get(tr, -1), b, s) not in moved:
                    continue
                best = max(best, 4)
                if (tr, int(j), float(times[s])) not in tied:
                    continue
                best = max(best, 5)
        c = REACH_CAUSES[best]
        causes[c] += 1
        if c == "seed_dies" and kept is not None:
            n_carried += any(((t_person == p) & (t_part == b) & kept[:, s] & kept[:, s + 1]).sum() >= need
                             for b, js in enumerate(TIED_JOINTS) if j in js for s in (k - 1, k) if 0 <= s < T - 1)
        if c == "seed_dies" and seed_time_ms is not None:
            around = [clouds[clouds <= k].max(initial=-1), clouds[clouds > k].min(initial=T)]
            seeded = max(int(((t_person == p) & (t_part == b) & np.isin(cloud, around)).sum())
                         for b, js in enumerate(TIED_JOINTS) if j in js)
            by_seeding["seeded_then_ended" if seeded >= need else "too_few_seeded"] += 1
        by_joint.setdefault(JOINTS19[j], {}).setdefault(c, 0)
        by_joint[JOINTS19[j]][c] += 1
    out = {"by_part": parts, "missed_causes": causes, "missed_by_joint": by_joint}
    if seed_time_ms is not None:
        out["seed_dies_by_seeding"] = by_seeding
    if carried is not None:
        out["seed_dies_carried"] = n_carried
    return out


def _judge(rig, seed, n_people, stream, how, end_to_end, cams, times, X, present, removed, alone, fit, track_ids,
           est, conf, seq, dt_s, Pt, normal, alive, t_person, t_part, cpu_alone, cpu_patches, extra,
           part_options=None, motion_options=None, seed_time_ms=None, quiet=False, carried=None) -> list:
    """One set of patches: labelled, their motions tied to the body, the fit with the ties, both rows emitted
    (``quiet``: not emitted) -> [row alone, row with the patches, the bodies fitted with the ties]."""
    cpu = time.process_time()
    ties, lab, motions = ties_from_patches(Pt, normal, alive, times, alone.bodies,  # labelled with the body alone
                                           part_options=part_options, motion_options=motion_options)
    tracks = np.unique(np.concatenate([b.ids for b in alone.bodies]))
    lab_track = np.where(lab.person >= 0, tracks[np.maximum(lab.person, 0)], -1)
    withp = fit(ties)
    cpu_with = time.process_time() - cpu
    judged = lab.bone >= 0
    t_track = np.where(t_person >= 0, track_ids[np.maximum(t_person, 0)], -2)
    right = judged & (lab_track == t_track) & (lab.bone == t_part)
    rows = []
    est, conf = dict(est), dict(conf)
    mids, est["with_patches"], _ = match_bodies([b.ids for b in withp.bodies], [b.X_cm for b in withp.bodies], X,
                                                present)
    conf["with_patches"] = _matched_confidence(withp.bodies, mids)
    frame = _on_tracks(seq.bodies, mids, X.shape)  # the per-frame joints of the same tracks
    tied = np.zeros(X.shape[:3], bool)  # joint-times a tie reaches (from or to)
    for p, tid in enumerate(track_ids):
        on = ties.track_id == tid
        for col in (ties.from_ms[on], ties.to_ms[on]):
            tied[np.searchsorted(times, col), p, ties.joint[on]] = True
    frame_wrong = np.linalg.norm(frame - X, axis=-1) > 5.0
    both = np.isfinite(est["body_over_time"]).all(-1) & np.isfinite(est["with_patches"]).all(-1) & present[..., None]
    for mode, Y in est.items():
        err, acc_err, m3 = _scores(Y, X, both, dt_s)
        out = np.isfinite(Y).all(-1) & present[..., None]
        e_all = np.linalg.norm(Y - X, axis=-1)
        rec = removed & out
        row = {"rig": rig, "patches_from": f"own stream, seeds {how}" if how else "stream" if stream else "truth",
               "seed": seed, "people": n_people,
               "path": "reconstruct (session windows, refit_over_time)" if end_to_end else "one window",
               "views": len(cams), "times": len(times), "method": mode,
               "mpjpe_common_cm": round(float(err[both].mean()), 3),
               "mpjpe_cm": round(float(np.nanmean(e_all[out])), 3),
               "accel_error_cm_s2": round(float(acc_err[m3].mean()), 1),
               "occluded_joint_times": int(removed.sum()),
               "occluded_put_out": round(float(rec.sum() / max(removed.sum(), 1)), 4),
               "occluded_within_3cm": round(float((rec & (e_all < 3.0)).sum() / max(removed.sum(), 1)), 4),
               "occluded_median_error_cm": round(float(np.median(e_all[rec])), 2) if rec.any() else None}
        shin = np.zeros(X.shape[:3], bool)
        shin[..., SHIN_JOINTS] = True
        rs = rec & shin
        row["shins"] = {"mpjpe_common_cm": round(float(err[both & shin].mean()), 3) if (both & shin).any() else None,
                        "accel_error_cm_s2": round(float(acc_err[m3 & shin[2:]].mean()), 1)
                        if (m3 & shin[2:]).any() else None,
                        "occluded_joint_times": int((removed & shin).sum()),
                        "occluded_within_3cm": round(float((rs & (e_all < 3.0)).sum() / max((removed & shin).sum(),
                                                                                          1)), 4)}
        if mode == "with_patches":
            row["shins"]["occluded_tied"] = round(float((removed & tied & shin).sum()
                                                        / max((removed & shin).sum(), 1)), 4)
            row["shins"]["patches_labelled"] = int(np.isin(lab.bone, [10, 11]).sum())  # l_shin, r_shin
            row.update(extra)
            # where the patches are (the truth's part of each, per person) and what they are labelled
            row["patches_by_true_part"] = {f"person_{p}": {name: int(np.sum((t_person == p) & (t_part == b)))
                                                           for b, (name, _, _) in enumerate(BONES)}
                                           for p in range(X.shape[1])}
            row["patches_by_label"] = {name: int(np.sum(lab.bone == b)) for b, (name, _, _) in enumerate(BONES)}
            # per removed joint: [recovered within 3 cm, a tie reaches it, removed] joint-times
            row["reach"] = reach(removed, out & (e_all < 3.0), times, track_ids, tracks, lab, t_person, t_part,
                                 alive, motions, ties, seed_time_ms, carried)
            row["occluded_by_joint"] = {JOINTS19[j]: [int((removed[..., j] & out[..., j]
                                                           & (e_all[..., j] < 3.0)).sum()),
                                                      int((removed[..., j] & tied[..., j]).sum()),
                                                      int(removed[..., j].sum())]
                                        for j in range(19) if removed[..., j].any()}
            if seed_time_ms is not None:
                row["limb_end_seeds"] = limb_end_seeds(removed, times, seed_time_ms, alive, t_person, t_part)
        flags = flag_joints(frame, Y, conf[mode])
        row.update(flags=int(flags.sum()), flags_precision=round(float((flags & frame_wrong).sum() / max(
            flags.sum(), 1)), 4), flags_recall=round(float((flags & frame_wrong).sum() / max(frame_wrong.sum(), 1)), 4),
                   per_frame_wrong=int(frame_wrong.sum()))
        if mode == "with_patches":
            rt = removed & tied
            row.update(occluded_tied=round(float(rt.sum() / max(removed.sum(), 1)), 4),
                       occluded_tied_within_3cm=round(float((rt & out & (e_all < 3.0)).sum() / max(rt.sum(), 1)), 4))
            row.update(patches=int(len(lab.bone)), labelled=round(float(judged.mean()), 4),
                       labels_right=round(float(right.sum() / max(judged.sum(), 1)), 4), motions=len(motions),
                       motion_rms_cm_median=round(float(np.median(motions.rms_cm)), 3) if len(motions) else None,
                       ties=len(ties), cpu_s_patches_truth=round(cpu_patches, 1), cpu_s_labels_motions_fit=round(
                           cpu_with, 1))
        else:
            row.update(cpu_s=round(cpu_alone, 1))
        rows.append(row)
        if not quiet:
            emit(**row)
    return rows + [withp.bodies]


#: The limb ends (:data:`BONES` index, its distal joint): the forearms and shins.
LIMB_ENDS = [(6, 5), (7, 11), (10, 8), (11, 14)]


def limb_end_seeds(removed, times, seed_time_ms, alive, t_person, t_part) -> dict:
    """The seeds (alive at their cloud's time) on each person's forearms and shins (the truth's part), per (cloud,
    person, limb end): ``in_span`` where the limb end's distal joint is occluded at the cloud's time, ``elsewhere``
    the others; each [cases, seeds]."""
    out = {"in_span": [0, 0], "elsewhere": [0, 0]}
    for ts in np.unique(seed_time_ms):
        k = int(np.argmin(np.abs(times - ts)))
        live = (seed_time_ms == ts) & alive[:, k]
        for p in range(removed.shape[1]):
            for b, j in LIMB_ENDS:
                key = "in_span" if removed[k, p, j] else "elsewhere"
                out[key][0] += 1
                out[key][1] += int(np.sum(live & (t_person == p) & (t_part == b)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rig", default="fewcam,panel")
    ap.add_argument("--people", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--occlusions", type=int, default=6)
    ap.add_argument("--stream", default="", help="bench/patches.py --save FILE: its tracked patches (panel, its seed)")
    ap.add_argument("--limbs", default="arms,legs", help="which limbs the occluded spans take: arms (a wrist and "
                    "its elbow), legs (an ankle and its knee), or both")
    ap.add_argument("--end-to-end", action="store_true", help="reconstruct's path: the session's windows, then "
                    "the body over time fitted again with the ties (recon.people.run.refit_over_time)")
    ap.add_argument("--own-stream", default="", help="comma list of sweep, skeleton, both, auto: the stream's own "
                    "patches tracked here in the rendered images, one row each (images alone, no depth; skeleton: "
                    "the body over time alone as the seeds' depth prior; both: the two side by side; auto: what "
                    "reconstruct --images picks by default)")
    ap.add_argument("--patch-options", default="", help="--own-stream: PatchOptions fields, FIELD=VALUE,... "
                    "(values JSON), e.g. seed_min_views=2")
    ap.add_argument("--part-options", default="", help="PartOptions fields of the labels, FIELD=VALUE,... "
                    "(values JSON), e.g. crease_cm=1.0")
    ap.add_argument("--motion-options", default="", help="MotionOptions fields of the part motions, FIELD=VALUE,... "
                    "(values JSON), e.g. min_patches=2")
    ap.add_argument("--frames", type=int, default=30, help="--own-stream: the cloud is tracked this many reference "
                    "frames each way (the times judged: 2 x frames + 1)")
    ap.add_argument("--stream-cache", default="", help="--own-stream: a folder where each (rig, seed, seeding, "
                    "frame) stream is kept once computed and read back (pickle; to judge labels and ties again: "
                    "the key holds --patch-options; clear it when the stream's code changes)")
    ap.add_argument("--seed-every", type=int, default=0, help="--own-stream: a cloud at every reference frame "
                    "of the judged span that is a multiple of this (reconstruct's rule: 20; each tracked --frames each "
                    "way within the span), not one cloud at its middle (0)")
    args = ap.parse_args()
    if set(args.own_stream.split(",")) - {"", "sweep", "skeleton", "both", "auto"}:
        raise SystemExit(f"--own-stream {args.own_stream!r}: a comma list of sweep, skeleton, both, auto")
    if args.own_stream and args.stream:
        raise SystemExit("--own-stream and --stream: one source of the stream's patches")
    patch_options = PatchOptions(**{k: json.loads(v) for k, v in (
        item.split("=", 1) for item in args.patch_options.split(",") if item)})
    part_options = PartOptions(**{k: json.loads(v) for k, v in (
        item.split("=", 1) for item in args.part_options.split(",") if item)})
    motion_options = MotionOptions(**{k: json.loads(v) for k, v in (
        item.split("=", 1) for item in args.motion_options.split(",") if item)})
    emit(bench="patches_body", patch_options=args.patch_options, part_options=args.part_options,
         motion_options=args.motion_options, seed_every=args.seed_every,
         cpus=os.cpu_count(), load=[round(x, 2) for x in os.getloadavg()])
    rows = []
    for rig in args.rig.split(","):
        for seed in [int(x) for x in args.seeds.split(",")]:
            rows += run(rig, args.people, args.seconds, seed, args.occlusions, args.stream, args.end_to_end,
                        [lb for k, lb in zip(("arms", "arms", "legs", "legs"), LIMBS) if k in args.limbs.split(",")],
                        tuple(x for x in args.own_stream.split(",") if x), args.frames, patch_options,
                        part_options, args.stream_cache, args.seed_every, motion_options)
    a = [r for r in rows if r["method"] == "body_over_time"]
    b = [r for r in rows if r["method"] == "with_patches"]
    emit(aims={"patches_from": [y["patches_from"] for y in b],
               "mpjpe_ratio": [round(y["mpjpe_common_cm"] / x["mpjpe_common_cm"], 3) for x, y in zip(a, b)],
               "accel_ratio": [round(y["accel_error_cm_s2"] / x["accel_error_cm_s2"], 3) for x, y in zip(a, b)],
               "occluded_within_3cm": [y["occluded_within_3cm"] for y in b],
               "occluded_within_3cm_alone": [x["occluded_within_3cm"] for x in a]},
         load=[round(x, 2) for x in os.getloadavg()])


if __name__ == "__main__":
    main()
