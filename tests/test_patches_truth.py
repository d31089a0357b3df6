"""The textured synthetic people (dome_calib.synth.textured): parts move rigidly, the images and the visibility
truth agree with the geometry."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.project import project_points, view_set
from dome_calib.synth.dome import nominal_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.textured import (N_PARTS, TexturedScene, TextureOptions, nearest_surface_points, part_frames,
                                       scaled_camera, surface_points_cm, surface_visibility)
from dome_calib.synth.skeleton import synthetic_sync


@pytest.fixture(scope="module")
def scene():
    bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=2000.0, seed=0)
    truth = make_group(GroupOptions(n_people=2, scenario="conversation", start_ms=200.0, duration_ms=1600.0,
                                    seed=1))
    return bundle, truth


def _surface_sample(truth, t_ms, n=400, seed=0):
    """Random surface points at t: (person, part, local) on the capsules."""
    rng = np.random.default_rng(seed)
    X, _ = truth.joints_cm(np.array([t_ms]))
    fr = part_frames(X[0])
    person = rng.integers(0, len(truth.ids), n)
    part = rng.integers(0, N_PARTS, n)
    L, r = fr.length[person, part], fr.radius[person, part]
    theta = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0, 1, n) * L
    local = np.stack([r * np.cos(theta), r * np.sin(theta), z], 1)
    return person, part, local


def test_parts_move_rigidly_and_stay_on_the_surface(scene):
    _, truth = scene
    person, part, local = _surface_sample(truth, 500.0)
    times = np.array([300.0, 700.0, 1500.0])
    P, normal = surface_points_cm(truth, times, person, part, local)
    same = (person[:, None] == person[None]) & (part[:, None] == part[None])
    d = np.linalg.norm(P[:, :, None] - P[:, None], axis=-1)  # (T, N, N)
    assert np.max(np.abs(d - d[0])[:, same]) < 1e-6  # distances within a part do not change: rigid
    assert np.allclose(np.linalg.norm(normal, axis=-1), 1.0)
    moved = np.linalg.norm(P[-1] - P[0], axis=-1)
    assert np.mean(moved > 1.0) > 0.2  # the people do move (arms, heads)
    for k, t in enumerate(times):
        on = nearest_surface_points(truth, t, P[k])
        exposed = on.distance_cm < 1e-6
        # a point on the outer surface is found where it is, on its own part
        assert exposed.mean() > 0.6
        assert np.mean(((on.person == person) & (on.part == part))[exposed]) > 0.99
        # the others are buried in another capsule (a hip inside the torso): not on the outer surface
        assert np.all(on.distance_cm[~exposed] > 0.04)


def test_image_shows_the_visible_surface_points(scene):
    bundle, truth = scene
    t = 800.0
    person, part, local = _surface_sample(truth, t, n=2000, seed=3)
    P, normal = surface_points_cm(truth, np.array([t]), person, part, local)
    names = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:3]
    seen = surface_visibility(bundle, names, truth, t, P[0], normal[0])
    assert 0.15 < seen.mean() < 0.85  # one side of the bodies, and the other person in the way
    X, present = truth.joints_cm(np.array([t]))
    from dome_calib.synth.textured import render_view

    for v, name in enumerate(names):
        cam = scaled_camera(bundle.cameras[name], 1.0)
        view = render_view(cam, X[0], present[0], truth.ids, frame=0, options=TextureOptions(blur_px=0.0))
        p = project_points(view_set(bundle, [name]), P[0])
        uv = np.rint(p.uv_px[0]).astype(int)
        inside = p.visible[0]
        lab = np.full(len(P[0]), -2)
        lab[inside] = view.label[uv[inside, 1], uv[inside, 0]]
        rng_px = np.full(len(P[0]), np.inf)
        rng_px[inside] = view.range_cm[uv[inside, 1], uv[inside, 0]]
        dist = np.linalg.norm(P[0] - bundle.cameras[name].center_cm, axis=1)
        expected = person * N_PARTS + part
        vis = seen[:, v]
        # a visible point is what its pixel shows (its part; the range within a pixel's footprint on the surface)
        agree = (lab == expected) & (np.abs(rng_px - dist) < 2.0)
        assert np.mean(agree[vis]) > 0.9
        # a hidden point's pixel shows something nearer (or its own surface seen edge-on)
        hidden = inside & ~vis
        assert np.mean(rng_px[hidden] < dist[hidden] - 0.5) > 0.8


def test_scene_renders_each_stream_at_its_own_frames(scene):
    bundle, truth = scene
    sc = TexturedScene(bundle, truth, TextureOptions(scale={"vga": 1.0, "hd": 0.25, "kinect-color": 0.25}))
    hd = next(n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "hd")
    f = int(sc.frame_indices(hd)[20])
    img = sc.gray(hd, f)
    assert img.shape == (270, 480) and img.dtype == np.uint8
    assert sc.view(hd, f) is sc.view(hd, f)  # cached
    assert np.array_equal(sc.gray(hd, f), img)
