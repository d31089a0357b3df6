"""Write a synthetic capture folder (the CONTRACTS.md layout) with ground truth, rendering cameras in parallel
through the project's executor (the local process pool, or a Dask cluster with ``dome-calib synth --scheduler``).

```
CAPTURE/
  capture.json                 preset, seed, scenes, cameras, generator_version, tent poses, projectors, timings
  scenes/<scene>/<camera>.png  8-bit grayscale
  ground_truth/                bundle folder (calibration_synth.json), tent_<scene>.npz, projectors.json
```
The folder is assembled under ``.<name>.tmp-<pid>`` beside the target and renamed into place at the end, so a
reader never sees a half-written capture. Deterministic for a seed (noise is seeded per scene and camera; each
worker prepares the scenes from the seed itself), so the PNGs are the same bytes whichever executor rendered them.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import multiprocessing
import os
import pickle
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np

from dome_calib.bundle import CAMERA_NAMES_HELP, Bundle, Camera, CameraType, is_camera_name

from dome_calib.bundle_io import write_bundle
from dome_calib.capture_checks import file_sha256
from dome_calib.errors import DomeCalibError
from dome_calib.executor import Executor
from dome_calib.executor.local import make_executor
from dome_calib.io_utils import atomic_write_text
from dome_calib.ownership import claim_folder, replace_folder
from dome_calib.layout import Preset, nominal_dome
from dome_calib.synth.dome import Projector, dome_from_calibration, projectors
from dome_calib.synth.render import RenderOptions, SceneState, camera_rays, prepare_scene, render_image
from dome_calib.synth.tent import TENT_CONES, TENT_ELLIPSOIDS, TentPose, scene_poses, tent_mesh
from projector.patterns import make_patterns
from dome_calib.options import AtLeast, Field, Lax, options
from dome_calib.schema import path_of_name, show

logger = logging.getLogger(__name__)

GENERATOR_VERSION = "synth-1"
MAX_SCENES = 99
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 6]


@options
class SynthOptions:
    """What to generate. ``layout``: a real Panoptic calibration file for the cameras (default: the nominal dome)."""

    preset: Annotated[Preset, Lax] = Preset.TINY
    n_scenes: Annotated[int, Field(ge=1, le=MAX_SCENES)] = 3
    seed: AtLeast(0) = 0
    layout: Annotated[Path | None, Lax] = None
    cameras: list[str] | None = None  # render only these cameras of the preset (default: all)
    workers: AtLeast(1) = 2
    overwrite: bool = False
    render: RenderOptions = field(default_factory=RenderOptions)


@dataclass(kw_only=True)
class CaptureSummary:
    folder: Path
    scenes: list[str]
    cameras: list[str]
    n_images: int
    seconds: float


def scene_name(i: int) -> str:
    return f"scene_{i + 1:02d}"


def _projector_json(p: Projector) -> dict:
    return {"name": p.name, "resolution": list(p.resolution), "K": p.K.tolist(), "R": p.R.tolist(),
            "t": p.t_cm.tolist()}


@dataclass(frozen=True)
class RenderJob:
    """What every rendering task of one capture shares (small and picklable: it travels with each task). The
    scenes are prepared from it on each worker, once (:func:`_prepared_scenes`)."""

    seed: int
    scenes: tuple[tuple[str, TentPose], ...]  # (scene name, tent pose)
    render: RenderOptions


@dataclass(kw_only=True)
class RenderedCamera:
    """What one rendering task returns: the camera's PNG files (bytes, by scene) and its seconds on the worker."""

    camera: str
    png: dict[str, bytes]
    seconds: float  # rendering and encoding this camera
    prepare_s: float = 0.0  # preparing the scenes first (the worker's first task only)


# This process's prepared scenes for one job (a worker keeps them across its tasks; a new job replaces them).
_PREPARED: dict[bytes, list[SceneState]] = {}
_PREPARED_LOCK = threading.Lock()


def _prepared_scenes(job: RenderJob) -> list[SceneState]:
    """The job's scenes (projector depth maps and patterns), prepared once per process: deterministic for the
    job, so every worker holds the same ones."""
    key = hashlib.sha256(pickle.dumps(job)).digest()
    with _PREPARED_LOCK:
        if key not in _PREPARED:
            _PREPARED.clear()
            projs = projectors(job.seed)
            patterns = make_patterns(job.seed, tuple(sorted(projs)))
            _PREPARED[key] = [prepare_scene(name, pose, projs, patterns, job.render) for name, pose in job.scenes]
        return _PREPARED[key]


