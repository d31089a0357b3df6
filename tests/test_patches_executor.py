"""The patch stream on the executor: one task, many tasks in this process, a local pool of 2 workers and a Dask
cluster of 2 worker processes give the same arrays bit for bit, from the rendered scene and from its images read
back from a video and PNG folders (the image source pickles without its open video and reopens it in the worker);
seeding from Kinect depth places seeds on the true surface."""
from __future__ import annotations

import json
import pickle

import cv2
import numpy as np
import pytest

from dome_calib.executor import SerialExecutor
from dome_calib.executor.local import LocalProcessExecutor
from dome_calib.recon.patches.images import open_images
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import patch_stream
from dome_calib.synth.textured import TexturedScene, TextureOptions

from .patches_helpers import one_person_capture


@pytest.fixture(scope="module")
def scene():
    bundle, truth = one_person_capture()
    scene = TexturedScene(bundle, truth, TextureOptions(scale={"vga": 1.0, "hd": 0.5, "kinect-color": 0.5}))
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:5]
    return bundle, scene, cams


def _same(a, b) -> None:
    assert a.cameras == b.cameras
    for field in ("ids", "seed_time_ms", "times_ms", "X_cm", "normal", "visible", "photometric", "alive"):
        x, y = getattr(a, field), getattr(b, field)
        assert x.shape == y.shape and x.dtype == y.dtype, field
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), field


OPTIONS = PatchOptions(track_frames=1, seed_features=40, seed_neighbours=3, seed_views=4, seed_every_frames=3)
SEED_FRAMES = [120, 123]


@pytest.fixture(scope="module")
def whole(scene):
    """Two clouds, in this process: one seed task per camera and cloud, one track task per cloud."""
    bundle, source, cams = scene
    table = bundle.sync.streams["vga"]
    span = (table.time_of(119), table.time_of(124))
    traj = patch_stream(bundle, source, cams, span, OPTIONS, seed_frames=SEED_FRAMES)
    assert traj.alive.any(1).sum() > 30 and len(np.unique(traj.ids // 100_000)) == 2
    return span, traj


def test_many_tasks_give_the_arrays_of_one(scene, whole):
    bundle, source, cams = scene
    span, traj = whole
    many = patch_stream(bundle, source, cams, span, OPTIONS, seed_frames=SEED_FRAMES, executor=SerialExecutor(),
                        patches_per_task=9)
    _same(traj, many)


@pytest.mark.slow  # two spawned workers import the toolkit and render their own frames: ~12 CPU-s
def test_a_pool_of_two_workers_gives_the_arrays_of_one_task(scene, whole):
    bundle, source, cams = scene
    span, traj = whole
    with LocalProcessExecutor(2) as pool:
        pooled = patch_stream(bundle, source, cams, span, OPTIONS, seed_frames=SEED_FRAMES, executor=pool,
                              patches_per_task=40)
    _same(traj, pooled)


def write_images(folder, scene, cams: list[str], frames: range) -> None:
    """The scene's grey frames of ``cams``: the first camera as a lossless video (FFV1), the others as PNG folders."""
    folder.mkdir()
    files = {}
    for i, cam in enumerate(cams):
        if i == 0:
            video = cv2.VideoWriter(str(folder / f"{cam}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 25, (640, 480))
            for f in frames:
                video.write(cv2.cvtColor(scene.gray(cam, f), cv2.COLOR_GRAY2BGR))
            video.release()
            files[cam] = f"{cam}.avi"
        else:
            (folder / cam).mkdir()
            for f in frames:
                cv2.imwrite(str(folder / cam / f"img_{f:05d}.png"), scene.gray(cam, f))
            files[cam] = cam
    (folder / "images.json").write_text(json.dumps({"cameras": files, "first_frame": {cams[0]: frames[0]}}))


@pytest.fixture(scope="module")
def images(scene, tmp_path_factory):
    bundle, source, cams = scene
    folder = tmp_path_factory.mktemp("patch_images") / "images"
    write_images(folder, source, cams, range(119, 125))
    return folder


class _Noise:
    """Grey noise frames (cheap to make): what the image source reads back needs no scene."""

    def gray(self, cam: str, frame: int) -> np.ndarray:
        return np.random.default_rng([int(cam.replace("_", "")), frame]).integers(0, 256, (480, 640), np.uint8)


def test_the_image_source_pickles_without_its_open_video_and_frames(scene, tmp_path):
    bundle, _, cams = scene
    write_images(tmp_path / "images", _Noise(), cams[:2], range(119, 125))
    source = open_images(tmp_path / "images", bundle)
    first = source.gray(cams[0], 122)  # the video is open and frames are cached
    copy = pickle.loads(pickle.dumps(source))
    assert len(pickle.dumps(source)) < 20_000  # paths and sizes, not decoded frames
    for cam in cams[:2]:
        for f in (123, 120):  # backward: the copy reopens and seeks
            assert np.array_equal(copy.gray(cam, f), source.gray(cam, f))
    assert np.array_equal(copy.gray(cams[0], 122), first)
    source.close(), copy.close()


@pytest.mark.slow  # a LocalCluster of 2 processes: each imports the toolkit, compiles and renders/decodes: ~25 CPU-s
def test_a_dask_cluster_gives_the_arrays_of_one_task(scene, whole, images):
    from distributed import Client, LocalCluster

    from dome_calib.executor.dask import DaskExecutor

    bundle, source, cams = scene
    span, traj = whole
    read = open_images(images, bundle)
    from_images = patch_stream(bundle, read, cams, span, OPTIONS, seed_frames=SEED_FRAMES)
    assert from_images.alive.any(1).sum() > 30
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      worker_dashboard_address=":0") as lc, Client(lc, set_as_default=False) as client:
        ex = DaskExecutor(lc.scheduler_address, client=client)
        rendered = patch_stream(bundle, source, cams, span, OPTIONS, seed_frames=SEED_FRAMES, executor=ex,
                                patches_per_task=40)
        decoded = patch_stream(bundle, read, cams, span, OPTIONS, seed_frames=SEED_FRAMES, executor=ex,
                               patches_per_task=40)
        stages = ex.stats_dict()["stages"]
    _same(traj, rendered)
    _same(from_images, decoded)
    assert len(stages["seed_task"]["workers"]) == 2 and stages["track_task"]["tasks"] > 2
