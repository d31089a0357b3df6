"""Patch trajectory bench: the dense 3D patch stream (:mod:`dome_calib.recon.patches`) on a synthetic textured group
(:mod:`dome_calib.synth.textured`), judged against the renderer's truth.

Run: .venv/bin/python bench/patches.py [--people 2] [--scenario conversation] [--vga 24] [--hd 4] [--kinect 2]
         [--frames 30] [--seed 0] [--seeding images,depth,skeleton] [--joint-noise 1.5] [--executors here,pool,dask --workers 2 --patches-per-task 1000]
         [--variants 'base:;drift:anchor_flow=true']  (PatchOptions variants, one run each on the same frames)
     (``python -P`` with ``dask``: bench/distributed.py would shadow the ``distributed`` package)
Options not shown above: ``--render-cache FOLDER`` (the grey frames read from disk when there, else rendered and
written there: a re-run renders nothing), ``--judge-chunk 1000`` (patches judged together: bounds the judging's
memory on the full dome; no figure depends on it), ``--patches-per-task 1000,4000`` (one run per cut),
``--oracle-normals all|outline`` (a ceiling: the seeds tracked with the true normal, :func:`oracle_normals`).
Setup: the as-built dome's panel preset (VGA of panels 1-2, the HD and Kinect colour cameras nearest them), the
first ``--vga`` VGA by name and the first ``--hd`` / ``--kinect`` others; VGA at 640 x 480, HD and Kinect colour
rendered at half size (960 x 540); the group seeded by ``--seed``; one cloud seeded at a VGA frame (a multiple of
20) and tracked ``--frames`` frames each way. Prints one JSON object per line:

- ``render``: CPU ms per view per frame of the textured renderer, by camera type;
- ``patches``: seeds, centre error against the true surface point (the one nearest the patch at the seed, followed
  on its part) after 0, 1, 10 and ``--frames`` frames (median and 90th percentile, mm; both directions pooled),
  trajectory length (frames each way, median and share reaching 25; ``length_share_25_on_point``: share reaching 25
  with the centre within 1 cm of its true point at every time on the way; ``reach_share``: share of the seeds'
  tracks, both ways, alive all of 10 and of ``--frames`` frames), visibility against the renderer's truth
  (precision and recall of the MAP labels and of photometric consistency alone, the CVPR 2014 baseline, over all
  live patch-times and cameras; split: patches within 1 cm of their true point, views within 78 deg of the true
  normal; ``visibility_errors``: the false positives and negatives of each, counted by cause, :func:`error_causes`),
  patches given to the right body part (true skeleton, and the truth plus 1.5 cm noise per joint),
  patch-views-frames per CPU-second of the stage (rendering excluded), load average, and the costs of
  ``stream_cost``;
- ``stream_cost`` (printed before the judging, which takes minutes on the full dome): CPU of the stage by phase,
  rendering excluded (seeding, placing, the track tasks), and of the tracking steps alone (``steps_cpu_s``: the
  track tasks' :func:`~dome_calib.recon.patches.track.track_cloud` calls; ``per_cloud_cpu_s``: the rest of the track
  tasks, the seeds' normals refined and the seed time's visibility), ``patch_steps`` (a patch alive at a time
  before its direction's last is tried one step further) and ``patch_steps_kept`` (alive after the step),
  ``steps_cpu_ms_per_patch_step``, the same by step number from the seed (``..._by_step``: step 1, a direction's
  first, has no prediction and flows with ``lk_levels``; the CPU between the starts of two steps), rendering CPU, wall, ``patches_per_task`` and the process's peak memory so far;
- ``same_stream`` (a second ``--patches-per-task`` cut of the same run): whether its arrays are the first cut's bits
  (not judged again), and its costs;
- ``executor`` (with ``--executors``, image seeding only, not judged): per executor the CPU of this process and of
  its worker processes (rendering included: each worker renders the frames it reads), the wall of the stream and of
  starting the executor, and whether the arrays are the bits of the first executor's.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from dome_calib.io_utils import atomic_path  # noqa: E402
from dome_calib.panoptic_io import read_kcalibration  # noqa: E402
from dome_calib.recon.depth import depth_folder_reader  # noqa: E402
from dome_calib.recon.patches import run as patch_run  # noqa: E402
from dome_calib.recon.patches import track as patch_track  # noqa: E402
from dome_calib.recon.patches.seed_depth import DepthFrames  # noqa: E402
from dome_calib.synth.depth_people import write_group_depth  # noqa: E402
from dome_calib.synth.dome import as_built_dome  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.skeleton import synthetic_sync  # noqa: E402
from dome_calib.synth.depth_people import nearest_capsule_hits  # noqa: E402
from dome_calib.synth.textured import (VISIBILITY_TOLERANCE_CM, TexturedScene, TextureOptions,  # noqa: E402
                                       nearest_surface_points, part_frames, surface_points_cm, surface_visibility)
from dome_calib.recon.patches.frames import patch_grid_cm  # noqa: E402
from dome_calib.recon.patches.model import PatchOptions  # noqa: E402
from dome_calib.recon.patches.parts import BONES, PartOptions, label_parts  # noqa: E402
from dome_calib.recon.patches.run import imaged_views, patch_stream  # noqa: E402
from dome_calib.recon.patches.seed import reference_cameras  # noqa: E402
from dome_calib.recon.patches.seed_skeleton import BodyPrior  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402


KCALIBRATION = Path(__file__).resolve().parents[1] / "tests" / "data" / "panoptic" / "kcalibration_171026_cello3.json"


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def _pct(x: np.ndarray, q: float) -> float | None:
    return round(float(np.percentile(x, q)), 2) if len(x) else None


def precision_recall(est: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    tp = np.sum(est & true)
    return round(float(tp / max(est.sum(), 1)), 4), round(float(tp / max(true.sum(), 1)), 4)


#: Causes of the visibility's errors, first that applies (:func:`error_causes`).
FALSE_POSITIVE_CAUSES = ("drifted", "back_facing", "occluded_other_person", "occluded_own_other_part",
                         "occluded_own_part", "out_of_image", "other")
FALSE_NEGATIVE_CAUSES = ("drifted", "near_border", "grazing", "wrong_normal", "labelled_not_visible")


def cause_rules(truth, views, t_ms: float, X: np.ndarray, P: np.ndarray, normal: np.ndarray, person: np.ndarray,
                part: np.ndarray, err_mm: np.ndarray, true: np.ndarray, o: PatchOptions
                ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The (N, V) rules of the visibility's errors at one time, in the order they are given (the first that applies
    is the cause): false positives' (:data:`FALSE_POSITIVE_CAUSES`), false negatives' (:data:`FALSE_NEGATIVE_CAUSES`).

    False positive (labelled visible, the truth says not): ``drifted`` (the patch is more than 1 cm from its true
    point), ``back_facing`` (the true surface faces away), occluded by a capsule of ``other_person``, of the same
    person's ``own_other_part`` or ``own_part`` (the truth's ray test), ``out_of_image``, ``other``. False negative:
    ``drifted``, ``near_border`` (the patch's square leaves the image: no candidate), ``grazing`` (true cosine
    below ``min_cos_view``: no candidate), ``wrong_normal`` (true cosine above it, the estimated one not),
    ``labelled_not_visible`` (a candidate the minimum cut labelled not visible)."""
    V = len(views.names)
    C = views.center_cm
    to_t = C[None] - P[:, None]
    cos_t = np.einsum("nvi,ni->nv", to_t, normal) / np.linalg.norm(to_t, axis=-1)
    to_e = C[None] - X[:, None, 0]
    n_e = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    cos_e = np.einsum("nvi,ni->nv", to_e, n_e) / np.linalg.norm(to_e, axis=-1) / np.linalg.norm(n_e, axis=-1)[:, None]
    grid = patch_grid_cm(X[:, 0], X[:, 1], X[:, 2], o.ncc_size_cm)
    square_in = project_points(views, grid.reshape(-1, 3)).visible.reshape(V, len(X), -1).all(-1).T
    in_image = project_points(views, P).visible.T
    Xj, present = truth.joints_cm(np.array([t_ms]))
    people = np.flatnonzero(present[0])
    fr = part_frames(Xj[0, people])
    A = fr.A.reshape(-1, 3)
    B = A + fr.R[..., 2].reshape(-1, 3) * fr.length.reshape(-1, 1)
    occ_person, occ_part = np.full((len(X), V), -1), np.full((len(X), V), -1)
    for v in range(V):
        d = P - C[v]
        s = np.linalg.norm(d, axis=1)
        hit, which = nearest_capsule_hits(C[v], d / s[:, None], A, B, fr.radius.reshape(-1))
        hidden = hit < s - VISIBILITY_TOLERANCE_CM
        occ_person[hidden, v] = people[which[hidden] // fr.radius.shape[1]]
        occ_part[hidden, v] = which[hidden] % fr.radius.shape[1]
    drift = np.broadcast_to((err_mm > 10.0)[:, None], true.shape)
    own = occ_person == person[:, None]
    every = np.ones_like(true)
    fp_rules = [drift, cos_t <= 0, (occ_person >= 0) & ~own, own & (occ_part != part[:, None]),
                own & (occ_part == part[:, None]), ~in_image, every]
    fn_rules = [drift, ~square_in, cos_t < o.min_cos_view, cos_e <= o.min_cos_view, every]
    return fp_rules, fn_rules


def first_cause(rules: list[np.ndarray]) -> np.ndarray:
    """(N, V) the index of the first of ``rules`` ((N, V) bool each, the last all True) that holds."""
    out = np.full(rules[0].shape, len(rules) - 1, np.int64)
    for i in range(len(rules) - 1, -1, -1):
        out = np.where(rules[i], i, out)
    return out


def error_causes(truth, views, t_ms: float, X: np.ndarray, P: np.ndarray, normal: np.ndarray, person: np.ndarray,
                 part: np.ndarray, err_mm: np.ndarray, labellings: dict[str, np.ndarray], true: np.ndarray,
                 o: PatchOptions) -> dict[str, dict[str, dict[str, int]]]:
    """The visibility's false positives and negatives at one time, each given the first cause that applies, for each
    of ``labellings`` (name -> (N, V) labels; the causes' geometry is computed once for all of them): the classes
    of :func:`cause_rules`."""
    fp_rules, fn_rules = cause_rules(truth, views, t_ms, X, P, normal, person, part, err_mm, true, o)
    out = {}
    for method, est in labellings.items():
        out[method] = {}
        for kind, wrong, rules, names in (("false_positive", est & ~true, fp_rules, FALSE_POSITIVE_CAUSES),
                                          ("false_negative", true & ~est, fn_rules, FALSE_NEGATIVE_CAUSES)):
            left, counts = wrong.copy(), {}
            for name, rule in zip(names, rules):
                counts[name] = int((left & rule).sum())
                left &= ~rule
            out[method][kind] = counts
    return out


#: The modules whose code draws a pixel of the rendered frames (the render cache's key holds their text).
RENDER_MODULES = ("dome_calib/synth/textured.py", "dome_calib/synth/group.py", "dome_calib/synth/dome.py",
                  "dome_calib/synth/skeleton.py", "dome_calib/camera.py", "dome_calib/recon/project.py")


def render_cache_key(bundle, truth_options: GroupOptions, texture: TextureOptions, preset: str, seed: int) -> str:
    """What makes every pixel of a rendered frame: the dome (preset, seed: the cameras), the group, the texture
    options (seed, blur, noise, scale) and the renderer's code; a hash of all of it (``--render-cache``)."""
    import hashlib

    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    h.update(repr((preset, seed, dataclasses.asdict(truth_options), dataclasses.asdict(texture))).encode())
    h.update(repr(sorted((n, repr(c)) for n, c in bundle.cameras.items())).encode())
    h.update(repr(bundle.sync).encode())
    for m in RENDER_MODULES:
        if (root / m).exists():
            h.update((root / m).read_bytes())
    return h.hexdigest()[:16]


class GrayCache:
    """The scene's grey images kept once rendered (``--track-views`` / ``--ref-spacing-deg`` run the stage several
    times on the same frames: each is rendered once); the frame source the stage reads. With ``disk`` (a folder,
    ``--render-cache``; its name the :func:`render_cache_key`), each grey image is also read from and written to
    ``disk/CAMERA_FRAME.npy`` (written to a staging file, then renamed): a later run on the same scene renders
    nothing. Reading one counts as rendering (``render_s["disk"]``): the bench's cost, not the stream's."""

    def __init__(self, scene: TexturedScene, disk: Path | None = None) -> None:
        self.scene, self._gray, self.disk = scene, {}, disk
        self.render_s, self.renders = scene.render_s, scene.renders

    def camera(self, name: str):
        return self.scene.camera(name)

    def frame_indices(self, name: str) -> np.ndarray:
        return self.scene.frame_indices(name)

    def gray(self, name: str, frame: int) -> np.ndarray:
        key = (name, int(frame))
        if key not in self._gray:
            path = None if self.disk is None else self.disk / f"{name}_{int(frame)}.npy"
            if path is not None and path.exists():
                c0 = time.process_time()
                self._gray[key] = np.load(path)
                self.render_s["disk"] = self.render_s.get("disk", 0.0) + time.process_time() - c0
                self.renders["disk"] = self.renders.get("disk", 0) + 1
            else:
                self._gray[key] = self.scene.gray(name, frame)
                if path is not None:
                    c0 = time.process_time()
                    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
                        np.save(fh, self._gray[key])
                    self.render_s["disk"] = self.render_s.get("disk", 0.0) + time.process_time() - c0
        return self._gray[key]


class PhaseTimer:
    """CPU seconds of the stage's seed and track tasks (run in this process), rendering inside them apart."""

    def __init__(self, scene: TexturedScene, seeds_memo: dict | None = None) -> None:
        self.scene = scene
        self.cpu = {"seed": 0.0, "place": 0.0, "track": 0.0}
        self.render = {"seed": 0.0, "place": 0.0, "track": 0.0}
        self._saved = (patch_run.seed_task, patch_run.place_task, patch_run.track_task)
        self.memo = seeds_memo  # seed tasks' results by key, reused (their CPU then counted as at the first run)
        self.reused = 0.0
        # the tracking steps alone (track_cloud inside the track tasks; not the seeds' refinement and seed-time
        # visibility, the per-cloud work of a track task): CPU, rendering inside it, patch-steps tried and kept
        self.steps = {"cpu_s": 0.0, "render_s": 0.0, "tried": 0, "kept": 0}
        self._in_track = False

    def _wrap(self, phase: str, fn):
        def timed(task):
            if phase == "seed" and self.memo is not None and task.key in self.memo:
                out, cpu = self.memo[task.key]
                self.cpu[phase] += cpu
                self.reused += cpu
                return out
            c0, r0 = time.process_time(), sum(self.scene.render_s.values())
            self._in_track = phase == "track"
            try:
                out = fn(task)
            finally:
                self._in_track = False
            if phase == "seed" and self.memo is not None:
                self.memo[task.key] = (out, time.process_time() - c0 - (sum(self.scene.render_s.values()) - r0))
            self.cpu[phase] += time.process_time() - c0
            self.render[phase] += sum(self.scene.render_s.values()) - r0
            return out
        return timed

    def __enter__(self) -> PhaseTimer:
        self.lk = {"calls": 0, "points": 0}
        self._lk_saved = cv2.calcOpticalFlowPyrLK

        def counted(prev, nxt, pts, *a, **k):  # every optical-flow call builds both images' pyramids anew
            self.lk["calls"] += 1
            self.lk["points"] += len(pts)
            return self._lk_saved(prev, nxt, pts, *a, **k)
        cv2.calcOpticalFlowPyrLK = counted
        self._track_cloud_saved = patch_run.track_cloud

        marks: list[float] = []  # CPU less rendering at each step's start (its flown views chosen) and at the end
        self.by_step: dict[int, list] = {}  # step number (1: the first from the seed) -> [CPU s, patch-steps tried]

        def net() -> float:
            return time.process_time() - sum(self.scene.render_s.values())

        def stepped(*a, **k):  # a patch alive at a time before the last is tried one step further
            if not self._in_track:
                return self._track_cloud_saved(*a, **k)
            c0, r0 = time.process_time(), sum(self.scene.render_s.values())
            marks.clear()
            out = self._track_cloud_saved(*a, **k)
            marks.append(net())
            self.steps["render_s"] += sum(self.scene.render_s.values()) - r0
            self.steps["cpu_s"] += time.process_time() - c0
            self.steps["tried"] += int(out.alive[:, :-1].sum())
            self.steps["kept"] += int(out.alive[:, 1:].sum())
            for j in range(1, len(marks)):
                got = self.by_step.setdefault(j, [0.0, 0])
                got[0] += marks[j] - marks[j - 1]
                got[1] += int(out.alive[:, j - 1].sum())
            marks.clear()
            return out
        self._best_views_saved = patch_track.best_views

        def step_start(*a, **k):  # called once at the start of every tracking step
            if self._in_track:
                marks.append(net())
            return self._best_views_saved(*a, **k)
        patch_track.best_views = step_start
        patch_run.track_cloud = stepped
        patch_run.seed_task = self._wrap("seed", self._saved[0])
        patch_run.place_task = self._wrap("place", self._saved[1])
        patch_run.track_task = self._wrap("track", self._saved[2])
        return self

    def __exit__(self, *exc: object) -> None:
        patch_run.seed_task, patch_run.place_task, patch_run.track_task = self._saved
        patch_run.track_cloud = self._track_cloud_saved
        patch_track.best_views = self._best_views_saved
        cv2.calcOpticalFlowPyrLK = self._lk_saved


def evaluate(args, bundle, truth, cams, traj, t_seed: float, nf: int, imaged=None, o: PatchOptions | None = None
             ) -> dict:
    """The stream against the renderer's truth (module docstring)."""
    s = int(np.argmin(np.abs(traj.times_ms - t_seed)))
    sp = nearest_surface_points(truth, t_seed, traj.X_cm[:, s, 0])
    P, normal = surface_points_cm(truth, traj.times_ms, sp.person, sp.part, sp.local_cm)  # (T, N, 3)
    err_mm = 10.0 * np.linalg.norm(traj.X_cm[:, :, 0] - P.transpose(1, 0, 2), axis=-1)  # (N, T)
    errors = {}
    for lag in sorted({0, 1, 10, nf}):
        cols = [c for c in (s - lag, s + lag) if 0 <= c < len(traj.times_ms)]
        e = np.concatenate([err_mm[traj.alive[:, c], c] for c in cols] + [np.zeros(0)])
        errors[f"after_{lag}"] = {"median_mm": _pct(e, 50), "p90_mm": _pct(e, 90), "n": int(len(e))}
    seed_normal_deg = None
    live = traj.alive[:, s]
    if live.any():
        cos = np.clip(np.sum(traj.normal[live, s] * normal[s][live], -1), -1.0, 1.0)
        seed_normal_deg = {"median": _pct(np.degrees(np.arccos(cos)), 50), "p90": _pct(np.degrees(np.arccos(cos)), 90)}
    back = traj.alive[:, :s + 1][:, ::-1].cumprod(axis=1).sum(axis=1) - 1
    fwd = traj.alive[:, s:].cumprod(axis=1).sum(axis=1) - 1
    lengths = np.concatenate([back, fwd])[np.concatenate([traj.alive[:, s]] * 2)]
    on = traj.alive & (err_mm <= 10.0)  # alive and within 1 cm of its point: the trajectory still follows it
    on_back = on[:, :s + 1][:, ::-1].cumprod(axis=1).sum(axis=1) - 1
    on_fwd = on[:, s:].cumprod(axis=1).sum(axis=1) - 1
    on_lengths = np.concatenate([on_back, on_fwd])[np.concatenate([traj.alive[:, s]] * 2)]
    est, base, true, near, facing = [], [], [], [], []
    causes = {m: {} for m in ("map", "photometric")}
    centres = view_set(bundle, cams).center_cm
    chunk = max(1, int(getattr(args, "judge_chunk", 0) or len(traj.alive) or 1))
    for k in range(len(traj.times_ms)):
        for lo in range(0, len(traj.alive), chunk):  # every figure is per patch: judged in chunks of rows
            a = np.flatnonzero(traj.alive[lo:lo + chunk, k]) + lo
            if len(a) == 0:
                continue
            true.append(surface_visibility(bundle, cams, truth, float(traj.times_ms[k]), P[k][a], normal[k][a]))
            est.append(traj.visible[a, k])
            base.append(traj.photometric[a, k])
            near.append(np.broadcast_to((err_mm[a, k] < 10.0)[:, None], true[-1].shape))
            to_cam = centres[None] - P[k][a][:, None]
            facing.append(np.sum(to_cam * normal[k][a][:, None], -1) / np.linalg.norm(to_cam, axis=-1) >= 0.2)
            if imaged is not None:
                got_all = error_causes(truth, imaged, float(traj.times_ms[k]), traj.X_cm[a, k], P[k][a], normal[k][a],
                                       sp.person[a], sp.part[a], err_mm[a, k],
                                       {"map": est[-1], "photometric": base[-1]}, true[-1], o)
                for m, got in got_all.items():
                    for kind, counts in got.items():
                        for name, c in counts.items():
                            causes[m].setdefault(kind, {}).setdefault(name, 0)
                            causes[m][kind][name] += c
    V = len(cams)
    est, base, true = (np.concatenate(x + [np.zeros((0, V), bool)]) for x in (est, base, true))
    near, facing = (np.concatenate(x + [np.zeros((0, V), bool)]) for x in (near, facing))
    split = {}
    for name, m in (("patch_within_1cm", near), ("view_cos_at_least_0.2", facing)):
        split[name] = {"share": round(float(m.mean()), 3) if m.size else None,
                       "map": precision_recall(est & m, true & m), "photometric": precision_recall(base & m, true & m)}
    labels = {}
    by_part = {}  # the true part of each seeded patch (alive at the seed): how many, per person
    for person in np.unique(sp.person[live]):
        on = live & (sp.person == person)
        by_part[f"person_{int(person)}"] = {name: int(np.sum(on & (sp.part == b))) for b, (name, _, _) in
                                            enumerate(BONES)}
    Xj, present = truth.joints_cm(traj.times_ms)
    Xj[~present] = np.nan
    rng = np.random.default_rng(args.seed)
    for kind, joints in (("true_skeleton", Xj), ("skeleton_noise_1.5cm", Xj + rng.normal(0.0, 1.5, Xj.shape))):
        lab = label_parts(traj.X_cm[:, :, 0], traj.normal, traj.alive, joints)
        judged = traj.alive.sum(1) >= PartOptions().min_frames
        given = judged & (lab.bone >= 0)
        right = given & (lab.person == sp.person) & (lab.bone == sp.part)
        labels[kind] = {"accuracy": round(float(right.sum() / max(given.sum(), 1)), 4),
                        "labelled_share": round(float(given.sum() / max(judged.sum(), 1)), 4), "n": int(judged.sum()),
                        "by_true_part": {name: [int(np.sum(right & (sp.part == b))),  # [right, labelled]
                                                int(np.sum(given & (sp.part == b)))]
                                         for b, (name, _, _) in enumerate(BONES)}}
    if args.save:
        np.savez_compressed(args.save, X_cm=traj.X_cm, normal=traj.normal, alive=traj.alive, visible=traj.visible,
                            photometric=traj.photometric, times_ms=traj.times_ms, person=sp.person, part=sp.part,
                            local_cm=sp.local_cm, joints_cm=Xj)
    return dict(seeds=int(live.sum()), seeds_by_true_part=by_part, errors=errors, seed_normal_error_deg=seed_normal_deg,
                length_median_frames=float(np.median(lengths)) if len(lengths) else None,
                length_share_25=round(float(np.mean(lengths >= min(25, nf))), 3) if len(lengths) else None,
                length_share_25_on_point=round(float(np.mean(on_lengths >= min(25, nf))), 3) if len(lengths) else None,
                reach_share={str(n): round(float(np.mean(lengths >= n)), 4) if len(lengths) else None
                             for n in sorted({min(10, nf), nf})},
                visibility_map={"precision": precision_recall(est, true)[0], "recall": precision_recall(est, true)[1]},
                visibility_photometric={"precision": precision_recall(base, true)[0],
                                        "recall": precision_recall(base, true)[1]},
                visibility_split=split, visibility_errors=causes if imaged is not None else None,
                true_views_per_patch=round(float(true.sum(1).mean()), 2) if len(true) else None,
                map_views_per_patch=round(float(est.sum(1).mean()), 2) if len(est) else None,
                parts=labels, patch_frames=int(traj.alive.sum()), patch_views_frames=int(traj.visible.sum()))


def _children_cpu_s() -> dict[int, float]:
    """CPU seconds so far of this process's descendants (a pool's workers, a LocalCluster's nannies and workers)."""
    import psutil  # distributed's dependency

    out = {}
    for child in psutil.Process().children(recursive=True):
        try:
            t = child.cpu_times()
            out[child.pid] = t.user + t.system
        except psutil.Error:
            pass
    return out


def _open_executor(kind: str, workers: int):
    if kind == "here":
        return contextlib.nullcontext(None)
    if kind == "pool":
        from dome_calib.executor.local import LocalProcessExecutor
        return LocalProcessExecutor(workers)
    if kind == "dask":
        from distributed import Client, LocalCluster

        from dome_calib.executor.dask import DaskExecutor

        @contextlib.contextmanager
        def cluster():
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                              worker_dashboard_address=":0") as lc, Client(lc, set_as_default=False) as client:
                yield DaskExecutor(lc.scheduler_address, client=client)
        return cluster()
    raise SystemExit(f"--executors: unknown executor {kind!r} (here, pool, dask)")


