"""Issue 42 for `dome-calib import`: every peer file mutated (a field of another type, null, NaN, infinity, out of
range, removed; unknown fields added) gives no traceback: either a bundle the loader accepts, or exit 1 with one
line naming the file, and nothing written. And the situations found by hand: our own aniposelib file imported as
Pose2Sim, `import -o` onto a session's bundle folder, `--seq a/b`."""
from __future__ import annotations

import copy
import json
import math
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tomli_w
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dome_calib.bundle import Bundle
from dome_calib.ownership import RECORD
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.interop.common import ExportOptions
from dome_calib.interop.convert import export_bundle
from dome_calib.layout import nominal_dome

from .interop_helpers import kalibr_camchain

QCA = Path(__file__).parent / "data" / "pose2sim_qualisys" / "Calib.qca.txt"
HOSTILE = settings(max_examples=25, deadline=None, derandomize=True,
                   suppress_health_check=[HealthCheck.function_scoped_fixture])


def _run(args: list[str], monkeypatch, capsys) -> tuple[int, str, str]:
    from dome_calib.cli import app
    from dome_calib.errors import run_cli

    monkeypatch.setattr(sys, "argv", ["dome-calib", *map(str, args)])
    with pytest.raises(SystemExit) as exit_:  # any other exception escapes: a traceback, and the test fails
        run_cli(app, prog="dome-calib")
    out = capsys.readouterr()
    return int(exit_.value.code or 0), out.out, out.err


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """Three cameras of the tiny synthetic dome (HD, VGA, Kinect colour)."""
    dome = nominal_dome("tiny", seed=1)
    names = ["00_00", "01_01", "50_04"]
    folder = tmp_path_factory.mktemp("small") / "bundle"
    write_bundle(Bundle(seq="small", cameras={n: dome.cameras[n] for n in names}), folder)
    return folder


# -------------------------------------------------------------------------------------- mutating a document tree
def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every place in a tree of dicts and lists (the root excluded)."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else []
    for key, value in items:
        out.append((*prefix, key))
        out += _paths(value, (*prefix, key))
    return out


KINDS = ("string", "bool", "null", "nan", "inf", "huge", "negative", "zero", "list", "object", "remove", "unknown")


def _mutate(doc: Any, path: tuple, kind: str) -> Any:
    doc = copy.deepcopy(doc)
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    key = path[-1]
    value = {"string": "1.5", "bool": True, "null": None, "nan": math.nan, "inf": math.inf, "huge": 1e300,
             "negative": -7.0, "zero": 0, "list": [1.0, "x"], "object": {"a": 1}}.get(kind)
    if kind == "remove":
        if isinstance(parent, dict):
            del parent[key]
        else:
            parent.pop(key)
    elif kind == "unknown":
        target = parent[key] if isinstance(parent[key], dict) else parent if isinstance(parent, dict) else None
        if target is not None:
            target["surprise_field"] = 1
    else:
        parent[key] = value
    return doc


def _check(args: list, out: Path, source: Path, monkeypatch, capsys) -> str:
    """Accepted (the bundle loads) or refused in one line naming the file, nothing written."""
    code, _, err = _run(["import", *args, "-o", out], monkeypatch, capsys)
    if code == 0:
        load_bundle(out)
        return "accepted"
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1, err
    assert source.name in lines[0], lines[0]
    assert not out.exists(), "something was written"
    return "refused"


def _strip_none(node: Any) -> Any:
    """TOML has no null: a None is a removed key there."""
    if isinstance(node, dict):
        return {k: _strip_none(v) for k, v in node.items() if v is not None}
    if isinstance(node, list):
        return [_strip_none(v) for v in node if v is not None]
    return node


TREE_FORMATS = {
    # format: (file name, export? or None, read the text into a tree, write a tree into text)
    "pose2sim": ("Calib.toml", lambda t: tomllib.loads(t), lambda d: tomli_w.dumps(_strip_none(d))),
    "aniposelib": ("calibration.toml", lambda t: tomllib.loads(t), lambda d: tomli_w.dumps(_strip_none(d))),
    "nerfstudio": ("transforms.json", json.loads, lambda d: json.dumps(d)),
}


