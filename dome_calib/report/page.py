"""The report page ``report/index.html``: one self-contained file a technician opens from the file system (no
network, no server): the template :file:`page.html` (plain JavaScript and SVG) with the report's data inline.

Everything on the page comes from the files of the report folder, each read through its schema: ``report.json``
(:class:`dome_calib.report.schema.Report`: cameras, reasons to check, world frame, stage times, uncertainties, lens
model, change since the previous calibration; older layouts migrated), ``residuals.npz`` (per observation the
camera, the residual and, since report version 2, the pixel where it was seen) and, in a session bundle,
``session.json`` and ``sync.json`` (:mod:`dome_calib.report.kept`: Kinect depth-to-colour figures, per stream clock
fits). A file that does not match its schema is refused in one line naming the file and the field (ReportError):
no value of the wrong type reaches the page. What is missing or from an older layout is listed at the top of the
page (``"missing"``), never a blank page.

A file is data, never code: the page's data is inline JSON with ``<``, ``>`` and ``&`` escaped (no string can close
the script element or open a comment), and the template inserts every value through ``esc`` (text) or ``num``
(numbers), never as markup.

Sizes (to stay interactive on 521 cameras): per camera at most ``MAX_ARROWS`` residual arrows, every k-th
observation in saved order (k = ceil(n / MAX_ARROWS), stated on the page), packed as little-endian int16
``[u_px, v_px, du_centi_px, dv_centi_px]`` (residuals saturate at +-327.67 px; the true maximum is stated), and
an observation-coverage grid of ``COVERAGE_GRID`` cells over the image built from every observation; residual
distributions per type as histograms up to the 99.5th percentile plus one tail bin stating its range, count
and maximum.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from dome_calib.errors import BundleFormatError, ReportError
from dome_calib.io_utils import atomic_write_text
from dome_calib.pages import pack_b64, render
from dome_calib.panoptic_io import read_ksynctables, read_synctables
from dome_calib.report.kept import SessionReport, SyncReport, read_kept
from dome_calib.report.schema import CameraLens, Report, read_report
from dome_calib.residuals import Residuals

logger = logging.getLogger(__name__)

PAGE_FILE = "index.html"
MAX_ARROWS = 200  # residual arrows per camera on the page
COVERAGE_GRID = (16, 12)  # cells across, down the image
HIST_BINS = 40
TAIL_PERCENTILE = 99.5  # the histogram's regular bins end here; the rest is one stated tail bin
CENTI_PX_MAX = 32767  # int16


def arrows_of(uv_px: np.ndarray, res_px: np.ndarray, max_arrows: int = MAX_ARROWS) -> dict:
    """One camera's arrows for the page: every k-th observation (k = ceil(n / max_arrows)) packed as int16."""
    n = len(res_px)
    step = max(1, math.ceil(n / max_arrows))
    keep = np.arange(0, n, step)
    packed = np.column_stack([np.rint(uv_px[keep]), np.clip(np.rint(res_px[keep] * 100.0), -CENTI_PX_MAX,
                                                            CENTI_PX_MAX)])
    return {"n": int(n), "step": int(step), "kept": int(len(keep)), "b64": pack_b64(packed, "<i2")}


