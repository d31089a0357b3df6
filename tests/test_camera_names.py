"""Issue 50, names as paths: a camera name from any file kind becomes file names (``<camera>.png``, an OpenPose
folder, a plot), so one rule (dome_calib.schema.name_problem, the type CameraName) holds it in every file kind that
carries camera names, and every place a name becomes a path goes through dome_calib.schema.path_of_name.

Before (main at aaf6910): `synth OUT --layout CAL.json --preset full` wrote `<name>.png` wherever a name pointed
(`/abs/x`, `../../../x`), a NUL in a name was `ValueError: embedded null byte`, and every file kind took any name."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest
import tomli_w

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.errors import DomeCalibError
from dome_calib.layout import nominal_dome
from dome_calib.report.schema import read_report
from dome_calib.schema import NAME_MAX_CHARS, name_problem, path_of_name

from .conftest import REAL_CALIBRATION

#: Names that are not one component of a path, and a reason each is refused.
HOSTILE = {"/abs/x": "separator", "../../../x": "separator", "a\\b": "separator", "..": "folder reference",
           ".": "folder reference", "": "empty", "01_01\x00x": "control", "a\nb": "control",
           "a" * 300: "longer", "é" * (NAME_MAX_CHARS + 1): "longer"}
#: Names a user's tool may well write: kept.
PLAIN = ["01_01", "cam_0", "int_cam01_img", "Camera 1", "<b>x&y", "é" * NAME_MAX_CHARS, "-x", ".hidden"]


def _one_line(out) -> str:
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1 and len(lines) == 1 and lines[0].startswith("dome-calib: error:"), out.stderr[-3000:]
    return lines[0]


@pytest.mark.parametrize("name", HOSTILE)
def test_the_rule_and_the_path_guard(name, tmp_path):
    assert HOSTILE[name] in name_problem(name)
    with pytest.raises(DomeCalibError, match="not a file name"):
        path_of_name(tmp_path, name, ".png")


@pytest.mark.parametrize("name", PLAIN)
def test_plain_names_pass(name, tmp_path):
    assert name_problem(name) is None
    assert path_of_name(tmp_path, name, ".png").parent == tmp_path


def _calibration(tmp_path: Path, name: str, n: int = 3) -> Path:
    doc = json.loads(Path(REAL_CALIBRATION).read_text())
    cams = [c for c in doc["cameras"] if c["type"] == "vga"][:n]
    cams[0] = {**cams[0], "name": name}
    path = tmp_path / "calibration_x.json"
    path.write_text(json.dumps({"calibDataSource": "test", "cameras": cams}))
    return path


@pytest.mark.parametrize("name", ["/abs/x", "../../../x", "01_01\x00x", "a" * 300, "a\nb"])
def test_synth_layout_names_are_refused_before_work(name, dome_calib_cli, tmp_path):
    """Before: exit 0 with `<name>.png` written outside OUT (or a traceback for the NUL)."""
    layout = _calibration(tmp_path, name)
    before = sorted(tmp_path.rglob("*"))
    line = _one_line(dome_calib_cli("synth", str(tmp_path / "OUT"), "--layout", str(layout), "--scenes", "1",
                                    "--preset", "full"))
    assert "calibration_x.json" in line and "cameras[0].name" in line, line
    assert sorted(tmp_path.rglob("*")) == before


def test_synth_layout_of_other_names_is_refused(dome_calib_cli, tmp_path):
    """A plain name that is not the dome's (`cam_0`): the capture's cameras are Panoptic names (capture.json)."""
    line = _one_line(dome_calib_cli("synth", str(tmp_path / "OUT"), "--layout", str(_calibration(tmp_path, "cam_0")),
                                    "--scenes", "1", "--preset", "full"))
    assert "not a Panoptic camera name" in line, line
    assert not (tmp_path / "OUT").exists()


@pytest.mark.parametrize("name", ["/abs/x", "..", "a\x00b", "a" * 300])
def test_a_bundle_with_such_a_name_is_refused_in_one_line(name, dome_calib_cli, tmp_path):
    """The calibration file of a bundle, read by every command that loads one (here `info`)."""
    (tmp_path / "b").mkdir()
    _calibration(tmp_path / "b", name)
    line = _one_line(dome_calib_cli("info", str(tmp_path / "b")))
    assert "cameras[0].name" in line, line


def test_the_report_file_names_cameras_by_the_rule(tmp_path):
    from dome_calib.report import write_report

    dome = nominal_dome("tiny", seed=1)
    names = sorted(dome.cameras)[:3]
    bundle = Bundle(seq="s", cameras={n: dome.cameras[n] for n in names})
    write_bundle(bundle, tmp_path / "b")
    write_report(tmp_path / "b", bundle)
    path = tmp_path / "b" / "report" / "report.json"
    doc = json.loads(path.read_text())
    read_report(path)  # as written: read
    for field in ("per_camera", "plots"):
        bad = dict(doc)
        if field == "per_camera":
            bad["per_camera"] = {"../../x" if k == names[0] else k: v for k, v in doc["per_camera"].items()}
        else:
            bad["plots"] = ["../../../etc/passwd"]
        path.write_text(json.dumps(bad))
        with pytest.raises(DomeCalibError, match=f"{field}"):
            read_report(path)


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    dome = nominal_dome("tiny", seed=1)
    folder = tmp_path_factory.mktemp("names") / "bundle"
    write_bundle(Bundle(seq="small", cameras={n: dome.cameras[n] for n in ["00_00", "01_01", "50_04"]}), folder)
    return folder


@pytest.mark.parametrize("fmt", ["colmap", "aniposelib", "pose2sim", "easymocap", "nerfstudio"])
@pytest.mark.parametrize("name", ["../../x", "a\x00b", "a" * 300])
def test_every_import_format_refuses_such_names(small, fmt, name, dome_calib_cli, tmp_path):
    """Through --names (every format goes through the same rule, named once in interop.common.to_bundle)."""
    exported = tmp_path / "exp"
    out = dome_calib_cli("export", str(small), "--to", fmt, "-o", str(exported), "--unit", "m")
    assert out.returncode == 0, out.stderr
    line = _one_line(dome_calib_cli("import", str(exported), "--from", fmt, "--unit", "m", "--names",
                                    f"00_00={name}", "-o", str(tmp_path / "b")))
    assert "camera 00_00: name" in line and "--names" in line, line
    assert not (tmp_path / "b").exists()


def test_a_peer_file_name_is_refused_by_its_schema(small, dome_calib_cli, tmp_path):
    """aniposelib's TOML names its cameras in a field: its schema holds the rule (the docs say so)."""
    assert dome_calib_cli("export", str(small), "--to", "aniposelib", "-o", str(tmp_path / "c.toml")).returncode == 0
    doc = tomllib.loads((tmp_path / "c.toml").read_text())
    first = next(k for k in doc if k != "metadata")
    doc[first]["name"] = "../../../x"
    (tmp_path / "c.toml").write_text(tomli_w.dumps(doc))
    line = _one_line(dome_calib_cli("import", str(tmp_path / "c.toml"), "--from", "aniposelib", "-o",
                                    str(tmp_path / "b")))
    assert f"{first}.name" in line, line


def test_colmap_image_folders_make_plain_names(small, dome_calib_cli, tmp_path):
    import pycolmap

    assert dome_calib_cli("export", str(small), "--to", "colmap", "-o", str(tmp_path / "m"), "--text").returncode == 0
    rec = pycolmap.Reconstruction(str(tmp_path / "m"))
    for image in rec.images.values():
        image.name = f"frames/{image.name}"
    rec.write_text(str(tmp_path / "m"))
    out = dome_calib_cli("import", str(tmp_path / "m"), "--from", "colmap", "--unit", "m", "-o", str(tmp_path / "b"))
    assert out.returncode == 0, out.stderr
    assert sorted(load_bundle(tmp_path / "b").cameras) == ["frames_00_00", "frames_01_01", "frames_50_04"]
