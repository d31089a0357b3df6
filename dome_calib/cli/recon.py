"""`dome-calib triangulate` and `dome-calib pointcloud`: thin shells over dome_calib.recon.

The stages are imported inside the commands: `dome-calib --help` starts without loading them.
"""
from __future__ import annotations

from pathlib import Path

import typer

from dome_calib.errors import flags


def triangulate(
    detections: Path = typer.Argument(..., help="Detections JSON: 2D joints per camera per frame (see docs/recon.md, "
                                      "'Detections file').", show_default=False),
    bundle: Path = typer.Option(..., "--bundle", help="Calibration bundle folder (calibration_<seq>.json plus "
                                "synctables/ksynctables).", show_default=False),
    out: Path = typer.Option(None, "-o", "--out", help="Folder for the body3DScene_<k>.json skeleton files "
                             "(default: <DETECTIONS name>_skeletons beside DETECTIONS)."),
    threshold_px: float = typer.Option(8.0, "--threshold-px", help="A camera supports a joint if the joint "
                                       "reprojects within this many pixels of its detection."),
    min_views: int = typer.Option(2, "--min-views", help="Joints seen by fewer supporting cameras are left out."),
) -> None:
    """Triangulate 2D joint detections from all cameras (VGA, HD, Kinect colour, each at its own frame rate) into
    3D skeletons in the world frame (cm), one Panoptic body3DScene file per time."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.recon.commands import triangulate_file
    from dome_calib.recon.triangulate import TriangulationOptions

    out = out or detections.with_name(f"{detections.stem}_skeletons")
    with flags({"TriangulationOptions.inlier_threshold_px": "--threshold-px",
                "TriangulationOptions.min_views": "--min-views"}):
        options = TriangulationOptions(inlier_threshold_px=threshold_px, min_views=min_views)
    with ProgressBars(transient=True) as bars:
        summary = triangulate_file(bundle, detections, out, options=options, progress=bars.task("triangulating times"))
    typer.echo(f"{summary.times} times x {summary.joints} joints from streams {', '.join(summary.streams)}: "
               f"{summary.reconstructed} joints reconstructed (median {summary.median_inlier_views:.0f} supporting "
               f"cameras) -> {summary.out}")


def exact_ms(time_ms: float) -> str:
    """A time for a file name, exact (two times, two names): 36001040 -> '36001040', 0.5 -> '0.5' (shortest
    round trip), never ``{:g}``'s six digits (36001000 and 36001040 both '3.6001e+07')."""
    return str(int(time_ms)) if float(time_ms).is_integer() else repr(float(time_ms))


def pointcloud(
    bundle: Path = typer.Option(..., "--bundle", help="Calibration bundle folder (needs kcalibration_<seq>.json and "
                                "ksynctables_<seq>.json).", show_default=False),
    time_ms: float = typer.Option(..., "--time-ms", help="Universal time (ms on the HD timecode timeline).",
                                  show_default=False),
    depth: Path = typer.Option(..., "--depth", help="Folder with KINECTNODE<n>/depth_<k>.png (16-bit, mm).",
                               show_default=False),
    out: Path = typer.Option(None, "-o", "--out", help="PLY file to write (default: pointcloud_<time>ms.ply in "
                             "the current folder)."),
    max_offset_ms: float = typer.Option(None, "--max-offset-ms", help="Leave out Kinects whose nearest depth "
                                        "frame is further than this from the time."),
) -> None:
    """Turn the depth frames of every Kinect nearest to a universal time into one point cloud in the world frame
    (cm), each point tagged with its Kinect and the frame's time offset (ms)."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.recon.commands import pointcloud_file

    out = out or Path(f"pointcloud_{exact_ms(time_ms)}ms.ply")
    with ProgressBars(transient=True) as bars:
        summary = pointcloud_file(bundle, time_ms, depth, out, max_offset_ms=max_offset_ms,
                                  progress=bars.task("depth to world: Kinects"))
    offsets = ", ".join(f"{s} {o:+.1f} ms" for s, o in zip(summary.sensors, summary.time_offsets_ms))
    typer.echo(f"{summary.points} points from {len(summary.sensors)} Kinects ({offsets}) -> {summary.out}")


def register(app: typer.Typer) -> None:
    """Add the reconstruction commands to the `dome-calib` app."""
    app.command()(triangulate)
    app.command()(pointcloud)
