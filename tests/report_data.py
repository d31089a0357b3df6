"""A calibration report with known content for the report tests and the page's screenshots: real cameras (the
Panoptic calibration in tests/data, see PROVENANCE.md) or a design preset, with synthetic residuals whose
patterns are known (a loose lens: radial; a rolling-shutter skew; a few outliers), one camera with too few
observations, uncertainties, a lens model, and a previous bundle in which three cameras were elsewhere.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dome_calib.bundle import Bundle, CameraType
from dome_calib.bundle_io import write_bundle
from dome_calib.compare import detect_changes
from dome_calib.reasons import ReasonCode, reason
from dome_calib.report import ReportOptions
from dome_calib.residuals import Residuals

OBS_RANGE = {CameraType.VGA: (500, 1400), CameraType.HD: (2000, 3500), CameraType.KINECT_COLOR: (1200, 2200)}
SIGMA_PX = {CameraType.VGA: 0.35, CameraType.HD: 0.25, CameraType.KINECT_COLOR: 0.3}

#: A report without its plots (1-2 s a report): for the tests that read no plot (test_report and test_session
#: check the plots' files; `dome-calib report` draws its own).
NO_PLOTS = ReportOptions(plots=False)


@dataclasses.dataclass(kw_only=True)
class Planted:
    """What the synthetic report holds, to check the page against."""

    loose_lens: str  # radial residual pattern, high RMS
    skewed: str  # rolling-shutter-like skew
    few: str  # too few observations
    moved: dict[str, float]  # camera -> mm it was moved in the previous bundle
    previous: Path


def synthetic_residuals(bundle: Bundle, *, loose_lens: str, skewed: str, few: str, seed: int = 0) -> Residuals:
    """Per camera: observations over a random part of the image, Gaussian residuals of the type's sigma, 0.3 %
    outliers of 3-12 px; ``loose_lens`` adds a radial pattern (up to ~4 px at the corners), ``skewed`` a shear
    proportional to the row, ``few`` has 40 observations."""
    rng = np.random.default_rng(seed)
    names = sorted(bundle.cameras)
    idx, res, uvs = [], [], []
    for k, n in enumerate(names):
        cam = bundle.cameras[n]
        w, h = cam.resolution
        m = 40 if n == few else int(rng.integers(*OBS_RANGE[cam.type]))
        lo = rng.uniform([0.0, 0.0], [0.25 * w, 0.3 * h])
        hi = rng.uniform([0.75 * w, 0.7 * h], [w, h])
        uv = rng.uniform(lo, hi, size=(m, 2))
        r = rng.normal(0.0, SIGMA_PX[cam.type], size=(m, 2))
        if n == loose_lens:
            d = (uv - [w / 2, h / 2]) / (w / 2)
            r += 6.0 * d * np.sum(d ** 2, axis=1, keepdims=True)
        if n == skewed:
            r[:, 0] += 4.0 * (uv[:, 1] / h - 0.5)
        bad = rng.random(m) < 0.003
        r[bad] += rng.uniform(3.0, 12.0, size=(int(bad.sum()), 1)) * rng.choice([-1.0, 1.0], size=(int(bad.sum()), 2))
        idx.append(np.full(m, k))
        res.append(r)
        uvs.append(uv)
    return Residuals(camera_names=names, camera_index=np.concatenate(idx), residual_px=np.concatenate(res),
                     uv_px=np.concatenate(uvs))


def moved_copy(bundle: Bundle, moves_cm: dict[str, float], seq: str = "previous") -> Bundle:
    """The bundle with the named cameras' centres shifted by the given cm along x and turned by 0.5 deg."""
    cams = dict(bundle.cameras)
    for n, d in moves_cm.items():
        c = cams[n]
        R = Rotation.from_rotvec([0.0, np.radians(0.5), 0.0]).as_matrix() @ c.R
        cams[n] = dataclasses.replace(c, R=R, t_cm=-R @ (c.center_cm + [d, 0.0, 0.0]))
    return Bundle(seq=seq, cameras=cams)


