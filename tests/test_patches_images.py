"""`reconstruct --images`: real cameras' images (a folder of frames, a video) read as a frame source, sizes checked
against the calibration, the patch stream written as Parquet that pandas reads without our code, and a run without
--images unchanged."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from dome_calib.body3d_scene import read_scene
from dome_calib.bundle_io import write_bundle
from dome_calib.recon.errors import ReconError
from dome_calib.recon.patches.images import open_images
from dome_calib.recon.patches.model import PatchTrajectories
from dome_calib.recon.patches.parts import BONES, PartLabels
from dome_calib.recon.patches.stage import people_at
from dome_calib.recon.patches.stream_file import METADATA_KEY, patch_table, write_patch_table
from dome_calib.recon.project import project_points, view_set
from dome_calib.synth.openpose_write import write_openpose_folder
from dome_calib.synth.textured import TexturedScene, TextureOptions

from .patches_helpers import one_person_capture

FRAMES = np.arange(116, 123)  # VGA frames: 120 seeds a cloud (every 20th); parts need 5 frames
VIDEO_CAMERA = "01_01"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """8 VGA cameras of the tiny dome, one person, 7 frames: the bundle and the detections (PANOPTIC19)."""
    root = tmp_path_factory.mktemp("images")
    bundle, truth = one_person_capture()
    cams = [n for n in sorted(bundle.cameras) if str(bundle.cameras[n].type) == "vga"][:8]
    table = bundle.sync.streams["vga"]
    X, _ = truth.joints_cm(table.times_of(FRAMES))
    det, noisy = {}, {}
    rng = np.random.default_rng(7)
    for cam in cams:
        p = project_points(view_set(bundle, [cam]), X.reshape(-1, 3))
        uv = p.uv_px[0].reshape(len(FRAMES), -1, 19, 2)
        conf = np.where(p.visible[0].reshape(len(FRAMES), -1, 19), 0.9, 0.0)
        det[cam] = {int(f): np.concatenate([uv[k], conf[k][..., None]], -1) for k, f in enumerate(FRAMES)}
        noisy[cam] = {f: np.concatenate([kp[..., :2] + rng.normal(0.0, 2.0, kp[..., :2].shape), kp[..., 2:]], -1)
                      for f, kp in det[cam].items()}  # 2 px per axis: what the patches have to lower
    write_openpose_folder(root / "det", det, body_model="PANOPTIC19")
    write_openpose_folder(root / "det_noisy", noisy, body_model="PANOPTIC19")
    write_bundle(bundle, root / "bundle")
    return root, bundle, truth, cams


def write_images(folder: Path, cams: list[str], image) -> None:
    """``image(cam, frame)`` (grey or RGB) for FRAMES: VIDEO_CAMERA as a lossless video (FFV1) starting at the
    first frame, the others as PNG folders, listed in images.json."""
    folder.mkdir()
    files = {}
    for cam in cams:
        if cam == VIDEO_CAMERA:
            first = np.atleast_3d(image(cam, int(FRAMES[0])))
            video = cv2.VideoWriter(str(folder / f"{cam}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 25,
                                    (first.shape[1], first.shape[0]))
            for f in FRAMES:
                im = np.atleast_3d(image(cam, int(f)))
                video.write(cv2.cvtColor(im, cv2.COLOR_GRAY2BGR if im.shape[2] == 1 else cv2.COLOR_RGB2BGR))
            video.release()
            files[cam] = f"{cam}.avi"
        else:
            (folder / f"frames_{cam}").mkdir()
            for f in FRAMES:
                cv2.imwrite(str(folder / f"frames_{cam}" / f"img_{f:05d}.png"), image(cam, int(f)))
            files[cam] = f"frames_{cam}"
    (folder / "images.json").write_text(json.dumps({"cameras": files, "first_frame": {VIDEO_CAMERA: int(FRAMES[0])}}))


@pytest.fixture(scope="module")
def capture(inputs):
    """The inputs with the textured person rendered into every camera (slow tests)."""
    root, bundle, truth, cams = inputs
    scene = TexturedScene(bundle, truth, TextureOptions())
    write_images(root / "images", cams, scene.gray)
    return root, bundle, scene, cams


def noise(cam: str, frame: int) -> np.ndarray:
    rng = np.random.default_rng([int(cam.replace("_", "")), frame])
    return rng.integers(0, 256, (480, 640), dtype=np.uint8)


def test_images_are_read_as_the_frames_they_are(inputs, tmp_path):
    _, bundle, _, cams = inputs
    write_images(tmp_path / "images", cams[:3], noise)
    source = open_images(tmp_path / "images", bundle)
    assert source.names == cams[:3]
    assert np.array_equal(source.frame_indices(VIDEO_CAMERA), FRAMES)
    for cam in (VIDEO_CAMERA, cams[1]):
        for f in (121, 117, 120, 116):  # backwards too: the video is reopened and sought
            assert np.array_equal(source.gray(cam, f), noise(cam, f)), (cam, f)  # lossless video, PNG


def test_an_image_of_another_size_is_refused_naming_the_camera(inputs, tmp_path):
    _, bundle, _, cams = inputs
    folder = tmp_path / "imgs"
    (folder / "a").mkdir(parents=True)
    w, h = bundle.cameras[cams[0]].resolution
    cv2.imwrite(str(folder / "a" / "f_119.png"), np.zeros((h, w - 8), np.uint8))
    (folder / "images.json").write_text(json.dumps({"cameras": {cams[0]: "a"}}))
    with pytest.raises(ReconError, match=rf"f_119.png: camera {cams[0]}: images of {w - 8} x {h} px but the "
                                          rf"calibration's camera is {w} x {h}"):
        open_images(folder, bundle)
    # a crop, stated: put back in the calibrated frame, the missing columns repeated from the edge
    (folder / "images.json").write_text(json.dumps({"cameras": {cams[0]: "a"},
                                                    "crop_origin_px": {cams[0]: [8, 0]}}))
    assert open_images(folder, bundle).gray(cams[0], 119).shape == (h, w)
    (folder / "images.json").write_text(json.dumps({"cameras": {cams[0]: "a"}, "crop_origin_px": {cams[0]: [9, 0]}}))
    with pytest.raises(ReconError, match="reach beyond the calibration"):
        open_images(folder, bundle)
    (folder / "images.json").write_text(json.dumps({"cameras": {"99_99": "a"}}))
    with pytest.raises(ReconError, match=r"images.json: cameras.99_99: no camera of that name"):
        open_images(folder, bundle)


def test_the_parquet_file_holds_the_trajectories_for_pandas(tmp_path):
    rng = np.random.default_rng(0)
    N, T, cams = 6, 5, ["00_01", "01_02", "50_01"]
    alive = rng.random((N, T)) < 0.7
    X = np.where(alive[..., None, None], rng.normal(size=(N, T, 3, 3)) * 50, np.nan)
    traj = PatchTrajectories(ids=np.arange(N) + 100000 * (np.arange(N) % 2), seed_time_ms=np.full(N, 40.0),
                             times_ms=np.arange(T) * 33.3667, cameras=cams, X_cm=X, normal=rng.normal(size=(N, T, 3)),
                             visible=rng.random((N, T, 3)) < 0.5, photometric=np.zeros((N, T, 3), bool), alive=alive)
    labels = PartLabels(person=np.where(np.arange(N) % 3, 1, -1), bone=np.where(np.arange(N) % 3, 3, -1),
                        cost=np.zeros(N))
    write_patch_table(tmp_path / "p.parquet", patch_table(traj, labels, np.array([4, 7]), reference_stream="hd"))
    df = pd.read_parquet(tmp_path / "p.parquet")  # pandas and pyarrow alone: no code of ours
    meta = json.loads(pq.read_schema(tmp_path / "p.parquet").metadata[METADATA_KEY])
    assert meta["cameras"] == cams and meta["units"] == {"position": "cm", "time": "ms"}
    assert meta["reference_stream"] == "hd" and meta["parts"][3] == BONES[3][0]
    assert len(df) == alive.sum()
    assert list(zip(df.patch_id, df.time_ms)) == sorted(zip(df.patch_id, df.time_ms))
    for row in df.itertuples():
        i = int(np.flatnonzero(traj.ids == row.patch_id)[0])
        k = int(np.flatnonzero(traj.times_ms == row.time_ms)[0])
        assert alive[i, k] and row.seed_time_ms == 40.0
        assert np.array_equal([row.centre_x_cm, row.centre_y_cm, row.centre_z_cm], X[i, k, 0])
        assert np.array_equal([row.plane1_x_cm, row.plane1_y_cm, row.plane1_z_cm], X[i, k, 1])
        assert np.array_equal([row.plane2_x_cm, row.plane2_y_cm, row.plane2_z_cm], X[i, k, 2])
        assert np.array_equal([row.normal_x, row.normal_y, row.normal_z], traj.normal[i, k])
        assert list(row.visible_cameras) == [c for c, v in zip(cams, traj.visible[i, k]) if v]
        assert (row.person_id, None if pd.isna(row.part) else row.part) == ((7, BONES[3][0]) if i % 3 else (-1, None))


def test_people_are_brought_to_the_patch_times():
    class B:
        def __init__(self, ids, x):
            self.ids, self.X_cm = np.array(ids), np.full((len(ids), 19, 3), x, float)
    J, ids = people_at(np.array([0.0, 40.0, 80.0]), [B([3], 0.0), B([3, 5], 4.0), B([5], 8.0)],
                       np.array([10.0, 40.0, 60.0, 90.0]))
    assert list(ids) == [3, 5]
    assert np.allclose(J[:, 0, 0, 0], [1.0, 4.0, np.nan, np.nan], equal_nan=True)  # 3 is gone at 80 ms
    assert np.allclose(J[:, 1, 0, 0], [np.nan, 4.0, 6.0, np.nan], equal_nan=True)


def mpjpe_cm(folder: Path, truth) -> float:
    """The mean joint error of a reconstruct output's one person against the truth (joints both have)."""
    errs = []
    for path in sorted(folder.glob("body3DScene_*.json")):
        time_ms, bodies = read_scene(path)
        X, present = truth.joints_cm(np.array([time_ms]))
        for J in bodies.values():
            d = np.linalg.norm(np.where(J[:, 3:] >= 0, J[:, :3], np.nan) - X[0, 0], axis=-1)
            errs.append(d[np.isfinite(d)])
    return float(np.concatenate(errs).mean())


