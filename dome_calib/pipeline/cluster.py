"""Where the SfM front end's tasks run: the local process pool, or a Dask cluster (``--scheduler``).

A capture may say which capture node holds which cameras' images (``capture.json``:
``"nodes": {"node07": ["07_01", "07_02"], ...}``; node names are the workers' ``dask worker --name``). Feature
extraction of those images is then pinned to that node's worker and reads the image from the node's own disk:
``$DOME_CALIB_CAPTURE_ROOT`` in the worker's environment, a folder with the capture's layout
(``scenes/<scene>/<camera>.png``), or else the head's CAPTURE path. Only the features (keypoints and
descriptors, ~0.5 MB a VGA image) come back. The keypoint refinement's two tasks per image (reference patches,
then alignment against them: :mod:`projector.refine_images`) go to the same node the same way; patches and
shifts move, never an image. Matching, mapping and the bundle adjustment read the scene
database the head writes: matching tasks go to any worker, which therefore reads the head's work folder by the
same path (a shared mount, or one machine). A capture without ``"nodes"`` is read from its shared path by any
worker.
"""
from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from dome_calib.capture_checks import file_sha256
from dome_calib.errors import DomeCalibError
from dome_calib.executor import Executor, Proven
from dome_calib.executor.local import make_executor
from dome_calib.io_utils import atomic_write_text
from dome_calib.pipeline.capture import capture_images, capture_nodes
from projector.features import ImageResult, extract_image
from projector.refine_images import align_image, reference_patches

CAPTURE_ROOT_ENV = "DOME_CALIB_CAPTURE_ROOT"
WORKER_WAIT_S = 20.0  # how long a run waits for the capture's node workers to connect


def node_image_path(head_capture: str, path: str) -> str:
    """Worker side: the image's path on this node (``$DOME_CALIB_CAPTURE_ROOT`` replaces the head's CAPTURE)."""
    root = os.environ.get(CAPTURE_ROOT_ENV)
    if not root:
        return path
    rel = os.path.relpath(path, head_capture)
    return path if rel.startswith("..") else os.path.join(root, rel)


def fingerprint(path: str | Path) -> tuple[int, str]:
    """(bytes, SHA-256) of a file: what a worker proves it read."""
    return os.path.getsize(path), file_sha256(path)


@dataclass(frozen=True)
class ProvenImageTask:
    """Worker side of a per-image task on a cluster (picklable; ``fn``: the feature task, or one of the keypoint
    refinement's): the image as this worker finds it (on its own disk for a camera pinned to its node), its
    (bytes, SHA-256) as evidence, then the task on that path; an image it cannot find is reported per camera,
    naming the path."""

    head_capture: str
    pinned: frozenset[str]
    fn: Callable[[tuple], object] = extract_image

    def __call__(self, task: tuple) -> object:
        camera, path, job = task
        local = node_image_path(self.head_capture, path) if camera in self.pinned else path
        if not os.path.isfile(local):
            if self.fn is extract_image:
                return Proven(ImageResult(camera=camera, failure=f"image not found on this worker ({local})"), None)
            return Proven(self.fn((camera, local, job)), None)  # the task says it found no image there
        return Proven(self.fn((camera, local, job)), fingerprint(local))


class ImageCheck:
    """Head side: each image a worker read must be the one this machine sees at that path (or, pinned to a
    capture node, the one ``capture.json``'s ``"images"`` lists); DomeCalibError naming the worker otherwise,
    before its result is used. ``verified`` / ``unverified`` count the images (each once, however many tasks read
    it: features, then the refinement's two phases)."""

    def __init__(self, capture: Path, pinned: set[str], listed: dict[str, tuple[int, str]]) -> None:
        self.capture, self.pinned, self.listed = capture, pinned, listed
        self._verified: set[str] = set()
        self._unverified: set[str] = set()

    @property
    def verified(self) -> int:
        return len(self._verified)

    @property
    def unverified(self) -> int:
        return len(self._unverified)

    def __call__(self, item: tuple, worker: str, evidence: tuple[int, str] | None) -> None:
        camera, path, _ = item
        key = Path(os.path.relpath(path, self.capture / "scenes")).with_suffix("").as_posix()
        if key in self.listed:
            expected, against = self.listed[key], f"{self.capture / 'capture.json'} lists for it"
        elif camera not in self.pinned and os.path.isfile(path):
            expected, against = fingerprint(path), "this machine reads there"
        else:
            self._unverified.add(key)  # on a capture node, and capture.json lists no fingerprint for it
            return
        if evidence is None and camera in self.pinned:
            return  # not on its node: reported per camera with the path the node looked at
        if evidence != expected:
            got = "no such file" if evidence is None else f"{evidence[0]:,} bytes, SHA-256 {evidence[1][:12]}..."
            raise DomeCalibError(
                f"worker {worker}: {path}: not the image {against} ({got}; expected {expected[0]:,} bytes, SHA-256 "
                f"{expected[1][:12]}...): the worker sees another capture; stopped before its features were used "
                "(give every worker the same capture, or a node its own copy through $DOME_CALIB_CAPTURE_ROOT)")
        self._verified.add(key)


@dataclass(frozen=True)
class _CameraNode:
    node_of: dict[str, str]

    def __call__(self, task: tuple) -> str | None:
        return self.node_of.get(task[0])


