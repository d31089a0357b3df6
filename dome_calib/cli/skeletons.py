"""`dome-calib export-people` and `dome-calib people-page`: thin shells over dome_calib.skeletons (and the pipeline
that joins a page with a bundle and detections).

The stages are imported inside the commands: `dome-calib --help` starts without loading them.
"""
from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer

from dome_calib.errors import flags


class PeopleFormatChoice(StrEnum):  # the same values as dome_calib.skeletons.export.PeopleFormat (start-up time)
    trc = "trc"
    c3d = "c3d"
    bvh = "bvh"


_PEOPLE_HELP = ("Folder of Panoptic body3DScene_<frame>.json files: the output of `dome-calib reconstruct`, or a "
                "Panoptic dataset folder such as hdPose3d_stage1_coco19.")


def export_people(
    people: Path = typer.Argument(..., help=_PEOPLE_HELP, show_default=False),
    to: PeopleFormatChoice = typer.Option(..., "--to", help="trc: one file per person for OpenSim and Pose2Sim "
                                          "(metres, y up); c3d: one file for the whole capture (millimetres, z up, "
                                          "markers P<id>:<joint>); bvh: one skeleton per person for animation tools "
                                          "(m by default, see --unit; y up).", show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="Folder to write (created; a folder dome-calib wrote is "
                             "replaced whole, any other folder is refused).", show_default=False),
    ids: str = typer.Option(None, "--ids", help="Only these people, e.g. 0,3,7 (default: everybody)."),
    min_confidence: float = typer.Option(0.0, "--min-confidence", help="Write joints whose confidence is below this "
                                         "as missing (default 0: every reconstructed joint)."),
    fps: str = typer.Option(None, "--fps", help="Frame rate to write, e.g. 25 or 30000/1001 (default: the files' "
                            "fpsType: vga_25, hd_29_97; else measured from their univTime); the TRC's Time column "
                            "steps by 1/RATE per frame number."),
    trial: str = typer.Option(None, "--trial", help="Name of the TRC files before _P<id>_<first>-<last>.trc "
                              "(Pose2Sim's multi-person names; default: the PEOPLE folder's name)."),
    fill_gaps: int = typer.Option(20, "--fill-gaps", help="TRC: fill a marker missing for at most this many "
                                  "frames as Pose2Sim fills its own TRC (linear inside, held at the ends; Pose2Sim's "
                                  "marker augmentation fails on empty fields); 0: missing stays missing."),
    unit: str = typer.Option("m", "--unit", help="BVH: length unit, m (one Blender unit: the person at true size "
                             "in Blender's importer), cm or mm."),
) -> None:
    """Write the people of a body3DScene folder for other tools: TRC (OpenSim, Pose2Sim), C3D or BVH. Person ids
    are kept (<trial>_P<id>_<first>-<last>.trc, person<id>.bvh, C3D markers P<id>:Neck ...); joints that were not
    reconstructed are
    written as the format's missing value (BVH, which has none, holds the last pose)."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.skeletons.export import ExportPeopleOptions, export_people as run, parse_fps, parse_ids

    with flags({"ExportPeopleOptions.min_confidence": "--min-confidence", "ExportPeopleOptions.fps": "--fps",
                "ExportPeopleOptions.ids[0]": "--ids", "ExportPeopleOptions.fill_gaps": "--fill-gaps",
                "ExportPeopleOptions.unit": "--unit"}):
        options = ExportPeopleOptions(min_confidence=min_confidence, fps=parse_fps(fps), ids=parse_ids(ids),
                                       trial=trial, fill_gaps=fill_gaps, unit=unit)
    with ProgressBars(transient=True) as bars:
        summary = run(people, to.value, out, options, progress=bars.task("reading and writing files"))
    typer.echo(f"{summary.people} people, {summary.frames} frames at {float(summary.fps):g} fps: "
               f"{len(summary.files)} {to.value} file(s), {summary.joints_written} joints written, "
               f"{summary.joints_missing} missing -> {summary.out}")


def people_page(
    people: Path = typer.Argument(..., help=_PEOPLE_HELP, show_default=False),
    out: Path = typer.Option(None, "-o", "--out", help="Page to write (default: PEOPLE/index.html)."),
    bundle: Path = typer.Option(None, "--bundle", help="Calibration bundle folder: draws the cameras in the dome and "
                                "lets you pick a camera to see the bodies reprojected into its image."),
    detections: Path = typer.Option(None, "--detections", help="The OpenPose folder reconstruct read (needs "
                                    "--bundle): the chosen camera's detections are drawn against the reprojected "
                                    "bodies."),
    camera_map: str = typer.Option(None, "--camera-map", help="Folder-to-camera names of the detections, as for "
                                   "reconstruct: 'cam01=00_01,cam02=00_02' or a JSON file."),
    body_model: str = typer.Option(None, "--body-model", help="The detector's model, as for reconstruct: BODY_25, "
                                   "BODY_25B, COCO_18 or PANOPTIC19 (needed for 25-joint files)."),
    cameras: str = typer.Option(None, "--cameras", help="Cameras whose detections go on the page, e.g. "
                                "00_03,00_07 (default: in name order while the page holds at most 60,000 detected "
                                "people)."),
) -> None:
    """Build a self-contained page (index.html, opens from the file system) to watch the people of a body3DScene
    folder: the dome from the top and the side, every body over time with play, pause, step and a time slider, each
    person's id and trail, and a camera's detections against the reprojected bodies."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.pipeline.people_page import build_people_page

    chosen = [c.strip() for c in cameras.split(",") if c.strip()] if cameras else None
    with ProgressBars(transient=True) as bars:
        summary = build_people_page(people, out=out, bundle=bundle, detections=detections, camera_map=camera_map,
                                    body_model=body_model, cameras=chosen, progress=bars.task("reading files"))
    det = f", detections of {len(summary.detection_cameras)} cameras" if summary.detection_cameras else ""
    typer.echo(f"{summary.people} people, {summary.frames} frames, {summary.cameras} cameras{det} -> {summary.page}")
    for note in summary.notes:
        typer.echo(f"note: {note}")


def register(app: typer.Typer) -> None:
    """Add `export-people` and `people-page` to the `dome-calib` app."""
    app.command("export-people")(export_people)
    app.command("people-page")(people_page)