def _page_data(folder: Path) -> dict:
    """The data the people page of ``folder`` shows (its JSON element)."""
    html = (folder / "index.html").read_text(encoding="utf-8")
    start = html.index('<script id="people-data" type="application/json">') + len(
        '<script id="people-data" type="application/json">')
    return json.loads(html[start:html.index("</script>", start)])


@pytest.mark.slow
def test_reconstruct_with_images_refines_the_people_and_adds_the_patch_stream(capture, inputs, dome_calib_cli):
    root, _, _, cams = capture
    truth = inputs[2]
    args = ("reconstruct", str(root / "det"), "--bundle", str(root / "bundle"), "--body-model", "PANOPTIC19")
    plain = dome_calib_cli(*args, "-o", str(root / "plain"))
    assert plain.returncode == 0, plain.stderr
    out = dome_calib_cli(*args, "--images", str(root / "images"), "-o", str(root / "with"))
    assert out.returncode == 0, out.stderr
    assert "patches: " in out.stdout and "given a body part -> patches.parquet" in out.stdout
    assert "joint ties on the people's times" in out.stdout and "per-frame joints as wrong" in out.stdout
    assert "(seeds: sweep, auto: stream vga's 8 cameras' nearest neighbours stand 3.3 deg apart" in out.stdout
    seeding = json.loads(pq.read_schema(root / "with" / "patches.parquet").metadata[METADATA_KEY])["seeding"]
    assert seeding["method"] == "sweep" and seeding["chosen"] == "auto" and seeding["neighbour_deg"] < 45.0
    df = pd.read_parquet(root / "with" / "patches.parquet")
    assert len(df) > 100 and set(df["person_id"]) <= {-1, 0}
    assert df["part"].notna().mean() > 0.5
    mine = {p.name for p in (root / "with").iterdir()} - {"patches.parquet"}
    assert mine == {p.name for p in (root / "plain").iterdir()}
    scenes = sorted(n for n in mine if n.startswith("body3DScene"))
    assert any((root / "with" / n).read_bytes() != (root / "plain" / n).read_bytes() for n in scenes)
    assert _page_data(root / "plain")["patches"] is None  # the people page: the patches coloured by part
    layer = _page_data(root / "with")["patches"]
    assert layer is not None and layer["parts"], sorted(layer or {})
    noisy = ("reconstruct", str(root / "det_noisy"), "--bundle", str(root / "bundle"), "--body-model", "PANOPTIC19")
    assert dome_calib_cli(*noisy, "-o", str(root / "noisy")).returncode == 0
    got = dome_calib_cli(*noisy, "--images", str(root / "images"), "-o", str(root / "noisy_with"))
    assert got.returncode == 0, got.stderr
    e0, e1 = mpjpe_cm(root / "noisy", truth), mpjpe_cm(root / "noisy_with", truth)
    print(f"MPJPE without --images {e0:.3f} cm, with {e1:.3f} cm; {got.stdout}")
    assert e1 < 0.95 * e0, (e0, e1, got.stdout)
    again = dome_calib_cli(*args, "-o", str(root / "with"))  # ours, patches.parquet included: replaced whole
    assert again.returncode == 0, again.stderr
    assert not (root / "with" / "patches.parquet").exists()
    for name in sorted(mine):  # without --images: the people of the run without, byte for byte
        if name.startswith("body3DScene") or name == "cameras.json":
            assert (root / "with" / name).read_bytes() == (root / "plain" / name).read_bytes(), name


