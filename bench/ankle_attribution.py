"""Where an ankle angle's difference from Pose2Sim's run comes from (issue 51): the ankle point, or the foot markers
(big toe, small toe, heel) that OpenSim's ankle angle also hangs on, frame by frame; and which run the four cameras'
detections side with, per camera.

Reads a folder kept by ``bench/pose2sim_pipeline.py --keep DIR`` (our TRC, Pose2Sim's own TRC, both runs' ``.mot``).
Run: .venv/bin/python bench/ankle_attribution.py DIR [--side L] [--no-swaps]
Prints one JSON object per line:
- ``markers_cm``: per marker of the leg, the distance between the two runs' TRC markers (median, 90th percentile,
  cm) and its mean vector (lab x, y, z: the runs' systematic difference);
- ``per_frame``: per frame, the ankle angle of each run (deg) and the distance between the runs' ankle, big toe,
  small toe and heel (cm);
- ``correlation``: over the frames, the correlation of the ankle angle's difference with each marker's difference
  along each lab axis (which marker moves with the angle);
- ``swaps``: our TRC with one group of markers replaced by Pose2Sim's (frame by frame), through Pose2Sim's filtering,
  augmentation and OpenSim IK again: the ankle, knee and hip angles' RMS against Pose2Sim's run. A group whose swap
  closes the gap is where the gap comes from;
- ``per_camera_px``: per marker and camera, each run's marker reprojected against the participant's detection
  (median px over the frames) and, per frame, which camera is farthest from the other three's triangulation.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import pose2sim_pipeline as p2p  # noqa: E402

from dome_calib.bundle_io import load_bundle  # noqa: E402
from dome_calib.recon.openpose_io import read_openpose_folder  # noqa: E402
from tests.pose2sim_pipeline_helpers import ANGLES, angle_rms_deg, pose2sim_on_trcs, read_mot  # noqa: E402

#: BODY_25B index of each foot marker (Pose2Sim's skeletons.py); the other markers are pose2sim_pipeline's.
FOOT_ID = {"LSmallToe": 20, "RSmallToe": 23}


def read_trc_table(path: Path) -> tuple[list[str], list[str], np.ndarray]:
    """A TRC -> (header lines up to the axis line, marker names, (F, M, 3) in the file's units and axes)."""
    lines = path.read_text().splitlines()
    names = [n for n in lines[3].split("\t")[2:] if n.strip()]
    rows = [ln.split("\t") for ln in lines[5:] if ln.strip()]
    X = np.array([[float(v) if v.strip() else np.nan for v in r[2:2 + 3 * len(names)]] for r in rows])
    return lines[:5], names, X.reshape(len(rows), len(names), 3)


def write_swapped(ours: Path, theirs: Path, markers: list[str], out: Path) -> None:
    """``ours`` with ``markers`` replaced by ``theirs``' frame by frame (frames both hold) -> ``out``."""
    head, names, X = read_trc_table(ours)
    _, their_names, Y = read_trc_table(theirs)
    F = min(len(X), len(Y))
    for m in markers:
        X[:F, names.index(m)] = Y[:F, their_names.index(m)]
    lines = ours.read_text().splitlines()
    rows = [ln.split("\t") for ln in lines[5:] if ln.strip()]
    body = ["\t".join(r[:2] + [f"{v:.6f}" for v in X[k].ravel()]) for k, r in enumerate(rows)]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(head + body) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a folder kept by bench/pose2sim_pipeline.py --keep")
    ap.add_argument("--side", default="L", choices=("L", "R"))
    ap.add_argument("--data", type=Path, default=p2p.DATA)
    ap.add_argument("--no-swaps", action="store_true")
    args = ap.parse_args()
    p2p.DATA_USED = args.data
    s = args.side
    side = "l" if s == "L" else "r"
    ours_trc = next((args.run / "trc").glob("*.trc"))
    ref_trc = next((args.run / "pose2sim" / "pose-3d").glob("*_0-99.trc"))
    mot_ours = next((args.run / "ours" / "kinematics").glob("*.mot"))
    mot_ref = next((args.run / "pose2sim" / "kinematics").glob("*.mot"))
    leg = [f"{s}Hip", f"{s}Knee", f"{s}Ankle", f"{s}BigToe", f"{s}SmallToe", f"{s}Heel"]
    _, na, A = read_trc_table(ours_trc)
    _, nb, B = read_trc_table(ref_trc)
    F = min(len(A), len(B))
    d = {m: (A[:F, na.index(m)] - B[:F, nb.index(m)]) * 100.0 for m in leg}  # cm, ours - Pose2Sim's, TRC axes
    p2p.emit(markers_cm={m: {"median": round(float(np.nanmedian(np.linalg.norm(v, axis=1))), 2),
                             "p90": round(float(np.nanpercentile(np.linalg.norm(v, axis=1), 90)), 2),
                             "mean_xyz": [round(float(x), 2) for x in np.nanmean(v, axis=0)]} for m, v in d.items()})
    a, b = read_mot(mot_ours), read_mot(mot_ref)
    common, ia, ib = np.intersect1d(np.round(a["time"], 4), np.round(b["time"], 4), return_indices=True)
    frames = np.round(common * 60).astype(int)
    ang = f"ankle_angle_{side}"
    diff = a[ang][ia] - b[ang][ib]
    p2p.emit(per_frame=[{"frame": int(f), "ankle_ours": round(float(a[ang][i]), 1),
                         "ankle_pose2sim": round(float(b[ang][j]), 1),
                         **{m: round(float(np.linalg.norm(d[m][f])), 1) for m in leg[2:] if f < F}}
                        for f, i, j in zip(frames, ia, ib)])
    ok = frames < F
    corr = {}
    for m in leg:
        corr[m] = [round(float(np.corrcoef(diff[ok], d[m][frames[ok], x])[0, 1]), 2) for x in range(3)]
    p2p.emit(correlation={"ankle_diff_rms_deg": round(float(np.sqrt(np.mean(diff ** 2))), 2),
                          "ankle_diff_mean_deg": round(float(diff.mean()), 2), "marker_axis_xyz": corr})
    if not args.no_swaps:
        groups = {"ankle": [f"{s}Ankle"], "foot": [f"{s}BigToe", f"{s}SmallToe", f"{s}Heel"],
                  "ankle_and_foot": [f"{s}Ankle", f"{s}BigToe", f"{s}SmallToe", f"{s}Heel"],
                  "knee": [f"{s}Knee"], "heel": [f"{s}Heel"], "toes": [f"{s}BigToe", f"{s}SmallToe"]}
        for name, markers in groups.items():
            work = args.run / f"swap_{s}_{name}"
            write_swapped(ours_trc, ref_trc, markers, work / "in" / ours_trc.name)
            mots = pose2sim_on_trcs(work / "p2s", [work / "in" / ours_trc.name], model="BODY_25B", fps=60)
            rms = angle_rms_deg(mots[0], mot_ref)
            p2p.emit(swaps={name: markers, **{k: round(v, 2) for k, v in rms.items() if k.endswith(f"_{side}")
                                               or k.startswith("pelvis")}})
    bundle = load_bundle(args.run / "bundle")
    det = read_openpose_folder(args.data / "pose", body_model="BODY_25B",
                               camera_map={f"cam{k:02d}_json": f"cam_{k:02d}" for k in range(1, 5)})
    p2p.BODY_25B_ID.update(FOOT_ID)
    cams, kp = p2p.participant_detections(bundle, det, [ours_trc, ref_trc])
    agreeing = p2p.agreeing_cameras(bundle, cams, kp)
    p2p.emit(per_camera_px={k: {m: v for m, v in p2p.per_camera_px(bundle, t, cams, kp).items() if m in leg}
                            for k, t in (("ours", ours_trc), ("pose2sim", ref_trc))},
             odd_camera_frames={m: {"frames_3_agree": int(ok_.sum()),
                                    **{c: int((ok_ & ~ag[:, v]).sum()) for v, c in enumerate(cams)}}
                                for m, (ok_, ag) in agreeing.items() if m in leg},
             px_on_agreeing_cameras={k: {m: v for m, v in p2p.on_agreeing_cameras(bundle, t, cams, kp, agreeing).items()
                                         if m in leg} for k, t in (("ours", ours_trc), ("pose2sim", ref_trc))})


if __name__ == "__main__":
    main()
