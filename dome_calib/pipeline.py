"""`dome-calib calibrate`: the technician's one command, as a straight run of stages.

    sfm (features, pairs, matching, per-scene mapping, merge)  -> BAProblem   [projector.run_sfm]
    ba (5-parameter bundle adjustment, outlier schedule)        -> refined    [dome_calib.ba]
    normalize (similarity to the prior, or the nominal dome)   -> Panoptic world frame
    write (bundle, then report/)                                -> OUT/

Resumable: every finished stage leaves its result in the work folder (``OUT.work`` by default) and a rerun
with the same capture and options starts after the last finished stage; SfM also reuses its own databases.
Nothing is written to OUT until the end (bundle files atomically, then the report folder by rename).

With ``--prior`` the cameras are compared with the prior bundle (cm, deg, intrinsics) and the report lists
those that moved; ``--only-changed`` then re-estimates just those, all other cameras held at the prior
(:mod:`dome_calib.pipeline_quick`).
"""
from __future__ import annotations

import contextlib
import json
import logging
import pickle
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle, CameraType, load_bundle, write_bundle
from dome_calib.compare import CameraChange, ChangeOptions, detect_changes
from dome_calib.errors import CaptureError, DomeCalibError
from dome_calib.io_utils import atomic_path, atomic_write_text
from dome_calib.normalize import Normalized, NormalizeOptions, normalize
from dome_calib.report import ReportOptions, Residuals, load_residuals, write_report
from dome_calib.pipeline_stages import BAOutcome, SfmOutcome, run_ba_stage, run_sfm_stage

logger = logging.getLogger(__name__)

STATE_FILE = "state.json"
STAGE_LABELS = {"sfm": "features, pairs, matching, per-scene mapping, merging scenes",
                "ba": "bundle adjustment (lens terms chosen per camera, outlier rejection)",
                "match": "features, pairs and matching of one scene",
                "detect": "which cameras disagree with the prior", "quick_ba": "re-estimating the changed cameras"}
STATE_VERSION = 1


@dataclass(kw_only=True)
class CalibrateOptions:
    """What `dome-calib calibrate` does. ``seq`` defaults to the capture folder's name."""

    prior: Path | None = None
    only_changed: bool = False
    seq: str | None = None
    work_dir: Path | None = None
    progress: bool = True
    normalize: NormalizeOptions = field(default_factory=NormalizeOptions)
    changes: ChangeOptions = field(default_factory=ChangeOptions)
    report: ReportOptions = field(default_factory=ReportOptions)
    max_center_sigma_cm: float = 0.5  # flag cameras whose centre is less certain than this (1 sigma)


@dataclass(kw_only=True)
class CalibrationResult:
    """What a calibration produced, for the summary and the demo."""

    bundle_dir: Path
    report_dir: Path
    bundle: Bundle
    expected: list[str]  # cameras of the capture
    failures: dict[str, str]  # camera -> why it was not calibrated
    normalized: Normalized
    residuals: Residuals
    stage_seconds: dict[str, float]
    resumed: list[str]  # stages taken from the work folder
    changes: dict[str, CameraChange] | None = None
    to_check: list[dict] = field(default_factory=list)
    sfm: SfmOutcome | None = None
    ba: BAOutcome | None = None

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(self.residuals.residual_px ** 2)))  # per coordinate


def capture_contents(capture: Path) -> tuple[list[str], list[str]]:
    """Scenes and cameras named by ``capture.json`` (or found under scenes/)."""
    if not capture.is_dir():
        raise CaptureError(f"{capture}: not a folder")
    meta_path = capture / "capture.json"
    if meta_path.exists():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            return list(meta["scenes"]), list(meta["cameras"])
        except (ValueError, KeyError, TypeError) as exc:
            raise CaptureError(f"{meta_path}: malformed ({exc})") from exc
    scenes = sorted(p.name for p in (capture / "scenes").glob("*") if p.is_dir())
    if not scenes:
        raise CaptureError(f"{capture}: no capture.json and no scenes/<scene>/ folders")
    cams = sorted({p.stem for s in scenes for p in (capture / "scenes" / s).glob("*.png")})
    return scenes, cams