@pytest.mark.slow  # reconstruct --images twice, once on a pool of 2 spawned workers: ~40 CPU-s
def test_reconstruct_images_on_two_workers_writes_the_same_patch_file(capture, dome_calib_cli):
    root, _, _, _ = capture
    args = ("reconstruct", str(root / "det"), "--bundle", str(root / "bundle"), "--body-model", "PANOPTIC19",
            "--images", str(root / "images"))
    one = dome_calib_cli(*args, "--workers", "1", "-o", str(root / "workers1"))
    assert one.returncode == 0, one.stderr
    two = dome_calib_cli(*args, "--workers", "2", "-o", str(root / "workers2"))
    assert two.returncode == 0, two.stderr
    names = sorted(p.name for p in (root / "workers1").iterdir())
    assert "patches.parquet" in names and names == sorted(p.name for p in (root / "workers2").iterdir())
    for name in names:  # the patch file and the people byte for byte; the page and the manifest name their folder
        if name not in ("index.html", ".dome-calib-written.json"):
            assert (root / "workers2" / name).read_bytes() == (root / "workers1" / name).read_bytes(), name
    page = [(root / f"workers{n}" / "index.html").read_text().replace(f"workers{n}", "OUT") for n in (1, 2)]
    assert page[0] == page[1]
    assert one.stdout.replace("workers1", "OUT") == two.stdout.replace("workers2", "OUT")


