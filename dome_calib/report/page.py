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


def _num(v) -> float | None:
    """A finite number, else None (bool, strings, NaN and the like from a damaged file are not numbers)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return v


def _dict(v) -> dict:
    return v if isinstance(v, dict) else {}


def _strs(v) -> list[str]:
    return [x for x in v if isinstance(x, str)] if isinstance(v, list) else []


def _nums(v, n: int) -> list[float] | None:
    """A list of n finite numbers, else None."""
    if not isinstance(v, list) or len(v) != n or any(_num(x) is None for x in v):
        return None
    return v


def _plain(v):
    """JSON-safe copy: non-finite floats become None (sync.json and session.json may hold NaN)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_plain(x) for x in v]
    return v


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


def _lens_text(model: dict, held: str | None) -> tuple[str, str]:
    """Short text for the table and the reasons behind it (tooltip)."""
    if held:
        return "all held", held
    if not model:
        return "", ""
    why = "; ".join(f"{d.get('group')}: {'free' if d.get('free') else 'held'} ({d.get('reason', '')})"
                    for d in model.get("decisions") or [] if isinstance(d, dict))
    free, kept = " ".join(_strs(model.get("free"))), " ".join(_strs(model.get("held")))
    return (f"free {free}" + (f"; held {kept}" if kept else "")), why


def to_check_list(report: dict) -> list[dict]:
    """The report's cameras to check as ``{"name", "reasons"}`` (entries of another shape left out)."""
    rows = report.get("to_check")
    return [{"name": r["name"], "reasons": _strs(r.get("reasons"))} for r in (rows if isinstance(rows, list) else [])
            if isinstance(r, dict) and isinstance(r.get("name"), str)]


