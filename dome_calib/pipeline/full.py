"""`dome-calib calibrate`: the technician's one command, as a straight run of stages.

    sfm (features, pairs, matching, per-scene mapping, merge)  -> observations -> BAProblem   [projector.run_sfm]
    ba (5-parameter bundle adjustment, outlier schedule)        -> refined    [dome_calib.ba]
    normalize (similarity to the prior, or the design layout)  -> Panoptic world frame
    write (bundle and report staged beside OUT, then swapped in) -> OUT/

Resumable: every finished stage leaves its result in the work folder (``OUT.work`` by default,
:class:`dome_calib.pipeline.workstate.WorkState`, locked while a run uses it) and a rerun with the same inputs
(images and prior by size and mtime, options) starts after the last finished stage; SfM also reuses its own
databases.
OUT is checked before any work and replaced whole at the end (:mod:`dome_calib.pipeline.finish`).

With ``--prior`` the cameras are compared with the prior bundle (cm, deg, intrinsics) and the report lists
those that moved; ``--only-changed`` then re-estimates just those, all other cameras held at the prior
(:mod:`dome_calib.pipeline.quick`).
"""
from __future__ import annotations

import dataclasses
import logging
import os
from functools import partial
from pathlib import Path

import numpy as np

from dome_calib.align import require_shared
from dome_calib.bundle import CameraType, camera_type_from_name
from dome_calib.pipeline.capture import capture_contents, capture_nodes
from dome_calib.pipeline.cluster import (check_scheduler, cluster_section, format_cluster, open_executor,
                                         settle_cluster_stats)
from dome_calib.bundle_io import check_output_folder, load_bundle, recover_folder
from dome_calib.errors import DomeCalibError
from dome_calib.io_utils import refuse_output_among_inputs
from dome_calib.layout import check_dome_scale
from dome_calib.normalize import normalize
from dome_calib.pipeline.finish import carried_names, check_carried_report_files, finish
from dome_calib.pipeline.quick import run_quick
from dome_calib.pipeline.stages import refine_notes, run_ba_stage, run_sfm_stage
from dome_calib.pipeline.types import CalibrateOptions, Calibrated, CalibrationInputs, CalibrationResult
from dome_calib.pipeline.workstate import WorkState, input_fingerprint

logger = logging.getLogger(__name__)

__all__ = ["format_result", "run_calibration", "run_full"]

STAGE_LABELS = {"sfm": "features, pairs, matching, per-scene mapping, merging scenes",
                "ba": "bundle adjustment (lens terms chosen per camera, outlier rejection)",
                "normalize": "world frame", "write": "bundle and report",
                "match": "features, pairs and matching of one scene",
                "detect": "which cameras disagree with the prior",
                "suspect_match": "halved suspects again at full resolution; suspects matched with more partners",
                "quick_ba": "re-estimating the changed cameras"}


def run_calibration(capture: Path, out: Path, options: CalibrateOptions | None = None) -> CalibrationResult:
    """Calibrate the dome from a capture folder and write the bundle and its report to ``out``.

    Raises :class:`CaptureError` for an unusable capture, BundleFormatError for a bad prior, DomeCalibError for
    an output that is not a (bundle) folder or a work folder in use, and AlignmentError when the world frame
    cannot be fixed; ``out`` is untouched then. An interrupt raises :class:`dome_calib.errors.Interrupted`.
    """
    options = options or CalibrateOptions()
    # absolute: the paths in the tasks are read by pool or cluster workers whose working folder is not ours
    capture, out = Path(os.path.abspath(capture)), Path(os.path.abspath(out))
    scenes, expected = capture_contents(capture)
    if options.only_changed and options.prior is None:
        raise DomeCalibError("--only-changed needs --prior (the bundle the unchanged cameras are taken from)")
    seq = options.seq or capture.resolve().name
    check_carried_report_files(out)  # read through their schemas first (inputs, when carried)
    check_output_folder(out, [capture], keep=carried_names(out, seq))  # replaced whole: ours only (but what it
    # carries), and it must not hold the capture
    work = Path(os.path.abspath(options.work_dir)) if options.work_dir else out.with_name(out.name + ".work")
    refuse_output_among_inputs(work, [capture, out, *([options.prior] if options.prior else [])], option="--work",
                               whole_folder=True)  # a work folder of other inputs is emptied
    prior = load_bundle(options.prior) if options.prior is not None else None
    if options.previous is not None:  # the report compares with it at the end: refuse a bad one before the work
        load_bundle(options.previous)
    if prior is not None:
        check_dome_scale(prior.cameras, f"--prior {options.prior}")
        require_shared(expected, prior.cameras, given=f"--prior {options.prior}", against=f"the capture {capture}")
    check_scheduler(options.scheduler)  # a bounded handshake, before the work folder is opened (or emptied)
    inputs = CalibrationInputs(capture=capture, out=out, seq=seq, scenes=scenes,
                               expected=expected, prior=prior, options=options)
    fingerprint = input_fingerprint(capture, scenes, expected, options.prior, {"only_changed": options.only_changed})
    with WorkState.open(work, fingerprint, progress=options.progress, labels=STAGE_LABELS) as state:
        recover_folder(out)
        return run_quick(inputs, state) if options.only_changed else run_full(inputs, state)