def run_executors(args, bundle, scene, cams, span, o, f: int) -> None:
    """The same stream (``--seeding images``) on each of ``--executors``: CPU (this process and its worker
    processes, rendering included: workers render what they read) and wall, and whether the arrays are the bits of
    the first run."""
    first = None
    for kind in args.executors.split(","):
        load = os.getloadavg()
        w0 = time.perf_counter()
        with _open_executor(kind, args.workers) as ex:
            start_wall = time.perf_counter() - w0
            before, cpu0, wall0 = _children_cpu_s(), time.process_time(), time.perf_counter()
            traj = patch_stream(bundle, scene, cams, span, o, seed_frames=[f], executor=ex,
                                patches_per_task=cuts(args)[0])
            wall = time.perf_counter() - wall0
            head_cpu, after = time.process_time() - cpu0, _children_cpu_s()
        workers_cpu = sum(c - before.get(pid, 0.0) for pid, c in after.items())
        arrays = {k: getattr(traj, k) for k in ("ids", "seed_time_ms", "times_ms", "X_cm", "normal", "visible",
                                                "photometric", "alive")}
        same = None if first is None else all(
            np.array_equal(first[k], a, equal_nan=a.dtype.kind == "f") and first[k].dtype == a.dtype
            for k, a in arrays.items())
        first = arrays if first is None else first
        emit(what="executor", executor=kind, workers=1 if kind == "here" else args.workers,
             patches_per_task=cuts(args)[0], cameras=len(cams), frames_each_way=args.frames,
             seeds=int(traj.alive.any(1).sum()), patch_views_frames=int(traj.visible.sum()),
             same_bits_as_first=same, start_wall_s=round(start_wall, 1), wall_s=round(wall, 1),
             head_cpu_s=round(head_cpu, 1), workers_cpu_s=round(workers_cpu, 1),
             cpu_s=round(head_cpu + workers_cpu, 1), load_before=[round(x, 2) for x in load],
             load=[round(x, 2) for x in os.getloadavg()])


