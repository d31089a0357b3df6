"""The patch stream's rules for a dense dome: a patch is flown in at most ``track_views`` cameras, the most face-on
and spread in direction (visibility still judged in all); a patch is projected for its visibility only into the
cameras its normal faces (the others are never candidates); clouds seeded from a cover of the reference cameras."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches import track as track_mod
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.run import clocks_of, imaged_views, run_cloud
from dome_calib.recon.patches.seed import Seeds, patch_triplets, reference_cameras
from dome_calib.recon.patches import visibility as vis_mod
from dome_calib.recon.patches.track import best_views, judged_frames
from dome_calib.recon.patches.visibility import camera_neighbours, estimate_visibility
from dome_calib.recon.project import view_set
from dome_calib.synth.dome import as_built_dome
from dome_calib.synth.textured import TexturedScene, TextureOptions, nearest_surface_points, surface_points_cm

from .patches_helpers import one_person_capture


@pytest.fixture(scope="module")
def capture():
    """The tiny dome's 8 VGA and 1 HD (half size), one person; 60 patches on the true surface at frame 120, 30 with
    their true normal and 30 turned to random directions (cameras facing away from some, not from others)."""
    bundle, truth = one_person_capture()
    scene = TexturedScene(bundle, truth, TextureOptions(scale={"vga": 1.0, "hd": 0.5, "kinect-color": 0.5}))
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"]
    cams += [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "hd"][:1]
    views = imaged_views(scene, cams)
    clocks = clocks_of(bundle, scene, cams)
    t = bundle.sync.streams["vga"].time_of(120)
    rng = np.random.default_rng(1)
    Xj, _ = truth.joints_cm(np.array([t]))
    J = Xj[0, 0][np.all(np.isfinite(Xj[0, 0]), axis=1)]
    sp = nearest_surface_points(truth, t, J[rng.integers(0, len(J), 60)] + rng.uniform(-10, 10, (60, 3)))
    P, normal = surface_points_cm(truth, np.array([t]), sp.person, sp.part, sp.local_cm)
    n = normal[0].copy()
    turned = rng.normal(size=(30, 3))
    n[30:] = turned / np.linalg.norm(turned, axis=1, keepdims=True)
    X = patch_triplets(P[0], n, rng.normal(size=(60, 3)), 3.0)
    return bundle, scene, views, clocks, t, X


def test_visibility_projects_a_patch_only_into_the_cameras_it_faces(capture, monkeypatch):
    _, scene, views, clocks, t, X = capture
    o = PatchOptions()
    frames = judged_frames(clocks, t)
    nb = camera_neighbours(views, o.prior_neighbours)
    prev = np.ones((len(X), len(views.names)), bool)
    velocity = np.random.default_rng(2).normal(0, 0.01, X.shape)  # cm per ms: the HD camera judged at its own time
    projected = []
    real = vis_mod.project_view_rows

    def counting(views, v, P, rows):
        projected.append(P.shape[1] * len(rows))
        return real(views, v, P, rows)
    monkeypatch.setattr(vis_mod, "project_view_rows", counting)
    got = estimate_visibility(scene, views, frames, X, velocity, prev, None, nb, o)
    _, _, n = track_mod.patch_axes(X[:, 0], X[:, 1], X[:, 2])
    facing = np.zeros((len(X), len(views.names)), bool)
    for v in range(len(views.names)):
        to_cam = views.center_cm[v] - (X + velocity * frames.offset_ms[v])[:, 0]
        facing[:, v] = np.sum(to_cam * n, 1) / np.linalg.norm(to_cam, axis=1) > o.min_cos_view
    assert 0 < facing.sum() < facing.size  # some patches turn away from some cameras
    assert sum(projected) == 49 * int(facing.sum())  # the 7 x 7 grid, in the facing cameras only
    assert got.visible.any() and not (got.visible & ~got.candidate).any()
    assert not (got.photometric & ~facing).any() and np.all(got.ncc[~facing] == -1.0)
    part = estimate_visibility(scene, views, frames, X[::3], velocity[::3], prev[::3], None, nb, o)
    assert np.array_equal(part.visible, got.visible[::3])  # a patch's labels do not depend on the others


def test_best_views_are_the_most_face_on_spread_and_at_most_k(monkeypatch):
    views = view_set(as_built_dome("panel", seed=0))
    V = len(views.names)
    X = patch_triplets(np.array([[0.0, -100.0, 0.0], [20.0, -120.0, 10.0]]),
                       np.array([[0.0, -0.6, -0.8], [0.8, -0.6, 0.0]]), np.array([[1.0, 0.0, 0.0]] * 2), 3.0)
    candidates = np.ones((2, V), bool)
    candidates[1, 5:] = False  # the second patch has 5 candidates: all kept at k = 8
    d = views.center_cm[None] - X[:, None, 0]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    _, _, n = track_mod.patch_axes(X[:, 0], X[:, 1], X[:, 2])
    cos = np.sum(d * n[:, None], -1)
    tight = best_views(views, X, candidates, 8, 0.0)
    spread = best_views(views, X, candidates, 8, 15.0)
    assert tight[0].sum() == 8 and spread[0].sum() == 8
    assert np.array_equal(tight[1], candidates[1]) and np.array_equal(spread[1], candidates[1])
    assert set(np.flatnonzero(tight[0])) == set(np.argsort(-cos[0])[:8])  # no spread: the 8 most face-on
    assert spread[0, np.argmax(cos[0])]  # the most face-on is always taken

    def min_pair_deg(sel):
        D = d[0, sel]
        c = np.clip(D @ D.T, -1, 1)[np.triu_indices(len(D), 1)]
        return np.degrees(np.arccos(c)).min()
    assert min_pair_deg(spread[0]) > min_pair_deg(tight[0])
    assert np.array_equal(best_views(views, X, candidates, 0, 10.0), candidates)  # k = 0: all
    monkeypatch.setattr(track_mod, "BEST_VIEWS_CHUNK", 1)
    assert np.array_equal(best_views(views, X, candidates, 8, 15.0), spread)  # patch by patch: the same


def test_a_patch_is_flown_in_at_most_track_views_cameras(capture, monkeypatch):
    _, scene, views, clocks, t, X = capture
    flown = []
    real = track_mod.flow_camera

    def counting(source, name, clock, t0, t1, p, o, *predict):
        flown.append(len(p) // 3)
        return real(source, name, clock, t0, t1, p, o, *predict)
    monkeypatch.setattr(track_mod, "flow_camera", counting)
    seeds = Seeds(X_cm=X[:30], normal=np.zeros((30, 3)), seen=np.ones((30, len(views.names)), bool))
    times = np.array([t, t + 40.0])
    o = PatchOptions(track_views=2)
    back, fwd = run_cloud(scene, views, clocks, t, times, seeds, o, refine=False)
    seen = fwd.visible[:, 0].sum(1)
    assert seen.max() > 2  # visible in more cameras than it is flown in
    assert 0 < sum(flown) <= 2 * int(fwd.alive[:, 0].sum())


def test_reference_cameras_cover_the_dome_once():
    bundle = as_built_dome("full", seed=0)
    vga = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"]
    vs = view_set(bundle, vga)
    refs = reference_cameras(vs, 10.0, 220.0)
    assert np.array_equal(reference_cameras(vs, 0.0, 220.0), np.arange(len(vga)))
    assert 40 < len(refs) < len(vga) // 3
    d = vs.center_cm - np.array([0.0, -110.0, 0.0])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(d @ d[refs].T, -1, 1)))
    assert ang.min(1).max() <= 10.0  # every camera within 10 deg of a reference
    off = ang[refs] + 180.0 * np.eye(len(refs))
    assert off.min() > 10.0  # no two references within 10 deg
    shuffled = vs.subset(list(np.array(vga)[np.random.default_rng(0).permutation(len(vga))]))
    again = reference_cameras(shuffled, 10.0, 220.0)
    assert sorted(shuffled.names[i] for i in again) == sorted(vs.names[i] for i in refs)  # by name, not order


def test_a_cloud_judges_its_seed_time_once_and_samples_only_squares_in_the_image(capture, monkeypatch):
    _, scene, views, clocks, t, X = capture
    judged, sampled = [], []
    real_vis, real_sample = track_mod.estimate_visibility, vis_mod.sample

    def counting_vis(*args):
        got = real_vis(*args)
        judged.append(int(got.candidate.sum()))
        return got

    def counting_sample(gray, uv):
        sampled.append(len(uv))
        return real_sample(gray, uv)
    monkeypatch.setattr(track_mod, "estimate_visibility", counting_vis)
    monkeypatch.setattr(vis_mod, "sample", counting_sample)
    seeds = Seeds(X_cm=X[:30], normal=np.zeros((30, 3)), seen=np.ones((30, len(views.names)), bool))
    back, fwd = run_cloud(scene, views, clocks, t, np.array([t - 40.0, t, t + 40.0]), seeds, PatchOptions(),
                          refine=False)
    assert len(judged) == 3  # the seed time once for both directions, then one per step
    assert sum(sampled) == sum(judged)  # one square per patch and camera where it is in the image, no more
    assert np.array_equal(back.visible[:, 0], fwd.visible[:, 0])
