"""What one tracking step of the patch stream costs per patch on a whole dome, piece by piece, without rendering: the
figure that scales the stream to the full dome (480 VGA, 31 HD, 10 Kinect) and to a cluster.

Run: .venv/bin/python bench/patch_step_cost.py [--presets panel,full] [--people 8] [--patches 250,1000]
         [--track-views 8] [--seed 0]
         [--predicted-levels 3,2,1] [--anchor-levels 1,0]
Setup: the as-built dome's preset, every camera (HD and Kinect colour at half size, as bench/patches.py renders
them); the group at 2.5 s; patches on the people's true surface (the nearest surface point of random points within
15 cm of the joints) with their true normals, ``previous`` = the cameras that truly see them
(``surface_visibility``). The images are smooth random texture of each camera's size, the next frame shifted by
1 px (the cost of optical flow, sampling, NCC and the cut does not depend on what the texture shows; the labels
do, so they are not judged here: bench/patches.py judges them). Per preset and number of patches, CPU ms per
patch for: choosing the flown views (``track.best_views``), optical flow forward-backward in the flown views (one
call per camera and direction, as a track task makes them, with its calls counted) and in every view that sees the
patch (the rule before ``track_views``), triangulating the three points from the flown views, and the visibility in
every camera (``visibility.estimate_visibility``), and the same with the people (the truth's joints at the time) as
occluders of the views (``body_occlusion``, :mod:`dome_calib.recon.patches.occlusion`; and the occlusion test alone
on the facing patch-cameras, with the views it hides per patch and the truly seen views among them); and the flown
views' flow started at its prediction (the true shift) with each of ``--predicted-levels`` pyramid levels
(``PatchOptions.lk_predict``); the visibility with ``border_squares`` the other way than the default
(``visibility_border_squares_false``: the whole square in the image); and afnn4e's pieces (docs/patches.md): the
visibility with ``neighbour_ncc`` (``map_ncc_threshold`` 0.75), with the 4 cm square (``ncc_size_cm``), with all of
afnn4e and with afnn4e and the occluders, the anchor flow's realignment of the flown views' points to their seed
appearance (``anchor_flow``: seed frame 0, now frame 1; ``track.SeedViews.realign``; with each of
``--anchor-levels`` pyramid levels, ``anchor_levels``) and the seed-appearance end
test (``seed_appearance_end``, ``visibility.off_seed``). Prints one JSON object per line. The flow here is a lower
bound of the stream's: the
texture moves 1 px, and real motion takes Lucas-Kanade more iterations (the stream on the
panel spent ~2x this bench's flow per patch-step, docs/benchmarks.md); the step also triangulates twice.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
import zlib  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

import dataclasses  # noqa: E402

from dome_calib.recon.patches.model import PatchOptions  # noqa: E402
from dome_calib.recon.patches.occlusion import BodyPrior, Occluders, occluded_views  # noqa: E402
from dome_calib.recon.patches.seed import optical_flow, patch_triplets  # noqa: E402
from dome_calib.recon.patches.track import SeedViews, _triangulate_points, best_views  # noqa: E402
from dome_calib.recon.patches.visibility import Frames, camera_neighbours, estimate_visibility, off_seed  # noqa: E402
from dome_calib.recon.project import project_points, view_set  # noqa: E402
from dome_calib.synth.dome import as_built_dome  # noqa: E402
from dome_calib.synth.group import GroupOptions, make_group  # noqa: E402
from dome_calib.synth.textured import (nearest_surface_points, scaled_camera, surface_points_cm,  # noqa: E402
                                       surface_visibility)
from dome_calib.bundle import Bundle  # noqa: E402


class NoiseFrames:
    """Smooth random texture per camera (its imaged size); frame 1 is frame 0 shifted by 1 px."""

    def __init__(self, sizes: dict[str, tuple[int, int]], seed: int) -> None:
        self.sizes, self.seed, self._img = sizes, seed, {}

    def gray(self, name: str, frame: int) -> np.ndarray:
        key = (name, frame)
        if key not in self._img:
            w, h = self.sizes[name]
            rng = np.random.default_rng([self.seed, zlib.crc32(name.encode())])
            base = cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 2.0)
            base = cv2.normalize(base, None, 10, 245, cv2.NORM_MINMAX).astype(np.uint8)
            self._img[(name, 0)], self._img[(name, 1)] = base, np.roll(base, 1, axis=1)
        return self._img[key]


def cpu_ms(fn):
    c0 = time.process_time()
    out = fn()
    return out, 1000.0 * (time.process_time() - c0)


def run(args: argparse.Namespace) -> None:
    truth = make_group(GroupOptions(n_people=args.people, scenario="conversation", start_ms=500.0,
                                    duration_ms=5000.0, seed=args.seed))
    t = 2500.0
    Xj, present = truth.joints_cm(np.array([t]))
    o = PatchOptions(track_views=args.track_views)
    for preset in args.presets.split(","):
        dome = as_built_dome(preset, seed=args.seed)
        scale = {"vga": 1.0, "hd": 0.5, "kinect-color": 0.5}
        names = sorted(dome.cameras)
        imaged = Bundle(seq="imaged", cameras={n: scaled_camera(dome.cameras[n], scale[str(dome.cameras[n].type)])
                                               for n in names})
        views = view_set(imaged, names)
        V = len(names)
        source = NoiseFrames({n: tuple(imaged.cameras[n].resolution) for n in names}, args.seed)
        nb = camera_neighbours(views, o.prior_neighbours)
        for n in names:  # the images made before any timing
            source.gray(n, 0)
        for n_patches in [int(x) for x in args.patches.split(",")]:
            rng = np.random.default_rng(args.seed)
            per = max(1, n_patches // int(present[0].sum()))
            q = []
            for p in np.flatnonzero(present[0]):
                J = Xj[0, p][np.all(np.isfinite(Xj[0, p]), axis=1)]
                q.append(J[rng.integers(0, len(J), per)] + rng.uniform(-15.0, 15.0, (per, 3)))
            sp = nearest_surface_points(truth, t, np.concatenate(q))
            P, normal = surface_points_cm(truth, np.array([t]), sp.person, sp.part, sp.local_cm)
            X = patch_triplets(P[0], normal[0], rng.normal(size=P[0].shape), o.axis_cm)
            N = len(X)
            seen = surface_visibility(dome, names, truth, t, P[0], normal[0])
            frames = Frames(frame=np.ones(V, np.int64), offset_ms=np.zeros(V), t_ms=t)
            body = BodyPrior(times_ms=np.array([t]), joints_cm=np.where(present[..., None, None], Xj, np.nan))
            ob = dataclasses.replace(o, body_occlusion=True)
            flown, ms_select = cpu_ms(lambda: best_views(views, X, seen, o.track_views, o.track_view_spread_deg))

            def flow(mask, levels=None):
                calls = 0
                uv = np.full((N, 3, V, 2), np.nan)
                ok = np.zeros((N, 3, V), bool)
                for v in np.flatnonzero(mask.any(0)):
                    idx = np.flatnonzero(mask[:, v])
                    p = project_points(views.subset([names[v]]), X[idx].reshape(-1, 3)).uv_px[0]
                    a, b = source.gray(names[v], 0), source.gray(names[v], 1)
                    if levels is None:
                        got, good = optical_flow(a, b, p, o)
                    else:  # started at the prediction (the true 1 px shift), as track.py with lk_predict
                        got, good = optical_flow(a, b, p, o, guess=p + [1.0, 0.0], levels=levels, predicted=True)
                    uv[idx, :, v], ok[idx, :, v] = got.reshape(-1, 3, 2), good.reshape(-1, 3)
                    calls += 2
                return uv, ok, calls
            (uv, ok, calls), ms_flow = cpu_ms(lambda: flow(flown))
            (_, _, calls_all), ms_flow_all = cpu_ms(lambda: flow(seen))
            ms_predicted = {f"flow_flown_predicted_levels_{lv}": cpu_ms(lambda: flow(flown, lv))[1]
                            for lv in [int(x) for x in args.predicted_levels.split(",") if x]}
            _triangulate_points(views, uv[:2], ok[:2].astype(float), o)  # compiled before timing
            _, ms_tri = cpu_ms(lambda: _triangulate_points(views, uv, ok.astype(float), o))
            motion = np.where(flown, 0.5, np.nan)
            estimate_visibility(source, views, frames, X[:2], np.zeros_like(X[:2]), seen[:2], motion[:2], nb,
                                o)  # compiled (numba's cache: the first run of a checkout) before timing
            full, ms_vis_all = cpu_ms(lambda: estimate_visibility(source, views, frames, X, np.zeros_like(X), seen,
                                                                  motion, nb, o))
            occ_full, ms_vis_body = cpu_ms(lambda: estimate_visibility(source, views, frames, X, np.zeros_like(X),
                                                                       seen, motion, nb, ob, body))
            whole = dataclasses.replace(o, border_squares=not o.border_squares)
            ms_vis_other = []
            for _ in range(2):  # alternated with the default's, each the faster of two (the first call pays more)
                other, ms = cpu_ms(lambda: estimate_visibility(source, views, frames, X, np.zeros_like(X), seen,
                                                               motion, nb, whole))
                ms_vis_other.append(ms)
                ms_vis_all = min(ms_vis_all, cpu_ms(lambda: estimate_visibility(source, views, frames, X,
                                                                                np.zeros_like(X), seen, motion, nb,
                                                                                o))[1])
            ms_vis_other = min(ms_vis_other)
            # afnn4e's pieces (docs/patches.md): neighbour_ncc (map_ncc_threshold 0.75), the 4 cm square, the
            # anchor flow (each flown camera's points aligned to their seed appearance: seed frame 0, now frame 1)
            # and the seed appearance's end test, each alone, then all four with the people as occluders
            afnn4e = dict(anchor_flow=True, neighbour_ncc=True, ncc_size_cm=4.0, seed_appearance_end=True,
                          map_ncc_threshold=0.75)
            on = {k: dataclasses.replace(o, **v) for k, v in (
                ("neighbour_ncc", dict(neighbour_ncc=True, map_ncc_threshold=0.75)), ("ncc_size_4", dict(ncc_size_cm=4.0)),
                ("afnn4e", afnn4e), ("afnn4e_body_occlusion", dict(afnn4e, body_occlusion=True)))}
            ms_vis_on = {f"visibility_{k}": cpu_ms(lambda: estimate_visibility(
                source, views, frames, X, np.zeros_like(X), seen, motion, nb, ok_, body))[1] for k, ok_ in on.items()}
            seed_views = SeedViews.at_seed(source, views, Frames(frame=np.zeros(V, np.int64), offset_ms=np.zeros(V),
                                                                 t_ms=t), X, seen)

            def realign(levels):
                oa = dataclasses.replace(on["afnn4e"], anchor_levels=levels)
                for v in np.flatnonzero(flown.any(0)):
                    idx = np.flatnonzero(flown[:, v])
                    seed_views.realign(source, names[v], frames, v, idx, uv[idx, :, v], ok[idx, :, v], oa)
            ms_anchor = {f"anchor_realign_flown_levels_{lv}": cpu_ms(lambda: realign(lv))[1]
                         for lv in [int(x) for x in args.anchor_levels.split(",") if x]}
            look = full.appearance.keep(full.visible)
            _, ms_off_seed = cpu_ms(lambda: off_seed(full, look, on["afnn4e"]))
            ms_afnn4e = {**ms_vis_on, **ms_anchor, "seed_appearance_end": ms_off_seed}
            to_cam = views.center_cm[None] - X[:, None, 0]
            pi, ci = np.nonzero(np.sum(to_cam * normal[0][:, None], -1) / np.linalg.norm(to_cam, axis=-1)
                                > o.min_cos_view)

            def occlusion():
                return occluded_views(Occluders.of(body.at(t), o.occluder_margin_cm), X[:, 0],
                                      views.center_cm, pi, ci, o.occlusion_stop_cm)
            hidden, ms_occ = cpu_ms(occlusion)
            per_patch = {k: round(v / N, 3) for k, v in (("select_views", ms_select), ("flow_flown", ms_flow),
                                                          ("flow_every_seen_view", ms_flow_all),
                                                          ("triangulate_flown", ms_tri),
                                                          ("visibility", ms_vis_all),
                                                          ("visibility_body_occlusion", ms_vis_body),
                                                          ("occlusion_alone", ms_occ),
                                                          (f"visibility_border_squares_{whole.border_squares}".lower(),
                                                           ms_vis_other), *ms_predicted.items(),
                                                          *ms_afnn4e.items())}
            print(json.dumps({"preset": preset, "cameras": V, "people": args.people, "patches": N,
                              "track_views": o.track_views, "seen_views_per_patch": round(float(seen.sum(1).mean()), 1),
                              "flown_views_per_patch": round(float(flown.sum(1).mean()), 1),
                              "facing_views_per_patch": round(float(full.candidate.sum(1).mean()), 1),
                              "border_squares": o.border_squares,
                              "candidates_per_patch_border_squares_other": round(float(other.candidate.sum(1).mean()),
                                                                                 1),
                              "hidden_views_per_patch": round(float(hidden.sum() / N), 1),
                              "candidates_per_patch_body_occlusion": round(float(occ_full.candidate.sum(1).mean()), 1),
                              "true_views_hidden": int(np.sum(hidden & seen[pi, ci])),
                              "flow_calls_flown": calls, "flow_calls_every_seen": calls_all,
                              "cpu_ms_per_patch": per_patch,

                              "load": [round(x, 2) for x in os.getloadavg()]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--presets", default="panel,full")
    ap.add_argument("--people", type=int, default=8)
    ap.add_argument("--patches", default="250,1000")
    ap.add_argument("--track-views", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--predicted-levels", default="3,2,1",
                    help="also the flown views' flow started at the prediction with these pyramid levels (lk_predict)")
    ap.add_argument("--anchor-levels", default="1,0",
                    help="the anchor flow's realignment timed with each of these pyramid levels (anchor_levels)")
    run(ap.parse_args())


if __name__ == "__main__":
    main()
