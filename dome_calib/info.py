"""A summary of a bundle: cameras by type, intrinsics per type, world extents, sync coverage."""
from __future__ import annotations

import numpy as np

from dome_calib.bundle import Bundle, CameraType


def bundle_summary(bundle: Bundle) -> dict:
    """Plain-data summary of a bundle (what `dome-calib info` prints)."""
    out: dict = {"seq": bundle.seq, "calib_data_source": bundle.calib_data_source, "cameras": len(bundle.cameras),
                 "types": {}}
    for cam_type in CameraType:
        cams = list(bundle.of_type(cam_type).values())
        if not cams:
            continue
        intr = np.array([c.intr for c in cams])
        dist = np.array([c.dist for c in cams])
        centers = np.array([c.center_cm for c in cams])
        out["types"][str(cam_type)] = {
            "count": len(cams),
            "resolutions": sorted({f"{c.resolution[0]}x{c.resolution[1]}" for c in cams}),
            "f_px_mean": float(intr[:, :2].mean()), "f_px_min": float(intr[:, :2].min()),
            "f_px_max": float(intr[:, :2].max()),
            "k1_mean": float(dist[:, 0].mean()), "k1_min": float(dist[:, 0].min()), "k1_max": float(dist[:, 0].max()),
            "center_cm_min": centers.min(axis=0).round(1).tolist(),
            "center_cm_max": centers.max(axis=0).round(1).tolist(),
        }
    if bundle.kinect is not None:
        out["kinect_sensors"] = sorted(bundle.kinect.sensors)
    if bundle.sync is not None:
        sync = {}
        tables = {**bundle.sync.streams, **{f"kinect-color/{k}": v for k, v in bundle.sync.kinect_color.items()},
                  **{f"kinect-depth/{k}": v for k, v in bundle.sync.kinect_depth.items()}}
        for name, table in tables.items():
            sync[name] = {"frames": int(len(table.index)),
                          "first_index": int(table.index[0]) if len(table.index) else None,
                          "univ_time_ms": [float(table.univ_time_ms[0]), float(table.univ_time_ms[-1])]
                          if len(table.index) else None}
        out["sync"] = sync
    return out


def format_summary(summary: dict) -> str:
    """Human-readable text of :func:`bundle_summary`."""
    lines = [f"bundle {summary['seq']} ({summary['calib_data_source'] or 'no source'}): {summary['cameras']} cameras"]
    for cam_type, s in summary["types"].items():
        lines.append(
            f"  {cam_type:<13}{s['count']:>4} cameras  {', '.join(s['resolutions'])}  "
            f"f {s['f_px_mean']:.1f} px [{s['f_px_min']:.1f}, {s['f_px_max']:.1f}]  "
            f"k1 {s['k1_mean']:+.3f} [{s['k1_min']:+.3f}, {s['k1_max']:+.3f}]"
        )
        lo, hi = s["center_cm_min"], s["center_cm_max"]
        lines.append(f"  {'':<13}centres x [{lo[0]:.0f}, {hi[0]:.0f}] y [{lo[1]:.0f}, {hi[1]:.0f}] "
                     f"z [{lo[2]:.0f}, {hi[2]:.0f}] cm (world: floor centre, y down)")
    if "kinect_sensors" in summary:
        lines.append(f"  kinect depth calibration: {len(summary['kinect_sensors'])} sensors")
    if "sync" in summary:
        lines.append("  sync coverage:")
        for name, s in summary["sync"].items():
            span = s["univ_time_ms"]
            span_txt = f"{span[0]:.3f} .. {span[1]:.3f} ms" if span else "empty"
            lines.append(f"    {name:<24}{s['frames']:>7} frames  {span_txt}")
    else:
        lines.append("  sync: none (no synctables in this bundle)")
    return "\n".join(lines)
