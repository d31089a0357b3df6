"""`dome-calib export` and `dome-calib import`: thin shells over dome_calib.interop.convert.

The choices and their help come from the format registry (:mod:`dome_calib.interop.registry`, which loads no
numpy); the stages are imported inside the commands: `dome-calib --help` starts without loading pycolmap or OpenCV.
"""
from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer

from dome_calib.interop.registry import EXPORT_FORMATS, IMPORT_FORMATS, UNIT_CHOICES, UP_AXES, help_list

ExportFormat = StrEnum("ExportFormat", {n: n for n in EXPORT_FORMATS})
ImportFormat = StrEnum("ImportFormat", {n: n for n in IMPORT_FORMATS})
UpChoice = StrEnum("UpChoice", {a: a for a in UP_AXES})
UnitChoice = StrEnum("UnitChoice", {u: u for u in UNIT_CHOICES})

_NAMES_HELP = "Rename cameras: OLD=NEW,OLD2=NEW2 (unlisted cameras keep their names)."


def export(
    bundle: Path = typer.Argument(..., help="Bundle folder (holds calibration_<seq>.json).", show_default=False),
    to: ExportFormat = typer.Option(..., "--to", help=f"Format to write: {help_list('export')}.",
                                    show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="File to write (a folder for colmap and easymocap); what is "
                             "there is replaced only if dome-calib wrote it (its record says so), else refused.",
                             show_default=False),
    unit: UnitChoice = typer.Option(None, "--unit", help="Length unit of the written translations (default: m; "
                                    "aniposelib mm, the usual board unit; pose2sim, easymocap and blender are "
                                    "always m)."),
    world_up: UpChoice = typer.Option(None, "--world-up", help="Axis that points up in the written world (ours: "
                                      "-y). Default: +z for pose2sim and easymocap (their worlds are z up), our -y "
                                      "kept for colmap and aniposelib; nerfstudio and blender are always +z."),
    names: str = typer.Option(None, "--names", help=_NAMES_HELP),
    text: bool = typer.Option(False, "--text", help="colmap: write .txt files instead of .bin."),
    cameras: str = typer.Option(None, "--cameras", help="Only these cameras, e.g. 00_03,00_07 (in the bundle's "
                                "order; default: every camera)."),
) -> None:
    """Write a calibration bundle for another tool (cameras in the bundle's order). Says what the format cannot
    hold, per camera where it moves pixels."""
    from dome_calib.interop.common import ExportOptions, parse_names
    from dome_calib.interop.convert import export_bundle

    chosen = [c.strip() for c in cameras.split(",") if c.strip()] if cameras else None
    options = ExportOptions(unit=unit and str(unit), world_up=world_up and str(world_up), names=parse_names(names),
                            binary=not text, cameras=chosen)
    result = export_bundle(bundle, str(to), out, options)
    typer.echo(f"{result.cameras} cameras -> {result.out} ({result.format}, lengths in {result.unit}, "
               f"up {result.world_up})")
    for line in result.dropped:
        typer.echo(f"not carried: {line}")
    for name, shift in result.corner_shift_px.items():
        typer.echo(f"  {name}: distortion dropped, corner point moves {shift:.3f} px")


def import_(
    source: Path = typer.Argument(..., help="The other tool's calibration: a file, or a folder (colmap model, "
                                  "easymocap).", show_default=False),
    from_: ImportFormat = typer.Option(..., "--from", help=f"Format of SOURCE: {help_list('import')}.",
                                       show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="Bundle folder to write: new, empty, or one dome-calib wrote "
                             "(replaced whole). A folder holding anything else (your notes, a file changed since) is "
                             "refused, never emptied.", show_default=False),
    unit: UnitChoice = typer.Option(None, "--unit", help="Length unit of SOURCE when the format does not say it "
                                    "(colmap, aniposelib, nerfstudio from other tools): mm, cm, m, or squares "
                                    "(the calibration board's squares: give --square-size-mm)."),
    square_size_mm: float = typer.Option(None, "--square-size-mm", help="With --unit squares: the board's square "
                                         "side in mm."),
    world_up: UpChoice = typer.Option(None, "--world-up", help="Axis that points up in SOURCE's world; it is "
                                      "turned to our -y (x kept where possible). Default: +z for pose2sim, "
                                      "easymocap, qualisys, vicon, biocv, caliscope; the world kept for colmap, "
                                      "aniposelib, "
                                      "kalibr (cam0's frame) and opencap (its board's, y down); nerfstudio: undone from its applied_transform."),
    names: str = typer.Option(None, "--names", help=_NAMES_HELP),
    seq: str = typer.Option(None, "--seq", help="Sequence name for calibration_<seq>.json (default: the output "
                            "folder's name)."),
    image_size: str = typer.Option(None, "--image-size", help="WIDTHxHEIGHT px of every camera, for files that do "
                                   "not record it (EasyMocap's calib_intri output, when its images/ are not beside "
                                   "it)."),
    binning: int = typer.Option(None, "--binning", help="qualisys: sensor pixels binned per image pixel (2 for "
                                "video filmed in 540p on a 1080p sensor; Pose2Sim's binning_factor). Default: what "
                                "the file's video_resolution says, else 1."),
) -> None:
    """Turn another tool's camera calibration into a calibration bundle the reconstruction and sync stages read
    (cameras in the file's order, lengths converted to cm, the world turned to ours, names kept or renamed)."""
    from dome_calib.interop.common import ImportOptions, parse_image_size, parse_names
    from dome_calib.interop.convert import import_calibration

    options = ImportOptions(unit=unit and str(unit), square_size_mm=square_size_mm, names=parse_names(names),
                            world_up=world_up and str(world_up), seq=seq if seq is not None else out.resolve().name,
                            image_size=parse_image_size(image_size), binning=binning)
    result = import_calibration(source, str(from_), out, options)
    typer.echo(f"{result.cameras} cameras from {source} ({result.format}, lengths in {result.unit}, "
               f"up {result.world_up}) -> {result.out}")


def register(app: typer.Typer) -> None:
    """Add the export and import commands to the `dome-calib` app."""
    app.command()(export)
    app.command("import")(import_)
