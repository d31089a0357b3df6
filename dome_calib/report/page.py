"""The report page ``report/index.html``: one self-contained file a technician opens from the file system (no
network, no server): the template :file:`page.html` (plain JavaScript and SVG) with the report's data inline.

Everything on the page comes from the files of the report folder: ``report.json`` (cameras, reasons to check,
world frame, stage times, uncertainties, lens model, change since the previous calibration), ``residuals.npz``
(per observation the camera, the residual and, since report version 2, the pixel where it was seen) and, in a
session bundle, ``session.json`` (Kinect depth-to-colour figures) and ``sync.json`` (per stream clock fits).
What is missing or from an older version is listed at the top of the page (``"missing"``), never a blank page.

Sizes (to stay interactive on 521 cameras): per camera at most ``MAX_ARROWS`` residual arrows, every k-th
observation in saved order (k = ceil(n / MAX_ARROWS), stated on the page), packed as little-endian int16
``[u_px, v_px, du_centi_px, dv_centi_px]`` (residuals saturate at +-327.67 px; the true maximum is stated), and
an observation-coverage grid of ``COVERAGE_GRID`` cells over the image built from every observation; residual
distributions per type as histograms up to the 99.5th percentile plus one tail bin stating its range, count
and maximum.
"""
from __future__ import annotations

import base64
import json
import logging
import math
from importlib import resources
from pathlib import Path

import numpy as np

from dome_calib.errors import ReportError
from dome_calib.io_utils import atomic_write_text
from dome_calib.residuals import Residuals

logger = logging.getLogger(__name__)

PAGE_FILE = "index.html"
MAX_ARROWS = 200  # residual arrows per camera on the page
COVERAGE_GRID = (16, 12)  # cells across, down the image
HIST_BINS = 40
TAIL_PERCENTILE = 99.5  # the histogram's regular bins end here; the rest is one stated tail bin
CENTI_PX_MAX = 32767  # int16


