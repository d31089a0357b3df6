"""Why the stream's patches end, on the limb ends against the torso (issue 49, branch limb63).

Run: .venv/bin/python bench/patch_ends.py [bench/patches_body.py's arguments]
     e.g. --rig fewcam --seeds 1 --occlusions 3 --frames 30 --own-stream auto --seed-every 20

bench/patches_body.py runs as given (its rows printed as it prints them; no ``--stream-cache``: the clouds must be
tracked here), with every cloud's tracks (:func:`dome_calib.recon.patches.run.run_cloud`) kept: each patch alive at
its seed time is given the truth's surface point nearest its centre there
(:func:`~dome_calib.synth.textured.nearest_surface_points`) and, where it ended, the rule that ended it
(:attr:`~dome_calib.recon.patches.track.CloudTrack.ended`, :data:`~dome_calib.recon.patches.track.END_CAUSES`) and
how many cameras truly saw that surface point at the time it ended (the point carried by its part,
:func:`~dome_calib.synth.textured.surface_visibility`: in the image, facing the camera, nothing in front). Per seed
one row per group: the limb ends' patches (forearms and shins) that ended inside or before an occluded span of that
limb (the span's joint removed from the detections at the step's time, or later in the track's direction), the
other limb-end patches, and the torso's (torso, shoulders, hips): patches, tracks that reached the end of the span
judged, and per end cause the patches and how many of them two or more cameras truly saw when it ended (the rule's
doing, not the image's) and their median frames alive.
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import patches_body as pb  # noqa: E402  (bench/patches_body.py: the setup and the judging)
from dome_calib.recon.body_models import JOINTS19  # noqa: E402
from dome_calib.recon.patches import run as patch_run  # noqa: E402
from dome_calib.recon.patches.track import END_CAUSES  # noqa: E402
from dome_calib.synth.body_volume import CAPSULE_NAMES  # noqa: E402
from dome_calib.synth.textured import nearest_surface_points, surface_points_cm, surface_visibility  # noqa: E402

#: The limb ends' parts and the joint whose removal is their occluded span.
LIMB_END = {CAPSULE_NAMES.index(p): JOINTS19.index(j) for p, j in (
    ("l_forearm", "l_wrist"), ("r_forearm", "r_wrist"), ("l_shin", "l_ankle"), ("r_shin", "r_ankle"))}
TORSO = {CAPSULE_NAMES.index(p) for p in ("torso", "shoulders", "hips")}


def ends_of(ctx: dict) -> list[dict]:
    """One record per patch alive at its seed time: group, end cause, frames alive, cameras truly seeing it."""
    truth, bundle, removed, times = ctx["truth"], ctx["bundle"], ctx["removed"], ctx["times"]
    out = []
    for cams, tr in ctx["clouds"]:
        t = tr.times_ms
        if len(t) < 2 or tr.ended is None:
            continue
        live0 = np.flatnonzero(tr.alive[:, 0])
        sp = nearest_surface_points(truth, float(t[0]), tr.X_cm[live0, 0, 0])
        held = tr.alive | (tr.carried if tr.carried is not None else False)
        for i, n in enumerate(live0):
            person, part = int(sp.person[i]), int(sp.part[i])
            if person < 0:
                continue
            last = int(np.flatnonzero(held[n]).max())
            cause = END_CAUSES[int(tr.ended[n])]
            rec = dict(part=part, cause=cause or ("reached" if last == len(t) - 1 else "unended"),
                       frames=int(tr.alive[n].sum()))
            group = "torso" if part in TORSO else "limb_end" if part in LIMB_END else "other"
            if cause and last + 1 < len(t):
                t_end = float(t[last + 1])
                W, nrm = surface_points_cm(truth, np.array([t_end]), np.array([person]), np.array([part]),
                                           sp.local_cm[i:i + 1])
                rec["true_views"] = int(surface_visibility(bundle, cams, truth, t_end, W[0], nrm[0]).sum())
                if part in LIMB_END:
                    k = np.searchsorted(times, t[last + 1:] - 0.5)  # the track's times from the end on
                    k = k[(k < len(times))]
                    span = removed[k, person, LIMB_END[part]] if len(k) else np.zeros(0, bool)
                    group = "limb_end_span" if span.any() else "limb_end"
            elif part in LIMB_END:
                group = "limb_end"
            rec["group"] = group
            out.append(rec)
    return out


def table(recs: list[dict]) -> dict:
    rows = {}
    for g in ("limb_end_span", "limb_end", "torso", "other"):
        rs = [r for r in recs if r["group"] == g]
        row = {"patches": len(rs)}
        for c in [c for c in END_CAUSES if c] + ["reached", "unended"]:
            cs = [r for r in rs if r["cause"] == c]
            if cs:
                row[c] = {"n": len(cs), "truly_seen_2plus": sum(r.get("true_views", 0) >= 2 for r in cs),
                          "frames_median": float(np.median([r["frames"] for r in cs]))}
        rows[g] = row
    return rows


def main() -> None:
    ctx: dict = {}
    per_seed: dict[int, list] = {}
    rig_group, occlude, run_cloud = pb.rig_group, pb.occlude, patch_run.run_cloud

    def watched_rig_group(bundle, *a, **k):
        ctx.clear()  # a new seed: its own record
        ctx.update(truth=rig_group(bundle, *a, **k), bundle=bundle, seed=k.get("seed", -1), clouds=[])
        per_seed[ctx["seed"]] = ctx.copy()
        return ctx["truth"]

    def watched_occlude(det, bundle, truth, times_ms, *a, **k):
        det, removed = occlude(det, bundle, truth, times_ms, *a, **k)
        ctx.update(removed=removed, times=np.asarray(times_ms, float))
        return det, removed

    def watched_run_cloud(source, views, *a, **k):
        back, fwd = run_cloud(source, views, *a, **k)
        ctx["clouds"] += [(list(views.names), back), (list(views.names), fwd)]
        per_seed[ctx["seed"]] = dict(ctx)
        return back, fwd

    pb.rig_group, pb.occlude, patch_run.run_cloud = watched_rig_group, watched_occlude, watched_run_cloud
    pb.main()
    for seed, c in per_seed.items():
        print(json.dumps({"what": "patch_ends", "seed": seed, "causes": table(ends_of(c))}), flush=True)


if __name__ == "__main__":
    main()