def add_scene_arguments(ap: argparse.ArgumentParser, scenario: str = "conversation") -> None:
    """The scene options of a bench that judges a saved stream (``--save``) again: the same as the run's."""
    ap.add_argument("--preset", default="panel")
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--scenario", default=scenario)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vga", type=int, default=24)
    ap.add_argument("--hd", type=int, default=4)
    ap.add_argument("--kinect", type=int, default=2)


def cameras_by_type(bundle) -> dict[str, list[str]]:
    """The bundle's VGA, HD and Kinect colour cameras, each by name."""
    return {t: sorted(n for n, c in bundle.cameras.items() if str(c.type) == t) for t in ("vga", "hd", "kinect-color")}


def bench_cameras(bundle, vga: int, hd: int, kinect: int) -> list[str]:
    """The bench's cameras: the first ``vga`` VGA by name, then the first ``hd`` HD and ``kinect`` Kinect colour."""
    by_type = cameras_by_type(bundle)
    return by_type["vga"][:vga] + by_type["hd"][:hd] + by_type["kinect-color"][:kinect]


def parse_variants(text: str) -> dict[str, dict]:
    """``--variants``: ``NAME:FIELD=VALUE,FIELD=VALUE;NAME2:...`` (values JSON; lists become tuples) -> {name:
    PatchOptions fields}; empty: one run with the defaults, named "default"."""
    if not text:
        return {"default": {}}
    out = {}
    for item in text.split(";"):
        name, _, fields = item.partition(":")
        out[name.strip()] = {}
        for key, value in re.findall(r"(\w+)=(\[[^\]]*\]|[^,]*)", fields):
            v = json.loads(value)
            out[name.strip()][key] = tuple(v) if isinstance(v, list) else v
    return out


