"""Judge a produced bundle against a synthetic session's one ground truth, pillar by pillar (demo and bench).

- Kinect: depth-to-colour transform error (translation mm, rotation deg) of each sensor against the truth.
- Sync: every stream's frame times (us) against the true times; Kinect frames against the bound the simulated
  timestamp jitter allows (frame jitter plus the clock fit's own share of the audio block jitter).
- Skeleton: MPJPE (mm) of the person triangulated from the session's detections with the produced bundle
  (cameras + sync) and with the ground-truth bundle, on a 100 Hz grid of universal times, in four frames:

  - ``mpjpe_world_mm``: in the bundle's own world, as a consumer reads it. The produced world is fixed by the
    design layout, the truth's by the dome as built (centres ~1 cm off the design), so this includes how well
    the dome matches its design, which no calibration from the session alone can know.
  - ``mpjpe_cameras_mm``: after the similarity that aligns the bundle's camera centres onto the true ones
    (:func:`dome_calib.align.align_cameras`, as every calibration figure of the project is judged). The centres
    pin the capture volume only to a few mm: the bundle adjustment's weakest mode is a common turn of the
    cameras with the scene shifted, which the centres do not see, and the fit moves with single cameras.
  - ``mpjpe_mm`` (session-aligned; the aim is judged on it): after ONE rigid motion (rotation + translation,
    scale kept) for the whole session, fitted on the reconstructed joints (:func:`session_rigid_fit`): the
    placement of the volume is taken out, as a trajectory's absolute error is judged in SLAM (one motion for
    the whole trajectory), while the bundle's scale error, every per-time error and any bending of the volume
    count. Six numbers against ~6000 joints: the ground-truth bundle's own figure moves by < 0.1 %.
  - ``pa_mpjpe_mm``: after a similarity per time (the pose literature's PA-MPJPE: the body's shape alone; a
    per-time least-squares fit, so a few gross joint errors pull it above the MPJPE).

  The aim (produced within 10 % of the ground-truth bundle) is about the bundle's calibration quality for
  reconstruction: the world frame is a convention (the design fit) and the camera-centre alignment adds its own
  few-mm uncertainty, so the session-aligned figure judges it; the other two are printed beside it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dome_calib.align import align_cameras, rigid_fit, sim3_apply
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
#: A joint this far from the truth is a gross error (a wrong joint), not a calibration error: left out of the
#: session alignment's refit (mm; a body segment is 25-45 cm, calibration errors are a few mm).
GROSS_JOINT_ERROR_MM = 50.0


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
    return lambda X: sim3_apply(al.tgt_from_src, X)


def session_rigid_fit(X_cm: np.ndarray, X_true_cm: np.ndarray, *, gate_mm: float = GROSS_JOINT_ERROR_MM):
    """One rigid motion (R, t) for a whole session's (T, J, 3) reconstructed joints onto the true ones.

    Fitted on every reconstructed joint, then twice refitted on the joints within ``gate_mm`` of the truth (a
    wrong joint metres away must not move the volume). Returns ``f(X) = X @ R.T + t``.
    """
    ok = np.all(np.isfinite(X_cm), axis=-1)
    src, tgt = X_cm[ok], X_true_cm[ok]
    fit = rigid_fit(src, tgt)
    for _ in range(2):
        keep = np.linalg.norm(sim3_apply(fit, src) - tgt, axis=1) * 10.0 <= gate_mm
        if keep.sum() >= 3:
            fit = rigid_fit(src[keep], tgt[keep])
    return lambda X: sim3_apply(fit, X)


def pa_mpjpe_mm(X_cm: np.ndarray, X_true_cm: np.ndarray) -> float:
    """Mean joint error (mm) after a similarity (Umeyama) per time on that time's reconstructed joints (>= 3)."""
    errs = []
    for x, y in zip(X_cm, X_true_cm):
        ok = np.all(np.isfinite(x), axis=1)
        if ok.sum() < 3:
            continue
        a, b = x[ok] - x[ok].mean(axis=0), y[ok] - y[ok].mean(axis=0)
        U, S, Vt = np.linalg.svd(b.T @ a)
        d = np.array([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        scale = float((S * d).sum() / (a ** 2).sum())
        errs.append(np.linalg.norm(scale * a @ (U @ np.diag(d) @ Vt).T - b, axis=1) * 10.0)
    return float(np.concatenate(errs).mean()) if errs else float("nan")


def _mean_mm(X_cm: np.ndarray, X_true_cm: np.ndarray) -> tuple[float, np.ndarray]:
    err_mm = np.linalg.norm(X_cm - X_true_cm, axis=-1) * 10.0
    return float(err_mm[np.isfinite(err_mm)].mean()), err_mm


def skeleton_mpjpe(bundle: Bundle, truth: Bundle, session: Path, *, streams: str = "all",
                   margin_ms: float = 150.0, step_ms: float = 10.0) -> dict:
    """MPJPE (mm) of the session's person triangulated with ``bundle`` on a 100 Hz grid of universal times, in
    the four frames of the module docstring (``mpjpe_mm``: session-aligned; p95 of that one too).

    A grid, not a stream's own frame times: between frames every bundle interpolates alike (a grid time within
    ``FRAME_TIME_TOLERANCE_MS`` of a frame takes that frame alone, :meth:`SyncTable.bracket`).
    """
    tracks, _ = load_detection_streams(bundle, session / "detections.json")
    if streams == "vga":
        tracks = [t for t in tracks if t.stream == "vga"]
    vga = truth.sync.streams["vga"].univ_time_ms
    times = np.arange(vga[0] + margin_ms, vga[-1] - margin_ms, step_ms)
    views = view_set(bundle, [n for t in tracks for n in t.cameras])
    X = triangulate_streams(views, tracks, times).X_cm
    X_true = skeleton_cm(times)
    world, _ = _mean_mm(X, X_true)
    cameras = world if bundle is truth else _mean_mm(_world_to_truth(bundle, truth)(X), X_true)[0]
    session_mm, err_mm = _mean_mm(session_rigid_fit(X, X_true)(X), X_true)
    ok = np.isfinite(err_mm)
    return {"mpjpe_mm": session_mm, "mpjpe_cameras_mm": cameras, "mpjpe_world_mm": world,
            "pa_mpjpe_mm": pa_mpjpe_mm(X, X_true), "p95_mm": float(np.percentile(err_mm[ok], 95)),
            "reconstructed": float(ok.mean()), "times": int(times.size), "views": len(views.names)}


def evaluate(produced: Bundle, truth: Bundle, session: Path) -> dict:
    """Every pillar's figures (plain data: printed by the demo, one JSON line each in bench/product.py)."""
    session = Path(session)
    mp = {"produced_all": skeleton_mpjpe(produced, truth, session),
          "truth_all": skeleton_mpjpe(truth, truth, session),
          "produced_vga": skeleton_mpjpe(produced, truth, session, streams="vga")}
    return {"kinect": kinect_errors(produced, truth), "sync": sync_errors(produced, session), "skeleton": mp}
