"""Seeds from every stream (``PatchOptions.seed_streams``): a stream other than the reference seeds at its own frame
nearest the seed time, and its seeds are carried to the seed time by one tracking step (``run.place_seeds``); the
reference stream's seeds are kept as they were."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dome_calib.bundle import Bundle
from dome_calib.executor import SerialExecutor
from dome_calib.panoptic_io import read_kcalibration
from dome_calib.recon.depth import depth_folder_reader
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import (clocks_of, imaged_views, patch_stream, place_seeds, stream_seed_frame)
from dome_calib.recon.patches.seed import seed_patches
from dome_calib.recon.patches.seed_depth import DepthFrames, seed_from_own_kinect
from dome_calib.recon.patches.track import quantise_cm
from dome_calib.recon.patches.visibility import camera_neighbours
from dome_calib.synth.depth_people import write_group_depth
from dome_calib.synth.dome import nominal_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.skeleton import synthetic_sync
from dome_calib.synth.textured import TexturedScene, TextureOptions, nearest_surface_points, surface_points_cm

from .patches_helpers import one_person_capture
from .recon_helpers import REAL_KCALIBRATION

FRAME = 144  # HD frame of the seed (735 ms): the walker is in the tiny dome's middle


@pytest.fixture(scope="module")
def walker():
    """The tiny dome's 5 HD (the reference stream: the most cameras) and the 4 VGA of panel 1 (25 fps on their own
    clock: their frame nearest the seed time is 10 ms off it); one person walking ~0.9 m/s, so a VGA seed not
    carried to the seed time is ~1 cm off. (The 5 HD stand far apart and seed little by the sweep: which stream is
    the reference does not matter to the rule.)"""
    bundle: Bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=1500.0, seed=0)
    truth = make_group(GroupOptions(n_people=1, scenario="walk_past", start_ms=100.0, duration_ms=1300.0, seed=2))
    scene = TexturedScene(bundle, truth, TextureOptions(scale={"vga": 1.0, "hd": 0.5, "kinect-color": 0.5}))
    vga = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:4]
    hd = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "hd"]
    o = PatchOptions(track_frames=0, seed_features=150, seed_neighbours=3, seed_views=4)
    return bundle, truth, scene, hd, vga, o


def test_another_streams_seeds_are_carried_to_the_seed_time(walker):
    bundle, truth, scene, ref, other, o = walker
    cams = ref + other
    views, clocks = imaged_views(scene, cams), clocks_of(bundle, scene, cams)
    t_seed = bundle.sync.streams["hd"].time_of(FRAME)
    g = stream_seed_frame(clocks[len(ref):], t_seed)
    t_g = bundle.sync.streams["vga"].time_of(g)
    assert 5.0 < abs(t_g - t_seed) <= 20.0  # the VGA frame is not at the seed time
    seeds = seed_patches(scene, views.subset(other), {n: g for n in other}, o)
    assert len(seeds.X_cm) > 20
    seen = np.zeros((len(seeds.X_cm), len(cams)), bool)
    seen[:, len(ref):] = seeds.seen
    placed, kept = place_seeds(scene, views, clocks, t_g, t_seed, dataclasses.replace(seeds, seen=seen),
                         camera_neighbours(views, o.prior_neighbours), dataclasses.replace(o, refine_normals=False))
    assert kept.mean() > 0.8
    # the truth: each seed's surface point (nearest at the VGA frame's time) followed to the seed time
    sp = nearest_surface_points(truth, t_g, seeds.X_cm[kept, 0])
    at_g, _ = surface_points_cm(truth, np.array([t_g]), sp.person, sp.part, sp.local_cm)
    at_seed, _ = surface_points_cm(truth, np.array([t_seed]), sp.person, sp.part, sp.local_cm)
    moved_mm = 10 * np.linalg.norm(at_seed[0] - at_g[0], axis=1)
    # the step moves each seed as its surface point moved (the seeds' own error, ~7 mm on 4 cameras of one panel,
    # is the sweep's, not the placement's)
    step_err_mm = 10 * np.linalg.norm((placed.X_cm[:, 0] - seeds.X_cm[kept, 0]) - (at_seed[0] - at_g[0]), axis=1)
    assert np.median(moved_mm) > 5.0  # left at the VGA frame, the seeds would be this far behind
    assert np.median(step_err_mm) < 0.3 * np.median(moved_mm)
    assert placed.seen.sum(1).min() >= o.min_visible  # seen at the seed time (MAP), mostly by the seeding stream
    assert np.mean(placed.seen[:, len(ref):].sum(1) >= 2) > 0.8


@pytest.mark.slow  # two streams of 9 cameras seeded and placed twice: ~10 CPU-s
def test_every_stream_seeds_and_the_reference_streams_seeds_are_kept(walker):
    bundle, truth, scene, ref, other, o = walker
    cams = ref + other
    table = bundle.sync.streams["hd"]
    span = (table.time_of(FRAME), table.time_of(FRAME))
    traj = patch_stream(bundle, scene, cams, span, o, seed_frames=[FRAME])
    views = imaged_views(scene, cams)
    ref_seeds = seed_patches(scene, views.subset(ref), {n: FRAME for n in ref}, o)
    n_ref = len(ref_seeds.X_cm)
    assert len(traj.ids) > n_ref  # the other stream's seeds join
    live = traj.alive[:n_ref, 0]
    assert np.array_equal(quantise_cm(ref_seeds.X_cm)[live, 0], traj.X_cm[:n_ref][live, 0, 0])  # first, as they were
    added = traj.alive[n_ref:, 0]
    assert added.sum() > 10
    sp = nearest_surface_points(truth, table.time_of(FRAME), traj.X_cm[n_ref:][added, 0, 0])
    assert np.median(sp.distance_cm) < 1.0  # on the surface (the sweep on 4 cameras of one panel: ~7 mm)
    # cut into tasks on an executor (seeds per stream and camera, placing per stream, tracks of 9): the same bits
    many = patch_stream(bundle, scene, cams, span, o, seed_frames=[FRAME], executor=SerialExecutor(), patches_per_task=9)
    for field in ("ids", "X_cm", "normal", "visible", "alive"):
        x, y = getattr(traj, field), getattr(many, field)
        assert x.shape == y.shape and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), field


def test_a_kinect_seeds_from_its_own_depth_in_its_colour_camera(tmp_path):
    """A Kinect's colour camera is a stream of one camera (its own clock): its own depth gives the seeds' points,
    on the surface it sees, facing it."""
    bundle, truth = one_person_capture()
    bundle.kinect = read_kcalibration(REAL_KCALIBRATION)
    scene = TexturedScene(bundle, truth, TextureOptions(scale={"vga": 1.0, "hd": 0.5, "kinect-color": 0.5}))
    cams = ["01_01", "50_04"]
    views = imaged_views(scene, cams)
    table = bundle.sync.kinect_color["KINECTNODE4"]
    t = bundle.sync.streams["vga"].time_of(120)
    frame, _ = table.nearest(t)
    t_c = table.time_of(int(frame))
    write_group_depth(tmp_path / "depth", bundle, truth, (t_c - 40.0, t_c + 40.0), nodes=["KINECTNODE4"])
    depth = DepthFrames(depth_folder_reader(tmp_path / "depth"))
    seeds = seed_from_own_kinect(bundle, depth, "KINECTNODE4", t_c, scene, views, 1, int(frame), PatchOptions())
    assert len(seeds.X_cm) > 200
    assert seeds.seen[:, 1].all() and not seeds.seen[:, 0].any()
    sp = nearest_surface_points(truth, t_c, seeds.X_cm[:, 0])
    _, normal = surface_points_cm(truth, np.array([t_c]), sp.person, sp.part, sp.local_cm)
    assert np.median(sp.distance_cm) < 0.5 and np.percentile(sp.distance_cm, 90) < 2.0  # not the floor or walls
    assert np.median(np.sum(seeds.normal * normal[0], axis=1)) > np.cos(np.radians(15.0))
    to_cam = views.center_cm[1] - seeds.X_cm[:, 0]
    assert np.all(np.sum(to_cam * seeds.normal, axis=1) > 0)  # facing the camera that sees it


def test_the_body_prior_between_its_times_is_linear():
    from dome_calib.recon.patches.seed_skeleton import BodyPrior

    J = np.zeros((2, 1, 19, 3))
    J[1] = 10.0
    J[1, 0, 5] = np.nan
    prior = BodyPrior(times_ms=np.array([100.0, 140.0]), joints_cm=J)
    assert np.array_equal(prior.at(100.2), J[0]) and np.array_equal(prior.at(139.9), J[1], equal_nan=True)
    mid = prior.at(110.0)
    assert np.allclose(mid[0, 0], 2.5) and np.isnan(mid[0, 5]).all()  # a joint missing on either side: NaN
    assert prior.at(99.0).shape == (0, 19, 3) and prior.at(141.0).shape == (0, 19, 3)


@pytest.mark.slow  # two streams of 9 cameras seeded on the body twice: ~25 CPU-s
def test_skeleton_seeds_come_from_every_stream_on_the_body_at_its_own_time(walker):
    """``seed_method="skeleton"`` with ``seed_streams="all"``: the other stream (the 4 VGA of panel 1) seeds on the
    people at its own frame time (the body prior between its times), and its seeds are carried to the seed time
    and land on the surface; with ``seed_streams="reference"`` only the reference stream's seeds. (Before, the
    skeleton seeded from the reference stream alone whatever ``seed_streams`` said: a dome's VGA, whose frames cut
    off the legs, alone.)"""
    from dome_calib.recon.patches.seed_skeleton import BodyPrior

    bundle, truth, scene, ref, other, o = walker
    o = dataclasses.replace(o, seed_method="skeleton", seed_features=120)
    cams = ref + other
    table = bundle.sync.streams["hd"]
    at = table.times_of(np.arange(FRAME - 2, FRAME + 3))
    J, present = truth.joints_cm(at)
    body = BodyPrior(times_ms=at, joints_cm=np.where(present[..., None, None], J, np.nan))
    span = (table.time_of(FRAME), table.time_of(FRAME))
    alone = patch_stream(bundle, scene, cams, span, dataclasses.replace(o, seed_streams="reference"),
                         seed_frames=[FRAME], body=body)
    every = patch_stream(bundle, scene, cams, span, o, seed_frames=[FRAME], body=body)
    n_ref = len(alone.ids)
    added = every.alive[n_ref:, 0]
    assert added.sum() >= 10
    t = table.time_of(FRAME)
    sp = nearest_surface_points(truth, t, every.X_cm[n_ref:][added, 0, 0])
    assert np.median(sp.distance_cm) < 1.0
    assert np.array_equal(every.X_cm[:n_ref], alone.X_cm, equal_nan=True)  # the reference stream's, as they were