@pytest.mark.slow  # reconstruct --images: ~15 CPU-s
def test_reconstruct_images_seeds_patches_on_the_people_with_patch_seeds_skeleton(capture, dome_calib_cli):
    """``--patch-seeds skeleton``: the people just reconstructed are the seeds' depth prior (seed_skeleton)."""
    root, _, _, _ = capture
    out = dome_calib_cli("reconstruct", str(root / "det"), "--bundle", str(root / "bundle"), "--body-model",
                         "PANOPTIC19", "--images", str(root / "images"), "--patch-seeds", "skeleton", "-o",
                         str(root / "skeleton_seeds"))
    assert out.returncode == 0, out.stderr
    meta = json.loads(pq.read_schema(root / "skeleton_seeds" / "patches.parquet").metadata[METADATA_KEY])
    assert meta["seeding"] == {"method": "skeleton", "chosen": "given"}
    df = pd.read_parquet(root / "skeleton_seeds" / "patches.parquet")
    assert len(df) > 100 and df["part"].notna().mean() > 0.5, out.stdout


@pytest.mark.slow  # reconstruct --images in this process, with reseed_hidden and without: ~10 s
def test_reseed_hidden_runs_the_stage_again_from_the_people_fitted_with_its_ties(capture, monkeypatch, tmp_path):
    """``PatchOptions.reseed_hidden``: run_reconstruction fits the people with the first stream's ties and gives them
    to the stage's ``again``, whose clouds are streamed again where their seeds' prior changed
    (:func:`~dome_calib.recon.patches.stage.reseed_clouds`). Here the detector saw every joint: no prior changes,
    nothing is streamed again, and the files are those of one stream."""
    import dome_calib.recon.patches.stage as stage_module
    from dome_calib.recon.patches.model import PatchOptions
    from dome_calib.recon.people.commands import plan_reconstruction, run_reconstruction

    root = capture[0]
    streams, reseeded = [], []
    real_stream, real_reseed = stage_module.patch_stream, stage_module.reseed_clouds
    monkeypatch.setattr(stage_module, "patch_stream", lambda *a, **k: streams.append(1) or real_stream(*a, **k))
    monkeypatch.setattr(stage_module, "reseed_clouds", lambda *a: reseeded.append(1) or real_reseed(*a))
    for name, options in (("once", PatchOptions(reseed_hidden=False)), ("twice", PatchOptions(reseed_hidden=True))):
        plan = plan_reconstruction(root / "det", root / "bundle", tmp_path / name, body_model="PANOPTIC19",
                                   images=root / "images")
        stage = stage_module.plan_patches(plan, options)
        run_reconstruction(plan, after_people=lambda seq: stage.run(seq.times_ms, seq.bodies))
    assert len(streams) == 2 and len(reseeded) == 1  # the second pass ran, and streamed nothing again
    once, twice = (pd.read_parquet(tmp_path / n / "patches.parquet") for n in ("once", "twice"))
    pd.testing.assert_frame_equal(once, twice)
    for n in sorted(p.name for p in (tmp_path / "once").iterdir() if p.name.startswith("body3DScene")):
        assert (tmp_path / "once" / n).read_bytes() == (tmp_path / "twice" / n).read_bytes(), n
