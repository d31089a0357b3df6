"""`dome-calib export` / `dome-calib import`: what they print, and bad input: one line naming file, camera and
field, exit 1, nothing written."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import pytest

from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.layout import nominal_dome

from .interop_helpers import projection_gap_px

CALIB_QUALISYS = Path(__file__).parent / "data" / "pose2sim_balancing" / "calibration" / "Calib_qualisys.toml"


@pytest.fixture
def tiny(tmp_path) -> Path:
    write_bundle(nominal_dome("tiny", seed=1), tmp_path / "tiny")
    return tmp_path / "tiny"


def _one_line_error(result, *fragments: str) -> str:
    assert result.returncode == 1, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_help_explains_both_commands(dome_calib_cli):
    for command, words in (("export", ("--to", "--unit", "--names", "colmap")),
                           ("import", ("--from", "--unit", "--square-size-mm", "squares"))):
        out = dome_calib_cli(command, "--help")
        assert out.returncode == 0
        for word in words:
            assert word in out.stdout


@pytest.mark.parametrize("fmt", ["colmap", "aniposelib", "pose2sim", "easymocap", "nerfstudio"])
def test_export_then_import_through_the_commands(dome_calib_cli, tiny, tmp_path, fmt):
    target = tmp_path / ("out" if fmt in ("colmap", "easymocap") else "out.file")
    out = dome_calib_cli("export", tiny, "--to", fmt, "-o", target, "--text")
    assert out.returncode == 0, out.stderr
    count = len(load_bundle(tiny).cameras)
    assert out.stdout.startswith(f"{count} cameras -> {target} ({fmt}, lengths in ")
    assert "dropped" not in out.stdout  # every format that goes both ways holds our cameras whole
    unit = ["--unit", "m"] if fmt == "colmap" else []
    back = dome_calib_cli("import", target, "--from", fmt, "-o", tmp_path / "back", *unit)
    assert back.returncode == 0, back.stderr
    assert f"{count} cameras from" in back.stdout
    original, again = load_bundle(tiny), load_bundle(tmp_path / "back")
    assert list(again.cameras) == list(original.cameras)
    assert (tmp_path / "back" / "calibration_back.json").is_file()  # seq: the folder's name
    if fmt != "pose2sim":
        assert max(projection_gap_px(c, again.cameras[n]) for n, c in original.cameras.items()) < 1e-6


def test_pose2sim_file_imports_with_names_mapped(dome_calib_cli, tmp_path):
    out = dome_calib_cli("import", CALIB_QUALISYS, "--from", "pose2sim", "-o", tmp_path / "b",
                         "--names", "cam_01=01_01,cam_02=01_02", "--seq", "balancing")
    assert out.returncode == 0, out.stderr
    bundle = load_bundle(tmp_path / "b")
    assert list(bundle.cameras) == ["01_01", "01_02", "cam_03", "cam_04"]
    assert (bundle.cameras["01_02"].panel, bundle.cameras["01_02"].node) == (1, 2)


# --------------------------------------------------------------------------------------------------- bad input
def _check_refused(dome_calib_cli, tmp_path, args, *fragments):
    before = _listing(tmp_path)
    line = _one_line_error(dome_calib_cli(*args), *fragments)
    assert _listing(tmp_path) == before, "something was written"
    return line


def test_a_file_of_another_format_is_refused(dome_calib_cli, tiny, tmp_path):
    calib_json = next(tiny.glob("calibration_*.json"))
    _check_refused(dome_calib_cli, tmp_path, ("import", calib_json, "--from", "pose2sim", "-o", tmp_path / "o"),
                   str(calib_json), "not valid TOML")
    _check_refused(dome_calib_cli, tmp_path, ("import", CALIB_QUALISYS, "--from", "nerfstudio", "-o", tmp_path / "o"),
                   "Calib_qualisys.toml", "not valid JSON")
    _check_refused(dome_calib_cli, tmp_path, ("import", tiny, "--from", "colmap", "--unit", "m", "-o", tmp_path / "o"),
                   "not a COLMAP model")
    _check_refused(dome_calib_cli, tmp_path, ("import", tiny, "--from", "easymocap", "-o", tmp_path / "o"),
                   "intri.yml: missing")
    (tmp_path / "intri.yml").write_text("this: [is, not\n")
    shutil.copy(tmp_path / "intri.yml", tmp_path / "extri.yml")
    _check_refused(dome_calib_cli, tmp_path, ("import", tmp_path, "--from", "easymocap", "-o", tmp_path / "o"),
                   "intri.yml: not a YAML file OpenCV can read")


def _pose2sim_text(tmp_path: Path, edit) -> Path:
    path = tmp_path / "edited.toml"
    path.write_text(edit(CALIB_QUALISYS.read_text()))
    return path


def test_missing_fields_duplicates_and_fisheye_are_refused(dome_calib_cli, tmp_path):
    no_matrix = _pose2sim_text(tmp_path, lambda t: t.replace("matrix = [ [ 1673.7", "matrixx = [ [ 1673.7"))
    _check_refused(dome_calib_cli, tmp_path, ("import", no_matrix, "--from", "pose2sim", "-o", tmp_path / "o"),
                   str(no_matrix), "cam_02.matrix: missing")
    dup = _pose2sim_text(tmp_path, lambda t: t.replace('name = "cam_03"', 'name = "cam_01"'))
    _check_refused(dome_calib_cli, tmp_path, ("import", dup, "--from", "pose2sim", "-o", tmp_path / "o"),
                   "camera cam_01", "name: duplicate camera name")
    fisheye = _pose2sim_text(tmp_path, lambda t: t.replace("fisheye = false", "fisheye = true", 1))
    _check_refused(dome_calib_cli, tmp_path, ("import", fisheye, "--from", "pose2sim", "-o", tmp_path / "o"),
                   "cam_01.fisheye", "cannot be represented")
    _check_refused(dome_calib_cli, tmp_path, ("import", CALIB_QUALISYS, "--from", "pose2sim", "--unit", "mm",
                                              "-o", tmp_path / "o"), "states its unit (m)")
    _check_refused(dome_calib_cli, tmp_path, ("import", CALIB_QUALISYS, "--from", "pose2sim", "--names", "cam_9=a",
                                              "-o", tmp_path / "o"), "--names maps 'cam_9'")
    _check_refused(dome_calib_cli, tmp_path, ("import", CALIB_QUALISYS, "--from", "pose2sim",
                                              "--names", "cam_01=cam_02", "-o", tmp_path / "o"),
                   "camera cam_02", "'cam_02' would be a duplicate name")


def test_a_rotation_that_is_not_one_is_refused(dome_calib_cli, tiny, tmp_path):
    work = tmp_path / "work"
    assert dome_calib_cli("export", tiny, "--to", "nerfstudio", "-o", work / "transforms.json").returncode == 0
    doc = json.loads((work / "transforms.json").read_text())
    name = doc["frames"][3]["camera_name"]
    pose = np.array(doc["frames"][3]["transform_matrix"])
    pose[:3, :3] *= 1.01
    doc["frames"][3]["transform_matrix"] = pose.tolist()
    (work / "transforms.json").write_text(json.dumps(doc))
    _check_refused(dome_calib_cli, tmp_path, ("import", work / "transforms.json", "--from", "nerfstudio",
                                              "-o", tmp_path / "o"),
                   "transforms.json", "frames[3]", f"camera {name}", "transform_matrix: not a rotation")
    assert dome_calib_cli("export", tiny, "--to", "easymocap", "-o", work / "emc").returncode == 0
    text = (work / "emc" / "extri.yml").read_text()
    first = re.search(r"^R_(\S+):", text, re.M).group(1)
    block = re.search(rf"Rot_{first}: !!opencv-matrix.*?data: \[ ([^,]+),", text, re.S)
    (work / "emc" / "extri.yml").write_text(text.replace(block.group(0), block.group(0).replace(
        block.group(1), repr(float(block.group(1)) + 0.5))))
    _check_refused(dome_calib_cli, tmp_path, ("import", work / "emc", "--from", "easymocap", "-o", tmp_path / "o"),
                   "extri.yml", f"camera {first}", "Rot: not a rotation")


def test_colmap_models_we_cannot_represent_are_refused(dome_calib_cli, tiny, tmp_path):
    model = tmp_path / "model"
    assert dome_calib_cli("export", tiny, "--to", "colmap", "-o", model).returncode == 0
    for camera_model, params, words in (
        ("OPENCV_FISHEYE", [800, 800, 320, 240, 0.1, 0.01, 0, 0],
         ("model: COLMAP model OPENCV_FISHEYE cannot be represented",)),
        ("FULL_OPENCV", [800, 800, 320, 240, 0.1, 0.01, 0, 0, 0, 0.02, 0, 0],
         ("params: FULL_OPENCV with k4..k6", "cannot be represented")),
    ):
        rec = pycolmap.Reconstruction(str(model))
        first = rec.images[1]
        old = rec.cameras[first.camera_id]
        rec.cameras[first.camera_id] = pycolmap.Camera(model=camera_model, width=old.width, height=old.height,
                                                       params=params, camera_id=first.camera_id)
        bad = tmp_path / camera_model
        bad.mkdir(exist_ok=True)
        rec.write_binary(str(bad))
        _check_refused(dome_calib_cli, tmp_path, ("import", bad, "--from", "colmap", "--unit", "m",
                                                  "-o", tmp_path / "o"),
                       str(bad), f"camera {first.name.removesuffix('.png')}", *words)
    _check_refused(dome_calib_cli, tmp_path, ("import", model, "--from", "colmap", "-o", tmp_path / "o"),
                   "does not record its length unit", "--unit")


def test_outputs_that_hold_other_things_are_not_replaced(dome_calib_cli, tiny, tmp_path):
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    _check_refused(dome_calib_cli, tmp_path, ("export", tiny, "--to", "colmap", "-o", busy), "notes.txt")
    _check_refused(dome_calib_cli, tmp_path, ("import", CALIB_QUALISYS, "--from", "pose2sim", "-o", busy),
                   "holds notes.txt", "choose another path")
    _check_refused(dome_calib_cli, tmp_path, ("export", tiny, "--to", "pose2sim", "--unit", "mm", "-o",
                                              tmp_path / "c.toml"), "in m by the format")
    assert (busy / "notes.txt").read_text() == "mine"


def test_every_format_is_one_row_of_the_registry_and_its_module():
    """The command line's choices, units and axes are the registry's; every row's module has what the row promises
    (read for import, write for export); the unit and axis tables cover the registry's lists."""
    import importlib
    import inspect

    from dome_calib.cli import interop as cli
    from dome_calib.interop import registry
    from dome_calib.interop.common import CM_PER_UNIT, PANOPTIC_FROM_UP

    assert [e.value for e in cli.ExportFormat] == list(registry.EXPORT_FORMATS)
    assert [e.value for e in cli.ImportFormat] == list(registry.IMPORT_FORMATS)
    assert [e.value for e in cli.UpChoice] == list(registry.UP_AXES) == list(PANOPTIC_FROM_UP)
    assert [e.value for e in cli.UnitChoice] == list(registry.UNIT_CHOICES)
    assert list(CM_PER_UNIT) == list(registry.UNITS)
    for row in registry.FORMATS:
        module = importlib.import_module(row.module)
        assert row.module == f"dome_calib.interop.{row.name}"
        assert hasattr(module, "read") == row.reads and hasattr(module, "write") == row.writes, row.name
        if row.writes:  # write(cams, out, unit, options)
            assert list(inspect.signature(module.write).parameters)[0::2] == ["cams", "unit"], row.name
        if row.reads:  # read(source, options)
            assert len(inspect.signature(module.read).parameters) == 2, row.name
        for unit in (row.fixed_unit, row.default_unit):
            assert unit is None or unit in registry.UNITS
        assert row.export_up in registry.UP_AXES and row.import_up in registry.UP_AXES
        assert not row.folder_files or row.folder
