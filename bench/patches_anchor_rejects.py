"""Which points the anchor flow rejects, on a turning body, and how wrong they were (issue 49, branch anchor62).

Run: .venv/bin/python bench/patches_anchor_rejects.py [bench/patches_body.py's arguments]
     e.g. --rig fewcam --seeds 1,2 --occlusions 3 --frames 30 --own-stream auto --seed-every 20
          --patch-options anchor_flow=true,...

bench/patches_body.py runs as given (its rows printed as it prints them), with every realignment of the anchor flow
(:meth:`dome_calib.recon.patches.track.SeedViews.realign`, the tracking steps of clouds tracked more than one step)
watched: each flown point's patch is the truth's surface point nearest its seed-time position
(:func:`~dome_calib.synth.textured.nearest_surface_points`, each of the three points), carried by its part
(:func:`~dome_calib.synth.textured.surface_points_cm`) to the step's time and projected into the camera. Per seed it
prints, by how far the point's part turned since the seed (the angle of the part frame's rotation), for every point
and for those of two-view limb patches (the patch flown in two cameras at that step, on an arm or a leg): the points,
the share rejected, split into not aligned (the flow from the seed image failed its checks) and moved more than
``anchor_flow_px``, the rejected points' true error as flown (median, px, and the share within 1 px: a rejection
that was wrong) and the kept points' (median, px).
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import patches_body as pb  # noqa: E402  (bench/patches_body.py: the setup and the judging)
from dome_calib import ties  # noqa: E402
from dome_calib.recon.patches import run as patch_run  # noqa: E402
from dome_calib.recon.patches import track, warp  # noqa: E402
from dome_calib.synth.textured import nearest_surface_points, part_frames, surface_points_cm  # noqa: E402

#: Bins of the part's turn since the seed (deg).
TURN_BINS = ((0, 5), (5, 10), (10, 20), (20, 30), (30, 45), (45, 180))
#: Parts from this index on are the limbs (dome_calib.recon.patches.parts.BONES: upper arms to shins).
FIRST_LIMB = 4


def main() -> None:
    ctx: dict = {}
    points: dict[int, list[dict]] = {}
    rig_group, judged_frames, track_cloud = pb.rig_group, track.judged_frames, track.track_cloud
    realign, flow = track.SeedViews.realign, warp.optical_flow

    def watched_rig_group(*a, **k):
        ctx["truth"], ctx["seed"] = rig_group(*a, **k), k.get("seed", -1)
        return ctx["truth"]

    def watched_judged_frames(clocks, t):
        ctx["t"] = float(t)
        return judged_frames(clocks, t)

    def watched_track_cloud(source, views, clocks, times_ms, X0, *a, **k):
        sp = nearest_surface_points(ctx["truth"], float(times_ms[0]), np.asarray(X0, float).reshape(-1, 3))
        ctx.update(views=views, sp=sp, t0=float(times_ms[0]), steps=len(times_ms), cloud=ctx.get("cloud", 0) + 1)
        return track_cloud(source, views, clocks, times_ms, X0, *a, **k)

    def watched_flow(*a, **k):
        out = flow(*a, **k)
        ctx.setdefault("flows", []).append(out[1])  # each call's "aligned" (the plain flow's, then the warp's)
        return out

    def watched_realign(self, source, name, frames, v, idx, q, ok, o, now=None):
        ctx["flows"] = []
        q2, ok2, off = realign(self, source, name, frames, v, idx, q, ok, o, now)
        if ctx["steps"] <= 2 or not ctx["flows"] or self.frame[v] < 0 or not track.now_frames(frames)[v]:
            return q2, ok2, off
        truth, sp = ctx["truth"], ctx["sp"]
        rows = (idx[:, None] * 3 + np.arange(3)[None]).reshape(-1)
        person, part, local = sp.person[rows], sp.part[rows], sp.local_cm[rows]
        on = person >= 0
        uv_true, turn = np.full((len(rows), 2), np.nan), np.full(len(rows), np.nan)
        if on.any():
            Xt = surface_points_cm(truth, np.array([ctx["t"]]), person[on], part[on], local[on])[0][0]
            uv_true[on] = track.project_one(ctx["views"], v, Xt)[0]
            Xj, _ = truth.joints_cm(np.array([ctx["t0"], ctx["t"]]))
            R0, R1 = (part_frames(Xj[k]).R[person[on], part[on]] for k in (0, 1))
            cos = (np.trace(np.einsum("nij,nkj->nik", R1, R0), axis1=1, axis2=2) - 1) / 2
            turn[on] = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        p0 = self.uv[idx, :, v].reshape(-1, 2)
        has = np.all(np.isfinite(p0), axis=1) & np.asarray(ok).reshape(-1)
        # realign's split: the points its warp takes (anchor_warp) are flown after the others
        A = (np.repeat(warp.seed_to_now(self.uv[idx, :, v], now.reshape(-1, 3, 2)), 3, axis=0)[has]
             if o.anchor_warp and now is not None else np.repeat(np.eye(2)[None], int(has.sum()), axis=0))
        warped = ties.above(warp.warp_px(A, o.lk_window_px), o.anchor_warp_px, ties.FLOW_QUANTUM_PX)
        flows = ctx["flows"] if (~warped).any() else [np.zeros(0, bool)] + ctx["flows"]
        aligned = np.zeros(int(has.sum()), bool)
        aligned[~warped], aligned[warped] = flows[0], np.concatenate(flows[1:] or [np.zeros(0, bool)])
        good = np.zeros(len(rows), bool)
        good[has] = aligned
        points.setdefault(ctx["seed"], []).append(dict(
            key=np.stack([np.full(len(rows), ctx["cloud"]), np.full(len(rows), ctx["t"]), rows // 3], 1),
            ok=has, off=off.copy(), good=good, err=np.linalg.norm(np.asarray(q).reshape(-1, 2) - uv_true, axis=1),
            part=part, turn=turn))
        return q2, ok2, off

    pb.rig_group, track.judged_frames = watched_rig_group, watched_judged_frames
    track.track_cloud = patch_run.track_cloud = watched_track_cloud
    track.SeedViews.realign = watched_realign
    track.optical_flow = warp.optical_flow = watched_flow  # the plain realignment's and the warp's
    pb.main()
    for seed, recs in points.items():
        c = {k: np.concatenate([r[k] for r in recs]) for k in recs[0]}
        _, inverse, count = np.unique(c["key"], axis=0, return_inverse=True, return_counts=True)
        views = count[inverse.ravel()] // 3  # the cameras the point's patch was realigned in at that step
        ok, off, good = c["ok"], c["off"], c["good"]
        row = {"what": "anchor_rejects", "seed": seed, "points": int(ok.sum()), "rejected": round(float(
            off.sum() / max(ok.sum(), 1)), 4), "rejected_two_view_share": round(float(
                (off & (views == 2)).sum() / max(off.sum(), 1)), 4)}
        for label, base in (("all", ok), ("two_view_limbs", ok & (c["part"] >= FIRST_LIMB) & (views == 2))):
            row[label] = {}
            for lo, hi in TURN_BINS:
                m = base & (c["turn"] >= lo) & (c["turn"] < hi)
                if not m.any():
                    continue
                rej, kept = c["err"][m & off], c["err"][m & ~off]
                row[label][f"{lo}-{hi}"] = {
                    "points": int(m.sum()), "rejected": round(float(off[m].mean()), 4),
                    "not_aligned": round(float((off & ~good)[m].mean()), 4),
                    "moved_too_far": round(float((off & good)[m].mean()), 4),
                    "rejected_err_px_median": round(float(np.nanmedian(rej)), 2) if len(rej) else None,
                    "rejected_within_1px": round(float(np.mean(rej < 1.0)), 3) if len(rej) else None,
                    "kept_err_px_median": round(float(np.nanmedian(kept)), 2) if len(kept) else None}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