def _mutations(base: dict, name: str, dump, args: list[str], tmp_path: Path, monkeypatch, capsys) -> dict[str, int]:
    """Each mutation of the document ``base``, written by ``dump`` as ``name``, imported with ``args``."""
    seen = {"accepted": 0, "refused": 0}

    @HOSTILE
    @given(path=st.sampled_from(_paths(base)), kind=st.sampled_from(KINDS))
    def run(path, kind):
        with tempfile.TemporaryDirectory(dir=tmp_path) as tmp:
            source = Path(tmp) / name
            source.write_text(dump(_mutate(base, path, kind)))
            seen[_check([source, *args], Path(tmp) / "out", source, monkeypatch, capsys)] += 1

    run()
    return seen


@pytest.mark.parametrize("fmt", list(TREE_FORMATS))
def test_mutated_files_are_read_or_refused_in_one_line(small, tmp_path, fmt, monkeypatch, capsys):
    name, parse, dump = TREE_FORMATS[fmt]
    export_bundle(small, fmt, tmp_path / name)
    seen = _mutations(parse((tmp_path / name).read_text()), name, dump,
                      ["--from", fmt, *(["--unit", "m"] if fmt == "aniposelib" else [])], tmp_path, monkeypatch,
                      capsys)
    assert seen["refused"] > 5, seen


def test_mutated_kalibr_camchains_are_read_or_refused_in_one_line(tmp_path, monkeypatch, capsys):
    dome = nominal_dome("tiny", seed=1)
    base = kalibr_camchain([dome.cameras[n] for n in ("00_00", "01_01", "50_04")])
    seen = _mutations(base, "camchain.yaml", yaml.dump, ["--from", "kalibr"], tmp_path, monkeypatch, capsys)
    assert seen["refused"] > 5, seen


def test_mutated_caliscope_camera_arrays_are_read_or_refused_in_one_line(tmp_path, monkeypatch, capsys):
    dome = nominal_dome("tiny", seed=1)
    base = {"cameras": {str(i): {"cam_id": i, "size": list(c.resolution), "rotation_count": 0, "error": 0.3,
                                 "matrix": c.K.tolist(), "distortions": c.dist.tolist(),
                                 "translation": (c.t_cm / 100).tolist(),
                                 "rotation": cv2.Rodrigues(c.R)[0].ravel().tolist(),
                                 "exposure": -4, "grid_count": 12, "fisheye": False}
                        for i, c in enumerate(dome.cameras[n] for n in ("00_00", "01_01", "50_04"))}}
    seen = _mutations(base, "camera_array.toml", lambda d: tomli_w.dumps(_strip_none(d)), ["--from", "caliscope"],
                      tmp_path, monkeypatch, capsys)
    assert seen["refused"] > 5, seen


def test_mutated_qualisys_files_are_read_or_refused_in_one_line(tmp_path, monkeypatch, capsys):
    import xml.etree.ElementTree as ET

    root = ET.fromstring(QCA.read_bytes())
    places = [(i, child, attr) for i, cam in enumerate(root.findall("cameras/camera"))
              for child in ("", "fov_video", "intrinsic", "transform")
              for attr in (cam.find(child) if child else cam).attrib]
    seen = {"accepted": 0, "refused": 0}

    @HOSTILE
    @given(place=st.sampled_from(places), value=st.sampled_from(["abc", "nan", "inf", "1e400", "", "-1", "0", None]))
    def run(place, value):
        i, child, attr = place
        tree = ET.fromstring(QCA.read_bytes())
        cam = tree.findall("cameras/camera")[i]
        element = cam.find(child) if child else cam
        if value is None:
            del element.attrib[attr]
        else:
            element.set(attr, value)
        with tempfile.TemporaryDirectory(dir=tmp_path) as tmp:
            source = Path(tmp) / "Calib.qca.txt"
            source.write_bytes(ET.tostring(tree))
            seen[_check([source, "--from", "qualisys"], Path(tmp) / "out", source, monkeypatch, capsys)] += 1

    run()
    assert seen["refused"] > 5, seen


