"""`dome-calib export-people`: the demo's synthetic group (its truth, and reconstructed from its synthetic
detections) and the real Pose2Sim capture written as TRC, C3D and BVH and read back by each format's own tools (OpenSim's TRC reader, Pose2Sim's `read_trc`, ezc3d, the `c3d` package,
bvhio's forward kinematics): every joint within 1e-3 cm of ours, with the axes and units each file states, missing
joints missing, ids kept."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dome_calib.skeletons.bvh import constant_bone_body
from dome_calib.skeletons.joints import (JOINTS15, JOINTS19, MARKER, Z_UP_FROM_PANOPTIC,
                                         marker_names, y_up_axes, z_up_axes)
from dome_calib.skeletons.scenes import read_people
from dome_calib.ownership import RECORD
from dome_calib.skeletons.trc import fill_gaps, trc_name

from .skeletons_helpers import (bvhio_positions, c3d_package_read, chain_present, demo_group_reconstructed,
                                demo_group_scenes, ezc3d_read, opensim_trc, ours_dense, pose2sim_trc,
                                real_capture_scenes, write_scenes)

TOL_CM = 1e-3


@pytest.fixture(scope="module")
def group(tmp_path_factory):
    return demo_group_scenes(tmp_path_factory.mktemp("group") / "people")


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    return real_capture_scenes(tmp_path_factory.mktemp("real"))


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory):
    return demo_group_reconstructed(tmp_path_factory) / "people"


@pytest.fixture(scope="module")
def group_feet(tmp_path_factory):
    return demo_group_scenes(tmp_path_factory.mktemp("group_feet") / "people", feet=True)


@pytest.fixture(params=["group", "group_feet", "reconstructed", "real"])
def dataset(request):
    folder = request.getfixturevalue(request.param)
    return request.param, folder, read_people(folder)


def _export(dome_calib_cli, folder, fmt, out, *extra):
    run = dome_calib_cli("export-people", folder, "--to", fmt, "-o", out, *extra)
    assert run.returncode == 0, run.stderr
    return run


def test_trc_read_by_opensim_and_pose2sim(dataset, dome_calib_cli, tmp_path):
    name, folder, people = dataset
    _export(dome_calib_cli, folder, "trc", tmp_path / "trc", "--fill-gaps", "0")  # every missing joint missing
    files = sorted(p.name for p in (tmp_path / "trc").iterdir() if p.name != RECORD)
    trial = Path(folder).resolve().name  # one file per person, ids kept, in Pose2Sim's multi-person names
    names = {pid: trc_name(trial, pid, int(people.frames[t.rows[0]]), int(people.frames[t.rows[-1]]))
             for pid, t in people.tracks.items()}
    assert files == sorted(names.values())
    markers = marker_names(people)
    for pid, track in people.tracks.items():
        path = tmp_path / "trc" / names[pid]
        osim, p2s = opensim_trc(path), pose2sim_trc(path)
        assert osim["markers"] == markers == p2s["markers"]
        assert osim["units"] == "m" and osim["rate"] == pytest.approx(float(people.fps))
        span = people.frames[track.rows[0]:track.rows[-1] + 1]  # every file of the person's span
        np.testing.assert_array_equal(p2s["frames"], span)  # frame numbers as Pose2Sim 0.10 writes them
        t_s = (span - people.frames[0]) / float(people.fps)  # steps of 1 / DataRate
        np.testing.assert_allclose(osim["times_s"], t_s, atol=1e-6)
        ours_m = ours_dense(people, pid, span, y_up_axes(people), 0.01)  # an imported lab's own axes (real)
        for got in (osim["X"], p2s["X"]):
            np.testing.assert_array_equal(np.isnan(got), np.isnan(ours_m))  # missing is missing, nothing else
            assert np.nanmax(np.abs(got - ours_m)) * 100.0 < TOL_CM
    if name in ("group", "group_feet"):  # joints written as not reconstructed (c = -1) came back missing above
        assert sum(np.isnan(t.X_cm).any() for t in people.tracks.values()) == len(people.tracks)


def test_c3d_read_by_ezc3d_and_the_c3d_package(dataset, dome_calib_cli, tmp_path):
    _, folder, people = dataset
    _export(dome_calib_cli, folder, "c3d", tmp_path / "c3d")
    path = tmp_path / "c3d" / "people.c3d"
    written = sorted(p.name for p in (tmp_path / "c3d").iterdir() if p.name != RECORD)
    assert written == ["people.c3d"]  # one file per capture
    ez, pkg = ezc3d_read(path), c3d_package_read(path)
    ids = list(people.tracks)
    labels = [f"P{pid}:{m}" for pid in ids for m in marker_names(people)]
    assert ez["labels"] == labels == pkg["labels"]
    assert ez["subjects"] == [f"P{pid}" for pid in ids] and ez["units"] == "mm" and ez["y_screen"] == "+Z"
    assert ez["rate"] == pytest.approx(float(people.fps))
    frames = np.arange(people.frames[0], people.frames[-1] + 1)
    assert ez["first_frame"] == frames[0] and pkg["first_frame"] == frames[0] + 1  # C3D counts from 1
    ours_mm = np.concatenate([ours_dense(people, pid, frames, z_up_axes(people), 10.0) for pid in ids], axis=1)
    np.testing.assert_array_equal(np.isnan(ez["X"]), np.isnan(ours_mm))
    assert np.nanmax(np.abs(ez["X"] - ours_mm)) / 10.0 < TOL_CM
    missing = np.isnan(ours_mm).any(-1)
    assert np.all(pkg["residual"][missing] == -1) and np.all(pkg["residual"][~missing] == 0)  # C3D's missing
    assert np.max(np.abs(pkg["X"][~missing] - ours_mm[~missing])) / 10.0 < TOL_CM


def test_bvh_read_by_bvhio(dataset, dome_calib_cli, tmp_path):
    """bvhio's forward kinematics puts every joint where the person's constant-bone skeleton is (1e-3 cm); where the
    whole chain is reconstructed that is our joint up to the bone's length difference from its median: nothing on
    the synthetic group (its bones are constant), the real reconstruction's stated below."""
    name, folder, people = dataset
    _export(dome_calib_cli, folder, "bvh", tmp_path / "bvh")
    written = sorted(p.name for p in (tmp_path / "bvh").iterdir() if p.name != RECORD)
    assert written == sorted(f"person{i}.bvh" for i in people.tracks)
    names = marker_names(people)
    gaps = []
    for pid, track in people.tracks.items():
        frame_time, got_m = bvhio_positions(tmp_path / "bvh" / f"person{pid}.bvh", names)
        got = got_m * 100.0  # metres by default
        assert frame_time == pytest.approx(1.0 / float(people.fps), rel=1e-8)
        first, reference = constant_bone_body(people, track, track.confidence >= 0)
        assert first == people.frames[track.rows[0]] and len(got) == people.frames[track.rows[-1]] - first + 1
        assert np.max(np.abs(got - reference)) < TOL_CM
        ours = ours_dense(people, pid, np.arange(first, first + len(got)), y_up_axes(people), 1.0)
        held = chain_present(people, ours)
        gaps.append(np.linalg.norm(got - ours, axis=-1)[held])
    gaps = np.concatenate(gaps)
    if name in ("group", "group_feet"):  # constant bones, feet too
        assert np.max(gaps) < TOL_CM
    else:  # reconstructions: bone lengths vary frame to frame
        print(json.dumps({f"bvh_vs_ours_{name}_cm": {"median": round(float(np.median(gaps)), 2),
                                                  "p95": round(float(np.percentile(gaps, 95)), 2)}}))
        assert np.median(gaps) < 5.0


