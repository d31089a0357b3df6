"""Judge a produced bundle against a synthetic session's one ground truth, pillar by pillar (demo and bench).

- Kinect: depth-to-colour transform error (translation mm, rotation deg) of each sensor against the truth.
- Sync: every stream's frame times (us) against the true times; Kinect frames against the bound the simulated
  timestamp jitter allows (frame jitter plus the clock fit's own share of the audio block jitter).
- Skeleton: MPJPE (mm) of the person triangulated from the session's detections with the produced bundle
  (cameras + sync) and with the ground-truth bundle, on a 100 Hz grid of universal times. The produced bundle's world is
  fixed by the design layout, not the truth's: its skeleton is moved by the similarity that aligns its cameras
  to the true ones (as `dome-calib compare` does) before the error is taken.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dome_calib.align import align_cameras, sim3_rotation
from dome_calib.bundle import Bundle
from dome_calib.recon.formats import load_detection_streams
from dome_calib.recon.project import view_set
from dome_calib.recon.streams import triangulate_streams
from dome_calib.rotation import rotation_angle_deg
from dome_calib.synth.skeleton import skeleton_cm
from dome_calib.synth.sync_session import load_truth
from timecode.sync.session import load_session

#: Kinect frames meet the bound when their RMS error is below this factor times the simulated-jitter bound.
KINECT_BOUND_FACTOR = 1.2


def kinect_errors(produced: Bundle, truth: Bundle) -> dict[str, dict]:
    """Sensor -> depth-to-colour translation error (mm) and rotation error (deg)."""
    out = {}
    for name, s in sorted(produced.kinect.sensors.items()):
        t = truth.kinect.sensors[name]
        a, b = np.linalg.inv(s.M_color) @ s.M_depth, np.linalg.inv(t.M_color) @ t.M_depth
        out[name] = {"t_err_mm": float(np.linalg.norm(a[:3, 3] - b[:3, 3]) * 1000.0),
                     "rot_err_deg": float(rotation_angle_deg(a[:3, :3], b[:3, :3]))}
    return out


def _tables(bundle: Bundle) -> dict:
    t = dict(bundle.sync.streams)
    t |= {f"{n}/color": v for n, v in bundle.sync.kinect_color.items()}
    t |= {f"{n}/depth": v for n, v in bundle.sync.kinect_depth.items()}
    return t


def sync_errors(produced: Bundle, session: Path) -> dict[str, dict]:
    """Stream -> frames compared, error RMS / max (us) against the truth; Kinect streams also their bound (us)."""
    truth = load_truth(session / "sync")
    loaded = load_session(session / "sync")
    block_jitter_us = float(truth.params["kinect_block_jitter_us"])
    out = {}
    tables = _tables(produced)
    for key in sorted(tables, key=lambda k: ("/" in k, k != "vga", k)):  # vga, hd, then the Kinects
        table = tables[key]
        common, i_p, i_t = np.intersect1d(table.index, truth.index[key], return_indices=True)
        err_us = (table.univ_time_ms[i_p] - truth.univ_ms[key][i_t]) * 1000.0
        row = {"frames": int(common.size), "err_rms_us": float(np.sqrt(np.mean(err_us ** 2))),
               "err_max_us": float(np.max(np.abs(err_us)))}
        if "/" in key:
            node, kind = key.split("/")
            jit = truth.jitter_us[key][i_t]
            x = loaded.kinects[node].block_device_time_100ns.astype(float)
            fr = getattr(loaded.kinects[node], kind).device_time_100ns.astype(float)
            var_fit = block_jitter_us ** 2 * (1 / x.size + (fr - x.mean()) ** 2 / np.sum((x - x.mean()) ** 2))
            row["jitter_rms_us"] = float(np.sqrt(np.mean(jit ** 2)))
            row["bound_rms_us"] = float(KINECT_BOUND_FACTOR * np.sqrt(np.mean(jit ** 2) + np.mean(var_fit)))
        out[key] = row
    return out


def _world_to_truth(produced: Bundle, truth: Bundle):
    al = align_cameras(produced.cameras, truth.cameras)
    R, t, s = sim3_rotation(al.tgt_from_src), np.asarray(al.tgt_from_src.translation), float(al.tgt_from_src.scale)
    return lambda X: s * X @ R.T + t


def skeleton_mpjpe(bundle: Bundle, truth: Bundle, session: Path, *, streams: str = "all",
                   margin_ms: float = 150.0, step_ms: float = 10.0) -> dict:
    """MPJPE (mm) of the session's person triangulated with ``bundle`` on a 100 Hz grid of universal times.

    A grid, not a stream's own frame times: at a frame's exact true time the ground-truth bundle would need that
    frame alone while a bundle whose times are off by a nanosecond interpolates two (and loses the joint where
    the neighbour is a missed detection); between frames both bundles interpolate alike.
    """
    tracks, _ = load_detection_streams(bundle, session / "detections.json")
    if streams == "vga":
        tracks = [t for t in tracks if t.stream == "vga"]
    vga = truth.sync.streams["vga"].univ_time_ms
    times = np.arange(vga[0] + margin_ms, vga[-1] - margin_ms, step_ms)
    views = view_set(bundle, [n for t in tracks for n in t.cameras])
    seq = triangulate_streams(views, tracks, times)
    X = seq.X_cm if bundle is truth else _world_to_truth(bundle, truth)(seq.X_cm)
    err_mm = np.linalg.norm(X - skeleton_cm(times), axis=-1) * 10.0
    ok = np.isfinite(err_mm)
    return {"mpjpe_mm": float(err_mm[ok].mean()), "p95_mm": float(np.percentile(err_mm[ok], 95)),
            "reconstructed": float(ok.mean()), "times": int(times.size), "views": len(views.names)}


def evaluate(produced: Bundle, truth: Bundle, session: Path) -> dict:
    """Every pillar's figures (plain data: printed by the demo, one JSON line each in bench/product.py)."""
    session = Path(session)
    mp = {"produced_all": skeleton_mpjpe(produced, truth, session),
          "truth_all": skeleton_mpjpe(truth, truth, session),
          "produced_vga": skeleton_mpjpe(produced, truth, session, streams="vga")}
    return {"kinect": kinect_errors(produced, truth), "sync": sync_errors(produced, session), "skeleton": mp}
