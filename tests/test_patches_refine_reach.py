"""The photometric normal refinement's reach (recon.patches.refine, ``PatchOptions.normal_refine_reach_deg``): a
patch on a textured plane whose normal starts 25 deg off is brought back to the plane's normal when the first tilt
step is 16 deg (steps 16, 8, 4, 2: 30 deg about each plane axis); with the default 8 deg (steps 8, 4, 2: 14 deg) it
cannot get closer than 11 deg, and a start within reach is refined the same either way."""
from __future__ import annotations

import numpy as np
import pytest

from dome_calib.recon.patches.frames import patch_axes
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.refine import refine_normals, refine_steps_deg
from dome_calib.recon.patches.visibility import Frames

from .patches_helpers import one_person_capture
from .test_patches_visibility import P0, TexturedPlane, facing_plane


class _Kept(TexturedPlane):
    """The plane's images, each rendered once."""

    def __init__(self, *a):
        super().__init__(*a)
        self._kept = {}

    def gray(self, name: str, frame: int) -> np.ndarray:
        if name not in self._kept:
            self._kept[name] = super().gray(name, frame)
        return self._kept[name]


@pytest.fixture(scope="module")
def plane():
    bundle, _ = one_person_capture()
    names = sorted(n for n, c in bundle.cameras.items() if str(c.type) == "vga")
    views, normal = facing_plane(bundle, names)
    return views, names, normal, _Kept(bundle, normal, set())


def _refined_error_deg(plane, tilt_deg: float, reach_deg: float) -> float:
    views, names, normal, source = plane
    t = np.radians(tilt_deg)
    n = normal * np.cos(t) + np.cross(source.u, normal) * np.sin(t)
    a = np.cross(n, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    X = np.array([[P0, P0 + 3.0 * a, P0 + 3.0 * np.cross(n, a)]])
    frames = Frames(frame=np.zeros(len(names), np.int64), offset_ms=np.zeros(len(names)))
    out = refine_normals(source, views, frames, X, np.ones((1, len(names)), bool),
                         PatchOptions(normal_refine_reach_deg=reach_deg))
    assert np.allclose(out[:, 0], X[:, 0])  # the centre does not move
    _, _, m = patch_axes(out[:, 0], out[:, 1], out[:, 2])
    return float(np.degrees(np.arccos(np.clip(m[0] @ normal, -1.0, 1.0))))


def test_the_steps_halve_from_the_reach_down_to_2_deg():
    assert refine_steps_deg(PatchOptions().normal_refine_reach_deg) == (8.0, 4.0, 2.0)  # the old steps
    assert refine_steps_deg(16.0) == (16.0, 8.0, 4.0, 2.0)
    assert refine_steps_deg(2.0) == (2.0,)


def test_a_normal_25_deg_off_is_brought_back_with_the_wider_reach_only(plane):
    assert _refined_error_deg(plane, 25.0, 8.0) > 10.0  # 14 deg of reach leaves 11 deg
    assert _refined_error_deg(plane, 25.0, 16.0) < 2.0


def test_a_normal_within_the_old_reach_is_refined_either_way(plane):
    assert _refined_error_deg(plane, 10.0, 8.0) < 2.0
    assert _refined_error_deg(plane, 10.0, 16.0) < 2.0



@pytest.fixture(scope="module")
def streams():
    """One VGA camera and the HD cameras (another stream) see a still textured plane (each image rendered once)."""
    bundle, _ = one_person_capture()
    vga = sorted(n for n, c in bundle.cameras.items() if str(c.type) == "vga")[:1]
    hd = sorted(n for n, c in bundle.cameras.items() if str(c.type) == "hd")
    names = vga + hd
    views, normal = facing_plane(bundle, names)
    return views, names, normal, _Kept(bundle, normal, set())


def _error_with_streams(streams, tilt_deg: float, all_streams: bool) -> float:
    """A patch on the plane, its normal ``tilt_deg`` off, the HD frames 10 ms off the reference time -> the refined
    normal's error (deg)."""
    views, names, normal, source = streams
    t = np.radians(tilt_deg)
    n = normal * np.cos(t) + np.cross(source.u, normal) * np.sin(t)
    a = np.cross(n, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    X = np.array([[P0, P0 + 3.0 * a, P0 + 3.0 * np.cross(n, a)]])
    assert np.all((views.center_cm - P0) @ n > 0.2 * np.linalg.norm(views.center_cm - P0, axis=1))  # all face it
    frames = Frames(frame=np.zeros(len(names), np.int64), offset_ms=np.array([0.0] + [10.0] * (len(names) - 1)))
    out = refine_normals(source, views, frames, X, np.ones((1, len(names)), bool),
                         PatchOptions(normal_refine_all_streams=all_streams))
    _, _, m = patch_axes(out[:, 0], out[:, 1], out[:, 2])
    return float(np.degrees(np.arccos(np.clip(m[0] @ normal, -1.0, 1.0))))


def test_the_other_streams_cameras_refine_a_normal_the_seeding_stream_alone_cannot(streams):
    """The seeding stream has one camera here: alone it compares with nothing and the normal stays 10 deg off; with
    every stream's cameras (normal_refine_all_streams) the HD cameras bring it back to the plane's."""
    assert len(streams[1]) == 6
    assert abs(_error_with_streams(streams, 10.0, False) - 10.0) < 0.01
    assert _error_with_streams(streams, 10.0, True) < 2.0
