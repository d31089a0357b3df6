"""The `dome-calib` command: a thin shell over the stages. Each command parses, builds options, calls a stage.

The stages are imported inside the commands: `dome-calib --help` and every command start without loading
numpy, pycolmap, gtsam or matplotlib (about 1.5 s).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import typer

from dome_calib.errors import flags, interrupt_as_one_line, run_cli

app = typer.Typer(
    help="Calibrate and synchronise the capture dome, and inspect calibration bundles.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Calibrate and synchronise the capture dome, and inspect calibration bundles."""


@app.command()
def info(
    bundle: Path = typer.Argument(..., help="Bundle folder (holds calibration_<seq>.json).", show_default=False),
    json_out: bool = typer.Option(False, "--json", help="Print the summary as JSON instead of a table."),
) -> None:
    """Summarise a calibration bundle: cameras by type, intrinsics, camera positions, sync coverage."""
    from dome_calib.bundle_io import load_bundle
    from dome_calib.info import bundle_summary, format_summary

    summary = bundle_summary(load_bundle(bundle))
    typer.echo(json.dumps(summary, indent=2) if json_out else format_summary(summary))


@app.command()
def calibrate(
    capture: Path = typer.Argument(..., help="Capture folder (scenes/<scene>/<camera>.png).", show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="Bundle folder to write (created).", show_default=False),
    prior: Path = typer.Option(None, "--prior", help="Previous calibration bundle of this dome: sets the world "
                               "frame, seeds the matching, and shows which cameras moved."),
    previous: Path = typer.Option(None, "--previous", help="Bundle the report compares with (how far each camera "
                                  "moved and turned since; default: --prior, else the bundle OUT already holds)."),
    only_changed: bool = typer.Option(False, "--only-changed", help="Quick recalibration after a hardware "
                                      "change: uses the first scene only, finds the cameras that no longer agree "
                                      "with --prior and re-estimates just those; the rest stay exactly as in "
                                      "--prior (about 1.5 min for the full dome)."),
    seq: str = typer.Option(None, "--seq", help="Sequence name for calibration_<seq>.json (default: the capture "
                            "folder's name)."),
    work: Path = typer.Option(None, "--work", help="Work folder for intermediate results; a rerun resumes from "
                              "it (default: OUT.work beside the bundle)."),
    scheduler: str = typer.Option(None, "--scheduler", help="Dask scheduler (tcp://HOST:PORT): features, "
                                  "matching and the keypoint refinement run on its workers; images listed under "
                                  "capture.json's \"nodes\" are read on the worker of that --name (default: the local "
                                  "process pool)."),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log every bundle-adjustment iteration."),
) -> None:
    """Calibrate every camera of the dome from one capture session: features, matching, reconstruction, bundle
    adjustment, world frame, then the bundle and its report. Rerun the same command to resume after a stop."""
    with interrupt_as_one_line("dome-calib"):  # SIGINT / SIGTERM: one line naming the stage, exit 130
        from dome_calib.cli.progress import ProgressBars
        from dome_calib.pipeline.full import format_result, run_calibration
        from dome_calib.pipeline.types import CalibrateOptions

        logging.getLogger("dome_calib.ba").setLevel(logging.INFO if verbose else logging.WARNING)
        with ProgressBars() as bars:  # no bars in a log file
            options = CalibrateOptions(prior=prior, previous=previous, only_changed=only_changed, seq=seq,
                                       work_dir=work, scheduler=scheduler, progress=bars.tasks)
            result = run_calibration(capture, out, options)
        typer.echo(format_result(result))


@app.command()
def report(
    bundle: Path = typer.Argument(..., help="Bundle folder; the report is written to BUNDLE/report/.",
                                  show_default=False),
    previous: Path = typer.Option(None, "--previous", "--prior", help="Previous calibration bundle: per camera "
                                  "how far it moved and turned since, its focal change, cameras added or gone; the "
                                  "cameras that moved are listed to check (default: the comparison the calibration "
                                  "made, kept)."),
    min_observations: int = typer.Option(None, help="Flag estimated cameras with fewer observations than this "
                                         "(default: the calibration's rule, 100)."),
) -> None:
    """Rebuild BUNDLE/report/ and its page BUNDLE/report/index.html (open it in a browser: summary, cameras to
    check, camera table, dome, residuals over each image, distributions, Kinect and sync in a session bundle) from
    the bundle, the residuals its calibration saved and what the calibration found (kept)."""
    from dome_calib.report.command import report_bundle

    with flags({"ReportOptions.min_observations": "--min-observations"}):
        text = report_bundle(bundle, previous=previous, min_observations=min_observations)
    typer.echo(text)