def render_camera(task: tuple[RenderJob, Camera]) -> RenderedCamera:
    """Task: render one camera for every scene of the job; its PNGs come back as bytes (the head writes them, so
    a worker needs no access to the capture folder)."""
    job, cam = task
    if multiprocessing.parent_process() is not None:  # a pool or Dask worker process: one OpenCV thread per task
        cv2.setNumThreads(1)
    t0 = time.perf_counter()
    scenes = _prepared_scenes(job)
    prepare_s, t0 = time.perf_counter() - t0, time.perf_counter()
    rays = camera_rays(cam, job.render)
    png = {}
    for scene in scenes:
        ok, buf = cv2.imencode(".png", render_image(rays, scene, job.render, job.seed), PNG_PARAMS)
        if not ok:
            raise OSError(f"camera {cam.name}, {scene.name}: PNG encoding failed")
        png[scene.name] = buf.tobytes()
    return RenderedCamera(camera=cam.name, png=png, seconds=time.perf_counter() - t0, prepare_s=prepare_s)


def _cost(bundle: Bundle, name: str) -> float:
    w, h = bundle.cameras[name].resolution
    return w * h


def load_layout(options: SynthOptions) -> Bundle:
    """The ground-truth bundle of the capture's cameras."""
    if options.layout is not None:
        if not Path(options.layout).is_file():
            raise DomeCalibError(f"{options.layout}: layout file not found (expected a calibration_<seq>.json)")
        bundle = dome_from_calibration(options.layout, options.preset, options.seed)
        other = sorted(n for n in bundle.cameras if not is_camera_name(n))
        if other:  # the capture's cameras are Panoptic names (capture.json): its images are <camera>.png
            raise DomeCalibError(f"{options.layout}: camera {show(other[0])}: not a Panoptic camera name "
                                 f"({CAMERA_NAMES_HELP}): a synthetic capture names its cameras as the dome does")
    else:
        bundle = nominal_dome(options.preset, options.seed)
    if options.cameras:
        unknown = sorted(set(options.cameras) - set(bundle.cameras))
        if unknown:
            raise DomeCalibError(f"camera {unknown[0]}: not in preset {options.preset} "
                                 f"(it has {', '.join(sorted(bundle.cameras)[:4])}, ...)")
        bundle.cameras = {n: bundle.cameras[n] for n in sorted(set(options.cameras))}
    return bundle