def _b64(a: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode("ascii")


def _finite(v) -> float | None:
    return None if v is None or not np.isfinite(v) else float(v)


def arrows_of(uv_px: np.ndarray, res_px: np.ndarray, max_arrows: int = MAX_ARROWS) -> dict:
    """One camera's arrows for the page: every k-th observation (k = ceil(n / max_arrows)) packed as int16."""
    n = len(res_px)
    step = max(1, math.ceil(n / max_arrows))
    keep = np.arange(0, n, step)
    packed = np.column_stack([np.rint(uv_px[keep]), np.clip(np.rint(res_px[keep] * 100.0), -CENTI_PX_MAX,
                                                            CENTI_PX_MAX)])
    return {"n": int(n), "step": int(step), "kept": int(len(keep)), "b64": _b64(packed, "<i2")}


def coverage_of(uv_px: np.ndarray, resolution: list[int], grid: tuple[int, int] = COVERAGE_GRID) -> dict:
    """Observation counts on a grid of cells over the image (row-major, ``grid[1]`` rows of ``grid[0]``)."""
    w, h = resolution
    gx = np.clip((uv_px[:, 0] / w * grid[0]).astype(int), 0, grid[0] - 1)
    gy = np.clip((uv_px[:, 1] / h * grid[1]).astype(int), 0, grid[1] - 1)
    counts = np.bincount(gy * grid[0] + gx, minlength=grid[0] * grid[1])
    return {"grid": list(grid), "b64": _b64(np.minimum(counts, 65535), "<u2"),
            "covered_pct": round(100.0 * float(np.count_nonzero(counts)) / counts.size, 1)}


def histogram_of(norms_px: np.ndarray) -> dict:
    """Residual norms (px): regular bins up to the TAIL_PERCENTILE, then the tail as one bin with its range."""
    if not len(norms_px):
        return {"n": 0}
    hi = max(float(np.percentile(norms_px, TAIL_PERCENTILE)), 1e-3)
    counts, edges = np.histogram(norms_px[norms_px <= hi], bins=HIST_BINS, range=(0.0, hi))
    tail = norms_px[norms_px > hi]
    return {"n": int(len(norms_px)), "edges_px": [round(float(e), 4) for e in edges], "counts": counts.tolist(),
            "tail": {"from_px": round(hi, 4), "count": int(len(tail)), "max_px": round(float(norms_px.max()), 4)},
            "rms_px": round(float(np.sqrt(np.mean(norms_px ** 2) / 2)), 4),
            "median_px": round(float(np.median(norms_px)), 4)}


def _lens_text(model: dict | None, held: str | None) -> tuple[str, str]:
    """Short text for the table and the reasons behind it (tooltip)."""
    if held:
        return "all held", held
    if not model:
        return "", ""
    why = "; ".join(f"{d.get('group')}: {'free' if d.get('free') else 'held'} ({d.get('reason', '')})"
                    for d in model.get("decisions", []))
    free, kept = " ".join(model.get("free", [])), " ".join(model.get("held", []))
    return (f"free {free}" + (f"; held {kept}" if kept else "")), why


def camera_table(report: dict) -> list[dict]:
    """One row per camera, in name order, with everything the table, the dome view and the panel show."""
    per_cam = report.get("per_camera") or {}
    sigma_c = report.get("center_sigma_cm") or {}
    sigma_r = report.get("rotation_sigma_deg") or {}
    lens = ((report.get("lens_model") or {}).get("cameras")) or {}
    prev = (report.get("previous") or {}).get("cameras") or {}
    check = {row["name"]: row.get("reasons", []) for row in report.get("to_check") or []}
    rows = []
    for name in sorted(per_cam):
        c = per_cam[name]
        lens_text, lens_why = _lens_text(lens.get(name), c.get("held"))
        p = prev.get(name) or {}
        rows.append({"name": name, "type": c.get("type"), "panel": c.get("panel"),
                     "obs": c.get("observations"), "rms": _finite(c.get("rms_px")),
                     "csig_mm": round(sigma_c[name] * 10.0, 3) if name in sigma_c else None,
                     "rsig_deg": sigma_r.get(name), "lens": lens_text, "lens_why": lens_why,
                     "held": c.get("held"), "moved_mm": p.get("moved_mm"), "turned_deg": p.get("turned_deg"),
                     "focal_pct": p.get("focal_pct"), "c": c.get("center_cm"), "d": c.get("view_dir"),
                     "res": c.get("resolution"), "check": check.get(name, [])})
    return rows


def _per_camera_residuals(residuals: Residuals, cameras: dict[str, list[int] | None]) -> tuple[dict, dict]:
    arrows, coverage = {}, {}
    if residuals.uv_px is None:
        return arrows, coverage
    order = np.argsort(residuals.camera_index, kind="stable")
    bounds = np.searchsorted(residuals.camera_index[order], np.arange(len(residuals.camera_names) + 1))
    for c, name in enumerate(residuals.camera_names):
        rows = order[bounds[c]:bounds[c + 1]]
        if not len(rows) or name not in cameras:
            continue
        arrows[name] = arrows_of(residuals.uv_px[rows], residuals.residual_px[rows])
        if cameras[name]:
            coverage[name] = coverage_of(residuals.uv_px[rows], cameras[name])
    return arrows, coverage


def dropped_frames(bundle_folder: Path) -> dict[str, int]:
    """Per stream ("vga", "hd", "KINECTNODE4/color", ...) the frames missing from its sync table: indices between
    its first and last frame that have no time (synctables_*.json, ksynctables_*.json beside report/)."""
    tables: dict[str, list] = {}
    for path in sorted(bundle_folder.glob("synctables_*.json"))[:1]:
        for key, t in _load_or_empty(path).items():
            if isinstance(t, dict) and isinstance(t.get("index"), list):
                tables[key] = t["index"]
    for path in sorted(bundle_folder.glob("ksynctables_*.json"))[:1]:
        for kind, nodes in ((_load_or_empty(path).get("kinect") or {}).items()):
            for node, t in (nodes or {}).items():
                if isinstance(t, dict) and isinstance(t.get("index"), list):
                    tables[f"{node}/{kind}"] = t["index"]
    out = {}
    for key, index in tables.items():
        idx = np.unique(np.asarray(index, dtype=np.int64)) if index else np.zeros(0, np.int64)
        out[key] = int(idx[-1] - idx[0] + 1 - len(idx)) if len(idx) else 0
    return out


def _load_or_empty(path: Path) -> dict:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def _sync_section(sync: dict, session: dict | None, dropped: dict[str, int] | None = None) -> dict:
    """Per stream the clock fit's error (us), drift, frames and the frames dropped (missing from its sync table;
    and misread LTC frames, clock-fit outliers), from sync.json and the bundle's sync tables."""
    channels = sync.get("channels") or {}
    streams = []
    kinect_max = {node: max((d.get("residual_max_us") or 0.0 for d in k.get("device_clock") or []), default=None)
                  for node, k in (sync.get("kinect") or {}).items() if isinstance(k, dict)}
    for name, s in sorted((sync.get("streams") or {}).items()):
        ch = channels.get(name) or {"residual_max_us": kinect_max.get(name.split("/")[0])}
        streams.append({"stream": name, "frames": s.get("n_frames"), "dropped": (dropped or {}).get(name),
                        "first_ms": s.get("first_ms"),
                        "span_s": None if s.get("last_ms") is None or s.get("first_ms") is None
                        else round((s["last_ms"] - s["first_ms"]) / 1e3, 3),
                        "drift_ppm": s.get("drift_ppm"), "residual_rms_us": s.get("residual_rms_us"),
                        "residual_max_us": ch.get("residual_max_us", _seg_max(ch)),
                        "outliers": s.get("n_outliers"), "misread": ch.get("n_misread")})
    kinect = {k: {"status": v.get("status"), "reason": v.get("reason")} for k, v in (sync.get("kinect") or {}).items()}
    pillar = ((session or {}).get("pillars") or {}).get("sync") or {}
    return {"streams": streams, "kinect": kinect, "notes": sync.get("notes") or [],
            "to_check": pillar.get("to_check") or []}


def _seg_max(channel: dict) -> float | None:
    values = [s.get("residual_max_us") for s in channel.get("segments") or [] if s.get("residual_max_us") is not None]
    return max(values) if values else None


def page_data(report: dict | None, residuals: Residuals | None, *, session: dict | None = None,
              sync: dict | None = None, dropped: dict[str, int] | None = None,
              missing: list[str] | None = None) -> dict:
    """Everything the page shows, as plain data (the template's ``DATA``)."""
    missing = list(missing or [])
    report = report or {}
    for key, what in (("per_camera", "the camera table and the dome"), ("to_check", "the cameras to check"),
                      ("per_type", "the RMS per camera type")):
        if report and key not in report:
            missing.append(f"report.json has no \"{key}\" (an older or damaged report): {what} cannot be shown")
    if report and report.get("report_version", 1) < 2:
        missing.append("report.json is from an older version (no panels, image sizes or what the calibration held): "
                       "rerun `dome-calib calibrate` for the full page")
    rows = camera_table(report)
    arrows, coverage, hist = {}, {}, {}
    if residuals is not None:
        known = {r["name"]: r["res"] for r in rows}
        arrows, coverage = _per_camera_residuals(residuals, known)
        if residuals.uv_px is None:
            missing.append("residuals.npz holds no pixel positions (written before they were saved): the residuals "
                           "over the image cannot be drawn; rerun `dome-calib calibrate`")
        types = sorted({r["type"] for r in rows if r["type"]})
        for t in types:
            hist[t] = histogram_of(residuals.norms_of({r["name"] for r in rows if r["type"] == t}))
    summary = {k: report.get(k) for k in ("seq", "calib_data_source", "cameras", "expected_per_type", "has_residuals",
                                          "rms_px", "per_type", "world_frame", "stage_seconds", "cluster", "rules")}
    return {"summary": summary, "to_check": report.get("to_check") or [], "cameras": rows,
            "previous": report.get("previous"), "hist": hist, "arrows": arrows, "coverage": coverage,
            "max_arrows": MAX_ARROWS, "sync": _sync_section(sync, session, dropped) if sync else None,
            "kinect": (((session or {}).get("pillars") or {}).get("kinect")) if session else None,
            "session": {"stage_seconds": session.get("stage_seconds"),
                        "pillars": {k: {"achieved": v.get("achieved"), "to_check": v.get("to_check")}
                                    for k, v in (session.get("pillars") or {}).items()}} if session else None,
            "missing": missing}


def _read_json(path: Path, missing: list[str], what: str) -> dict | None:
    if not path.is_file():
        return None
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        missing.append(f"{path.name}: unreadable ({exc}): {what} not shown")
        return None
    if not isinstance(value, dict):
        missing.append(f"{path.name}: not a JSON object: {what} not shown")
        return None
    return value


def read_report_folder(folder: Path, residuals: Residuals | None = None) -> dict:
    """:func:`page_data` of the files in a report folder; what is missing or unreadable is listed, not raised."""
    folder = Path(folder)
    missing: list[str] = []
    report = _read_json(folder / "report.json", missing, "the calibration's figures")
    if report is None and not (folder / "report.json").is_file():
        missing.append("report.json: not found: nothing about the cameras can be shown; run `dome-calib report "
                       "BUNDLE` (or calibrate again)")
    if residuals is None:
        path = folder / "residuals.npz"
        if path.is_file():
            try:
                residuals = Residuals.load(path)
            except ReportError as exc:
                missing.append(f"{exc}: residual plots not shown")
        elif report is None or report.get("has_residuals", True):
            missing.append("residuals.npz: not found: no residual plots, distributions or coverage")
    session = _read_json(folder / "session.json", missing, "the session's Kinect section")
    sync = _read_json(folder / "sync.json", missing, "the sync section")
    dropped = dropped_frames(folder.parent) if sync else None
    return page_data(report, residuals, session=session, sync=sync, dropped=dropped, missing=missing)


def render_page(data: dict) -> str:
    """The page's HTML: the template with ``data`` inline (``</`` escaped so no string can close the script)."""
    template = resources.files("dome_calib.report").joinpath("page.html").read_text(encoding="utf-8")
    text = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    return template.replace("/*__DATA__*/null", text, 1)


def write_page(folder: str | Path, residuals: Residuals | None = None) -> Path:
    """Write ``<folder>/index.html`` from the report files in ``folder`` (atomic). Returns its path."""
    folder = Path(folder)
    path = folder / PAGE_FILE
    atomic_write_text(path, render_page(read_report_folder(folder, residuals)))
    logger.info("report page written to %s (%.0f kB)", path, path.stat().st_size / 1e3)
    return path