def test_mutated_easymocap_files_are_read_or_refused_in_one_line(small, tmp_path, monkeypatch, capsys):
    export_bundle(small, "easymocap", tmp_path / "emc")
    entries = {}
    for f in ("intri.yml", "extri.yml"):
        fs = cv2.FileStorage(str(tmp_path / "emc" / f), cv2.FILE_STORAGE_READ)
        entries[f] = {k: (fs.getNode(k).mat() if fs.getNode(k).isMap() else fs.getNode(k).real()
                          if fs.getNode(k).isInt() else None) for k in fs.root().keys() if k != "names"}
        fs.release()
    names = ["00_00", "01_01", "50_04"]
    places = [(f, k) for f in entries for k in entries[f]]

    def write(folder: Path, f: str, values: dict) -> None:
        fs = cv2.FileStorage(str(folder / f), cv2.FILE_STORAGE_WRITE)
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for n in names:
            fs.write("", n)
        fs.endWriteStruct()
        for k, v in values.items():
            if isinstance(v, np.ndarray):
                fs.write(k, v)
            elif isinstance(v, str):
                fs.write(k, v)
            elif v is not None:
                fs.write(k, int(v) if float(v).is_integer() and abs(v) < 2**31 else float(v))
        fs.release()

    seen = {"accepted": 0, "refused": 0}

    @HOSTILE
    @given(place=st.sampled_from(places), kind=st.sampled_from(["string", "nan", "inf", "huge", "zero", "remove",
                                                                "shape", "int"]))
    def run(place, kind):
        f, key = place
        values = {g: dict(v) for g, v in entries.items()}
        old = values[f][key]
        if kind == "remove":
            del values[f][key]
        elif kind == "string":
            values[f][key] = "1.5"
        elif kind == "int":
            values[f][key] = 7
        elif kind == "shape":
            values[f][key] = np.ones((2, 2))
        elif isinstance(old, np.ndarray):
            bad = old.astype(float).copy()
            bad.flat[0] = {"nan": np.nan, "inf": np.inf, "huge": 1e300, "zero": 0.0}[kind]
            values[f][key] = bad
        else:
            values[f][key] = {"nan": math.nan, "inf": math.inf, "huge": 1e300, "zero": 0}[kind]
        with tempfile.TemporaryDirectory(dir=tmp_path) as tmp:
            folder = Path(tmp) / "emc"
            folder.mkdir()
            for g in values:
                write(folder, g, values[g])
            code, _, err = _run(["import", folder, "--from", "easymocap", "-o", Path(tmp) / "out"], monkeypatch,
                                capsys)
            if code == 0:
                load_bundle(Path(tmp) / "out")
                seen["accepted"] += 1
                return
            lines = err.strip().splitlines()
            assert code == 1 and len(lines) == 1, err
            assert ".yml" in lines[0] or "emc" in lines[0], lines[0]
            assert not (Path(tmp) / "out").exists()
            seen["refused"] += 1

    run()
    assert seen["refused"] > 5, seen


def test_mutated_colmap_text_models_are_read_or_refused_in_one_line(small, tmp_path, monkeypatch, capsys):
    export_bundle(small, "colmap", tmp_path / "model", ExportOptions(binary=False))
    files = {f: (tmp_path / "model" / f).read_text().splitlines() for f in ("cameras.txt", "images.txt")}
    places = [(f, i, j) for f, lines in files.items() for i, line in enumerate(lines) if not line.startswith("#")
              for j in range(len(line.split()))]
    seen = {"accepted": 0, "refused": 0}

    @HOSTILE
    @given(place=st.sampled_from(places), value=st.sampled_from(["abc", "nan", "inf", "1e400", "-5", "0",
                                                                  "FISHEYE", ""]))
    def run(place, value):
        f, i, j = place
        with tempfile.TemporaryDirectory(dir=tmp_path) as tmp:
            model = Path(tmp) / "model"
            model.mkdir()
            for g in (tmp_path / "model").iterdir():
                (model / g.name).write_text(g.read_text())
            lines = list(files[f])
            tokens = lines[i].split()
            tokens[j] = value
            lines[i] = " ".join(tokens)
            (model / f).write_text("\n".join(lines) + "\n")
            seen[_check([model, "--from", "colmap", "--unit", "m"], Path(tmp) / "out", model, monkeypatch,
                        capsys)] += 1

    run()
    assert seen["refused"] > 5, seen


