"""Report plots (matplotlib, no pyplot state): the dome seen from the top and the side with each camera coloured
by its RMS residual, residual histograms per camera type, and observation counts per camera.

World frame: Panoptic (y down), so the top view plots x against z and the side view plots x against height -y.

The plots read the typed report (:class:`dome_calib.report.schema.Report`). Text from a file (the bundle's seq,
camera names) is drawn as it is: matplotlib's math parser is off for it (``parse_math=False``), so a ``$`` in a name
neither renders as a formula nor fails the plot.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dome_calib.bundle import Bundle, CameraType
from dome_calib.report.page import histogram_of  # the page's bins: one definition of the tail
from dome_calib.report.schema import Report

_MARKER = {CameraType.VGA: ("o", 22), CameraType.HD: ("s", 60), CameraType.KINECT_COLOR: ("^", 70)}
_COLOR = {CameraType.VGA: "tab:blue", CameraType.HD: "tab:orange", CameraType.KINECT_COLOR: "tab:green"}
_DPI = 110
MAX_LABELS = 20
DOME_RADIUS_CM = 274.5  # the Panoptic dome's sphere (5.49 m across), drawn for orientation
DOME_CENTRE_HEIGHT_CM = 140.0


def plot_dome(bundle: Bundle, report: Report, path: Path) -> Path:
    """Top and side view of the cameras, coloured by RMS residual (px); cameras to check ringed in red."""
    per_cam = report.per_camera
    flagged = {row.name for row in report.to_check if row.name in per_cam}
    rms_all = [v.rms_px for v in per_cam.values() if v.rms_px is not None]
    vmin, vmax = (float(np.percentile(rms_all, 2)), float(np.percentile(rms_all, 98))) if rms_all else (0.0, 1.0)
    fig = Figure(figsize=(13, 6), layout="constrained")
    axes = fig.subplots(1, 2)
    views = [("top view (looking down)", 0, 2, "x (cm)", "z (cm)"), ("side view", 0, 1, "x (cm)", "height -y (cm)")]
    mappable = None
    for ax, (title, i, j, xlabel, ylabel) in zip(axes, views):
        for cam_type in CameraType:
            names = [n for n, c in bundle.cameras.items() if c.type == cam_type]
            if not names:
                continue
            centers = np.array([bundle.cameras[n].center_cm for n in names])
            xs, ys = centers[:, i], (-centers[:, 1] if j == 1 else centers[:, j])
            rms = np.array([np.nan if per_cam[n].rms_px is None else per_cam[n].rms_px for n in names])
            marker, size = _MARKER[cam_type]
            has = np.isfinite(rms)
            if np.any(~has):
                ax.scatter(xs[~has], ys[~has], s=size, marker=marker, facecolors="none", edgecolors="0.6",
                           linewidths=0.8, label=f"{cam_type} (no residuals)")
            if np.any(has):
                mappable = ax.scatter(xs[has], ys[has], c=rms[has], s=size, marker=marker, cmap="viridis",
                                      vmin=vmin, vmax=max(vmax, vmin + 1e-6), edgecolors="k", linewidths=0.3,
                                      label=str(cam_type))
            ringed = [k for k, n in enumerate(names) if n in flagged]
            if ringed:  # one collection for all of them (a scatter per camera cost ~1 s with 24 to check)
                ax.scatter(xs[ringed], ys[ringed], s=size * 4, marker="o", facecolors="none", edgecolors="red",
                           linewidths=1.4)
            if len(flagged) <= MAX_LABELS:  # beyond that, names would hide the dome: see report.json
                for k in ringed:
                    ax.annotate(names[k], (xs[k], ys[k]), xytext=(4, 4), textcoords="offset points", fontsize=7,
                                color="red", parse_math=False)
        ax.scatter([0], [0], marker="+", s=80, c="k")  # world origin: floor centre
        a = np.linspace(0, 2 * np.pi, 361)
        if j == 1:  # the dome sphere's outline above the floor, from the side
            a0 = np.arcsin(DOME_CENTRE_HEIGHT_CM / DOME_RADIUS_CM)
            a = np.linspace(-a0, np.pi + a0, 181)
            ax.plot(DOME_RADIUS_CM * np.cos(a), DOME_CENTRE_HEIGHT_CM + DOME_RADIUS_CM * np.sin(a), color="0.75",
                    lw=0.8, zorder=0)
            ax.axhline(0, color="0.5", lw=0.8, zorder=0)
        else:
            ax.plot(DOME_RADIUS_CM * np.cos(a), DOME_RADIUS_CM * np.sin(a), color="0.75", lw=0.8, zorder=0)
        ax.set(title=title, xlabel=xlabel, ylabel=ylabel, aspect="equal")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    if mappable is not None:
        fig.colorbar(mappable, ax=list(axes), label="RMS reprojection residual (px, per coordinate)", shrink=0.8)
    n_check = len(report.to_check)
    fig.suptitle(f"calibration {report.seq}: {report.cameras} cameras, "
                 f"RMS {report.rms_px:.3f} px, {n_check} to check (red)" if report.rms_px is not None else
                 f"calibration {report.seq}: {report.cameras} cameras (no residuals), {n_check} to check (red)",
                 parse_math=False)
    fig.savefig(path, dpi=_DPI)
    return path


def plot_residual_histograms(bundle: Bundle, residuals, path: Path) -> Path:
    """Histogram of residual norms (px) per camera type, log counts: regular bins up to the 99.5th percentile,
    then the tail as one red bar labelled with its range, count and maximum (nothing clipped away)."""
    types = [t for t in CameraType if bundle.of_type(t)]
    fig = Figure(figsize=(4.5 * max(len(types), 1), 3.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, max(len(types), 1)))
    for ax, cam_type in zip(axes, types):
        norms = residuals.norms_of(set(bundle.of_type(cam_type)))
        if len(norms):
            h = histogram_of(norms)
            edges = np.asarray(h["edges_px"])
            width = edges[1] - edges[0]
            ax.bar(edges[:-1], h["counts"], width=width, align="edge", color=_COLOR[cam_type], log=True)
            tail = h["tail"]
            if tail["count"]:
                ax.bar([edges[-1] + width], [tail["count"]], width=3 * width, align="edge", color="tab:red", log=True)
                ax.annotate(f"> {tail['from_px']:.2f} px: {tail['count']}\nmax {tail['max_px']:.2f} px",
                            (edges[-1] + 2.5 * width, tail["count"]), xytext=(0, 4), textcoords="offset points",
                            ha="center", fontsize=7, color="tab:red")
            ax.set_title(f"{cam_type}: {len(norms)} obs, RMS {np.sqrt(np.mean(norms ** 2) / 2):.3f} px per coord.")
        else:
            ax.set_title(f"{cam_type}: no observations")
        ax.set(xlabel="residual norm (px)", ylabel="observations")
    fig.savefig(path, dpi=_DPI)
    return path


def plot_observations(report: Report, path: Path) -> Path:
    """Observations per camera in name order, coloured by type, with the too-few line."""
    per_cam = report.per_camera
    names = sorted(per_cam)
    counts = np.array([per_cam[n].observations or 0 for n in names])
    colors = [_COLOR[per_cam[n].type] for n in names]
    fig = Figure(figsize=(max(8.0, 0.02 * len(names) + 6), 3.8), layout="constrained")
    ax = fig.subplots()
    ax.bar(np.arange(len(names)), counts, color=colors, width=1.0)
    ax.axhline(report.rules.min_observations, color="red", lw=1, ls="--", label="too few below this")
    step = max(1, len(names) // 40)
    ax.set_xticks(np.arange(0, len(names), step), [names[k] for k in range(0, len(names), step)], rotation=90,
                  fontsize=7, parse_math=False)
    ax.set(ylabel="observations", title="observations per camera" + ("" if report.has_residuals else
                                                                      " (no residuals in this bundle)"))
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=_DPI)
    return path