@contextlib.contextmanager
def _stage_status(text: str, enabled: bool):
    """A live spinner with the elapsed time on stderr while a stage runs (nothing when disabled)."""
    if not enabled:
        yield
        return
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task(text, total=1)
        yield
        bar.update(task, completed=1)


class _WorkState:
    """Which stages finished, for which inputs, kept as JSON in the work folder."""

    def __init__(self, folder: Path, fingerprint: dict) -> None:
        self.folder, self.fingerprint = folder, fingerprint
        self.path = folder / STATE_FILE
        folder.mkdir(parents=True, exist_ok=True)
        state = json.loads(self.path.read_text(encoding="utf-8")) if self.path.exists() else {}
        if state.get("version") != STATE_VERSION or state.get("fingerprint") != fingerprint:
            if state:
                logger.info("work folder %s was made for other inputs: starting over", folder)
            state = {"version": STATE_VERSION, "fingerprint": fingerprint, "stages": {}}
        self.state = state

    def done(self, stage: str) -> bool:
        return stage in self.state["stages"] and (self.folder / f"{stage}.pkl").exists()

    def load(self, stage: str):
        with open(self.folder / f"{stage}.pkl", "rb") as f:
            return pickle.load(f)

    def save(self, stage: str, value: object, seconds: float) -> None:
        with atomic_path(self.folder / f"{stage}.pkl") as tmp:
            tmp.write_bytes(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        self.state["stages"][stage] = {"seconds": seconds}
        atomic_write_text(self.path, json.dumps(self.state, indent=1))


def run_calibration(capture: Path, out: Path, options: CalibrateOptions | None = None) -> CalibrationResult:
    """Calibrate the dome from a capture folder and write the bundle and its report to ``out``.

    Raises :class:`CaptureError` for an unusable capture, BundleFormatError for a bad prior, and
    AlignmentError when the world frame cannot be fixed; nothing is written to ``out`` then.
    """
    options = options or CalibrateOptions()
    capture, out = Path(capture), Path(out)
    scenes, expected = capture_contents(capture)
    if options.only_changed and options.prior is None:
        raise DomeCalibError("--only-changed needs --prior (the bundle the unchanged cameras are taken from)")
    prior = load_bundle(options.prior) if options.prior is not None else None
    seq = options.seq or capture.resolve().name
    work = Path(options.work_dir) if options.work_dir else out.with_name(out.name + ".work")
    fingerprint = {"capture": str(capture.resolve()), "scenes": scenes, "cameras": expected,
                   "prior": str(Path(options.prior).resolve()) if options.prior else None,
                   "only_changed": options.only_changed}
    state = _WorkState(work, fingerprint)
    seconds: dict[str, float] = {}
    resumed: list[str] = []

    def stage(name: str, fn):
        if state.done(name):
            resumed.append(name)
            seconds[name] = state.state["stages"][name]["seconds"]
            logger.info("stage %s: taken from %s", name, work)
            return state.load(name)
        t0 = time.perf_counter()
        with _stage_status(f"{name}: {STAGE_LABELS.get(name, name)}", options.progress):
            value = fn()
        seconds[name] = time.perf_counter() - t0
        state.save(name, value, seconds[name])
        logger.info("stage %s: done in %.1f s", name, seconds[name])
        return value

    if options.only_changed:
        from dome_calib.pipeline_quick import run_quick

        return run_quick(capture=capture, out=out, seq=seq, scenes=scenes, expected=expected, prior=prior,
                         options=options, stage=stage, seconds=seconds, resumed=resumed)

    sfm: SfmOutcome = stage("sfm", lambda: run_sfm_stage(capture, work / "sfm", prior=prior,
                                                         progress=options.progress))
    ba: BAOutcome = stage("ba", lambda: run_ba_stage(sfm.problem, progress=options.progress))
    t0 = time.perf_counter()
    normalized = normalize(ba.cameras, options.normalize, prior=prior.cameras if prior else None,
                           prior_source=str(options.prior) if options.prior else "")
    seconds["normalize"] = time.perf_counter() - t0
    return finish(out=out, seq=seq, expected=expected, failures=sfm.failures, normalized=normalized,
                  residuals=ba.residuals, prior=prior, options=options, seconds=seconds, resumed=resumed,
                  sfm=sfm, ba=ba, source=f"dome-calib calibrate {capture.name} ({len(scenes)} scenes)")


def finish(*, out: Path, seq: str, expected: list[str], failures: dict[str, str], normalized: Normalized,
           residuals: Residuals, prior: Bundle | None, options: CalibrateOptions, seconds: dict[str, float],
           resumed: list[str], source: str, sfm: SfmOutcome | None = None, ba: BAOutcome | None = None,
           changes: dict[str, CameraChange] | None = None, ba_scale: float | None = None,
           notes: dict[str, str] | None = None) -> CalibrationResult:
    """Change detection against the prior, then the bundle and its report in ``out``. ``notes``: camera -> a
    further reason to check it (e.g. a quick run could not check it)."""
    t0 = time.perf_counter()
    bundle = Bundle(seq=seq, cameras=dict(sorted(normalized.cameras.items())), calib_data_source=source)
    if prior is not None and changes is None:
        changes = detect_changes(bundle.cameras, prior.cameras, options.changes)
    missing = {n: failures.get(n, "not reconstructed") for n in expected if n not in bundle.cameras}
    reasons = {n: list(c.reasons) for n, c in (changes or {}).items()}
    for n, note in (notes or {}).items():
        reasons.setdefault(n, []).append(note)
    scale = float(normalized.alignment.tgt_from_src.scale) if ba_scale is None else ba_scale  # BA units -> cm
    sigma_cm = {n: s * scale for n, s in (ba.center_sigma if ba else {}).items() if n in bundle.cameras}
    for n, s in sigma_cm.items():
        if s > options.max_center_sigma_cm:
            reasons.setdefault(n, []).append(f"position poorly determined (+-{s:.1f} cm, 1 sigma): few or one-sided "
                                             "views of the tent; add a tent position it sees")
    write_bundle(bundle, out)
    extra = {"world_frame": normalized.as_dict(), "stage_seconds": seconds,
             "center_sigma_cm": {n: round(s, 4) for n, s in sorted(sigma_cm.items())},
             "lens_model": ba.lens_model if ba else None,
             "changes_vs_prior": {n: c.as_dict() for n, c in (changes or {}).items()} if prior else None}
    report_dir = write_report(out, bundle, residuals, options.report, changes=reasons, missing=missing, extra=extra)
    seconds["write"] = time.perf_counter() - t0
    content = json.loads((report_dir / "report.json").read_text(encoding="utf-8"))
    return CalibrationResult(bundle_dir=out, report_dir=report_dir, bundle=bundle, expected=expected,
                             failures=missing, normalized=normalized, residuals=residuals, stage_seconds=seconds,
                             resumed=resumed, changes=changes, to_check=content["to_check"], sfm=sfm, ba=ba)


def format_result(result: CalibrationResult, max_rows: int = 12) -> str:
    """The summary printed at the end of `dome-calib calibrate`."""
    lines = []
    per_type = []
    for cam_type in CameraType:
        exp = [n for n in result.expected if _type_of_name(n) == cam_type]
        got = [n for n in exp if n in result.bundle.cameras]
        if exp:
            per_type.append(f"{cam_type} {len(got)}/{len(exp)}")
    lines.append(f"calibrated {len(result.bundle.cameras)} of {len(result.expected)} cameras ({', '.join(per_type)})")
    rms = result.residuals.per_camera()
    type_rms = []
    for cam_type in CameraType:
        names = set(result.bundle.of_type(cam_type))
        norms = result.residuals.norms_of(names)
        if len(norms):
            type_rms.append(f"{cam_type} {np.sqrt(np.mean(norms ** 2) / 2):.3f}")
    lines.append(f"reprojection RMS {result.rms_px:.3f} px per coordinate ({', '.join(type_rms)}) over "
                 f"{len(result.residuals.residual_px):,} observations")
    lines.append(result.normalized.describe())
    if result.changes is not None:
        lines.append(f"changed since the prior: {len(result.changes)} camera(s)")
        lines += [f"  {c.name}: {'; '.join(c.reasons)}" for c in list(result.changes.values())[:max_rows]]
    lines.append(f"cameras to check: {len(result.to_check)}")
    for row in result.to_check[:max_rows]:
        lines.append(f"  {row['name']}: {'; '.join(row['reasons'])}")
    if len(result.to_check) > max_rows:
        lines.append(f"  ... {len(result.to_check) - max_rows} more in the report")
    worst = sorted(((v[1], n) for n, v in rms.items() if v[1] is not None), reverse=True)[:3]
    if worst:
        lines.append("highest RMS: " + ", ".join(f"{n} {r:.3f} px" for r, n in worst))
    times = ", ".join(f"{k} {v:.1f} s" + (" (resumed)" if k in result.resumed else "")
                      for k, v in result.stage_seconds.items())
    lines.append(f"stage times: {times}")
    lines.append(f"bundle: {result.bundle_dir}/calibration_{result.bundle.seq}.json")
    lines.append(f"report: {result.report_dir}/ (report.json, dome.png, residuals.png, observations.png)")
    return "\n".join(lines)


def _type_of_name(name: str) -> CameraType:
    """Camera type from a Panoptic name: 00_* HD, 50_* Kinect colour, else VGA."""
    prefix = name.split("_", 1)[0]
    return CameraType.HD if prefix == "00" else CameraType.KINECT_COLOR if prefix == "50" else CameraType.VGA


def report_bundle(bundle_folder: Path, *, prior: Path | None = None, min_observations: int = 100) -> str:
    """`dome-calib report`: (re)write ``<bundle>/report/`` from the bundle, the residuals saved by calibrate,
    and optionally a prior bundle (cameras moved since). Returns a short text for the terminal."""
    bundle = load_bundle(bundle_folder)
    residuals = load_residuals(bundle_folder)
    changes = None
    if prior is not None:
        changes = {n: c.reasons for n, c in detect_changes(bundle.cameras, load_bundle(prior).cameras).items()}
    old_path = Path(bundle_folder) / "report" / "report.json"
    kept = {}
    if old_path.exists():  # what only calibrate knew (world frame, stage times) survives a re-report
        try:
            old = json.loads(old_path.read_text(encoding="utf-8"))
            kept = {k: old[k] for k in ("world_frame", "stage_seconds", "lens_model") if k in old}
        except ValueError:
            logger.warning("%s: unreadable, replaced", old_path)
    target = write_report(bundle_folder, bundle, residuals, ReportOptions(min_observations=min_observations),
                          changes=changes, extra=kept)
    content = json.loads((target / "report.json").read_text(encoding="utf-8"))
    lines = [f"report: {target}  ({', '.join(content.get('plots', []))})"]
    if not content["has_residuals"]:
        lines.append("  no residuals saved with this bundle: geometry only (run `dome-calib calibrate` to get them)")
    else:
        lines.append(f"  RMS {content['rms_px']:.3f} px over {len(content['per_camera'])} cameras")
    lines.append(f"  cameras to check: {len(content['to_check'])}")
    lines += [f"    {row['name']}: {'; '.join(row['reasons'])}" for row in content["to_check"][:20]]
    return "\n".join(lines)
