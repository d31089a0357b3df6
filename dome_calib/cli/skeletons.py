"""`dome-calib export-people` and `dome-calib people-page`: thin shells over dome_calib.skeletons (and the pipeline
that joins a page with a bundle and detections).

The stages are imported inside the commands: `dome-calib --help` starts without loading them.
"""
from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer


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
                                          "(cm, y up).", show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="Folder to write (created; a folder of an earlier export is "
                             "replaced whole, any other folder is refused).", show_default=False),
    ids: str = typer.Option(None, "--ids", help="Only these people, e.g. 0,3,7 (default: everybody)."),
    min_confidence: float = typer.Option(0.0, "--min-confidence", help="Write joints whose confidence is below this "
                                         "as missing (default 0: every reconstructed joint)."),
    fps: str = typer.Option(None, "--fps", help="Frame rate to write, e.g. 25 or 30000/1001 (default: the files' "
                            "fpsType: vga_25, hd_29_97; else measured from their univTime)."),
) -> None:
    """Write the people of a body3DScene folder for other tools: TRC (OpenSim, Pose2Sim), C3D or BVH. Person ids
    are kept (person<id>.trc, person<id>.bvh, C3D markers P<id>:Neck ...); joints that were not reconstructed are
    written as the format's missing value (BVH, which has none, holds the last pose)."""
    from dome_calib.cli.progress import ProgressBars
    from dome_calib.skeletons.export import ExportPeopleOptions, export_people as run, parse_fps, parse_ids

    options = ExportPeopleOptions(min_confidence=min_confidence, fps=parse_fps(fps), ids=parse_ids(ids))
    with ProgressBars(transient=True) as bars:
        summary = run(people, to.value, out, options, progress=bars.task("reading and writing files"))
    typer.echo(f"{summary.people} people, {summary.frames} frames at {float(summary.fps):g} fps: "
               f"{len(summary.files)} {to.value} file(s), {summary.joints_written} joints written, "
               f"{summary.joints_missing} missing -> {summary.out}")


def register(app: typer.Typer) -> None:
    """Add `export-people` to the `dome-calib` app."""
    app.command("export-people")(export_people)
