"""A step's second triangulation (recon.patches.track._triangulate_again): a patch whose tracked views all stay
visible keeps its first triangulation, the rest are triangulated again; the stream is the same bits as when every
patch is triangulated again (issue 49, branch speed50)."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches import track
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import clocks_of, imaged_views, run_cloud
from dome_calib.recon.patches.seed import seed_patches
from dome_calib.recon.project import project_points, view_set
from dome_calib.synth.textured import TexturedScene, TextureOptions

from .patches_helpers import one_person_capture


def test_triangulate_again_is_the_triangulation_in_the_views_used_bit_for_bit():
    bundle, _ = one_person_capture()
    names = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:40]
    views = view_set(bundle, names)
    rng = np.random.default_rng(5)
    N, V = 300, len(names)
    X = rng.uniform([-60.0, -150.0, -60.0], [60.0, -50.0, 60.0], (N, 3, 3))  # around the person
    uv = project_points(views, X.reshape(-1, 3)).uv_px.transpose(1, 0, 2).reshape(N, 3, V, 2)
    uv = uv + rng.normal(0.0, 0.3, uv.shape)
    uv[rng.random((N, 3, V)) < 0.03] += 25.0  # outliers for the robust fit
    flown = np.zeros((N, V), bool)  # 8 views per patch, as track_views
    for n in range(N):
        flown[n, rng.choice(V, 8, replace=False)] = True
    tracked = flown[:, None, :] & (rng.random((N, 3, V)) < 0.95)
    uv = np.where(flown[:, None, :, None], uv, np.nan)
    o = PatchOptions()
    X_tri = track._triangulate_points(views, uv, tracked.astype(float), o)
    dropped = rng.random(N) < 0.3  # a third of the patches lose a view or two to the visibility
    use = tracked & ~(dropped[:, None, None] & (rng.random((N, 1, V)) < 0.3))
    assert np.any(use != tracked) and np.any(np.all(use == tracked, axis=(1, 2)))
    got = track._triangulate_again(views, uv, tracked, use, X_tri, o)
    want = track._triangulate_points(views, uv, use.astype(float), o)
    assert np.isfinite(want).mean() > 0.9
    assert np.array_equal(np.nan_to_num(got, nan=-1.0), np.nan_to_num(want, nan=-1.0))


@pytest.mark.slow
def test_the_second_triangulation_of_unchanged_patches_is_reused_bit_for_bit(monkeypatch):
    bundle, truth = one_person_capture()
    scene = TexturedScene(bundle, truth, TextureOptions())
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"]
    table = bundle.sync.streams["vga"]
    f = 120
    o = PatchOptions(track_frames=2, seed_features=100, seed_neighbours=3, seed_views=4)
    times = table.times_of(np.arange(f - 2, f + 3))
    views = imaged_views(scene, cams)
    seeds = seed_patches(scene, views, {n: f for n in cams}, o)
    clocks = clocks_of(bundle, scene, cams)
    reused, again = [], []
    fast = track._triangulate_again

    def counted(views, uv, tracked, use, X_tri, o):
        changed = np.any(use != tracked, axis=(1, 2))
        reused.append(int((~changed & np.isfinite(X_tri).all(axis=(1, 2))).sum()))
        again.append(int(changed.sum()))
        return fast(views, uv, tracked, use, X_tri, o)

    monkeypatch.setattr(track, "_triangulate_again", counted)
    new = run_cloud(scene, views, clocks, table.time_of(f), times, seeds, o)
    assert sum(reused) > 0 and sum(again) > 0  # both ways are taken

    def every_patch(views, uv, tracked, use, X_tri, o):  # the rule before: every patch triangulated again
        return track._triangulate_points(views, uv, use.astype(float), o)

    monkeypatch.setattr(track, "_triangulate_again", every_patch)
    old = run_cloud(scene, views, clocks, table.time_of(f), times, seeds, o)
    for a, b in zip(new, old):  # backward, forward
        assert b.alive[:, -1].sum() > 50
        assert np.array_equal(np.nan_to_num(a.X_cm, nan=-1.0), np.nan_to_num(b.X_cm, nan=-1.0))
        assert np.array_equal(a.visible, b.visible) and np.array_equal(a.alive, b.alive)
