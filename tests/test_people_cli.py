"""`dome-calib reconstruct`: an OpenPose folder of a group + a bundle -> tracked people; bad input: one line, exit 1,
nothing written."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.body3d_scene import read_scene
from dome_calib.rotation import rotvec_to_matrix
from dome_calib.synth.detector import write_openpose_folder

from .people_helpers import group_detections, group_joints_cm
from .recon_helpers import real_bundle

N_PEOPLE = 3


def _small(bundle: Bundle, n_vga: int = 14, n_hd: int = 6) -> Bundle:
    vga = sorted(bundle.of_type("vga"))[:: max(len(bundle.of_type("vga")) // n_vga, 1)][:n_vga]
    hd = sorted(bundle.of_type("hd"))[:: 5][:n_hd]
    cams = {n: bundle.cameras[n] for n in vga + hd}
    return Bundle(seq=bundle.seq, cameras=cams, calib_data_source=bundle.calib_data_source, sync=bundle.sync)


def _one_line_error(out) -> str:
    assert out.returncode == 1, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dome-calib: error:"), out.stderr
    return lines[0]


@pytest.fixture(scope="module")
def group(tmp_path_factory):
    root = tmp_path_factory.mktemp("people_cli")
    bundle = _small(real_bundle(kinect=False, n_vga=40, start_ms=1000.0, duration_ms=600.0, seed=3))
    write_bundle(bundle, root / "bundle")
    people, _ = group_detections(bundle, sorted(bundle.cameras), N_PEOPLE, seed=4)
    write_openpose_folder(root / "det", people, body_model="BODY_25")
    return root, bundle, people


def test_reconstruct_writes_tracked_people(group, dome_calib_cli):
    root, bundle, _ = group
    out = dome_calib_cli("reconstruct", str(root / "det"), "--bundle", str(root / "bundle"), "-o", str(root / "out"),
                         "--body-model", "BODY_25")
    assert out.returncode == 0, out.stderr
    assert f"{N_PEOPLE} people" in out.stdout
    vga = bundle.sync.streams["vga"]
    files = sorted((root / "out").glob("body3DScene_*.json"))
    assert [int(f.stem.split("_")[1]) for f in files] == vga.index.tolist()
    truth = group_joints_cm(vga.univ_time_ms, N_PEOPLE, seed=4)
    id_of_truth: dict[int, set[int]] = {p: set() for p in range(N_PEOPLE)}
    errors = []
    for k, f in enumerate(files):
        t_ms, bodies = read_scene(f)
        assert t_ms == pytest.approx(vga.univ_time_ms[k], abs=1e-3)
        assert json.loads(f.read_text())["fpsType"] == "vga_25"
        if k in (0, len(files) - 1):
            continue  # the HD stream does not bracket the table's first and last VGA frames
        assert len(bodies) == N_PEOPLE
        for i, j in bodies.items():
            X = np.where(j[:, 3:] < 0, np.nan, j[:, :3])
            d = np.nanmean(np.linalg.norm(X[None] - truth[k], axis=-1), axis=1)
            p = int(np.argmin(d))
            id_of_truth[p].add(i)
            errors.append(d[p])
    assert all(len(ids) == 1 for ids in id_of_truth.values())  # one id per person, all the time
    assert np.median(errors) < 1.0 and np.max(errors) < 5.0  # cm; 2 px noise, ~20 views
    cams = json.loads((root / "out" / "cameras.json").read_text())
    assert sorted(cams["cameras"]) == sorted(bundle.cameras) and cams["flagged"] == []
    assert all(c["median_reprojection_px"] < 4.0 and c["share_used"] > 0.8 for c in cams["cameras"].values())


def test_a_moved_camera_stands_out(group, dome_calib_cli, tmp_path):
    """The detections come from the true cameras; the bundle given to reconstruct has one camera turned by 1 deg."""
    root, bundle, _ = group
    moved = sorted(bundle.of_type("vga"))[3]
    cams = dict(bundle.cameras)
    cam = cams[moved]
    # turned by 1 deg about its own vertical axis, around its centre (the centre stays where it is)
    R = rotvec_to_matrix(np.radians([0.0, 1.0, 0.0])) @ cam.R
    centre = -cam.R.T @ cam.t_cm
    cams[moved] = dataclasses.replace(cam, R=R, t_cm=-R @ centre)
    write_bundle(Bundle(seq=bundle.seq, cameras=cams, calib_data_source="moved", sync=bundle.sync), tmp_path / "b")
    out = dome_calib_cli("reconstruct", str(root / "det"), "--bundle", str(tmp_path / "b"), "-o",
                         str(tmp_path / "out"), "--body-model", "BODY_25")
    assert out.returncode == 0, out.stderr
    report = json.loads((tmp_path / "out" / "cameras.json").read_text())
    assert report["flagged"] == [moved]
    others = [c for n, c in report["cameras"].items() if n != moved]
    mine = report["cameras"][moved]
    worst_other = max(c["median_reprojection_px"] for c in others)
    assert (mine["median_reprojection_px"] or np.inf) > 3 * worst_other or mine["share_used"] < 0.5
    assert moved in out.stdout


def _copy_det(src, dst, limit=4):
    """The first ``limit`` frames of each camera of an OpenPose folder."""
    for cam in sorted(p for p in src.iterdir()):
        (dst / cam.name).mkdir(parents=True)
        for f in sorted(cam.iterdir())[:limit]:
            (dst / cam.name / f.name).write_text(f.read_text())


@pytest.mark.parametrize("case", ["absent_camera", "outside_sync", "malformed", "joint_count", "ambiguous"])
def test_bad_input_one_line_nothing_written(group, dome_calib_cli, tmp_path, case):
    root, bundle, _ = group
    det = tmp_path / "det"
    _copy_det(root / "det", det)
    cam = sorted(bundle.of_type("hd"))[0]
    first = sorted((det / cam).iterdir())[0]
    frame = int(first.name.split("_")[-2])
    args = ["--body-model", "BODY_25"]
    if case == "absent_camera":
        (det / cam).rename(det / "99_99")
        expect = ["99_99", "not in the bundle"]
    elif case == "outside_sync":
        bad = det / cam / f"{cam}_{999999:012d}_keypoints.json"
        bad.write_text(first.read_text())
        expect = [str(bad), cam, "frame 999999", "sync table"]
    elif case == "malformed":
        first.write_text('{"people": [')
        expect = [str(first), cam, f"frame {frame}", "not valid JSON"]
    elif case == "joint_count":
        first.write_text(json.dumps({"people": [{"pose_keypoints_2d": [1.0, 2.0, 0.5] * 21}]}))
        expect = [str(first), cam, f"frame {frame}", "21 joints", "fits no body model"]
    else:
        args = []
        expect = ["25 joints", "BODY_25 and BODY_25B", "--body-model"]
    out = dome_calib_cli("reconstruct", str(det), "--bundle", str(root / "bundle"), "-o", str(tmp_path / "out"), *args)
    line = _one_line_error(out)
    for e in expect:
        assert e in line, line
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["det"]  # no staging folder left either


def test_camera_map_dotted_names_and_no_sync_tables(dome_calib_cli, tmp_path):
    """A rig without sync tables (one shared frame index, as Pose2Sim's), folders named cam01.. mapped to the
    bundle's cameras, files named cam01.0042.json, COCO-18 keypoints, smoothing on."""
    full = real_bundle(kinect=False, sync=False, n_vga=40)
    bundle = _small(full, n_vga=8, n_hd=0)
    write_bundle(bundle, tmp_path / "bundle")
    frames = np.arange(40, 52)
    people, _ = group_detections(bundle, sorted(bundle.cameras), 2, seed=5, shared_frames=frames)
    folder_of = {n: f"cam{k + 1:02d}" for k, n in enumerate(sorted(bundle.cameras))}
    write_openpose_folder(tmp_path / "det", {folder_of[n]: d for n, d in people.items()}, body_model="COCO_18",
                          naming="dotted")
    mapping = ",".join(f"{f}={n}" for n, f in folder_of.items())
    out = dome_calib_cli("reconstruct", str(tmp_path / "det"), "--bundle", str(tmp_path / "bundle"),
                         "--camera-map", mapping, "--fps", "30", "--smooth", "2")
    assert out.returncode == 0, out.stderr
    files = sorted((tmp_path / "det_people").glob("body3DScene_*.json"))
    assert [int(f.stem.split("_")[1]) for f in files] == frames.tolist()
    truth = group_joints_cm(frames * 1000.0 / 30.0, 2, seed=5)
    for k, f in enumerate(files):
        t_ms, bodies = read_scene(f)
        assert t_ms == pytest.approx(frames[k] * 1000 / 30, abs=1e-3)
        assert sorted(bodies) == [0, 1]
        for j in bodies.values():
            X = np.where(j[:, 3:] < 0, np.nan, j[:, :3])
            # COCO-18 has no body_center: it comes from the hips
            assert np.nanmin(np.nanmean(np.linalg.norm(X[None] - truth[k], axis=-1), axis=1)) < 3.0


@pytest.mark.parametrize("args, message", [(["--fps", "abc"], "--fps 'abc': not a frame rate"),
                                           (["--min-views", "1"], "--min-views 1: a person must be seen by at"),
                                           (["--smooth", "-1"], "--smooth -1: expected 0 (off)"),
                                           (["--correct-offsets", "--images", "."], "--correct-offsets with --images")])
def test_bad_options_one_line(group, dome_calib_cli, tmp_path, args, message):
    root, _, _ = group
    out = dome_calib_cli("reconstruct", str(root / "det"), "--bundle", str(root / "bundle"), "-o", str(tmp_path / "o"),
                         "--body-model", "BODY_25", *args)
    assert message in _one_line_error(out)
    assert not (tmp_path / "o").exists()


def test_long_session_chunks_read_their_own_files(group, tmp_path):
    """Chunks of 5 times on a 2-process pool, each task reading only its chunk's OpenPose files (and each window of
    the body over time its own): the same people with the same ids as one run over everything."""
    from dome_calib.executor.local import LocalProcessExecutor
    from dome_calib.recon.people.commands import reconstruct_folder
    from dome_calib.recon.people.run import PeopleOptions

    root, bundle, _ = group
    whole = reconstruct_folder(root / "det", root / "bundle", tmp_path / "whole", body_model="BODY_25")
    with LocalProcessExecutor(2) as pool:
        chunked = reconstruct_folder(root / "det", root / "bundle", tmp_path / "chunked", body_model="BODY_25",
                                     options=PeopleOptions(chunk_times=5), executor=pool)
    assert (chunked.times, chunked.people, chunked.body_frames) == (whole.times, whole.people, whole.body_frames)
    for a, b in zip(sorted((tmp_path / "whole").glob("body3D*")), sorted((tmp_path / "chunked").glob("body3D*"))):
        _, A = read_scene(a)
        _, B = read_scene(b)
        assert sorted(A) == sorted(B)
        for i in A:
            np.testing.assert_allclose(A[i], B[i], atol=1e-2)


def test_later_passes_take_the_detections_the_first_one_kept(group, tmp_path):
    """The per-frame chunks keep what they read (recon.people.detection_cache); the bridging and the body over time
    then take it instead of parsing the JSON again: the same bodies to the last bit, in chunks of 5 and at once;
    the kept folder is gone after the run; an executor of other machines keeps nothing."""
    from dome_calib.recon.people.chunks import reconstruct_people_chunked
    from dome_calib.recon.people.commands import kept_detections, plan_reconstruction
    from dome_calib.recon.people.run import PeopleOptions

    root, _, _ = group
    for chunk_times in (5, 600):
        plan = plan_reconstruction(root / "det", root / "bundle", tmp_path / "out", body_model="BODY_25",
                                   options=PeopleOptions(chunk_times=chunk_times))
        plain = reconstruct_people_chunked(plan.views, plan.source, plan.times_ms, plan.options)
        with kept_detections(plan.source) as source:
            kept = reconstruct_people_chunked(plan.views, source, plan.times_ms, plan.options)
            folder = source.cache_dir
            assert sorted(folder.glob("*.npz")), "the first pass kept nothing"
        assert not folder.exists()
        assert len(plain.bodies) == len(kept.bodies)
        for a, b in zip(plain.bodies, kept.bodies):
            np.testing.assert_array_equal(a.ids, b.ids)
            np.testing.assert_array_equal(a.X_cm, b.X_cm)
            np.testing.assert_array_equal(a.confidence, b.confidence)
        np.testing.assert_array_equal(plain.cameras.used, kept.cameras.used)

    class Remote:
        remote = True

    with kept_detections(plan.source, Remote()) as source:  # no folder kept; each file's digest for the workers
        assert source.cache_dir is None and source.files is plan.source.files
        assert sorted(source.digests) == sorted(plan.source.files)


def test_the_extra_joints_pass_reads_no_file_the_first_pass_kept(group, tmp_path, monkeypatch):
    """The first pass keeps every joint the run uses (joints19 and the model's extra joints): the extra joints' pass
    (recon.people.extras) then reads no OpenPose file again, and gives the extra joints to the last bit as from the
    files."""
    import dome_calib.recon.people.sources as sources
    from dome_calib.recon.people.chunks import reconstruct_people_chunked
    from dome_calib.recon.people.commands import kept_detections, plan_reconstruction
    from dome_calib.recon.people.extras import extra_joints
    from dome_calib.recon.people.run import PeopleOptions

    root, _, _ = group
    options = PeopleOptions(temporal=dataclasses.replace(PeopleOptions().temporal, enabled=False))
    plan = plan_reconstruction(root / "det", root / "bundle", tmp_path / "out", body_model="BODY_25", options=options)
    seq = reconstruct_people_chunked(plan.views, plan.source, plan.times_ms, plan.options)
    plain = extra_joints(plan.views, plan.source, seq, plan.options)
    read = sources.read_openpose_files
    files_read = []
    monkeypatch.setattr(sources, "read_openpose_files",
                        lambda files, *a, **k: files_read.append(sum(map(len, files.values()))) or read(files, *a, **k))
    with kept_detections(plan.source) as source:
        again = reconstruct_people_chunked(plan.views, source, plan.times_ms, plan.options)
        first = sum(files_read)
        kept = extra_joints(plan.views, source, again, plan.options)
    assert first > 0 and sum(files_read) == first  # the extra joints' pass read nothing
    for a, b in zip(plain.X_cm, kept.X_cm):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(plain.confidence, kept.confidence):
        np.testing.assert_array_equal(a, b)


def test_reconstruct_reads_each_detection_file_once(group, tmp_path, monkeypatch):
    """`reconstruct` with its people page (as the command line runs it, one process): every OpenPose file is parsed
    once, by the run's first pass; the later passes and the page take the run's kept detections (float32, as the run
    used them), and the page shows the detections of its cameras."""
    import dome_calib.recon.openpose_io as openpose_io
    from dome_calib.pipeline.people_page import people_page_writer
    from dome_calib.recon.people.commands import plan_reconstruction, run_reconstruction
    from dome_calib.recon.people.run import PeopleOptions
    from dome_calib.skeletons.page import PAGE_FILE

    root, _, _ = group
    options = PeopleOptions(temporal=dataclasses.replace(PeopleOptions().temporal, enabled=False))
    plan = plan_reconstruction(root / "det", root / "bundle", tmp_path / "out", body_model="BODY_25", options=options)
    page = people_page_writer(plan.out, root / "bundle", root / "det", body_model=plan.model.value,
                              files=plan.source.files)
    raw, opened = openpose_io._raw_people, []
    monkeypatch.setattr(openpose_io, "_raw_people", lambda path, *a, **k: opened.append(path) or raw(path, *a, **k))
    run_reconstruction(plan, page=page)
    every = sorted(p for frames in plan.source.files.values() for p in frames.values())
    assert sorted(opened) == every  # each once: none left unread, none read twice
    html = (tmp_path / "out" / PAGE_FILE).read_text(encoding="utf-8")
    assert '"detections": {"' in html or '"detections":{"' in html


def test_kept_detections_come_back_as_read(tmp_path):
    """store / load: every (camera, frame) as it was read (float32), across files of 64 frames, and only the frames
    asked for."""
    from dome_calib.recon.people.detection_cache import FRAMES_PER_FILE, load, store

    rng = np.random.default_rng(0)
    cameras = ["00_01", "00_02", "00_03"]
    people = {c: {f: rng.normal(size=(int(rng.integers(0, 4)), 19, 3)) for f in range(0, 150, 1 + v)}
              for v, c in enumerate(cameras)}
    store(tmp_path, 0, cameras, people)
    assert len(list(tmp_path.glob("s0.*.npz"))) == -(-150 // FRAMES_PER_FILE)
    frames = np.arange(40, 131)
    got = load(tmp_path, 0, cameras, frames)
    want = {(c, f): p for c in cameras for f, p in people[c].items() if 40 <= f <= 130}
    assert sorted(got) == sorted(want)
    for key, p in want.items():
        np.testing.assert_array_equal(got[key], p.astype(np.float32))
    assert load(tmp_path, 1, cameras, frames) == {}


def test_the_page_takes_one_cameras_kept_joints19_and_only_the_frames_kept(tmp_path):
    """KeptDetections.of_camera (the people page of a run): the camera's joints19 of the frames kept (the extra
    joints dropped, the float32 values as float64), from its own stream; a frame not kept is absent (the page reads
    its file)."""
    from dome_calib.recon.people.detection_cache import KeptDetections, store

    rng = np.random.default_rng(1)
    streams = [["00_01", "00_02"], ["50_01"]]
    people = [{c: {f: rng.normal(size=(2, 19 + 4, 3)) for f in range(0, 10)} for c in cams} for cams in streams]
    for i, cams in enumerate(streams):
        store(tmp_path, i, cams, people[i])
    kept = KeptDetections(folder=tmp_path, streams=streams)
    got = kept.of_camera("50_01", np.array([3, 4, 12]))
    assert sorted(got) == [3, 4]
    for f in (3, 4):
        assert got[f].dtype == np.float64 and got[f].shape == (2, 19, 3)
        np.testing.assert_array_equal(got[f], people[1]["50_01"][f][:, :19].astype(np.float32))
    assert kept.of_camera("00_02", np.array([0]))[0].tolist() == people[0]["00_02"][0][:, :19].astype(
        np.float32).tolist()
    assert kept.of_camera("99_99", np.array([0])) == {}


def test_a_kept_detection_folder_left_by_a_killed_run_is_removed_by_the_next(tmp_path):
    """A run killed with SIGKILL cannot remove its kept detections: the next run on the machine removes the folder
    once that run is provably over (io_utils.run_temp_folder: the owner tag of its name), and leaves a live run's
    folder, another machine's, and anything not named like one alone."""
    import subprocess
    import sys

    from dome_calib import io_utils
    from dome_calib.recon.people.detection_cache import PREFIX

    tag = io_utils._owner_tag()
    if tag is None:
        pytest.skip("no /proc: a run's owner cannot be told")
    host, boot, _, _ = tag.split(".")
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    dead = tmp_path / f"{PREFIX}{host}.{boot}.{int(gone.stdout)}.1.abc"
    (dead / "sub").mkdir(parents=True)
    (dead / "s0.0-63.npz").write_bytes(b"x")
    live = tmp_path / f"{PREFIX}{tag}.def"
    live.mkdir()
    elsewhere = tmp_path / f"{PREFIX}{'0' * 8 if host != '0' * 8 else '1' * 8}.{boot}.{int(gone.stdout)}.1.ghi"
    elsewhere.mkdir()
    other = tmp_path / f"{PREFIX}notatag"
    other.mkdir()
    with io_utils.run_temp_folder(PREFIX, tmp_path) as folder:
        assert folder.is_dir() and folder.name.startswith(f"{PREFIX}{tag}.")
        assert not dead.exists() and live.exists() and elsewhere.exists() and other.exists()
    assert not folder.exists()


def test_every_input_place_of_reconstruct_is_checked_in_the_plan(group, tmp_path):
    """The plan holds every input place of `reconstruct` in one list (detections, bundle, --depth, --videos,
    --images): an output inside any of them, or holding one, is refused before any work. --videos and --images were
    outside that list (--images had its own copy of the check in the patch stage; --videos none)."""
    import pytest

    from dome_calib.io_utils import OutputPathError
    from dome_calib.recon.people.commands import plan_reconstruction

    root, _, _ = group
    for flag in ("videos", "images"):
        place = tmp_path / flag
        place.mkdir()
        with pytest.raises(OutputPathError, match="inside the input folder"):
            plan_reconstruction(root / "det", root / "bundle", place / "out", body_model="BODY_25", **{flag: place})
        holder = tmp_path / f"holds_{flag}"
        (holder / "in").mkdir(parents=True)
        with pytest.raises(OutputPathError, match="holds the input"):
            plan_reconstruction(root / "det", root / "bundle", holder, body_model="BODY_25", **{flag: holder / "in"})
    plan = plan_reconstruction(root / "det", root / "bundle", tmp_path / "out", body_model="BODY_25",
                               images=tmp_path / "images")
    assert plan.images == (tmp_path / "images").resolve()
