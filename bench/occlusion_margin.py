"""The people as occluders, geometry alone (no rendering): what each ``occluder_margin_cm`` hides and loses.

Run: .venv/bin/python bench/occlusion_margin.py
Setup: the panel preset; the bench's two groups (2 people seed 0, 3 people seed 1, conversation, at 2.5 s); 1000
points per person on the true surface (the nearest surface point of random points within 15 cm of the joints); the
true normal, and the true normal tilted 35 deg in a random direction (the diagnosed error of the back-facing false
positives); the body as occluder from the true joints and from the true joints plus 1.5 cm of noise per coordinate
(``bench/patches.py``'s ``--joint-noise``); the ray stopped 3 cm short. Per group, tilt, body and margin (0, 1.5, 3
cm), among the patch-cameras the (tilted) normal faces (cosine above 0.2): the share of those that truly do not see
the point that the term hides, and the share of those that truly see it that it hides (true views lost). One JSON
object per line.
"""
from __future__ import annotations

import json
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from dome_calib.recon.patches.occlusion import Occluders, occluded_views  # noqa: E402
from dome_calib.recon.project import view_set  # noqa: E402
from dome_calib.synth.dome import as_built_dome  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.textured import nearest_surface_points, surface_points_cm, surface_visibility  # noqa: E402

T_MS = 2500.0


def main() -> None:
    for people, seed in ((2, 0), (3, 1)):
        truth = make_group(GroupOptions(n_people=people, scenario="conversation", start_ms=500.0, duration_ms=5000.0,
                                        seed=seed))
        Xj, present = truth.joints_cm(np.array([T_MS]))
        rng = np.random.default_rng(seed)
        J = np.where(present[0][..., None, None], Xj[0], np.nan)
        noisy = J + rng.normal(0.0, 1.5, J.shape)
        q = np.concatenate([Xj[0, p][rng.integers(0, 19, 1000)] + rng.uniform(-15.0, 15.0, (1000, 3))
                            for p in range(people)])
        sp = nearest_surface_points(truth, T_MS, q)
        P, normal = surface_points_cm(truth, np.array([T_MS]), sp.person, sp.part, sp.local_cm)
        P, n = P[0], normal[0]
        dome = as_built_dome("panel", seed=seed)
        names = sorted(dome.cameras)
        C = view_set(dome, names).center_cm
        seen = surface_visibility(dome, names, truth, T_MS, P, n)
        for tilt in (0.0, 35.0):
            a = rng.normal(size=n.shape)
            a -= np.sum(a * n, 1, keepdims=True) * n
            a /= np.linalg.norm(a, axis=1, keepdims=True)
            nt = np.cos(np.radians(tilt)) * n + np.sin(np.radians(tilt)) * a
            to = C[None] - P[:, None]
            pi, ci = np.nonzero(np.sum(to * nt[:, None], -1) / np.linalg.norm(to, axis=-1) > 0.2)
            tv = seen[pi, ci]
            for body, joints in (("true", J), ("noise_1.5cm", noisy)):
                for margin in (0.0, 1.5, 3.0):
                    h = occluded_views(Occluders.of(joints, margin), P, C, pi, ci, 3.0)
                    print(json.dumps(dict(people=people, seed=seed, tilt_deg=tilt, body=body, margin_cm=margin,
                                          facing=len(pi), not_seen=int((~tv).sum()),
                                          not_seen_hidden=round(float(h[~tv].mean()), 3), seen=int(tv.sum()),
                                          seen_hidden=round(float(h[tv].mean()), 4))), flush=True)


if __name__ == "__main__":
    main()
