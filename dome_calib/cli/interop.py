"""`dome-calib export` and `dome-calib import`: thin shells over dome_calib.interop.convert.

The stages are imported inside the commands: `dome-calib --help` starts without loading pycolmap or OpenCV.
"""
from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer


class FormatChoice(StrEnum):  # the same values as dome_calib.interop.convert.Format (not imported: start-up time)
    colmap = "colmap"
    aniposelib = "aniposelib"
    pose2sim = "pose2sim"
    easymocap = "easymocap"
    nerfstudio = "nerfstudio"


class UpChoice(StrEnum):
    px = "+x"
    nx = "-x"
    py = "+y"
    ny = "-y"
    pz = "+z"
    nz = "-z"


class UnitChoice(StrEnum):
    mm = "mm"
    cm = "cm"
    m = "m"
    squares = "squares"


_FORMATS_HELP = ("colmap (folder: cameras, images, rigs, frames, points3D), aniposelib (calibration.toml), "
                 "pose2sim (Calib.toml), easymocap (folder: intri.yml + extri.yml), nerfstudio (transforms.json)")
_NAMES_HELP = "Rename cameras: OLD=NEW,OLD2=NEW2 (unlisted cameras keep their names)."


def export(
    bundle: Path = typer.Argument(..., help="Bundle folder (holds calibration_<seq>.json).", show_default=False),
    to: FormatChoice = typer.Option(..., "--to", help=f"Format to write: {_FORMATS_HELP}.", show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="File to write (a folder for colmap and easymocap; an "
                             "existing folder is replaced only if it holds nothing but such files).",
                             show_default=False),
    unit: UnitChoice = typer.Option(None, "--unit", help="Length unit of the written translations (default: m; "
                                    "aniposelib mm, the usual board unit; pose2sim and easymocap are always m)."),
    world_up: UpChoice = typer.Option(None, "--world-up", help="Axis that points up in the written world (ours: "
                                      "-y). Default: +z for pose2sim (Pose2Sim turns z-up into OpenSim's y-up), "
                                      "our -y kept for the others; nerfstudio is always +z."),
    names: str = typer.Option(None, "--names", help=_NAMES_HELP),
    text: bool = typer.Option(False, "--text", help="colmap: write .txt files instead of .bin."),
) -> None:
    """Write a calibration bundle for another tool (cameras in the bundle's order, world frame kept; nerfstudio:
    turned z-up, see docs/interop.md). Says what the format cannot hold, per camera where it moves pixels."""
    from dome_calib.interop.common import ExportOptions, parse_names
    from dome_calib.interop.convert import export_bundle

    options = ExportOptions(unit=unit and str(unit), world_up=world_up and str(world_up), names=parse_names(names),
                            binary=not text)
    result = export_bundle(bundle, str(to), out, options)
    typer.echo(f"{result.cameras} cameras -> {result.out} ({result.format}, lengths in {result.unit}, "
               f"up {result.world_up})")
    for line in result.dropped:
        typer.echo(f"not carried: {line}")
    for name, shift in result.corner_shift_px.items():
        typer.echo(f"  {name}: k3 dropped, corner point moves {shift:.3f} px")


def import_(
    source: Path = typer.Argument(..., help="The other tool's calibration: a file (aniposelib, pose2sim, "
                                  "nerfstudio) or a folder (colmap model, easymocap).", show_default=False),
    from_: FormatChoice = typer.Option(..., "--from", help=f"Format of SOURCE: {_FORMATS_HELP}.",
                                       show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="Bundle folder to write (replaced whole if it holds a "
                             "bundle; a folder holding anything else is refused).", show_default=False),
    unit: UnitChoice = typer.Option(None, "--unit", help="Length unit of SOURCE when the format does not say it "
                                    "(colmap, aniposelib, nerfstudio from other tools): mm, cm, m, or squares "
                                    "(the calibration board's squares: give --square-size-mm)."),
    square_size_mm: float = typer.Option(None, "--square-size-mm", help="With --unit squares: the board's square "
                                         "side in mm."),
    world_up: UpChoice = typer.Option(None, "--world-up", help="Axis that points up in SOURCE's world; it is "
                                      "turned to our -y (x kept where possible). Default: +z for pose2sim, none "
                                      "(world kept) for colmap, aniposelib, easymocap; nerfstudio: undone from its "
                                      "applied_transform."),
    names: str = typer.Option(None, "--names", help=_NAMES_HELP),
    seq: str = typer.Option(None, "--seq", help="Sequence name for calibration_<seq>.json (default: the output "
                            "folder's name)."),
) -> None:
    """Turn another tool's camera calibration into a calibration bundle the reconstruction and sync stages read
    (world frame kept, lengths converted to cm, camera names kept or renamed with --names)."""
    from dome_calib.interop.common import ImportOptions, parse_names
    from dome_calib.interop.convert import import_calibration

    options = ImportOptions(unit=unit and str(unit), square_size_mm=square_size_mm, names=parse_names(names),
                            world_up=world_up and str(world_up), seq=seq or out.resolve().name)
    result = import_calibration(source, str(from_), out, options)
    typer.echo(f"{result.cameras} cameras from {source} ({result.format}, lengths in {result.unit}, "
               f"up {result.world_up}) -> {result.out}")


def register(app: typer.Typer) -> None:
    """Add the export and import commands to the `dome-calib` app."""
    app.command()(export)
    app.command("import")(import_)
