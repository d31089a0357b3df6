"""Seeding from the skeleton's surface (dome_calib.recon.patches.seed_skeleton): two cameras 72 deg apart (one VGA
camera on each of the tiny dome's two panels, where the depth sweep seeds nothing) see a textured person; the
person's joints, 3 cm off per coordinate, give each corner's ray an initial depth and normal on the body's capsules,
and the photometric search within a few centimetres of it puts the seeds on the true surface."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.errors import ReconError
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import patch_stream
from dome_calib.recon.patches.seed_skeleton import BodyPrior, body_capsules, ray_capsules, seed_on_body, views_needed
from dome_calib.synth.textured import nearest_surface_points, surface_points_cm

from .patches_helpers import WIDE_PAIR, wide_pair_scene

CAMS = WIDE_PAIR
FRAME = 120
NOISE_CM = 3.0


@pytest.fixture(scope="module")
def wide():
    bundle, truth, scene, views, t = wide_pair_scene(FRAME)
    J, present = truth.joints_cm(np.array([t]))
    noisy = J[0][present[0]] + np.random.default_rng(1).normal(0.0, NOISE_CM, J[0][present[0]].shape)
    return bundle, truth, scene, views, t, noisy


def test_skeleton_seeds_land_on_the_true_surface_far_better_than_its_capsules(wide):
    _, truth, scene, views, t, joints = wide
    o = PatchOptions(seed_min_views=2, seed_method="skeleton")
    seeds = seed_on_body(scene, views, {n: FRAME for n in CAMS}, joints, o)
    assert len(seeds.X_cm) >= 60  # 113
    assert seeds.seen.all()  # both cameras agree on every seed
    X = seeds.X_cm[:, 0]
    near = nearest_surface_points(truth, t, X)
    assert np.median(near.distance_cm) < 0.3 and np.percentile(near.distance_cm, 90) < 1.0
    _, n_true = surface_points_cm(truth, np.array([t]), near.person, near.part, near.local_cm)
    angle = np.degrees(np.arccos(np.clip(np.sum(n_true[0] * seeds.normal, 1), -1.0, 1.0)))
    assert np.median(angle) < 10.0
    # the prior alone (the first capsule hit of the same rays) is centimetres off: the search is what finds the skin
    A, B, radius = body_capsules(joints)
    seer = views.center_cm[0]
    dirs = (X - seer) / np.linalg.norm(X - seer, axis=1, keepdims=True)
    s, _ = ray_capsules(seer, dirs, A, B, radius)
    prior = nearest_surface_points(truth, t, seer + s[np.isfinite(s), None] * dirs[np.isfinite(s)]).distance_cm
    assert np.median(prior) > 3 * np.median(near.distance_cm)


def test_ray_capsules_meet_the_cylinder_and_the_end_spheres():
    A, B, r = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 10.0]]), np.array([2.0])
    origin = np.array([10.0, 0.0, 5.0])
    dirs = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # at the side; away from it
    s, n = ray_capsules(origin, dirs, A, B, r)
    assert s[0] == pytest.approx(8.0) and np.allclose(n[0], [1.0, 0.0, 0.0])
    assert np.isinf(s[1]) and np.isnan(n[1]).all()
    s, n = ray_capsules(np.array([0.0, 0.0, 20.0]), np.array([[0.0, 0.0, -1.0]]), A, B, r)  # onto the end cap
    assert s[0] == pytest.approx(8.0) and np.allclose(n[0], [0.0, 0.0, 1.0])
    # missing joints leave their parts out
    J = np.zeros((1, 19, 3))
    J[0, :, 1] = -np.arange(19) * 5.0
    J[0, 4] = np.nan  # the left elbow: no left upper arm nor forearm
    assert len(body_capsules(J)[0]) == 10


def test_the_stream_seeds_on_the_body_alike_however_the_work_is_cut(wide):
    bundle, _, scene, views, t, joints = wide
    o = PatchOptions(seed_min_views=2, seed_method="skeleton", track_frames=1, seed_features=150)
    with pytest.raises(ReconError, match="skeleton"):
        patch_stream(bundle, scene, CAMS, (t - 50.0, t + 50.0), o, stream="vga", seed_frames=[FRAME])
    table = bundle.sync.streams["vga"]
    body = BodyPrior(times_ms=table.times_of(np.arange(FRAME - 2, FRAME + 3)), joints_cm=np.repeat(joints[None], 5, 0))
    seeds = seed_on_body(scene, views, {n: FRAME for n in CAMS}, joints, o)
    whole = patch_stream(bundle, scene, CAMS, (t - 50.0, t + 50.0), o, stream="vga", seed_frames=[FRAME], body=body)
    cut = patch_stream(bundle, scene, CAMS, (t - 50.0, t + 50.0), o, stream="vga", seed_frames=[FRAME], body=body,
                       patches_per_task=7)
    assert len(whole.ids) == len(seeds.X_cm) >= 10
    s = list(whole.times_ms).index(t)
    assert whole.alive[:, s].mean() > 0.9  # the MAP visibility at the seed keeps nearly all
    assert np.array_equal(whole.X_cm, cut.X_cm, equal_nan=True) and np.array_equal(whole.visible, cut.visible)


def test_where_fewer_cameras_may_see_a_seed_than_three_every_one_of_them_must_agree(wide):
    """Two cameras 72 deg apart: with the default ``seed_min_views`` (3) the skeleton seeds are those both cameras
    agree on, as with ``seed_min_views=2`` (before, a fixed three kept nothing on such a rig); where three or more
    may see a point, three must agree."""
    _, _, scene, views, _, joints = wide
    frames = {n: FRAME for n in CAMS}
    default = seed_on_body(scene, views, frames, joints, PatchOptions(seed_method="skeleton", seed_features=150))
    two = seed_on_body(scene, views, frames, joints, PatchOptions(seed_method="skeleton", seed_features=150,
                                                                  seed_min_views=2))
    assert len(default.X_cm) >= 30
    assert np.array_equal(default.X_cm, two.X_cm) and np.array_equal(default.seen, two.seen)
    assert list(views_needed(np.array([1, 2, 3, 4, 9]), 3)) == [2, 2, 3, 3, 3]
    assert list(views_needed(np.array([1, 2, 3, 4, 9]), 4)) == [2, 2, 3, 4, 4]
