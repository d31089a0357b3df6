"""Issue 50, item 1: the told situations of "whose file is it". Each output place below holds what someone else
wrote, under the names our commands write; today's main replaced it (exit 0) because it decided "ours" by name.
Each is now refused before any work, in one line naming it, and nothing changes. Only the command line is used, so
these run against any version."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import pytest


def _tree(root: Path) -> dict[str, str]:
    out = {}
    for here, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(here) / name
            out[str(p.relative_to(root))] = (("link:" + os.readlink(p)) if p.is_symlink() else "dir" if p.is_dir()
                                             else hashlib.sha256(p.read_bytes()).hexdigest())
    return out


def _refused(done, *named: str) -> str:
    assert done.returncode == 1, done.stdout + done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.startswith("dome-calib: error:")]
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert all(n in lines[0] for n in named), lines[0]
    return lines[0]


def _panoptic_scene(univ_time_ms: float) -> str:
    """A body3DScene file as the Panoptic dataset ships it (hdPose3d_stage1_coco19): not ours, same name."""
    joints = [v for j in range(19) for v in (10.0 * j, -100.0 - j, 5.0, 0.9)]
    return json.dumps({"version": 0.7, "univTime": univ_time_ms, "fpsType": "hd_29_97",
                       "bodies": [{"id": 0, "joints19": joints}]})


def _reconstruct(cli, i, out):
    return cli("reconstruct", i.det, "--bundle", i.bundle, "--body-model", "BODY_25", "-o", out)


def test_reconstruct_onto_the_panoptic_ground_truth_folder_is_refused_and_kept(hostile_inputs, tmp_path,
                                                                               dome_calib_cli):
    gt = tmp_path / "171204_pose1" / "hdPose3d_stage1_coco19"
    gt.mkdir(parents=True)
    for k in range(3):
        (gt / f"body3DScene_{k:08d}.json").write_text(_panoptic_scene(1000.0 + 33.4 * k))
    before = _tree(tmp_path)
    _refused(_reconstruct(dome_calib_cli, hostile_inputs, gt), str(gt), "body3DScene_00000000.json")
    assert _tree(tmp_path) == before


def test_reconstruct_onto_a_folder_holding_someones_cameras_json_is_refused(hostile_inputs, tmp_path,
                                                                            dome_calib_cli):
    out = tmp_path / "rig"
    out.mkdir()
    (out / "cameras.json").write_text('{"cam0": {"focal": 1200}}')  # another tool's camera file
    before = _tree(tmp_path)
    _refused(_reconstruct(dome_calib_cli, hostile_inputs, out), "cameras.json")
    assert _tree(tmp_path) == before


def test_a_rerun_of_reconstruct_replaces_its_own_output(hostile_inputs, tmp_path, dome_calib_cli):
    for _ in range(2):
        done = _reconstruct(dome_calib_cli, hostile_inputs, tmp_path / "people")
        assert done.returncode == 0, done.stderr
    edited = sorted((tmp_path / "people").glob("body3DScene_*.json"))[0]
    edited.write_text("edited by hand")  # changed since dome-calib wrote it: no longer provably ours
    _refused(_reconstruct(dome_calib_cli, hostile_inputs, tmp_path / "people"), edited.name, "changed since")


def test_export_colmap_over_a_real_colmap_reconstruction_is_refused(hostile_inputs, tmp_path, dome_calib_cli):
    ours = tmp_path / "ours"
    assert dome_calib_cli("export", hostile_inputs.bundle, "--to", "colmap", "-o", ours).returncode == 0
    rec = pycolmap.Reconstruction(str(ours))  # a reconstruction COLMAP made: its own files, with 3D points
    rec.add_point3D(np.array([0.0, 0.0, 1.0]), pycolmap.Track(), np.array([255, 0, 0], dtype=np.uint8))
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    rec.write(str(model))
    assert pycolmap.Reconstruction(str(model)).num_points3D() == 1
    before = _tree(tmp_path / "sparse")
    _refused(dome_calib_cli("export", hostile_inputs.bundle, "--to", "colmap", "-o", model), str(model))
    assert _tree(tmp_path / "sparse") == before


@pytest.mark.parametrize("which", ["the bundle's calibration", "a body3DScene file", "a detection file"])
def test_people_page_onto_its_own_inputs_is_refused(hostile_inputs, tmp_path, dome_calib_cli, which):
    i = hostile_inputs
    root = tmp_path / "in"
    shutil.copytree(i.root, root, symlinks=True)
    bundle, people, det = root / "bundle", root / "people", root / "det"
    target = {"the bundle's calibration": bundle / "calibration_test.json",
              "a body3DScene file": sorted(people.glob("body3DScene_*.json"))[0],
              "a detection file": sorted(p for p in det.rglob("*.json"))[0]}[which]
    before = _tree(root)
    done = dome_calib_cli("people-page", people, "-o", target, "--bundle", bundle, "--detections", det,
                          "--body-model", "BODY_25")
    _refused(done, str(target))
    assert _tree(root) == before


@pytest.mark.parametrize("theirs", ["people.c3d", "person0.trc"])
def test_export_people_onto_a_folder_of_the_users_own_files_is_refused(hostile_inputs, tmp_path, dome_calib_cli,
                                                                       theirs):
    out = tmp_path / "mocap"
    out.mkdir()
    (out / theirs).write_bytes(b"the user's own capture, not ours")
    before = _tree(tmp_path)
    _refused(dome_calib_cli("export-people", hostile_inputs.people, "--to", "trc", "-o", out), theirs)
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("what", ["symlink", "file"])
def test_report_onto_a_symlink_or_a_file_is_refused_before_any_work(hostile_inputs, tmp_path, dome_calib_cli,
                                                                     what, monkeypatch):
    bundle = tmp_path / "bundle"
    shutil.copytree(hostile_inputs.bundle, bundle)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "notes.txt").write_text("mine")
    if what == "symlink":
        (bundle / "report").symlink_to(elsewhere, target_is_directory=True)
    else:
        (bundle / "report").write_text("a file named report")
    import dome_calib.report.build as build

    monkeypatch.setattr(build, "build_report", lambda *a, **k: pytest.fail("the report was built first"))
    before = _tree(tmp_path)
    _refused(dome_calib_cli("report", bundle), str(bundle / "report"))
    assert _tree(tmp_path) == before  # no hidden staging folder left, the link and its folder as they were