def camera_table(report: dict) -> list[dict]:
    """One row per camera, in name order, with everything the table, the dome view and the panel show. Fields
    of the wrong type (an older or damaged report.json) are left empty."""
    per_cam = _dict(report.get("per_camera"))
    sigma_c, sigma_r = _dict(report.get("center_sigma_cm")), _dict(report.get("rotation_sigma_deg"))
    lens = _dict(_dict(report.get("lens_model")).get("cameras"))
    prev = _dict(_dict(report.get("previous")).get("cameras"))
    check = {r["name"]: r["reasons"] for r in to_check_list(report)}
    rows = []
    for name in sorted(per_cam):
        c = _dict(per_cam[name])
        held = c.get("held") if isinstance(c.get("held"), str) else None
        lens_text, lens_why = _lens_text(_dict(lens.get(name)), held)
        p = _dict(prev.get(name))
        panel, obs, res = c.get("panel"), c.get("observations"), _nums(c.get("resolution"), 2)
        csig = _num(sigma_c.get(name))
        rows.append({"name": name, "type": c.get("type") if isinstance(c.get("type"), str) else None,
                     "panel": panel if isinstance(panel, int) and not isinstance(panel, bool) else None,
                     "obs": obs if isinstance(obs, int) and not isinstance(obs, bool) else None,
                     "rms": _num(c.get("rms_px")), "csig_mm": None if csig is None else round(csig * 10.0, 3),
                     "rsig_deg": _num(sigma_r.get(name)), "lens": lens_text, "lens_why": lens_why, "held": held,
                     "moved_mm": _num(p.get("moved_mm")), "turned_deg": _num(p.get("turned_deg")),
                     "focal_pct": _num(p.get("focal_pct")), "c": _nums(c.get("center_cm"), 3),
                     "d": _nums(c.get("view_dir"), 3), "res": res if res and min(res) > 0 else None,
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
        try:
            idx = np.unique(np.asarray(index, dtype=np.int64)) if index else np.zeros(0, np.int64)
        except (TypeError, ValueError, OverflowError):  # not frame indices: no count rather than a wrong one
            continue
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


#: report.json's summary keys and the type each must have to be shown.
SUMMARY_TYPES = {"seq": str, "calib_data_source": str, "cameras": int, "expected_per_type": dict,
                 "has_residuals": bool, "rms_px": (int, float), "per_type": dict, "world_frame": dict,
                 "stage_seconds": dict, "cluster": dict, "rules": dict}
#: The errors a section of an unexpected layout raises while it is read.
LAYOUT_ERRORS = (TypeError, AttributeError, KeyError, ValueError, IndexError)


def _previous(report: dict) -> dict | None:
    p = report.get("previous")
    if not isinstance(p, dict):
        return None
    out = {k: p[k] for k in ("source", "seq", "compared", "error") if isinstance(p.get(k), str)}
    return out | {"added": _strs(p.get("added")), "gone": _strs(p.get("gone"))}


def _kinect_section(session: dict) -> dict | None:
    k = _dict(_dict(session.get("pillars")).get("kinect"))
    if not k:
        return None
    sensors = [s for s in k.get("sensors") or [] if isinstance(s, dict)] if isinstance(k.get("sensors"), list) else []
    return {"achieved": k.get("achieved") if isinstance(k.get("achieved"), str) else "", "sensors": sensors,
            "to_check": _strs(k.get("to_check"))}


def _session_section(session: dict) -> dict:
    pillars = {name: {"achieved": v.get("achieved"), "to_check": _strs(v.get("to_check"))}
               for name, v in _dict(session.get("pillars")).items() if isinstance(v, dict)}
    return {"stage_seconds": {k: v for k, v in _dict(session.get("stage_seconds")).items() if _num(v) is not None},
            "pillars": pillars}


def _guarded(missing: list[str], what: str, default, fn, *args):
    """``fn(*args)``; a file of an unexpected layout costs its section (named in ``missing``), not the page."""
    try:
        return fn(*args)
    except LAYOUT_ERRORS as exc:
        missing.append(f"{what}: unexpected layout ({type(exc).__name__}: {exc}): not shown")
        return default


def page_data(report: dict | None, residuals: Residuals | None, *, session: dict | None = None,
              sync: dict | None = None, dropped: dict[str, int] | None = None,
              missing: list[str] | None = None) -> dict:
    """Everything the page shows, as plain data (the template's ``DATA``). Every part is read defensively:
    what is missing or of another shape is listed in ``"missing"`` and the rest is shown."""
    missing = list(missing or [])
    report = _dict(report)
    for key, what in (("per_camera", "the camera table and the dome"), ("to_check", "the cameras to check"),
                      ("per_type", "the RMS per camera type")):
        if report and key not in report:
            missing.append(f"report.json has no \"{key}\" (an older or damaged report): {what} cannot be shown")
    version = report.get("report_version", 1)
    if report and (not isinstance(version, int) or version < 2):
        missing.append("report.json is from an older version (no panels, image sizes or what the calibration held): "
                       "rerun `dome-calib calibrate` for the full page")
    summary = {k: v for k, v in report.items() if k in SUMMARY_TYPES and isinstance(v, SUMMARY_TYPES[k])
               and not (isinstance(v, bool) and SUMMARY_TYPES[k] is not bool)}
    if "stage_seconds" in summary:
        summary["stage_seconds"] = {k: v for k, v in summary["stage_seconds"].items() if _num(v) is not None}
    wrong = sorted(k for k in SUMMARY_TYPES if k in report and report[k] is not None and k not in summary)
    if wrong:
        missing.append(f"report.json: {', '.join(wrong)} of an unexpected type: not shown")
    rows = _guarded(missing, "report.json per_camera", [], camera_table, report)
    arrows, coverage, hist = {}, {}, {}
    if residuals is not None:
        known = {r["name"]: r["res"] for r in rows}
        arrows, coverage = _per_camera_residuals(residuals, known)
        if residuals.uv_px is None:
            missing.append("residuals.npz holds no pixel positions (written before they were saved): the residuals "
                           "over the image cannot be drawn; rerun `dome-calib calibrate`")
        for t in sorted({r["type"] for r in rows if r["type"]}):
            hist[t] = histogram_of(residuals.norms_of({r["name"] for r in rows if r["type"] == t}))
    session = _dict(session) if session is not None else None
    return _plain({
        "summary": summary, "to_check": to_check_list(report), "cameras": rows, "previous": _previous(report),
        "hist": hist, "arrows": arrows, "coverage": coverage, "max_arrows": MAX_ARROWS,
        "sync": _guarded(missing, "sync.json", None, _sync_section, sync, session, dropped) if sync else None,
        "kinect": _guarded(missing, "session.json (Kinect)", None, _kinect_section, session) if session else None,
        "session": _guarded(missing, "session.json", None, _session_section, session) if session else None,
        "missing": missing})


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