def test_ids_min_confidence_and_fps(group, dome_calib_cli, tmp_path):
    people = read_people(group)
    ids = list(people.tracks)[:2]
    _export(dome_calib_cli, group, "trc", tmp_path / "some", "--ids", ",".join(map(str, ids)), "--min-confidence",
            "0.95", "--fps", "30000/1001")
    files = sorted(p for p in (tmp_path / "some").iterdir() if p.name != RECORD)
    assert [p.name.split("_")[-2] for p in files] == [f"P{i}" for i in sorted(ids)]
    got = opensim_trc(files[0])
    assert np.isnan(got["X"]).all() and got["rate"] == pytest.approx(30000 / 1001)  # every c is 0.9 < 0.95
    np.testing.assert_allclose(np.diff(got["times_s"]), 1001 / 30000, atol=1e-6)  # the steps are the rate's
    run = dome_calib_cli("export-people", group, "--to", "bvh", "-o", tmp_path / "none", "--ids", "99")
    assert run.returncode == 1 and "no person 99" in run.stderr and not (tmp_path / "none").exists()


def test_c3d_frame_numbers_beyond_the_headers_16_bits(dome_calib_cli, tmp_path):
    """Frame 100,000 (over an hour at 25 fps): C3D's header cannot hold it; TRIAL:ACTUAL_START_FIELD and
    ACTUAL_END_FIELD do (two 16-bit words, low first: C3D counts from 1, so 100,001 and 100,004). The c3d package
    reads the end as that; its first frame is one less (c3d 0.6.0's ``first_frame`` weighs the high word 65535, its
    ``last_frame`` 65536), so it numbers our four records one less and reads a fifth past them."""
    import ezc3d

    X = np.random.default_rng(3).uniform(-50, 50, (3, 19, 3))
    folder = write_scenes(tmp_path / "long", [100000, 100001, 100003], [0.0, 40.0, 120.0],
                          [{2: np.c_[X[k], np.full(19, 0.5)]} for k in range(3)])
    _export(dome_calib_cli, folder, "c3d", tmp_path / "c3d")
    trial = ezc3d.c3d(str(tmp_path / "c3d" / "people.c3d"))["parameters"]["TRIAL"]
    words = {k: [int(w) & 0xFFFF for w in trial[k]["value"]] for k in ("ACTUAL_START_FIELD", "ACTUAL_END_FIELD")}
    assert {k: w[0] + 65536 * w[1] for k, w in words.items()} == {"ACTUAL_START_FIELD": 100001,
                                                                  "ACTUAL_END_FIELD": 100004}
    pkg = c3d_package_read(tmp_path / "c3d" / "people.c3d")
    assert pkg["frames"][-1] == 100004  # it numbers from 100000: the records are ours, each numbered one less
    residual, got = pkg["residual"][:4], pkg["X"][:4]
    assert np.all(residual[2] == -1) and np.all(residual[[0, 1, 3]] == 0)  # frame 100002: no file
    np.testing.assert_allclose(got[[0, 1, 3]], X @ Z_UP_FROM_PANOPTIC.T * 10.0, atol=1e-2)


