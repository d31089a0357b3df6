"""The formats `export` and `import` know: one row per format, declared once.

A row says what the format's files are, which way it goes, its length unit and world axes, and which module
holds its code (``read(source, options)`` for import, ``write(cams, out, options)`` for export; see
:mod:`dome_calib.interop.convert`). A new format is its module plus one row here; the command line builds its
choices and help from these rows, and the tests check every row against its module.

This module imports nothing heavy (no numpy): ``dome-calib --help`` reads it.
"""
from __future__ import annotations

from dataclasses import dataclass

#: Length units a file may use (the centimetres per unit: :data:`dome_calib.interop.common.CM_PER_UNIT`).
UNITS = ("mm", "cm", "m")
#: ``--unit`` choices: a length unit, or the calibration board's squares (import only, needs the square size).
UNIT_CHOICES = (*UNITS, "squares")
#: ``--world-up`` choices: the axis that points up in another tool's world.
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
#: Our world's up axis (Panoptic: y down).
OUR_UP = "-y"


@dataclass(frozen=True, kw_only=True)
class FormatInfo:
    """One format. ``files``: what SOURCE / OUT is (for the help and the docs); ``folder``: OUT / SOURCE is a
    folder (an existing output folder is replaced only if it holds nothing but ``folder_files``);
    ``default_file``: the file taken when a folder is given for a file format; ``fixed_unit``: the format's length
    unit by its definition (``--unit`` may only repeat it); ``default_unit``: the export's unit when ``--unit`` is
    not given; ``export_up`` / ``import_up``: the up axis of the written / read world by default (ours, -y, kept
    unless said); ``fixed_up``: the format fixes its world's up axis itself (``--world-up`` refused)."""

    name: str
    module: str
    files: str
    reads: bool = False
    writes: bool = False
    folder: bool = False
    folder_files: tuple[str, ...] = ()
    default_file: str | None = None
    fixed_unit: str | None = None
    default_unit: str | None = None
    export_up: str = OUR_UP
    import_up: str = OUR_UP
    fixed_up: bool = False
    peer: str = ""  # whose format it is, and where its rules are written


FORMATS: tuple[FormatInfo, ...] = (
    FormatInfo(name="colmap", module="dome_calib.interop.colmap", reads=True, writes=True, folder=True,
               files="folder: cameras, images, rigs, frames, points3D (.bin or .txt)",
               folder_files=tuple(f"{k}.{e}" for k in ("cameras", "images", "points3D", "rigs", "frames")
                                  for e in ("bin", "txt")),
               default_unit="m", peer="COLMAP sparse model, read and written by pycolmap"),
    FormatInfo(name="aniposelib", module="dome_calib.interop.aniposelib", reads=True, writes=True,
               files="calibration.toml", default_file="calibration.toml", default_unit="mm",
               peer="aniposelib CameraGroup.dump / load"),
    FormatInfo(name="pose2sim", module="dome_calib.interop.pose2sim", reads=True, writes=True,
               files="Calib.toml", fixed_unit="m", export_up="+z", import_up="+z",
               peer="Pose2Sim calibration.py toml_write / common.py retrieve_calib_params"),
    FormatInfo(name="easymocap", module="dome_calib.interop.easymocap", reads=True, writes=True, folder=True,
               files="folder: intri.yml + extri.yml", folder_files=("intri.yml", "extri.yml"), fixed_unit="m",
               export_up="+z", import_up="+z", peer="EasyMocap mytools/camera_utils.py read_camera / write_camera"),
    FormatInfo(name="nerfstudio", module="dome_calib.interop.nerfstudio", reads=True, writes=True,
               files="transforms.json", default_file="transforms.json", default_unit="m", export_up="+z",
               fixed_up=True, peer="nerfstudio nerfstudio_dataparser.py"),
    FormatInfo(name="blender", module="dome_calib.interop.blender", writes=True,
               files="a Python script that Blender runs (blender --python FILE.py): one camera object per camera",
               fixed_unit="m", export_up="+z", fixed_up=True, peer="Blender (bpy) camera objects"),
    FormatInfo(name="qualisys", module="dome_calib.interop.qualisys", reads=True,
               files="Qualisys calibration .qca.txt (XML)", fixed_unit="mm", import_up="+z",
               peer="Qualisys Track Manager calibration, as Pose2Sim's calib_qca_fun reads it"),
    FormatInfo(name="vicon", module="dome_calib.interop.vicon", reads=True,
               files="Vicon calibration .xcp (XML)", fixed_unit="mm", import_up="+z",
               peer="Vicon Nexus .xcp, as Pose2Sim's calib_vicon_fun reads it"),
    FormatInfo(name="biocv", module="dome_calib.interop.biocv", reads=True, folder=True,
               files="folder of bioCV .calib files", fixed_unit="mm", import_up="+z",
               peer="bioCV .calib files, as Pose2Sim's calib_biocv_fun reads them"),
    FormatInfo(name="opencap", module="dome_calib.interop.opencap", reads=True, folder=True,
               files="folder of OpenCap .pickle files (numpy arrays only)", fixed_unit="mm",
               peer="OpenCap camera .pickle files, as Pose2Sim's calib_opencap_fun reads them"),
    FormatInfo(name="caliscope", module="dome_calib.interop.caliscope", reads=True,
               files="camera_array.toml", default_file="camera_array.toml", fixed_unit="m", import_up="+z",
               peer="caliscope CameraArray.to_toml / from_toml"),
    FormatInfo(name="easywand", module="dome_calib.interop.easywand", reads=True,
               files="easyWand DLT coefficients *_dltCoefs.csv (11 rows, a column per camera; needs --image-size)",
               import_up="+z", peer="easyWand / DLTdv 11-coefficient DLT, as argus_gui's tools.py dlt_inverse reads it"),
    FormatInfo(name="kalibr", module="dome_calib.interop.kalibr", reads=True,
               files="camchain.yaml (cam0, cam1, ... with T_cn_cnm1)", fixed_unit="m",
               peer="Kalibr kalibr_common/ConfigReader.py CameraChainParameters"),
)
BY_NAME: dict[str, FormatInfo] = {f.name: f for f in FORMATS}
EXPORT_FORMATS = tuple(f.name for f in FORMATS if f.writes)
IMPORT_FORMATS = tuple(f.name for f in FORMATS if f.reads)


def format_info(name: str, direction: str) -> FormatInfo:
    """The row of ``name``; ValueError naming the formats of ``direction`` ("export" or "import") otherwise."""
    names = EXPORT_FORMATS if direction == "export" else IMPORT_FORMATS
    if name not in names:
        raise ValueError(f"{direction}: unknown format {name!r} (choose one of {', '.join(names)})")
    return BY_NAME[name]


def help_list(direction: str) -> str:
    """``colmap (folder: ...), aniposelib (calibration.toml), ...``: the formats of one direction, for --help."""
    names = EXPORT_FORMATS if direction == "export" else IMPORT_FORMATS
    return ", ".join(f"{n} ({BY_NAME[n].files})" for n in names)
