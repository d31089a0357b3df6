"""The patch stream on the executor: one task, many tasks in this process and a local pool of 2 workers give the
same arrays bit for bit; seeding from Kinect depth places seeds on the true surface."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.executor import SerialExecutor
from dome_calib.executor.local import LocalProcessExecutor
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import patch_stream
from dome_calib.synth.dome import nominal_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.skeleton import synthetic_sync
from dome_calib.synth.textured import TexturedScene, TextureOptions


@pytest.fixture(scope="module")
def scene():
    bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=1500.0, seed=0)
    truth = make_group(GroupOptions(n_people=1, scenario="conversation", start_ms=100.0, duration_ms=1300.0, seed=2))
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