def synthesize(out: str | Path, options: SynthOptions, progress: Callable[[int, int], None] | None = None, *,
               executor: Executor | None = None) -> CaptureSummary:
    """Generate a capture folder at ``out``. ``progress(done_images, total_images)`` is called as images finish.

    The cameras are rendered by ``executor`` (one task per camera: the local pool, or a Dask cluster), by
    default a local pool of ``options.workers`` processes; the images are the same bytes either way.

    Raises :class:`DomeCalibError` for a bad request (scene count, existing output, missing layout file).
    """
    t_start = time.perf_counter()
    out = Path(out)
    if os.path.lexists(out) and not options.overwrite:
        raise DomeCalibError(f"{out}: already exists (choose another folder or pass --overwrite)")
    claim_folder(out)  # --overwrite replaces only a folder dome-calib wrote (dome_calib.ownership)
    bundle = load_layout(options)
    projs = projectors(options.seed)
    poses = scene_poses(options.n_scenes, options.seed)
    names = [scene_name(i) for i in range(options.n_scenes)]
    cameras = sorted(bundle.cameras)
    total = len(cameras) * len(names)
    if progress:
        progress(0, total)

    with replace_folder(out) as tmp:
        for s in names:
            (tmp / "scenes" / s).mkdir(parents=True)
        gt = tmp / "ground_truth"
        write_bundle(bundle, gt)
        for s, pose in zip(names, poses):
            V, F = tent_mesh(pose)
            np.savez_compressed(gt / f"tent_{s}.npz", vertices_cm=V, faces=F.astype(np.int32),
                                yaw_rad=pose.yaw_rad, position_cm=pose.T_cm)
        job = RenderJob(seed=options.seed, scenes=tuple(zip(names, poses)), render=options.render)
        order = sorted(cameras, key=lambda n: (-_cost(bundle, n), n))  # big images first: better load balance
        done = 0
        prepare_s = 0.0
        with contextlib.ExitStack() as stack:
            pool = executor if executor is not None else stack.enter_context(make_executor(options.workers))
            try:
                for res in pool.map(render_camera, [(job, bundle.cameras[n]) for n in order]):
                    for scene, data in res.png.items():  # files by name: the completion order does not matter
                        path_of_name(tmp / "scenes" / scene, res.camera, ".png").write_bytes(data)
                    done += len(res.png)
                    prepare_s = max(prepare_s, res.prepare_s)  # each worker prepares once, in parallel
                    if progress:
                        progress(done, total)
            finally:
                _PREPARED.clear()  # if this process rendered (1 worker), free its scenes
        atomic_write_text(gt / "projectors.json", json.dumps(
            {"projectors": [_projector_json(p) for _, p in sorted(projs.items())],
             "patterns": f"projector.patterns.make_patterns(seed={options.seed}) == `dome-calib patterns OUT "
                         f"--seed {options.seed}`"}, indent=1))
        seconds = time.perf_counter() - t_start
        meta = {
            "preset": str(options.preset), "seed": options.seed, "scenes": names, "cameras": cameras,
            "generator_version": GENERATOR_VERSION,
            "layout": str(options.layout) if options.layout else "nominal",
            "camera_types": {t.value: sorted(bundle.of_type(t)) for t in CameraType},
            "tent_poses": {s: {"yaw_rad": p.yaw_rad, "x_cm": p.x_cm, "z_cm": p.z_cm} for s, p in zip(names, poses)},
            "tent_primitives": {"cones": [vars(c) for c in TENT_CONES],
                                "ellipsoids": [vars(e) for e in TENT_ELLIPSOIDS]},
            "projectors": sorted(projs), "pattern_seed": options.seed,
            "ground_truth": "ground_truth/calibration_synth.json",
            "seconds": {"total": round(seconds, 2), "prepare_scenes": round(prepare_s, 2)},
        }
        atomic_write_text(tmp / "capture.json", json.dumps(meta, indent=1))
    logger.debug("capture %s: %d images in %.1f s", out, total, seconds)
    return CaptureSummary(folder=out, scenes=names, cameras=cameras, n_images=total, seconds=seconds)


def split_onto_nodes(capture: Path, base: Path, node_names: tuple[str, ...]) -> tuple[Path, dict[str, Path]]:
    """Lay a capture out as if its images sat on capture nodes (for tests and bench/distributed.py): ``base/head``
    holds capture.json with ``"nodes"`` (cameras dealt round-robin in name order) and ``"images"`` (each image's
    size and SHA-256, which the nodes' workers must read), and no images; ``base/<node>`` holds that node's images
    in the usual ``scenes/<scene>/`` layout. Returns (head folder, {node: its folder}); existing node folders are
    replaced."""
    meta = json.loads((capture / "capture.json").read_text(encoding="utf-8"))
    cams = sorted(meta["cameras"])
    nodes = {name: cams[k::len(node_names)] for k, name in enumerate(node_names)}
    images = {}
    for scene in meta["scenes"]:
        for c in cams:
            path = capture / "scenes" / scene / f"{c}.png"
            images[f"{scene}/{c}"] = {"bytes": path.stat().st_size, "sha256": file_sha256(path)}
    head = base / "head"
    shutil.rmtree(head, ignore_errors=True)
    head.mkdir(parents=True)
    (head / "capture.json").write_text(json.dumps({**meta, "nodes": nodes, "images": images}, indent=1),
                                       encoding="utf-8")
    folders = {}
    for node, node_cams in nodes.items():
        shutil.rmtree(base / node, ignore_errors=True)
        for scene in meta["scenes"]:
            dst = base / node / "scenes" / scene
            dst.mkdir(parents=True)
            for c in node_cams:
                shutil.copy(capture / "scenes" / scene / f"{c}.png", dst)
        folders[node] = base / node
    return head, folders