OUTLINE_EDGE_ON_DEG = 15.0  # --oracle-normals outline: every camera seeing the seed within this of edge-on


@contextlib.contextmanager
def oracle_normals(mode: str, truth):
    """``--oracle-normals``: a ceiling, not a method. ``all``: every seed within 1 cm of the true surface tracked
    with the true normal there (the photometric refinement off); ``outline``: after the refinement, only the seeds
    whose cameras labelled visible at the seed all see the true surface within :data:`OUTLINE_EDGE_ON_DEG` of edge-on
    get it. The stage's ``run_cloud`` / ``refine_normals`` are wrapped for the run and put back after."""
    from dome_calib.recon.patches.frames import patch_axes
    from dome_calib.recon.patches.seed import Seeds, patch_triplets

    def true_normals(X: np.ndarray, centres: np.ndarray, t_ms: float, seen: np.ndarray | None, axis_cm: float):
        sp = nearest_surface_points(truth, float(t_ms), X[:, 0])
        P, n_true = (a[0] for a in surface_points_cm(truth, np.array([float(t_ms)]), sp.person, sp.part,
                                                     sp.local_cm))
        take = np.linalg.norm(P - X[:, 0], axis=1) < 1.0
        if seen is not None:
            to = centres[None] - X[:, 0][:, None]
            to /= np.linalg.norm(to, axis=-1, keepdims=True)
            cos = np.einsum("nvi,ni->nv", to, n_true)
            take &= np.all(np.where(seen, np.abs(cos) <= np.sin(np.radians(OUTLINE_EDGE_ON_DEG)), True), 1)
        u, _, n = patch_axes(X[:, 0], X[:, 1], X[:, 2])
        n = np.where(take[:, None], n_true, n)
        return patch_triplets(X[:, 0], n, u, axis_cm), n

    saved = (patch_run.run_cloud, patch_run.refine_normals)
    if mode == "all":
        def run_cloud(source, views, clocks, t_ms, times, seeds, o, *a, **k):
            if len(seeds.X_cm):
                X, n = true_normals(seeds.X_cm, views.center_cm, t_ms, None, o.axis_cm)
                seeds = Seeds(X_cm=X, normal=n, seen=seeds.seen)
            return saved[0](source, views, clocks, t_ms, times, seeds, o, *a, **{**k, "refine": False})
        patch_run.run_cloud = run_cloud
    elif mode == "outline":
        def refine(source, views, frames, X, visible, o):
            return true_normals(saved[1](source, views, frames, X, visible, o), views.center_cm, frames.t_ms,
                                visible, o.axis_cm)[0]
        patch_run.refine_normals = refine
    try:
        yield
    finally:
        patch_run.run_cloud, patch_run.refine_normals = saved