def coverage_of(uv_px: np.ndarray, resolution: list[int], grid: tuple[int, int] = COVERAGE_GRID) -> dict:
    """Observation counts on a grid of cells over the image (row-major, ``grid[1]`` rows of ``grid[0]``)."""
    w, h = resolution
    gx = np.clip((uv_px[:, 0] / w * grid[0]).astype(int), 0, grid[0] - 1)
    gy = np.clip((uv_px[:, 1] / h * grid[1]).astype(int), 0, grid[1] - 1)
    counts = np.bincount(gy * grid[0] + gx, minlength=grid[0] * grid[1])
    return {"grid": list(grid), "b64": pack_b64(np.minimum(counts, 65535), "<u2"),
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



def _lens_text(model: CameraLens | None, held: str | None) -> tuple[str, str]:
    """Short text for the table and the reasons behind it (tooltip)."""
    if held:
        return "all held", held
    if model is None:
        return "", ""
    why = "; ".join(f"{d.group}: {'free' if d.free else 'held'} ({d.reason})" for d in model.decisions)
    return (f"free {' '.join(model.free)}" + (f"; held {' '.join(model.held)}" if model.held else "")), why


def to_check_list(report: Report) -> list[dict]:
    """The report's cameras to check as ``{"name", "reasons"}`` (the reasons' texts)."""
    return [{"name": r.name, "reasons": [x.text for x in r.reasons]} for r in report.to_check]


def camera_table(report: Report) -> list[dict]:
    """One row per camera, in name order, with everything the table, the dome view and the panel show."""
    lens = report.lens_model.cameras if report.lens_model else {}
    prev = report.previous.cameras if report.previous else {}
    check = {r["name"]: r["reasons"] for r in to_check_list(report)}
    rows = []
    for name, c in sorted(report.per_camera.items()):
        lens_text, lens_why = _lens_text(lens.get(name), c.held)
        p = prev.get(name)
        csig = report.center_sigma_cm.get(name)
        rows.append({"name": name, "type": str(c.type), "panel": c.panel, "obs": c.observations, "rms": c.rms_px,
                     "csig_mm": None if csig is None else round(csig * 10.0, 3),
                     "rsig_deg": report.rotation_sigma_deg.get(name), "lens": lens_text, "lens_why": lens_why,
                     "held": c.held, "moved_mm": p and p.moved_mm, "turned_deg": p and p.turned_deg,
                     "focal_pct": p and p.focal_pct, "c": c.center_cm, "d": c.view_dir, "res": c.resolution,
                     "check": check.get(name, [])})
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



def dropped_frames(bundle_folder: Path) -> tuple[dict[str, int], str | None]:
    """Per stream ("vga", "hd", "KINECTNODE4/color", ...) the frames missing from its sync table: indices between
    its first and last frame that have no time (synctables_*.json, ksynctables_*.json beside report/, read by the
    bundle's readers); and why none could be counted (a table that does not read), else None."""
    tables = {}
    try:
        for path in sorted(bundle_folder.glob("synctables_*.json"))[:1]:
            tables |= read_synctables(path)
        for path in sorted(bundle_folder.glob("ksynctables_*.json"))[:1]:
            color, depth = read_ksynctables(path)
            tables |= {f"{node}/color": t for node, t in color.items()}
            tables |= {f"{node}/depth": t for node, t in depth.items()}
    except BundleFormatError as exc:
        return {}, f"{exc}: dropped frames not counted"
    out = {}
    for key, table in tables.items():
        idx = np.unique(np.asarray(table.index, dtype=np.int64))
        out[key] = int(idx[-1] - idx[0] + 1 - len(idx)) if len(idx) else 0
    return out, None


def _sync_section(sync: SyncReport, session: SessionReport | None, dropped: dict[str, int]) -> dict:
    """Per stream the clock fit's error (us), drift, frames and the frames dropped (missing from its sync table;
    and misread LTC frames, clock-fit outliers), from sync.json and the bundle's sync tables."""
    channels = {"vga": sync.channels.vga, "hd": sync.channels.hd}
    kinect_max = {node: max((d.residual_max_us or 0.0 for d in k.device_clock), default=None)
                  for node, k in sync.kinect.items() if k.status == "synced"}
    streams = []
    for name, s in sorted(sync.streams.items()):
        ch = channels.get(name)
        if ch is not None:
            seg = [x.residual_max_us for x in ch.segments if x.residual_max_us is not None]
            resid_max = max(seg) if seg else None
        else:
            resid_max = kinect_max.get(name.split("/")[0])
        streams.append({"stream": name, "frames": s.n_frames, "dropped": dropped.get(name), "first_ms": s.first_ms,
                        "span_s": round((s.last_ms - s.first_ms) / 1e3, 3), "drift_ppm": s.drift_ppm,
                        "residual_rms_us": s.residual_rms_us, "residual_max_us": resid_max,
                        "outliers": s.n_outliers, "misread": ch.n_misread if ch is not None else None})
    kinect = {k: {"status": v.status, "reason": getattr(v, "reason", None)} for k, v in sorted(sync.kinect.items())}
    return {"streams": streams, "kinect": kinect, "notes": sync.notes,
            "to_check": session.pillars.sync.to_check if session else []}


def _previous(report: Report) -> dict | None:
    p = report.previous
    if p is None:
        return None
    return {"source": p.source, "seq": p.seq, "compared": p.compared, "error": p.error, "added": p.added,
            "gone": p.gone}


def _summary(report: Report) -> dict:
    """report.json's figures for the cards and "where and how long" (typed, as the template reads them)."""
    cluster = report.cluster
    return {"seq": report.seq, "calib_data_source": report.calib_data_source, "cameras": report.cameras,
            "expected_per_type": {str(t): c.model_dump() for t, c in report.expected_per_type.items()},
            "has_residuals": report.has_residuals, "rms_px": report.rms_px,
            "per_type": {str(t): s.model_dump() for t, s in report.per_type.items()},
            "rules": report.rules and report.rules.model_dump(),
            "world_frame": report.world_frame and {"residual_rms_cm": report.world_frame.residual_rms_cm,
                                                   "description": report.world_frame.description},
            "stage_seconds": report.stage_seconds,
            "cluster": cluster and {"executor": cluster.executor, "scheduler": cluster.scheduler,
                                    "description": cluster.description, "on_this_machine": cluster.on_this_machine,
                                    "stages": {k: {"workers": s.workers} for k, s in cluster.stages.items()}}}


def page_data(report: Report | None, residuals: Residuals | None, *, session: SessionReport | None = None,
              sync: SyncReport | None = None, dropped: dict[str, int] | None = None, version: int = 3,
              missing: list[str] | None = None) -> dict:
    """Everything the page shows, as plain data (the template's ``DATA``), from the typed files; ``version``:
    the layout report.json had (an older one is said on the page)."""
    missing = list(missing or [])
    if report is not None and version < 2:
        missing.append("report.json is from an older version (no panels, image sizes or what the calibration held): "
                       "rerun `dome-calib calibrate` for the full page")
        if not report.per_type:
            missing.append('report.json has no "per_type" (an older report): the RMS per camera type cannot be shown')
    rows = camera_table(report) if report is not None else []
    arrows, coverage, hist = {}, {}, {}
    if residuals is not None:
        arrows, coverage = _per_camera_residuals(residuals, {r["name"]: r["res"] for r in rows})
        if residuals.uv_px is None:
            missing.append("residuals.npz holds no pixel positions (written before they were saved): the residuals "
                           "over the image cannot be drawn; rerun `dome-calib calibrate`")
        for t in sorted({r["type"] for r in rows}):
            hist[t] = histogram_of(residuals.norms_of({r["name"] for r in rows if r["type"] == t}))
    kinect = session.pillars.kinect if session else None
    return {
        "summary": _summary(report) if report is not None else {},
        "to_check": to_check_list(report) if report is not None else [], "cameras": rows,
        "previous": _previous(report) if report is not None else None,
        "hist": hist, "arrows": arrows, "coverage": coverage, "max_arrows": MAX_ARROWS,
        "sync": _sync_section(sync, session, dropped or {}) if sync else None,
        "kinect": kinect and {"achieved": kinect.achieved, "sensors": [s.model_dump() for s in kinect.sensors],
                              "to_check": kinect.to_check},
        "session": session and {"stage_seconds": session.stage_seconds,
                                "pillars": {k: {"achieved": v.achieved, "to_check": v.to_check}
                                            for k, v in session.pillars}},
        "missing": missing}


def read_report_folder(folder: Path, residuals: Residuals | None = None) -> dict:
    """:func:`page_data` of the files in a report folder: a file that is missing is listed on the page; a file that
    does not match its schema raises ReportError naming the file and the field."""
    folder = Path(folder)
    missing: list[str] = []
    report, version = None, 3
    if (folder / "report.json").exists():
        report, version = read_report(folder / "report.json")
    else:
        missing.append("report.json: not found: nothing about the cameras can be shown; run `dome-calib report "
                       "BUNDLE` (or calibrate again)")
    if residuals is None:
        path = folder / "residuals.npz"
        if path.is_file():
            try:
                residuals = Residuals.load(path)
            except ReportError as exc:
                missing.append(f"{exc}: residual plots not shown")
        elif report is None or report.has_residuals:
            missing.append("residuals.npz: not found: no residual plots, distributions or coverage")
    session, sync = read_kept(folder)
    dropped = None
    if sync is not None:
        dropped, why = dropped_frames(folder.parent)
        missing += [why] if why else []
    return page_data(report, residuals, session=session, sync=sync, dropped=dropped, version=version,
                     missing=missing)


def render_page(data: dict) -> str:
    """The page's HTML: the template through the pages' one module (:func:`dome_calib.pages.render`: shared styles,
    error handler, escaping helpers, ``data`` inline)."""
    return render("dome_calib.report", "page.html", data)


def write_page(folder: str | Path, residuals: Residuals | None = None) -> Path:
    """Write ``<folder>/index.html`` from the report files in ``folder`` (atomic). Returns its path."""
    folder = Path(folder)
    path = folder / PAGE_FILE
    atomic_write_text(path, render_page(read_report_folder(folder, residuals)))
    logger.info("report page written to %s (%.0f kB)", path, path.stat().st_size / 1e3)
    return path