def write_synthetic_report(bundle: Bundle, folder: Path, *, seed: int = 0, missing: dict[str, str] | None = None,
                           session: bool = False) -> Planted:
    """Write ``bundle`` with a full report (residuals, uncertainties, lens model, previous) into ``folder``."""
    from dome_calib.report import previous_section, write_report

    bundle = Bundle(seq=bundle.seq, cameras={n: c for n, c in bundle.cameras.items() if n not in (missing or {})},
                    calib_data_source=bundle.calib_data_source)
    names = sorted(bundle.cameras)
    vga = [n for n in names if bundle.cameras[n].type == CameraType.VGA]
    planted = Planted(loose_lens=vga[len(vga) // 3], skewed=vga[2 * len(vga) // 3], few=vga[1],
                      moved={vga[5]: 40.0, vga[len(vga) // 2]: 15.0, [n for n in names if n.startswith("00_")][2]: 25.0},
                      previous=folder.parent / (folder.name + "_previous"))
    residuals = synthetic_residuals(bundle, loose_lens=planted.loose_lens, skewed=planted.skewed, few=planted.few,
                                    seed=seed)
    previous = moved_copy(bundle, {n: mm / 10.0 for n, mm in planted.moved.items()})
    write_bundle(previous, planted.previous)
    write_bundle(bundle, folder)
    rng = np.random.default_rng(seed + 1)
    changes = {n: c.reasons for n, c in detect_changes(bundle.cameras, previous.cameras).items()}
    sigma_cm = {n: round(float(rng.uniform(0.02, 0.08)), 4) for n in names}
    sigma_cm[planted.few] = 0.9
    changes.setdefault(planted.few, []).append(reason(ReasonCode.POSITION_UNCERTAIN, "position poorly determined "
                                                      "(+-0.9 cm, 1 sigma): few or one-sided views of the tent; add "
                                                      "a tent position it sees"))
    lens = {n: {"free": ["fx", "fy", "k1", "k2"], "held": ["cx", "cy", "p1", "p2", "k3"],
                "decisions": [{"group": "cx,cy", "terms": ["cx", "cy"], "free": False,
                               "reason": "one sigma moves an image point by 0.9 px (> 0.5 px)"},
                              {"group": "k1", "terms": ["k1"], "free": True, "reason": "determined (0.05 px)"}]}
            for n in names}
    extra = {"world_frame": {"reference": "prior", "reference_source": str(planted.previous), "shared_cameras": len(names),
                             "inliers": len(names) - 3, "outliers": sorted(planted.moved), "scale": 1.0,
                             "residual_rms_cm": 0.21, "not_aligned": [],
                             "description": f"world frame: similarity to the prior on {len(names) - 3} of "
                                            f"{len(names)} cameras, 2.1 mm RMS"},
             "stage_seconds": {"sfm": 2710.4, "ba": 431.2, "normalize": 1.3, "write": 9.8},
             "center_sigma_cm": sigma_cm,
             "rotation_sigma_deg": {n: round(float(rng.uniform(0.002, 0.01)), 5) for n in names},
             "lens_model": {"rule": "synthetic", "cameras": lens},
             "cluster": {"executor": "local", "processes": 2, "description": "local process pool, 2 processes",
                         "on_this_machine": ["mapping", "merge", "bundle adjustment", "normalize"]},
             "previous": previous_section(bundle, planted.previous)}
    write_report(folder, bundle, residuals, changes=changes, missing=missing, extra=extra)
    return planted


#: report.json of layout 2 (written by the code before the typed report), session.json and sync.json as
#: `dome-calib session` writes them (tests/data/PROVENANCE.md).
REPORT_FILES = Path(__file__).resolve().parent / "data" / "report_files"


def copy_kept_files(report_dir: Path) -> None:
    """Put the real session.json and sync.json (REPORT_FILES) into ``report_dir``."""
    report_dir.mkdir(parents=True, exist_ok=True)
    for name in ("session.json", "sync.json"):
        (report_dir / name).write_bytes((REPORT_FILES / name).read_bytes())


def old_report_json(bundle: Bundle, seq: str, to_check: list[dict]) -> dict:
    """A report.json as the first version of the report wrote it (its keys only: no lens model, no held cameras,
    no previous calibration), for the cameras of ``bundle``: 300 observations and 0.5 px each."""
    return {"seq": seq, "cameras": len(bundle.cameras), "has_residuals": True, "rms_px": 0.5, "to_check": to_check,
            "per_camera": {n: {"type": str(c.type), "center_cm": c.center_cm.tolist(), "observations": 300,
                               "rms_px": 0.5} for n, c in bundle.cameras.items()}}