def bench_scene(args: argparse.Namespace) -> tuple:
    """The bench's dome, group and texture from ``--preset``, ``--seed``, ``--people``, ``--scenario`` ->
    (bundle with its sync and Kinects, group options, the group's truth, texture options); other benches judge the
    same scene (``bench/patch_normals.py --seeds``)."""
    bundle = as_built_dome(args.preset, seed=args.seed)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=6000.0, seed=args.seed)
    bundle.kinect = read_kcalibration(KCALIBRATION)
    group = GroupOptions(n_people=args.people, scenario=args.scenario, start_ms=500.0, duration_ms=5000.0,
                         seed=args.seed)
    texture = TextureOptions(seed=args.seed, scale={"vga": 1.0, "hd": 0.5, "kinect-color": 0.5})
    return bundle, group, make_group(group), texture


def run(args: argparse.Namespace) -> None:
    bundle, group, truth, texture = bench_scene(args)
    scene = TexturedScene(bundle, truth, texture,
                          cache_frames=1 if args.preset == "full" else 3)  # the grey images are kept (GrayCache)
    by_type = cameras_by_type(bundle)
    cams = bench_cameras(bundle, args.vga, args.hd, args.kinect)
    table = bundle.sync.streams["vga"]
    pos = int(np.searchsorted(table.univ_time_ms, 2500.0))
    f = int(table.index[pos])
    f -= f % 20
    nf = args.frames
    span = (table.time_of(f - nf), table.time_of(f + nf))
    t_seed = table.time_of(f)
    o = PatchOptions(track_frames=nf)
    if args.executors != "here":
        return run_executors(args, bundle, scene, cams, span, o, f)
    disk = None
    if args.render_cache:
        disk = Path(args.render_cache) / render_cache_key(bundle, group, texture, args.preset, args.seed)
        disk.mkdir(parents=True, exist_ok=True)
        emit(what="render_cache", folder=str(disk), files=sum(1 for _ in disk.glob("*.npy")))
    source = GrayCache(scene, disk)
    track_views = [int(k) for k in args.track_views.split(",")] if args.track_views else [o.track_views]
    spacings = ([float(x) for x in args.ref_spacing_deg.split(",")] if args.ref_spacing_deg
                else [o.seed_reference_spacing_deg])
    with tempfile.TemporaryDirectory() as tmp:
        c0 = time.process_time()
        write_group_depth(Path(tmp) / "depth", bundle, truth, (t_seed - 40.0, t_seed + 40.0), seed=args.seed)
        depth = DepthFrames(depth_folder_reader(Path(tmp) / "depth"))
        depth_cpu = time.process_time() - c0
        emit(what="depth", nodes=list(depth.read_frame.nodes), cpu_s=round(depth_cpu, 2),
             load=[round(x, 2) for x in os.getloadavg()])
        variants = parse_variants(args.variants)
        at = table.times_of(np.arange(f - nf, f + nf + 1))  # "skeleton": the true people with --joint-noise
        J, present = truth.joints_cm(at)
        J = np.where(present[..., None, None], J, np.nan)
        body = BodyPrior(times_ms=at, joints_cm=J + np.random.default_rng(args.seed).normal(0.0, args.joint_noise,
                                                                                           J.shape))
        runs = [(seeding, spacing, k, streams, name, cut) for seeding in args.seeding.split(",")
                for spacing in (spacings if seeding == "images" else [0.0]) for k in track_views
                for streams in args.seed_streams.split(",") for name in variants for cut in cuts(args)]
        memo: dict = {}
        judged: dict = {}  # a run's arrays by its runs' key without the cut: a second cut is compared, not judged
        for seeding, spacing, k, streams, name, cut in runs:
            ok = dataclasses.replace(o, **{"track_views": k, "seed_reference_spacing_deg": spacing,
                                           "seed_streams": streams, **variants[name]})  # a variant may set any
            if seeding == "skeleton":
                ok = dataclasses.replace(ok, seed_method="skeleton")
            load = os.getloadavg()
            cpu0, wall0, render0 = time.process_time(), time.perf_counter(), sum(scene.render_s.values())
            # seed tasks are reused between runs whose seeding options are the same (a variant may change them:
            # ncc_size_cm and refine_ncc_size_cm size the skeleton seeds' NCC; seed_ncc_size_cm is a seed_ field)
            seeding_key = (seeding, spacing, ok.ncc_size_cm, ok.refine_ncc_size_cm, tuple(sorted(
                (k, repr(v)) for k, v in dataclasses.asdict(ok).items() if k.startswith(("seed_", "normal_")))))
            with PhaseTimer(scene, memo.setdefault(seeding_key, {})) as phases, \
                    oracle_normals(args.oracle_normals, truth):
                traj = patch_stream(bundle, source, cams, span, ok, seed_frames=[f], patches_per_task=cut,
                                    depth=depth if seeding == "depth" else None,
                                    body=(body if seeding == "skeleton" or ok.body_occlusion or ok.refind_from_body
                                          else None))
            cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
            render_cpu = sum(scene.render_s.values()) - render0
            emit(what="render", **{f"{k}_cpu_ms_per_view": round(1000.0 * scene.render_s[k] / scene.renders[k], 1)
                                   for k in sorted(scene.renders)}, renders=scene.renders, people=args.people,
                 load=[round(x, 2) for x in load])
            stage_cpu = cpu - render_cpu + phases.reused  # seeds reused from an earlier run count their CPU
            track_cpu = phases.cpu["track"] - phases.render["track"]
            steps_cpu = phases.steps["cpu_s"] - phases.steps["render_s"]
            cost = dict(stage_cpu_s=round(stage_cpu, 1), render_cpu_s=round(render_cpu, 1),
                        seed_cpu_s=round(phases.cpu["seed"] - phases.render["seed"], 2),
                        place_cpu_s=round(phases.cpu["place"] - phases.render["place"], 2),
                        track_cpu_s=round(track_cpu, 2), patch_steps=phases.steps["tried"],
                        patch_steps_kept=phases.steps["kept"], steps_cpu_s=round(steps_cpu, 2),
                        steps_cpu_ms_per_patch_step=round(1000.0 * steps_cpu / max(phases.steps["tried"], 1), 3),
                        per_cloud_cpu_s=round(track_cpu - steps_cpu, 2),
                        wall_s=round(wall, 1), lk_calls=phases.lk["calls"], lk_points=phases.lk["points"],
                        steps_cpu_ms_per_patch_step_by_step={
                            str(j): round(1000.0 * c / max(n, 1), 3) for j, (c, n) in sorted(phases.by_step.items())},
                        patch_steps_by_step={str(j): n for j, (_, n) in sorted(phases.by_step.items())},
                        patches_per_task=cut, max_rss_mb=max_rss_mb())
            # the costs before the judging (on the full dome the truth's visibility takes minutes)
            emit(what="stream_cost", seeding=seeding, variant=name, cameras=len(cams), people=args.people,
                 frames_each_way=nf, seeds=int(traj.alive.any(1).sum()), **cost,
                 load_before=[round(x, 2) for x in load], load=[round(x, 2) for x in os.getloadavg()])
            arrays = {a: getattr(traj, a) for a in ("ids", "X_cm", "normal", "visible", "photometric", "alive")}
            earlier = judged.get((seeding, spacing, k, streams, name))
            if earlier is not None:  # the same stream cut otherwise: the same bits expected, and judged once
                emit(what="same_stream", as_patches_per_task=earlier[0],
                     same_bits=all(np.array_equal(earlier[1][a], x, equal_nan=x.dtype.kind == "f")
                                   for a, x in arrays.items()), **cost)
                continue
            judged[seeding, spacing, k, streams, name] = (cut, arrays)
            if args.no_judge:
                continue
            save = args.save if len(runs) == 1 or not args.save else args.save.replace(
                ".npz", f"_{seeding}_{streams}_{k}_{spacing:g}_{name}.npz")
            rss_before = max_rss_mb()
            got = evaluate(argparse.Namespace(**{**vars(args), "save": save}), bundle, truth, cams, traj, t_seed, nf,
                           imaged_views(scene, cams), ok)
            emit(what="patches", seeding=seeding, seed_streams=streams, track_views=k, ref_spacing_deg=spacing,
                 variant=name, variant_options=variants[name],
                 reference_cameras=len(reference_cameras(view_set(bundle, [c for c in cams if c in by_type["vga"]]),
                                                         spacing, o.volume_height_cm)),
                 scenario=args.scenario, people=args.people, cameras=len(cams),
                 vga=args.vga, hd=args.hd, kinect=args.kinect, frames_each_way=nf, seed=args.seed, **got, **cost,
                 patch_views_frames_per_cpu_s=round(got["patch_views_frames"] / max(stage_cpu, 1e-9), 1),
                 tracking_patch_views_frames_per_cpu_s=round(got["patch_views_frames"] / max(track_cpu, 1e-9), 1),
                 max_rss_mb_before_judging=rss_before, max_rss_mb_after_judging=max_rss_mb(),
                 load_before=[round(x, 2) for x in load], load=[round(x, 2) for x in os.getloadavg()])