def node_cameras(inputs: CalibrationInputs, options: CalibrateOptions) -> list[str] | None:
    """The capture's cameras when a cluster reads their images on the capture nodes (not here), else None."""
    return list(inputs.expected) if options.scheduler and capture_nodes(inputs.capture) else None


def run_full(inputs: CalibrationInputs, state: WorkState) -> CalibrationResult:
    """Every camera from the images: SfM, bundle adjustment, world frame, then :func:`finish`."""
    options, prior = inputs.options, inputs.prior
    cluster: dict = {}
    with open_executor(inputs.capture, options.scheduler, cluster) as executor:
        sfm = state.run("sfm", partial(run_sfm_stage, inputs.capture, state.folder / "sfm", prior=prior,
                                       progress=options.progress, executor=executor,
                                       scenes=inputs.scenes if node_cameras(inputs, options) else None,
                                       cameras=node_cameras(inputs, options)))
    cluster = settle_cluster_stats(state.folder / "cluster.json", cluster, resumed="sfm" in state.resumed)
    ba = state.run("ba", partial(run_ba_stage, sfm.problem))
    normalized = state.time("normalize", partial(normalize, ba.cameras, options.normalize,
                                                 prior=prior.cameras if prior else None,
                                                 prior_source=str(options.prior) if options.prior else ""))
    to_cm = normalized.alignment.scale  # BA units -> cm
    calibrated = Calibrated(normalized=normalized, failures=sfm.failures, residuals=ba.residuals,
                            center_sigma_cm={n: s * to_cm for n, s in ba.center_sigma.items()},
                            rotation_sigma_deg=getattr(ba, "rotation_sigma_deg", {}),  # {}: a work folder from before
                            lens_model=ba.lens_model,
                            notes={n: r for n, r in refine_notes((sfm.stats.get("refine") or {}).get("unreadable_images") or {})
                                   .items() if n in normalized.cameras},
                            cluster=cluster_section(cluster, ["mapping", "merge", "bundle adjustment", "normalize"]),
                            source=f"dome-calib calibrate {inputs.capture.name} ({len(inputs.scenes)} scenes)")
    result = finish(inputs, state, calibrated)
    return dataclasses.replace(result, sfm=sfm, ba=ba, stats={"sfm": sfm.stats, "ba": ba.stats, "cluster": cluster})


def format_result(result: CalibrationResult, max_rows: int = 12) -> str:
    """The summary printed at the end of `dome-calib calibrate`."""
    lines = []
    per_type = []
    for cam_type in CameraType:
        exp = [n for n in result.expected if camera_type_from_name(n) == cam_type]
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
    if len(result.residuals.residual_px):
        lines.append(f"reprojection RMS {result.rms_px:.3f} px per coordinate ({', '.join(type_rms)}) over "
                     f"{len(result.residuals.residual_px):,} observations")
    else:
        lines.append("reprojection RMS: none (no camera was re-estimated; every camera held from the prior)")
    lines.append(result.normalized.describe())
    if result.changes is not None:
        lines.append(f"changed since the prior: {len(result.changes)} camera(s)")
        lines += [f"  {c.name}: {'; '.join(r.text for r in c.reasons)}" for c in list(result.changes.values())[:max_rows]]
    lines.append(f"cameras to check: {len(result.to_check)}")
    for row in result.to_check[:max_rows]:
        lines.append(f"  {row.name}: {'; '.join(r.text for r in row.reasons)}")
    if len(result.to_check) > max_rows:
        lines.append(f"  ... {len(result.to_check) - max_rows} more in the report")
    worst = sorted(((v[1], n) for n, v in rms.items() if v[1] is not None), reverse=True)[:3]
    if worst:
        lines.append("highest RMS: " + ", ".join(f"{n} {r:.3f} px" for r, n in worst))
    times = ", ".join(f"{k} {v:.1f} s" + (" (resumed)" if k in result.resumed else "")
                      for k, v in result.stage_seconds.items())
    lines.append(f"stage times: {times}")
    lines.append(f"bundle: {result.bundle_dir}/calibration_{result.bundle.seq}.json")
    lines.append(f"report: {result.report_dir}/index.html (open it in a browser; also report.json and plots)")
    lines += format_cluster(result.stats.get("cluster") or {})
    return "\n".join(lines)