# ----------------------------------------------------------------------------------- situations found by hand
def test_our_aniposelib_file_is_not_read_as_pose2sim_metres(small, tmp_path, monkeypatch, capsys):
    """Our calibration.toml records unit = "mm" and who wrote it: read as Pose2Sim (metres) it made a dome 5 km wide
    with exit 0. Refused in one line naming the file and what to give instead."""
    export_bundle(small, "aniposelib", tmp_path / "calibration.toml")
    code, _, err = _run(["import", tmp_path / "calibration.toml", "--from", "pose2sim", "-o", tmp_path / "out"],
                        monkeypatch, capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "calibration.toml: metadata:" in err and "--from aniposelib" in err
    assert not (tmp_path / "out").exists()


def test_import_onto_a_session_bundle_folder_deletes_nothing(small, tmp_path, monkeypatch, capsys):
    """`import -o` onto a calibration session's bundle folder used to replace it whole: the user's notes, report/,
    the sync and Kinect tables gone. Refused, naming what the folder holds; an earlier import's folder (only its
    calibration file) is still replaced."""
    session = tmp_path / "session_bundle"
    write_bundle(load_bundle(small), session)
    (session / "report").mkdir()
    (session / "report" / "report.json").write_text("{}")
    (session / "notes.txt").write_text("mine")
    (session / "synctables_small.json").write_text("{}")
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    export_bundle(small, "pose2sim", tmp_path / "x" / "Calib.toml")
    code, _, err = _run(["import", tmp_path / "x" / "Calib.toml", "--from", "pose2sim", "-o", session], monkeypatch,
                        capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "holds notes.txt" in err and "choose another path" in err
    after = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")
                   if "x" not in p.relative_to(tmp_path).parts)
    assert after == before and (session / "notes.txt").read_text() == "mine"
    code, _, err = _run(["import", tmp_path / "x" / "Calib.toml", "--from", "pose2sim", "-o", tmp_path / "first"],
                        monkeypatch, capsys)
    assert code == 0, err
    code, _, err = _run(["import", tmp_path / "x" / "Calib.toml", "--from", "pose2sim", "-o", tmp_path / "first",
                         "--seq", "again"], monkeypatch, capsys)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "first").iterdir()) == [RECORD, "calibration_again.json"]


@pytest.mark.parametrize("seq", ["a/b", "../up", ".hidden", "tab\there"])
def test_a_sequence_name_that_is_no_file_name_is_named_as_typed(small, tmp_path, seq, monkeypatch, capsys):
    """`import --seq a/b` answered with a hidden staging path; now with what the user typed, before any work."""
    export_bundle(small, "pose2sim", tmp_path / "Calib.toml")
    code, _, err = _run(["import", tmp_path / "Calib.toml", "--from", "pose2sim", "-o", tmp_path / "out",
                         "--seq", seq], monkeypatch, capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert f"--seq {seq!r}" in err and ".new." not in err and "staging" not in err
    assert not (tmp_path / "out").exists()


def _opencap_pickle(tree: dict) -> bytes:
    """An OpenCap camera file from a tree: numeric leaves as numpy arrays (OpenCap's), any other value as it is."""
    import pickle

    def array(v):
        try:
            a = np.array(v)
        except ValueError:  # ragged
            return v
        return a if a.dtype.kind in "biuf" else v

    return pickle.dumps({k: array(v) for k, v in tree.items()} if isinstance(tree, dict) else tree)


def test_mutated_opencap_pickles_are_read_or_refused_in_one_line(small, tmp_path, monkeypatch, capsys):
    cam = load_bundle(small).cameras["00_00"]
    base = {"imageSize": [[cam.resolution[1]], [cam.resolution[0]]], "intrinsicMat": cam.K.tolist(),
            "distortion": [cam.dist.tolist()], "rotation": cam.R.tolist(), "translation": (cam.t_cm * 10).tolist()}
    seen = {"accepted": 0, "refused": 0}

    @HOSTILE
    @given(path=st.sampled_from(_paths(base)), kind=st.sampled_from(KINDS))
    def run(path, kind):
        with tempfile.TemporaryDirectory(dir=tmp_path) as tmp:
            folder = Path(tmp) / "opencap"
            folder.mkdir()
            (folder / "cam0.pickle").write_bytes(_opencap_pickle(_mutate(base, path, kind)))
            seen[_check([folder, "--from", "opencap"], Path(tmp) / "out", folder / "cam0.pickle", monkeypatch,
                        capsys)] += 1

    run()
    assert seen["refused"] > 5, seen


def test_a_value_a_reader_lets_through_is_refused_naming_the_source(tmp_path, monkeypatch, capsys):
    """bioCV's reader takes K as 9 numbers; one whose last row is not [0, 0, 1] used to be refused by the bundle
    writer naming the OUTPUT file. Any such value is now refused naming the file read, nothing written."""
    folder = tmp_path / "biocv"
    folder.mkdir()
    (folder / "00.calib").write_text("1920\n1080\n1000 0 960\n0 1000 540\n0 0 2\n\n1 0 0 0\n0 1 0 0\n0 0 1 1000\n"
                                     "0 0 0 1\n\n0 0 0 0\n")
    assert _check([folder, "--from", "biocv"], tmp_path / "out", folder, monkeypatch, capsys) == "refused"