def local_pool_stats(executor: Executor) -> dict:
    """Where a local run's tasks ran: this machine's process pool (1 process: in the calling process)."""
    return {"executor": "local", "processes": int(getattr(executor, "num_workers", 1))}


def check_scheduler(scheduler: str | None) -> None:
    """Before any work: a ``--scheduler`` address answers as a Dask scheduler (bounded handshake); one line naming
    the address otherwise."""
    if scheduler is not None:
        from dome_calib.executor.dask import probe_scheduler  # noqa: PLC0415 (distributed: --scheduler runs only)

        probe_scheduler(scheduler)


@contextlib.contextmanager
def open_executor(capture: Path | None, scheduler: str | None, stats: dict | None = None, *,
                  workers: int | None = None) -> Iterator[Executor]:
    """The executor of one run: the local pool without ``scheduler`` (``workers`` processes, default one per
    core), else a :class:`DaskExecutor` whose feature tasks are pinned to the capture's nodes (after waiting for
    those workers; without a capture or its ``"nodes"``, for any worker) and verified (:class:`ImageCheck`).
    ``stats`` receives where the tasks ran: the pool's size, or the cluster's per-stage tallies when the block
    ends."""
    if scheduler is None:
        with make_executor(workers) as pool:
            if stats is not None:
                stats.update(local_pool_stats(pool))
            yield pool
        return
    from dome_calib.executor.dask import DaskExecutor, Route  # distributed takes ~0.5 s to load: --scheduler only

    nodes = capture_nodes(capture) if capture is not None else {}
    routes = {}
    check = None
    if capture is not None:
        node_of = {cam: node for node, cams in nodes.items() for cam in cams}
        check = ImageCheck(capture.resolve(), set(node_of), capture_images(capture))
        for fn in (extract_image, reference_patches, align_image):  # each image's tasks where the image is
            routes[fn] = Route(worker_of=_CameraNode(node_of), verify=check,
                               task_fn=ProvenImageTask(str(capture.resolve()), frozenset(node_of), fn))
    with DaskExecutor(scheduler, routes=routes) as executor:
        if nodes:
            executor.wait_for_workers(nodes, WORKER_WAIT_S)
        else:
            executor.wait_for_any_worker(WORKER_WAIT_S)
        try:
            yield executor
        finally:
            if stats is not None:
                stats.update({"executor": "dask", **executor.stats_dict()})
                if check is not None:
                    stats["images_verified"] = {"verified": check.verified, "unverified": check.unverified}


def settle_cluster_stats(path: Path, stats: dict, *, resumed: bool) -> dict:
    """The run's tallies, kept beside its other work files (``cluster.json``): a stage taken from the work folder
    ran no task now, so its tallies are those of the run that computed it (if that run wrote them)."""
    if resumed and path.is_file():
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            pass  # unreadable: this run's (empty) tallies replace it
    if stats:
        atomic_write_text(path, json.dumps(stats, indent=1))
    return stats


def stage_name(fn_name: str) -> str:
    return {"extract_image": "features", "match_batch": "matching", "render_camera": "rendering",
            "reference_patches": "refine (reference patches)", "align_image": "refine (alignment)"}.get(fn_name, fn_name)


def cluster_section(stats: dict, on_this_machine: list[str]) -> dict | None:
    """report.json's ``"cluster"`` section: where each stage ran. A cluster run: per stage (features, matching)
    the workers with their task counts, wall and task seconds, MB moved; a local run: the pool's size. Stages in
    ``on_this_machine`` ran in the calling process (mapping, the bundle adjustment, ...)."""
    if not stats:
        return None
    if stats.get("executor") == "local":
        n = stats["processes"]
        return {"executor": "local", "processes": n,
                "description": f"local process pool, {n} process{'es' if n != 1 else ''}" if n > 1
                else "in the calling process (1 worker)", "on_this_machine": on_this_machine}
    stages = {stage_name(fn): {"tasks": s["tasks"], "workers": s["workers"], "wall_s": s["wall_s"],
                               "task_s": s["task_s"], "mb_moved": round((s["bytes_out"] + s["bytes_back"]) / 1e6, 2)}
              for fn, s in stats.get("stages", {}).items()}
    return {"executor": "dask", "scheduler": stats["scheduler"], "stages": stages, "on_this_machine": on_this_machine}


def format_cluster(stats: dict, on_this_machine: str = "mapping, bundle adjustment, normalize") -> list[str]:
    """Lines for a command's summary: where each stage ran (nothing for a local run)."""
    if not stats or stats.get("executor") == "local":
        return []
    lines = [f"cluster {stats['scheduler']}:"]
    if "images_verified" in stats:
        v = stats["images_verified"]
        lines.append(f"  images each worker read: {v['verified']} verified (bytes and SHA-256)"
                     + (f", {v['unverified']} on capture nodes not verified (capture.json lists no \"images\")"
                        if v["unverified"] else ""))
    for fn_name, s in stats["stages"].items():
        workers = ", ".join(f"{w} {n}" for w, n in s["workers"].items())
        lines.append(f"  {stage_name(fn_name)}: {s['tasks']} tasks on {workers}; {s['wall_s']:.1f} s wall, "
                     f"{s['task_s']:.1f} s in tasks; {(s['bytes_out'] + s['bytes_back']) / 1e6:.1f} MB moved")
    if on_this_machine:
        lines.append(f"  {on_this_machine}: on this machine")
    return lines
