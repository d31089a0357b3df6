"""`dome-calib synth` and `dome-calib patterns`: thin shells over dome_calib.synth and projector.patterns.

The stages are imported inside the commands: `dome-calib --help` starts without loading them.
"""
from __future__ import annotations

import os
from pathlib import Path

import typer

from dome_calib.errors import DomeCalibError, flags
from dome_calib.ownership import claim_folder


def synth(
    out: Path = typer.Argument(..., help="Capture folder to create (scenes/, ground_truth/, capture.json).",
                               show_default=False),
    preset: str = typer.Option("tiny", help="Which cameras: tiny (16, seconds), panel (60, one or two panels plus "
                               "HD and Kinect colour), full (all 521)."),
    scenes: int = typer.Option(3, help="Number of tent positions (scene_01, scene_02, ...)."),
    seed: int = typer.Option(0, help="Random seed: same seed, same capture."),
    layout: Path = typer.Option(None, "--layout", help="Take the cameras from a real Panoptic calibration file "
                                "(calibration_<seq>.json) instead of the nominal dome."),
    cameras: str = typer.Option(None, "--cameras", help="Render only these cameras of the preset, comma-separated "
                                "(e.g. 01_01,00_00)."),
    workers: int = typer.Option(2, help="Processes rendering in parallel (on this machine, without --scheduler)."),
    scheduler: str = typer.Option(None, "--scheduler", help="Render on a Dask cluster: the address of its "
                                  "`dask scheduler` (tcp://HOST:PORT). The images come back to this machine; the "
                                  "same bytes as rendered locally."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace OUT if it exists and dome-calib wrote it."),
) -> None:
    """Make a synthetic capture with ground truth: the projectors' random patterns on a white tent at several
    positions, seen by every camera of the preset, plus the true calibration in OUT/ground_truth/."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.pipeline.cluster import format_cluster, open_executor
    from dome_calib.layout import Preset
    from dome_calib.synth.capture import SynthOptions, synthesize

    try:
        preset_value = Preset(preset)
    except ValueError:
        raise DomeCalibError(f"--preset {preset}: expected one of {', '.join(p.value for p in Preset)}") from None
    with flags({"SynthOptions.n_scenes": "--scenes", "SynthOptions.seed": "--seed", "SynthOptions.workers": "--workers"}):
        options = SynthOptions(preset=preset_value, n_scenes=scenes, seed=seed, layout=layout, workers=workers,
                               cameras=[c.strip() for c in cameras.split(",") if c.strip()] if cameras else None,
                               overwrite=overwrite)
    if os.path.lexists(out) and not overwrite:  # before connecting to a cluster
        raise DomeCalibError(f"{out}: already exists (choose another folder or pass --overwrite)")
    claim_folder(out)  # --overwrite replaces only what dome-calib wrote
    cluster: dict = {}
    with open_executor(None, scheduler, cluster, workers=workers) as executor, ProgressBars() as bars:
        summary = synthesize(out, options, bars.task("rendering images"), executor=executor)
    typer.echo(f"{summary.folder}: {summary.n_images} images ({len(summary.cameras)} cameras x "
               f"{len(summary.scenes)} scenes) in {summary.seconds:.1f} s")
    for line in format_cluster(cluster, on_this_machine="scene layout, ground truth, writing the PNGs"):
        typer.echo(line)


def patterns(
    out: Path = typer.Argument(..., help="Folder for pattern_P1.png .. pattern_P5.png.", show_default=False),
    seed: int = typer.Option(0, help="Random seed (use the capture's seed to get its patterns)."),
    width: int = typer.Option(1280, help="Projector width in pixels."),
    height: int = typer.Option(800, help="Projector height in pixels."),
) -> None:
    """Write the five projectors' random patterns as 8-bit PNGs (show each on its projector, full screen)."""
    from projector.patterns import PatternOptions, write_patterns

    if not (64 <= width <= 8192 and 64 <= height <= 8192):
        raise DomeCalibError(f"pattern size {width}x{height}: expected 64..8192 pixels per side")
    paths = write_patterns(out, seed, options=PatternOptions(resolution=(width, height)))
    typer.echo(f"{out}: wrote {', '.join(p.name for p in paths)}")


def register(app: typer.Typer) -> None:
    """Add the commands to the `dome-calib` app."""
    app.command()(synth)
    app.command()(patterns)