def test_joints15_files_of_the_older_panoptic_layout(dome_calib_cli, tmp_path):
    """The "mpi15" layout (head top in place of the nose) exports with Pose2Sim's "Head" marker."""
    rng = np.random.default_rng(1)
    X = rng.uniform(-100, 100, (3, 15, 3))
    bodies = [{4: np.concatenate([X[k], np.full((15, 1), 0.7)], axis=1)} for k in range(3)]
    folder = write_scenes(tmp_path / "old", [0, 1, 2], [0.0, 40.0, 80.0], bodies, layout="joints15")
    people = read_people(folder)
    assert people.joints == JOINTS15 and people.joints[:1] + people.joints[2:] == JOINTS19[:1] + JOINTS19[2:15]
    _export(dome_calib_cli, folder, "c3d", tmp_path / "c3d")
    ez = ezc3d_read(tmp_path / "c3d" / "people.c3d")
    assert ez["labels"][1] == "P4:Head"
    np.testing.assert_allclose(ez["X"][:, :15], X @ Z_UP_FROM_PANOPTIC.T * 10.0, atol=1e-2)
    _export(dome_calib_cli, folder, "bvh", tmp_path / "bvh")
    _, got_m = bvhio_positions(tmp_path / "bvh" / "person4.bvh", [MARKER[j] for j in JOINTS15])
    got = got_m * 100.0  # metres
    first, ref = constant_bone_body(people, people.tracks[4], people.tracks[4].confidence >= 0)
    assert np.max(np.abs(got - ref)) < TOL_CM