def cuts(args: argparse.Namespace) -> list[int]:
    """``--patches-per-task`` as a list (one run each in this process; the executors take the first)."""
    return [int(x) for x in str(args.patches_per_task).split(",")]


def max_rss_mb() -> int:
    """This process's peak resident memory so far (MB)."""
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", type=str, default="panel", help="the as-built dome's preset: panel or full")
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--scenario", type=str, default="conversation")
    ap.add_argument("--vga", type=int, default=24)
    ap.add_argument("--hd", type=int, default=4)
    ap.add_argument("--kinect", type=int, default=2)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0, help="the synthetic group's and the renderer's random seed")
    ap.add_argument("--seeding", type=str, default="images,depth",
                    help="how clouds are seeded, one run each: images (triangulated features), depth (the Kinects), "
                         "skeleton (seed_method skeleton on the true people with --joint-noise)")
    ap.add_argument("--joint-noise", type=float, default=1.5,
                    help="--seeding skeleton: cm of noise per joint coordinate on the true people (seeded)")
    ap.add_argument("--save", type=str, default="", help="also write the trajectories and truth to this .npz")
    ap.add_argument("--executors", type=str, default="here",
                    help="here (this process), or a comma list of here, pool (a local process pool), dask (a Dask "
                         "LocalCluster of worker processes): the image-seeded stream on each, CPU, wall, same bits")
    ap.add_argument("--workers", type=int, default=2, help="worker processes of --executors pool and dask")
    ap.add_argument("--patches-per-task", type=str, default="1000",
                    help="comma list: seeds per track task (the cut of the work: the same bits whatever it is), one "
                         "run each in this process (a second is compared with the first, not judged again); "
                         "--executors take the first")
    ap.add_argument("--track-views", type=str, default="",
                    help="comma list of PatchOptions.track_views (0: all), one run each on the same rendered frames")
    ap.add_argument("--seed-streams", type=str, default="all",
                    help="comma list of PatchOptions.seed_streams (image seeding): all (every stream with enough "
                         "cameras), reference (the VGA alone); one run each on the same rendered frames")
    ap.add_argument("--ref-spacing-deg", type=str, default="",
                    help="comma list of PatchOptions.seed_reference_spacing_deg (image seeding), one run each")
    ap.add_argument("--variants", type=str, default="",
                    help="PatchOptions variants, one run each on the same rendered frames: NAME:FIELD=VALUE,...;"
                         "NAME2:... (values JSON, e.g. 'base:;anchor:anchor=true,anchor_min_ncc=0.5')")
    ap.add_argument("--judge-chunk", type=int, default=1000,
                    help="patches judged together against the truth per time (the judging's memory grows with this "
                         "times the cameras; every figure is per patch, so the chunk changes no figure; 0: all)")
    ap.add_argument("--no-judge", action="store_true",
                    help="the costs alone (stream_cost, same_stream lines): the stream is not judged against the truth")
    ap.add_argument("--render-cache", type=str, default="",
                    help="a folder: the grey frames are read from it when there, else rendered and written to it "
                         "(a subfolder per scene, named by the hash of everything that changes a pixel)")
    ap.add_argument("--oracle-normals", choices=("", "all", "outline"), default="",
                    help="a ceiling, not a method: the seeds tracked with the true surface normal (all: every seed "
                         "within 1 cm, refinement off; outline: after the refinement, the seeds every visible camera "
                         "sees within 15 deg of edge-on)")
    args = ap.parse_args()
    if args.workers < 1 or min(cuts(args)) < 1:
        raise SystemExit("--workers and --patches-per-task must be at least 1")
    run(args)


if __name__ == "__main__":
    main()
