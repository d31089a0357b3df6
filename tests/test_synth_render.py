"""Rendering against the ground truth: exact rays, marker spots found where the true cameras project them."""
import numpy as np
import pytest

from dome_calib.camera import pixels_to_normalized, project
from dome_calib.layout import nominal_dome
from dome_calib.synth.dome import projectors
from dome_calib.synth.markers import locate_spot, marker_view, spot_window_px, surface_points_seen_by
from dome_calib.synth.rays import CameraRays
from dome_calib.synth.render import RenderOptions, camera_rays, edge_mask, prepare_scene, render_image
from dome_calib.ties import LENGTH_QUANTUM_CM, order_by
from dome_calib.synth.tent import inside_tent, intersect_scene, scene_poses, tent_mesh

MARKER_TOL_PX = 0.1


@pytest.fixture(scope="module")
def tiny():
    return nominal_dome("tiny", seed=0)


def _nearest_of_each_type(bundle, name: str, vga: int) -> list[str]:
    """The ``vga`` VGA cameras nearest camera ``name`` (itself first), and the nearest HD and Kinect colour."""
    c = bundle.cameras[name].center_cm
    out = []
    for t, n in (("vga", vga), ("hd", 1), ("kinect-color", 1)):
        names = sorted(bundle.of_type(t))
        d = [np.linalg.norm(bundle.cameras[m].center_cm - c) for m in names]
        out += [names[i] for i in order_by(d, names, LENGTH_QUANTUM_CM)[:n]]
    return out


def _one_of_each_type(bundle) -> list[str]:
    """The first camera of each type in the preset (the preset decides which; the test does not assume it)."""
    return [sorted(bundle.of_type(t))[0] for t in ("vga", "hd", "kinect-color")]


def test_rays_match_exact_undistortion(tiny):
    for name in _one_of_each_type(tiny):
        cam = tiny.cameras[name]
        rays = CameraRays(cam)
        w, h = cam.resolution
        rng = np.random.default_rng(1)
        uv = rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], size=(3000, 2))
        uv[:4] = [[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]  # corners: most distortion
        exact = pixels_to_normalized(uv, cam.intr, cam.dist)
        err_px = np.abs(rays.normalized(uv) - exact).max() * cam.intr[0]
        assert err_px < 1e-6
        # rays re-project onto their pixels
        X = cam.center_cm + 250.0 * rays.dirs_at(uv)
        p = project(X, cam.R, cam.t_cm, cam.intr, cam.dist)
        assert np.abs(p.uv_px - uv).max() < 1e-6


def test_tent_mesh_lies_on_surface_and_is_hit_first_from_outside():
    pose = scene_poses(2, seed=3)[1]
    V, F = tent_mesh(pose)
    assert F.max() < len(V) and len(F) > 1000
    assert V[:, 1].max() <= 1e-9 and V[:, 1].min() == pytest.approx(-200.0, abs=0.5)  # 2 m high, on the floor
    V_tent = pose.to_tent(V)
    extent = V_tent[:, [0, 2]].max(axis=0) - V_tent[:, [0, 2]].min(axis=0)
    assert np.all((extent > 140) & (extent < 210))  # 1.5-2 m across
    assert not inside_tent(pose.to_tent(V), margin_cm=0.05).any()
    # a ray aimed at a vertex from above hits at that vertex or before it (never misses it)
    rng = np.random.default_rng(0)
    X = V[rng.choice(len(V), 500, replace=False)]
    X = X[X[:, 1] < -5]  # not the base
    origin = np.array([30.0, -330.0, -250.0])
    d = X - origin
    dist = np.linalg.norm(d, axis=1)
    hits = intersect_scene(origin, d / dist[:, None], pose)
    assert np.all(hits.s <= dist + 1e-6)
    assert np.mean(np.abs(hits.s - dist) < 1e-6) > 0.3  # the front half is hit exactly at the vertex
    assert np.allclose(np.linalg.norm(hits.normal[hits.kind == 1], axis=1), 1.0)


def test_edge_mask_marks_silhouettes():
    kind = np.zeros((20, 20), np.uint8)
    kind[5:15, 5:15] = 1
    dist = np.where(kind == 1, 300.0, np.inf)
    m = edge_mask(kind, dist)
    assert m[5, 10] and m[4, 10] and m[10, 14] and not m[10, 10] and not m[0, 0]


def test_marker_found_within_tenth_pixel_of_ground_truth(tiny):
    """Emissive spots on the tent, found by a Gaussian fit in every image where visible (noise on)."""
    pose = scene_poses(1, seed=0)[0]
    ref = CameraRays(tiny.cameras["01_01"])
    markers = surface_points_seen_by(ref, pose, np.array([[260.0, 200.0], [400.0, 230.0], [330.0, 330.0],
                                                          [250.0, 380.0]]))  # all on the egg
    assert np.all(np.isfinite(markers))
    # uniform lighting (projectors off, room light on): see dome_calib.synth.markers
    options = RenderOptions(flat_patterns=True, markers_cm=markers, projector_power=0.0, ambient=0.3)
    scene = prepare_scene("scene_01", pose, projectors(0), {}, options)
    checked = 0
    for name in _nearest_of_each_type(tiny, "01_01", vga=3):  # VGA, HD and Kinect colour near the markers' view
        cam = tiny.cameras[name]
        image = render_image(camera_rays(cam, options), scene, options, seed=0)  # HD traced at 0.75 x
        for X in markers:
            view = marker_view(cam, X, pose)
            if not view.visible:
                continue
            found = locate_spot(image, view.uv_px, search_px=spot_window_px(cam))
            err = np.linalg.norm(found - view.uv_px)
            assert err < MARKER_TOL_PX, f"{name}: marker at {X.round(1)} off by {err:.3f} px"
            checked += 1
    assert checked >= 15


def test_marker_visibility_detects_occlusion(tiny):
    pose = scene_poses(1, seed=0)[0]
    cam = tiny.cameras["01_01"]
    far_side = np.array([0.0, -95.0, 0.0]) + (np.array([0.0, -95.0, 0.0]) - cam.center_cm) * np.array([1, 0, 1]) \
        / np.linalg.norm((np.array([0.0, -95.0, 0.0]) - cam.center_cm) * np.array([1, 0, 1])) * 70.0
    assert not marker_view(cam, far_side, pose).visible  # inside/behind the egg


def test_render_deterministic_and_looks_like_a_tent(tiny):
    pose = scene_poses(1, seed=0)[0]
    from projector.patterns import make_patterns

    options = RenderOptions()
    scene = prepare_scene("scene_01", pose, projectors(0), make_patterns(0), options)
    rays = CameraRays(tiny.cameras["01_01"])
    a = render_image(rays, scene, options, seed=0)
    b = render_image(rays, scene, options, seed=0)
    assert a.shape == (480, 640) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, render_image(rays, scene, options, seed=1))  # noise follows the seed
    tent = a[200:400, 200:450]
    assert tent.std() > 25 and tent.mean() > 60  # textured and lit
    assert a[:20].mean() < 20  # dark dome behind the tent
