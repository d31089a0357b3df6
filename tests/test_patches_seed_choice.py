"""``reconstruct --images`` seeds its patches as the rig allows by default (``--patch-seeds auto``,
seed_skeleton.choose_seed_method): the depth sweep where the reference stream's cameras stand close (the dome, the
bench's panel), the people as the depth prior where they stand far apart (the five-camera rig, a wide pair), where
the sweep seeds nothing; and a stream other than the reference may seed on the people with as few cameras as a
skeleton seed needs (stream_may_seed: views_needed, one rule)."""
from __future__ import annotations

import inspect
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from dome_calib.cli.people import reconstruct
from dome_calib.recon.errors import ReconError
from dome_calib.recon.patches import run as patch_run
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import patch_stream
from dome_calib.recon.patches.seed_skeleton import (SWEEP_REACH_DEG, BodyPrior, choose_seed_method,
                                                    neighbour_angle_deg, stream_may_seed)
from dome_calib.recon.patches.stage import PatchStage, plan_patches
from dome_calib.recon.project import view_set
from dome_calib.synth.dome import as_built_dome
from dome_calib.synth.rig import RigOptions, few_camera_rig
from dome_calib.synth.textured import TexturedScene, TextureOptions

from .patches_helpers import WIDE_PAIR, one_person_capture, wide_pair_scene

FRAME = 120


def test_reconstruct_seeds_patches_by_the_rig_by_default():
    assert inspect.signature(reconstruct).parameters["patch_seeds"].default.default == "auto"
    # a seeding it does not know: one line naming the option and what it takes, before the images are opened
    with pytest.raises(ReconError, match=r"--patch-seeds 'sweeps': expected \"auto\" or \"sweep\" or"):
        plan_patches(SimpleNamespace(images=Path("nowhere")), seed_method="sweeps")


def test_the_five_camera_rig_is_seeded_on_the_people_and_the_dome_by_the_sweep():
    rig = few_camera_rig(RigOptions(seed=1, duration_ms=5000.0))
    hd = sorted(n for n, c in rig.cameras.items() if str(c.type) == "hd")
    few = choose_seed_method(view_set(rig, hd), "hd")
    assert few.method == "skeleton" and few.neighbour_deg > SWEEP_REACH_DEG  # 63.2
    assert "63.2 deg" in few.reason and "beyond" in few.reason
    # the bench's panel (its reference stream: the first 24 VGA by name) and the tiny dome keep the sweep
    panel = as_built_dome("panel", seed=0)
    vga = sorted(n for n, c in panel.cameras.items() if str(c.type) == "vga")[:24]
    assert choose_seed_method(view_set(panel, vga)).method == "sweep"
    tiny, _ = one_person_capture()
    vga = sorted(n for n, c in tiny.cameras.items() if str(c.type) == "vga")[:8]
    assert choose_seed_method(view_set(tiny, vga)).method == "sweep"
    # the same cameras in any order, the same angle (a median of quantised angles)
    names = list(reversed(hd))
    assert neighbour_angle_deg(view_set(rig, names)) == few.neighbour_deg


def test_a_wide_pair_gets_patches_by_default_where_the_sweep_seeds_none():
    bundle, truth, scene, _, t = wide_pair_scene(FRAME)
    stage = PatchStage(source=scene, bundle=bundle, cameras=WIDE_PAIR, options=PatchOptions(track_frames=1,
                                                                                           seed_features=150),
                       auto_seeds=True)
    options, seeding = stage.seeding("vga")
    assert options.seed_method == "skeleton" and seeding["chosen"] == "auto" and seeding["method"] == "skeleton"
    table = bundle.sync.streams["vga"]
    at = table.times_of(np.arange(FRAME - 1, FRAME + 2))
    J, present = truth.joints_cm(at)
    body = BodyPrior(times_ms=at, joints_cm=np.where(present[..., None], J, np.nan))
    span = (float(at[0]), float(at[-1]))
    auto = patch_stream(bundle, scene, WIDE_PAIR, span, options, stream="vga", seed_frames=[FRAME], body=body)
    old = patch_stream(bundle, scene, WIDE_PAIR, span, stage.options, stream="vga", seed_frames=[FRAME])
    assert stage.options.seed_method == "sweep" and len(old.ids) == 0  # the old default: nothing
    assert len(auto.ids) >= 10
    given = PatchStage(source=scene, bundle=bundle, cameras=WIDE_PAIR, options=PatchOptions())
    assert given.seeding("vga") == (given.options, {"method": "sweep", "chosen": "given"})


def test_a_stream_of_two_cameras_seeds_on_the_people_but_not_by_the_sweep():
    o = PatchOptions()  # seed_min_views 3
    assert [stream_may_seed(n, o, on_body=True) for n in (1, 2, 3)] == [False, True, True]
    assert [stream_may_seed(n, o, on_body=False) for n in (1, 2, 3)] == [False, False, True]


@pytest.mark.slow  # two HD cameras rendered: ~9 CPU-s on a loaded machine
def test_a_pair_of_hd_cameras_beside_the_vga_reference_seeds_on_the_people(monkeypatch):
    """run.py's check of the other streams follows stream_may_seed: two HD cameras (fewer than ``seed_min_views``)
    seed on the body (before, only the VGA reference stream seeded)."""
    bundle, truth = one_person_capture()
    hd = sorted(n for n, c in bundle.cameras.items() if str(c.type) == "hd")[:2]
    cams = ["01_01", "01_02", "01_03"] + hd
    scene = TexturedScene(bundle, truth, TextureOptions())
    at = bundle.sync.streams["vga"].times_of(np.arange(FRAME - 1, FRAME + 2))
    J, present = truth.joints_cm(at)
    body = BodyPrior(times_ms=at, joints_cm=np.where(present[..., None], J, np.nan))
    seeded: dict[int, int] = {}
    run_one = patch_run.seed_task

    def counted(task):
        key, got = run_one(task)
        seeded[task.stream_rank] = seeded.get(task.stream_rank, 0) + len(got.seeds.X_cm)
        return key, got

    monkeypatch.setattr(patch_run, "seed_task", counted)
    o = PatchOptions(seed_method="skeleton", track_frames=1, seed_features=60)
    traj = patch_run.patch_stream(bundle, scene, cams, (float(at[0]), float(at[-1])), o, stream="vga",
                                  seed_frames=[FRAME], body=body)
    assert set(seeded) == {0, 1} and seeded[1] >= 20, seeded  # the HD pair's seeds: 67
    assert len(traj.ids) > seeded[0] // 2
