"""The capture the patch tests share: the tiny dome with synthetic sync tables (0-1.5 s) and one person talking
(scenario ``conversation``, 0.1-1.4 s, seed 2), the group's truth with its textured surface to render."""
from __future__ import annotations

from dome_calib.bundle import Bundle
from dome_calib.synth.dome import nominal_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.skeleton import synthetic_sync


def one_person_capture():
    """(bundle, truth): the tiny dome (seed 0) with sync tables, and one person's truth (``make_group``)."""
    bundle: Bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=1500.0, seed=0)
    truth = make_group(GroupOptions(n_people=1, scenario="conversation", start_ms=100.0, duration_ms=1300.0, seed=2))
    return bundle, truth


#: Two VGA cameras 72 deg apart (one on each of the tiny dome's two panels): a wide baseline, as a real rig's phones.
WIDE_PAIR = ["01_02", "13_02"]


def wide_pair_scene(frame: int = 120):
    """(bundle, truth, rendered scene, the pair's imaged views, the time of VGA ``frame``) of :func:`one_person_capture`
    seen by :data:`WIDE_PAIR`."""
    import numpy as np

    from dome_calib.recon.patches.run import imaged_views
    from dome_calib.synth.textured import TexturedScene, TextureOptions

    bundle, truth = one_person_capture()
    scene = TexturedScene(bundle, truth, TextureOptions())
    views = imaged_views(scene, WIDE_PAIR)
    axes = views.R[:, 2]
    assert np.degrees(np.arccos(axes[0] @ axes[1])) > 60.0
    return bundle, truth, scene, views, bundle.sync.streams["vga"].time_of(frame)


def blurred_texture(seed: int, shape: tuple[int, int], sigma_px: float):
    """(H, W) float32 grey levels 20-235: uniform noise (``seed``) blurred by a Gaussian of ``sigma_px``, stretched."""
    import cv2
    import numpy as np

    tex = cv2.GaussianBlur(np.random.default_rng(seed).uniform(0, 255, shape).astype(np.float32), (0, 0), sigma_px)
    return cv2.normalize(tex, None, 20, 235, cv2.NORM_MINMAX)


def uncarried(**options) -> "PatchOptions":
    """PatchOptions with the body's carry off (``refind_from_body``, ``refind_carry_steps``, ``refind_window_px``,
    ``carry_unseen`` as they were before merge63 made the carry the default), then ``options``: the tests of the
    carry's own pieces turn on what each tests."""
    from dome_calib.recon.patches.model import PatchOptions

    return PatchOptions(**{"refind_from_body": False, "refind_carry_steps": 0, "refind_window_px": 0,
                           "carry_unseen": False, **options})