def test_export_refuses_a_folder_it_did_not_write_and_leaves_it(group, dome_calib_cli, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    run = dome_calib_cli("export-people", group, "--to", "trc", "-o", out)
    assert run.returncode == 1 and "notes.txt" in run.stderr and len(run.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    _export(dome_calib_cli, group, "trc", tmp_path / "again")
    _export(dome_calib_cli, group, "bvh", tmp_path / "again")  # an earlier export's folder is replaced whole
    assert all(p.suffix == ".bvh" for p in (tmp_path / "again").iterdir() if p.name != RECORD)


def test_trc_header_is_laid_out_as_pose2sims_writer(group, dome_calib_cli, tmp_path):
    """Lines 4 and 5 as Pose2Sim 0.10.49's make_trc (Pose2Sim/triangulation.py) writes them: its marker
    augmentation inserts ``Hip`` by replacing line 4's closing ``\\t\\t\\t``, which a line without them fails in
    silence (the augmentation then died on 60 columns for 57 names); and Pose2Sim's own add_neck_hip_data does it."""
    import pandas as pd
    from Pose2Sim.common import add_neck_hip_data, read_trc

    _export(dome_calib_cli, group, "trc", tmp_path / "trc")
    path = sorted(p for p in (tmp_path / "trc").iterdir() if p.name != RECORD)[0]
    header = path.read_text().splitlines(keepends=True)[:5]
    people = read_people(group)
    names = marker_names(people)
    assert header[3] == "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t\t\n"  # make_trc's line 4
    assert header[4] == "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(len(names))) + "\t\n"
    import opensim

    table = opensim.TimeSeriesTableVec3()  # OpenSim 4.6's own writer ends lines 4 and 5 the same way
    table.setColumnLabels(names)
    table.appendRow(0.0, opensim.RowVectorVec3(len(names), opensim.Vec3(1, 2, 3)))
    table.addTableMetaDataString("DataRate", "25")
    table.addTableMetaDataString("Units", "m")
    opensim.TRCFileAdapter.write(table, str(tmp_path / "opensim.trc"))
    assert (tmp_path / "opensim.trc").read_text().splitlines(keepends=True)[3:5] == header[3:5]
    data, _, _, markers, head = read_trc(str(path))
    data, markers, head = add_neck_hip_data(data, [m for m in markers if m != "Hip"], list(head))
    assert [m.strip() for m in head[3].split("\t")[2::3] if m.strip()] == markers  # the header names Hip too
    assert markers[-1] == "Hip" and len(markers) == len(names) + 1
    assert isinstance(data, pd.DataFrame) and data.shape[1] == 3 * len(markers)


def test_fill_gaps_fills_as_pose2sims_triangulation_and_no_more():
    """Inside a marker's track a gap of at most N frames is linear between its ends, at the start or end the
    nearest value is held, a longer gap and a marker never seen stay missing."""
    X = np.full((12, 3, 3), np.nan)
    X[2:5, 0] = [[0, 0, 0], [1, 1, 1], [2, 2, 2]]
    X[7:10, 0] = [[7, 7, 7], [8, 8, 8], [9, 9, 9]]  # rows 5, 6 missing (2), 0, 1 and 10, 11 at the ends
    X[:, 1] = np.arange(12)[:, None]
    X[1:9, 1] = np.nan  # 8 rows missing
    got = fill_gaps(X, 2)
    np.testing.assert_allclose(got[:, 0, 0], [0, 0, 0, 1, 2, 2 + 5 / 3, 2 + 10 / 3, 7, 8, 9, 9, 9])
    assert np.isnan(got[1:9, 1]).all() and np.isnan(got[:, 2]).all()  # 8 > 2 rows; never seen
    assert not np.isnan(fill_gaps(X, 8)[:, 1]).any() and np.isnan(fill_gaps(X, 0)).sum() == np.isnan(X).sum()


_BLENDER_BVH = """
import json, sys
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=sys.argv[1])
(arm,) = [o for o in bpy.data.objects if o.type == "ARMATURE"]
scene = bpy.context.scene
out = {}
for k in json.loads(sys.argv[3]):
    scene.frame_set(scene.frame_start + k)
    out[k] = [tuple(arm.matrix_world @ arm.pose.bones[n].head) for n in json.loads(sys.argv[2])]
print(json.dumps(out))
"""


def test_bvh_is_at_true_size_in_blenders_importer(real, dome_calib_cli, tmp_path):
    """Blender's own BVH importer (bpy 5.0, ``import_anim.bvh`` at its default scale, one unit a metre; in a process
    of its own) puts the real participant's joints where ours are, in metres (Blender's z up is the file's y): a
    person ~1.7 m tall, not the 163 m a file in cm made; ``--unit cm`` writes 100 x the lengths."""
    import subprocess
    import sys

    people = read_people(real)
    (pid, track), = people.tracks.items()
    _export(dome_calib_cli, real, "bvh", tmp_path / "m")
    _export(dome_calib_cli, real, "bvh", tmp_path / "cm", "--unit", "cm")
    first, reference_cm = constant_bone_body(people, track, track.confidence >= 0)
    names = marker_names(people)
    frames = [0, len(reference_cm) // 2]
    run = subprocess.run([sys.executable, "-c", _BLENDER_BVH, str(tmp_path / "m" / f"person{pid}.bvh"),
                          json.dumps(names), json.dumps(frames)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    heads = json.loads(run.stdout.strip().splitlines()[-1])
    for k in frames:
        blender = np.array(heads[str(k)])
        file_axes = blender[:, [0, 2, 1]] * [1, 1, -1]  # Blender (x, y, z) = the file's (x, -z, y)
        np.testing.assert_allclose(file_axes, reference_cm[k] / 100.0, atol=1e-4)
        assert 1.2 < np.ptp(blender[:, 2]) < 2.2  # the participant's height in Blender, metres
    m_text = (tmp_path / "m" / f"person{pid}.bvh").read_text().split()
    cm_text = (tmp_path / "cm" / f"person{pid}.bvh").read_text().split()
    at = m_text.index("OFFSET", m_text.index("OFFSET") + 1)  # the first joint's offset below the root
    np.testing.assert_allclose(np.array(cm_text[at + 1:at + 4], float), 100 * np.array(m_text[at + 1:at + 4], float),
                               atol=1e-4)
