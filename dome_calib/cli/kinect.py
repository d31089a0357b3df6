"""`dome-calib kinect` (and `kinect-synth`): thin shells over dome_calib.kinect and dome_calib.synth.kinect_boards.

The stages are imported inside the commands: `dome-calib --help` starts without loading them.
"""
from __future__ import annotations

from pathlib import Path

import typer

from dome_calib.errors import DomeCalibError
from dome_calib.ownership import claim_folder, claim_into, replace_folder


def _board(spec: str, square_mm: float):
    from dome_calib.kinect.board import Checkerboard

    try:
        cols, rows = (int(v) for v in spec.lower().split("x"))
    except ValueError:
        raise DomeCalibError(f"--board {spec}: expected inner corners as COLSxROWS, e.g. 9x6") from None
    if cols < 3 or rows < 3 or cols == rows or not 0 < square_mm < float("inf"):  # NaN too
        raise DomeCalibError(f"--board {spec} --square-mm {square_mm:g}: need at least 3x3 inner corners, "
                             "different counts along the two sides, and a positive square size")
    return Checkerboard(cols=cols, rows=rows, square_mm=square_mm)


def format_sensor_line(summary: dict) -> list[str]:
    """Per-sensor summary lines of `dome-calib kinect`."""
    s = summary
    bias = ("depth bias not estimated (no depth maps)" if s["depth_bias_mm"] is None else
            f"depth bias {s['depth_bias_mm']:+.1f} mm, scale {100 * s['depth_scale']:+.3f} %")
    lines = [f"{s['sensor']:<13}({s['color_camera']})  frames used {s['frames_used']:>3}, rejected "
             f"{s['frames_rejected']:>2}  RMS IR {s['rms_ir_px']:.3f} px, colour {s['rms_color_px']:.3f} px  "
             f"baseline {s['baseline_mm']:.1f} mm  {bias}"]
    lines += [f"    rejected frame {k}: {reason}" for k, reason in s["rejected"].items()]
    return lines


def written_kinds(out: Path | None, bundle: Path, estimate_color_intrinsics: bool) -> tuple[str, ...]:
    """The bundle files `dome-calib kinect` writes: into --bundle itself the Kinect calibration (and the cameras'
    calibration when it re-estimates the colour intrinsics); into another folder the whole bundle."""
    from dome_calib.bundle_io import FILE_KINDS

    if out is None or (out.exists() and out.resolve() == bundle.resolve()):
        return ("kcalibration",) + (("calibration",) if estimate_color_intrinsics else ())
    return FILE_KINDS


def kinect(
    kinect_folder: Path = typer.Argument(..., help="Kinect checkerboard capture: KINECTNODE<n>/ir_<k>.png, "
                                         "color_<k>.png (and depth_<k>.png) per sensor.", show_default=False),
    bundle: Path = typer.Option(..., "--bundle", help="Dome calibration bundle: gives each Kinect's colour camera "
                                "(50_<nn>) intrinsics and world pose.", show_default=False),
    out: Path = typer.Option(None, "-o", "--out", help="Bundle folder to write (default: update --bundle in place)."),
    board: str = typer.Option("9x6", help="Checkerboard inner corners, COLSxROWS."),
    square_mm: float = typer.Option(60.0, "--square-mm", help="Checkerboard square size in millimetres."),
    estimate_color_intrinsics: bool = typer.Option(False, "--estimate-color-intrinsics", help="Refine the colour "
                                                   "cameras' intrinsics too (default: keep the dome bundle's)."),
) -> None:
    """Calibrate each Kinect's depth camera against its colour camera from checkerboard pairs: IR intrinsics,
    depth-to-colour transform, depth bias. Writes kcalibration_<seq>.json with the depth cameras placed in the
    dome's world. Frames with a blurred, cut-off or missing board are skipped and listed with the reason."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.bundle_io import check_bundle_update, load_bundle, update_bundle
    from dome_calib.kinect.calibrate import ColorIntrinsics, KinectCalibOptions, calibrate_kinect_folder
    from dome_calib.kinect.detect import find_sensor_frames

    options = KinectCalibOptions(board=_board(board, square_mm), color_intrinsics=ColorIntrinsics.ESTIMATE
                                 if estimate_color_intrinsics else ColorIntrinsics.BUNDLE)
    claim_into(out or bundle, inputs=[kinect_folder])  # not the Kinect capture's folder, nor holding it
    dome = load_bundle(bundle)
    kinds = written_kinds(out, bundle, estimate_color_intrinsics)
    check_bundle_update(out or bundle, dome.seq, kinds)  # each file written: new, or ours and unchanged
    total = sum(len(f.indices) for f in find_sensor_frames(kinect_folder).values())
    with ProgressBars(transient=True) as bars:
        results, updated = calibrate_kinect_folder(kinect_folder, dome, options,
                                                   on_frame=bars.counter("detecting boards: frame pairs", total))
    update_bundle(updated, out or bundle, kinds)
    for r in results:
        typer.echo("\n".join(format_sensor_line(r.summary())))
    typer.echo(f"wrote {(out or bundle) / f'kcalibration_{updated.seq}.json'} ({len(updated.kinect.sensors)} sensors)")


def kinect_synth(
    out: Path = typer.Argument(..., help="Kinect capture folder to create (KINECTNODE<n>/..., ground_truth.json).",
                               show_default=False),
    bundle: Path = typer.Option(..., "--bundle", help="Dome bundle whose Kinect colour cameras (50_<nn>) the "
                                "synthetic Kinects use.", show_default=False),
    sensors: str = typer.Option(None, help="Sensors to make, e.g. 1,2 (default: every Kinect colour camera)."),
    frames: int = typer.Option(32, help="Good board poses per sensor (2 blurred and 2 cut-off frames are added)."),
    seed: int = typer.Option(0, help="Random seed: same seed, same capture."),
) -> None:
    """Make a synthetic Kinect checkerboard capture with ground truth (to try or test `dome-calib kinect`)."""
    from dome_calib.bundle_io import load_bundle
    from dome_calib.synth.kinect_boards import KinectBoardsOptions, generate_kinect_boards

    try:
        names = [f"KINECTNODE{int(s)}" for s in sensors.split(",")] if sensors else None
    except ValueError:
        raise DomeCalibError(f"--sensors {sensors}: expected sensor numbers like 1,2") from None
    if frames < 1:
        raise DomeCalibError(f"--frames {frames}: need at least one frame")
    claim_folder(out, inputs=[bundle])  # created, or replaced whole when dome-calib wrote it; not the bundle
    dome = load_bundle(bundle)
    try:
        with replace_folder(out) as staging:
            truth = generate_kinect_boards(dome, staging, KinectBoardsOptions(sensors=names, good_frames=frames,
                                                                              seed=seed))
    except ValueError as exc:
        raise DomeCalibError(f"{bundle}: {exc}") from None
    typer.echo(f"{out}: {len(truth['sensors'])} sensors x {frames + 4} frame pairs (ground truth in "
               f"{out / 'ground_truth.json'})")


def register(app: typer.Typer) -> None:
    app.command()(kinect)
    app.command("kinect-synth")(kinect_synth)