@app.command()
def compare(
    bundle: Path = typer.Argument(..., help="Bundle folder to judge.", show_default=False),
    ground_truth: Path = typer.Argument(..., help="Reference bundle folder (ground truth or another calibration).",
                                        show_default=False),
    json_out: bool = typer.Option(False, "--json", help="Print per-camera errors as JSON."),
) -> None:
    """Per-camera centre, rotation, focal and distortion errors of BUNDLE against GROUND_TRUTH, after a
    similarity alignment on the camera centres."""
    from dome_calib.bundle_io import load_bundle
    from dome_calib.compare import compare_bundles, format_comparison

    cmp = compare_bundles(load_bundle(bundle), load_bundle(ground_truth), reference_source=str(ground_truth))
    typer.echo(json.dumps(cmp.as_dict(), indent=1) if json_out else format_comparison(cmp))


@app.command()
def demo(
    out: Path = typer.Option(Path("demo_out"), "-o", "--out", help="Folder for the capture, bundle and report."),
    preset: str = typer.Option("tiny", help="Synthetic dome size: tiny (16 cameras, the default: a few minutes), "
                               "panel (60 cameras, ~15 min on 2 cores) or full (521)."),
    scenes: int = typer.Option(None, help="Tent positions (default: the demo's choice for the preset)."),
    seed: int = typer.Option(0, help="Random seed of the synthetic capture."),
    people: int = typer.Option(7, "--people", help="People in the synthetic group (1-10; 7: two walking past each "
                               "other, a conversation, one crouching, one leaving, one coming in) whose OpenPose "
                               "detections are reconstructed with the calibrated bundle and judged against the "
                               "truth; 0: no group."),
) -> None:
    """Demonstration: synthesise a small dome capture, calibrate it, compare with the ground truth, reconstruct a
    group of people with the result, and print what a technician would look at."""
    logging.getLogger("dome_calib.ba").setLevel(logging.WARNING)
    with interrupt_as_one_line("dome-calib", "rerun the same command to resume"):  # SIGTERM: one line, exit 130
        from dome_calib.cli.progress import ProgressBars
        from dome_calib.pipeline.demo import DemoOptions, format_demo, run_demo

        with ProgressBars() as bars:
            with flags({"DemoOptions.preset": "--preset", "DemoOptions.scenes": "--scenes",
                        "DemoOptions.seed": "--seed", "DemoOptions.people": "--people"}):
                options = DemoOptions(preset=preset, scenes=scenes, seed=seed, people=people, progress=bars.tasks)
            result = run_demo(out, options)
        typer.echo(format_demo(result))


def main() -> None:
    run_cli(app, prog="dome-calib")


# ---- command registration: one module per room under dome_calib/cli/, each with a `register(app)` ----------
# (keep this block at the bottom: a new command adds its two lines here, `from dome_calib.cli.<room> import
# register as _register_<room>` then `_register_<room>(app)`; the modules import their stages inside the commands)
from dome_calib.cli.synth import register as _register_synth  # noqa: E402  (synth, patterns)

_register_synth(app)

from dome_calib.cli.recon import register as _register_recon  # noqa: E402  (triangulate, pointcloud)

_register_recon(app)

from dome_calib.cli.kinect import register as _register_kinect  # noqa: E402  (kinect, kinect-synth)

_register_kinect(app)

from dome_calib.cli.session import register as _register_session  # noqa: E402  (session)

_register_session(app)

from dome_calib.cli.people import register as _register_people  # noqa: E402  (reconstruct)

_register_people(app)

from dome_calib.cli.interop import register as _register_interop  # noqa: E402  (export, import)

_register_interop(app)

from dome_calib.cli.skeletons import register as _register_skeletons  # noqa: E402  (export-people, people-page)

_register_skeletons(app)
# ---- end of command registration ------------------------------------------------------------------------------
