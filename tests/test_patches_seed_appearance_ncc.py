"""The seed appearance's own threshold (``PatchOptions.seed_appearance_ncc``, visibility.off_seed): a patch whose
visible views show its seed square at NCC 0.65 is kept by the old rule (``ncc_threshold`` 0.6) and ended at 0.7;
unset, the old rule's answer."""
from __future__ import annotations

import numpy as np

from dome_calib.recon.patches.frames import GRID_SIDE
from dome_calib.recon.patches.model import PatchOptions
from dome_calib.recon.patches.visibility import Appearance, Visibility, off_seed

NCC = (0.95, 0.65, 0.3)  # each patch's squares now against its seed squares, in both cameras


def _squares() -> tuple[Visibility, Appearance]:
    rng = np.random.default_rng(3)
    G = GRID_SIDE * GRID_SIDE
    seed, now = [], []
    for r in NCC:
        for _ in range(2):  # two cameras
            x, z = rng.normal(size=G), rng.normal(size=G)
            x -= x.mean()
            z -= z.mean()
            z -= (z @ x) / (x @ x) * x  # centred, orthogonal to x, the same norm
            z *= np.linalg.norm(x) / np.linalg.norm(z)
            seed.append(100.0 + 10.0 * x)
            now.append(100.0 + 10.0 * (r * x + np.sqrt(1.0 - r * r) * z))
    rows = np.arange(2 * len(NCC)).reshape(len(NCC), 2)
    seen = np.ones((len(NCC), 2), bool)
    vis = Visibility(visible=seen, photometric=seen, ncc=np.ones((len(NCC), 2)), candidate=seen,
                     reference=np.zeros(len(NCC), np.int64),
                     appearance=Appearance(samples=np.array(now, np.float32), row_of=rows))
    return vis, Appearance(samples=np.array(seed, np.float32), row_of=rows)


def test_a_patch_between_the_two_thresholds_is_ended_only_by_the_stricter_one():
    vis, seed = _squares()
    assert np.allclose(vis.appearance.ncc_against(seed), np.array(NCC)[:, None], atol=1e-3)
    assert off_seed(vis, seed, PatchOptions()).tolist() == [False, False, True]
    assert off_seed(vis, seed, PatchOptions(seed_appearance_ncc=0.7)).tolist() == [False, True, True]


def test_unset_it_follows_ncc_threshold():
    vis, seed = _squares()
    for t in (0.5, 0.7):
        assert (off_seed(vis, seed, PatchOptions(ncc_threshold=t)).tolist()
                == off_seed(vis, seed, PatchOptions(ncc_threshold=0.0, seed_appearance_ncc=t)).tolist())
    assert off_seed(vis, seed, PatchOptions(ncc_threshold=0.7)).tolist() == [False, True, True]
