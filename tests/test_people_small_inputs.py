"""Issue 50: the smallest inputs a user has (a stereo rig, one snapshot, a window without a measured bone) give the
people seen in them, through the body over time and per frame alike. Every test here failed on main at aaf6910:
`ValueError: cannot reshape array of size 0` in temporal._sum_by, or "no person reconstructed", exit 0."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from dome_calib.arrays import per_row
from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.recon.people.run import PeopleOptions
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.people.tracking import TrackingOptions, track_bodies
from dome_calib.body3d_scene import read_scene
from dome_calib.synth.detector import write_openpose_folder

from .people_helpers import group_detections
from .recon_helpers import real_bundle
from .test_people_temporal import _run, rig  # noqa: F401  (rig: a fixture)

ROOT = Path(__file__).resolve().parents[1]


def test_per_row_holds_for_every_size():
    for shape in [(0,), (0, 3), (0, 3, 3), (4, 0), (2, 19, 3), (5,)]:
        a = np.zeros(shape)
        assert per_row(a).shape == (shape[0], int(np.prod(shape[1:])))


def test_no_reshape_infers_a_row_size():
    """The rule behind the crash, held for the whole code: ``reshape(len(a), -1)`` cannot infer from an empty a."""
    pattern = re.compile(r"reshape\(\s*len\([^()]*\)\s*,\s*-1\s*\)")
    found = [f"{p.relative_to(ROOT)}:{i}" for pkg in ("dome_calib", "projector", "timecode")
             for p in sorted((ROOT / pkg).rglob("*.py")) if p.name != "arrays.py"
             for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert found == [], f"use dome_calib.arrays.per_row: {found}"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Two HD cameras of the real dome 52 degrees apart, 2 people over 12 frames (COCO-18, one shared index)."""
    root = tmp_path_factory.mktemp("tiny")
    full = real_bundle(kinect=False, sync=False)
    bundle = Bundle(seq=full.seq, cameras={n: full.cameras[n] for n in ("00_02", "00_10", "00_06", "00_22")},
                    calib_data_source=full.calib_data_source)
    people, _ = group_detections(bundle, sorted(bundle.cameras), 2, seed=5, shared_frames=np.arange(40, 52))
    return root, bundle, people


def _folder(root: Path, bundle: Bundle, people, cameras, frames) -> Path:
    where = root / f"{'_'.join(cameras)}-{len(frames)}"
    if not where.exists():
        write_bundle(Bundle(seq=bundle.seq, cameras={n: bundle.cameras[n] for n in cameras},
                            calib_data_source=bundle.calib_data_source), where / "bundle")
        write_openpose_folder(where / "det", {c: {f: people[c][f] for f in frames} for c in cameras},
                              body_model="COCO_18")
    return where


def _people(out: Path) -> list[int]:
    return [len(read_scene(f)[1]) for f in sorted(out.glob("body3DScene_*.json"))]


@pytest.mark.parametrize("per_frame", [False, True])
def test_a_stereo_rig_gives_its_people(tiny, per_frame, dome_calib_cli, tmp_path):
    """Before: with the body over time, `ValueError` in temporal._sum_by (no bone is measured by 2 cameras:
    bone_min_views is 3); --per-frame worked."""
    root, bundle, people = tiny
    where = _folder(root, bundle, people, ["00_02", "00_10"], range(40, 52))
    out = dome_calib_cli("reconstruct", str(where / "det"), "--bundle", str(where / "bundle"), "-o",
                         str(tmp_path / "out"), "--min-views", "2", "--fps", "30",
                         *(["--per-frame"] if per_frame else []))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "2 people" in out.stdout
    assert sum(_people(tmp_path / "out")) >= 20


@pytest.mark.parametrize("n_times", [1, 2])
@pytest.mark.parametrize("per_frame", [False, True])
def test_one_and_two_times_give_the_people_seen(tiny, n_times, per_frame, dome_calib_cli, tmp_path):
    """Before: "no person reconstructed: ... none was tracked over 3 times", exit 0."""
    root, bundle, people = tiny
    where = _folder(root, bundle, people, ["00_02", "00_06", "00_10", "00_22"], range(40, 40 + n_times))
    out = dome_calib_cli("reconstruct", str(where / "det"), "--bundle", str(where / "bundle"), "-o",
                         str(tmp_path / "out"), "--fps", "30", *(["--per-frame"] if per_frame else []))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "2 people" in out.stdout, out.stdout
    assert _people(tmp_path / "out") == [2] * n_times


def test_the_tracker_asks_a_short_session_for_all_its_times():
    o = TrackingOptions()
    assert [o.min_frames_for(n) for n in (0, 1, 2, 3, 50)] == [1, 1, 2, 3, 3]
    X = np.zeros((1, 19, 3))
    assert [i.tolist() for i in track_bodies(np.array([0.0]), [X])] == [[0]]
    assert [i.tolist() for i in track_bodies(np.array([0.0, 40.0]), [X, X + 1])] == [[0], [0]]
    # three times or more: a body seen at one time only is still a false one
    three = track_bodies(np.array([0.0, 40.0, 80.0]), [X, X + 1, np.concatenate([X + 2, X + 500])])
    assert [i.tolist() for i in three] == [[0], [0], [0, -1]]


def test_a_window_without_a_measured_bone(rig):  # noqa: F811
    """No track of the session has a bone seen by enough views (here: bone_min_views above the rig's cameras; in
    the probe: detections at half scale): the body over time runs on motion and views alone. Before: ValueError."""
    bundle, det, times, _, _ = rig
    options = dataclasses.replace(PeopleOptions(), temporal=TemporalOptions(bone_min_views=50))
    seq = _run(bundle, det, times[:30], options)
    assert sum(len(b.ids) for b in seq.bodies) > 0
    assert all(np.isfinite(b.X_cm).any() for b in seq.bodies if len(b.ids))
