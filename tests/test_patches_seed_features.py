"""Seeding from matched features (dome_calib.recon.patches.seed_features) where the depth sweep cannot: two cameras
72 deg apart (one VGA camera on each of the tiny dome's two panels) see a textured person; the sweep scores its
windows upright in the other camera and finds nothing, SIFT matched along the epipolar lines finds patches on the
true surface."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.seed import seed_patches
from dome_calib.recon.patches.seed_features import match_pair, seed_from_features
from dome_calib.recon.project import project_points
from dome_calib.synth.textured import nearest_surface_points

from .patches_helpers import WIDE_PAIR, wide_pair_scene

CAMS = WIDE_PAIR
FRAME = 120


@pytest.fixture(scope="module")
def wide():
    return wide_pair_scene(FRAME)  # a wide baseline, as the phones of a real rig


def test_features_seed_the_true_surface_where_the_depth_sweep_finds_nothing(wide):
    _, truth, scene, views, t = wide
    frames = {n: FRAME for n in CAMS}
    o = PatchOptions(seed_min_views=2)
    assert len(seed_patches(scene, views, frames, o).X_cm) == 0  # the old seeding
    seeds = seed_from_features(scene, views, frames, PatchOptions(seed_min_views=2, seed_method="features"))
    assert len(seeds.X_cm) >= 5
    assert seeds.seen.all()
    d = nearest_surface_points(truth, t, seeds.X_cm[:, 0]).distance_cm
    assert np.median(d) < 0.3 and np.all(d < 1.0)
    # the normals face both cameras (the seeds were seen by both)
    to_cam = views.center_cm[None] - seeds.X_cm[:, None, 0]
    assert np.all(np.sum(to_cam * seeds.normal[:, None], -1) > 0)


def test_matches_keep_to_the_epipolar_band_and_are_mutual(wide):
    _, _, _, views, _ = wide
    rng = np.random.default_rng(0)
    X = np.c_[rng.uniform(-40, 40, 60), rng.uniform(-170, -20, 60), rng.uniform(-40, 40, 60)]
    uv = project_points(views, X).uv_px
    desc = rng.uniform(0, 100, (60, 128)).astype(np.float32)
    o = PatchOptions(seed_method="features")
    m = match_pair(uv[0], desc, uv[1], desc, views, 0, 1, o)
    assert np.array_equal(m, np.stack([np.arange(60), np.arange(60)], 1))  # every true pair, nothing else
    # 10 px off the epipolar lines (the band is 3 px): no match survives, however alike the descriptors
    assert len(match_pair(uv[0], desc, uv[1] + [0.0, 10.0], desc, views, 0, 1, o)) == 0
    # a second candidate with the same descriptor on the same line: ambiguous, refused by the ratio test
    twin = np.concatenate([uv[1], uv[1] + (uv[1] - uv[0]) * 1e-3])
    assert len(match_pair(uv[0], desc, twin, np.concatenate([desc, desc]), views, 0, 1, o)) == 0


def test_the_stream_seeds_by_features_in_one_task_per_cloud_and_tracks_them(wide):
    """patch_stream with ``seed_method="features"``: the cloud's seeds are the features' (one task per cloud, as
    depth seeds), tracked both ways."""
    from dome_calib.recon.patches.run import patch_stream

    bundle, _, scene, views, t = wide
    o = PatchOptions(seed_min_views=2, seed_method="features", track_frames=2, min_visible=2)
    seeds = seed_from_features(scene, views, {n: FRAME for n in CAMS}, o)
    traj = patch_stream(bundle, scene, CAMS, (t - 100.0, t + 100.0), o, stream="vga", seed_frames=[FRAME])
    assert len(traj.ids) == len(seeds.X_cm) >= 5
    assert traj.alive[:, list(traj.times_ms).index(t)].all()
