"""The keypoint refinement's image work where the images are (projector.refine_images through an executor).

Two capture nodes are Dask workers in their own processes on this machine, each holding half of the cameras'
images in its own folder (``DOME_CALIB_CAPTURE_ROOT`` in its environment only); the head holds capture.json and no
image, and runs the refinement through the executor ``calibrate --scheduler`` uses (:func:`open_executor`). The
refined keypoints equal those of the refinement on a full local copy to the last bit, as do a serial run and a
2-process pool's; an image a node lacks is named per scene and camera (the node's path) and its keypoints stay.
(Before, the head read the images itself: on a cluster it found none and refined nothing, silently.)
"""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from dome_calib.executor import SerialExecutor, is_remote
from dome_calib.executor.local import LocalProcessExecutor
from dome_calib.pipeline.cluster import open_executor
from dome_calib.pipeline.stages import refine_notes
from dome_calib.reasons import ReasonCode
from dome_calib.synth.capture import split_onto_nodes
from projector.observations import Observations
from projector.refine import RefineOptions, refine_observations
from tests.test_refine import scene  # noqa: F401 (the fixture: three rendered views of a textured plane)

NODES = ("nodeA", "nodeB")
OPTIONS = RefineOptions(patch_radius_px=6)


@pytest.fixture(scope="module")
def two_scenes(scene):  # noqa: F811
    """(observations of two scenes, the full capture folder): the fixture's views as scene_01 and again as
    scene_02 with other noise (each scene's patches are gathered on its own)."""
    obs, truth, ref, root = scene
    capture = root.parent / "capture"
    for s in ("scene_01", "scene_02"):
        shutil.copytree(root / "scene_01", capture / "scenes" / s, dirs_exist_ok=True)
    (capture / "capture.json").write_text(json.dumps({"scenes": ["scene_01", "scene_02"],
                                                      "cameras": obs.camera_names}))
    noisy = truth + np.random.default_rng(7).normal(0.0, 0.25, truth.shape)
    noisy[ref] = truth[ref]
    X = obs.scene_points_cm["scene_01"]
    both = Observations(camera_names=obs.camera_names, cameras=obs.cameras,
                        scene_points_cm={"scene_01": X, "scene_02": X},
                        camera_index=np.concatenate([obs.camera_index, obs.camera_index]),
                        point_index=np.concatenate([obs.point_index, obs.point_index + len(X)]),
                        uv_px=np.concatenate([obs.uv_px, noisy]))
    return both, capture


@pytest.fixture(scope="module")
def local(two_scenes):
    obs, capture = two_scenes
    return refine_observations(obs, lambda s: capture / "scenes" / s, OPTIONS)


@pytest.fixture(scope="module")
def nodes(two_scenes):
    """(head folder, {node: its folder}, scheduler address): a scheduler and a worker process per node."""
    from distributed import Nanny, Scheduler, SpecCluster

    _, capture = two_scenes
    head, folders = split_onto_nodes(capture, capture.parent / "split", NODES)
    workers = {n: {"cls": Nanny, "options": {"name": n, "nthreads": 1, "dashboard": False,
                                              "env": {"DOME_CALIB_CAPTURE_ROOT": str(folders[n]),
                                                      "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}}}
               for n in NODES}
    with SpecCluster(workers=workers, scheduler={"cls": Scheduler, "options": {"dashboard": False}}) as cluster:
        yield head, folders, cluster.scheduler_address


def test_on_the_nodes_holding_the_images_equals_the_local_refinement_to_the_bit(two_scenes, local, nodes):
    obs, _ = two_scenes
    head, _, address = nodes
    stats: dict = {}
    with open_executor(head, address, stats) as executor:
        assert is_remote(executor)  # calibrate hands the refinement the cluster's executor
        placed, report = refine_observations(obs, lambda s: head / "scenes" / s, OPTIONS, executor=executor)
    assert report.unreadable_images == {}
    assert report.moved > 0.9 * (obs.n_observations - report.references)
    assert np.array_equal(placed.uv_px, local[0].uv_px)
    meta = json.loads((head / "capture.json").read_text())
    per_node = {n: 2 * len(cams) for n, cams in meta["nodes"].items()}  # every image of both scenes, on its node
    assert stats["stages"]["reference_patches"]["workers"] == per_node
    assert stats["stages"]["align_image"]["workers"] == per_node
    assert stats["images_verified"] == {"verified": 6, "unverified": 0}  # each proven the listed one, counted once


def test_an_image_a_node_lacks_is_named_and_its_keypoints_stay(two_scenes, local, nodes):
    obs, _ = two_scenes
    head, folders, address = nodes
    meta = json.loads((head / "capture.json").read_text())
    camera = meta["nodes"][NODES[1]][0]
    gone = folders[NODES[1]] / "scenes" / "scene_02" / f"{camera}.png"
    kept = gone.with_suffix(".kept")
    gone.rename(kept)
    try:
        with open_executor(head, address) as executor:
            placed, report = refine_observations(obs, lambda s: head / "scenes" / s, OPTIONS, executor=executor)
    finally:
        kept.rename(gone)
    assert report.unreadable_images == {f"scene_02/{camera}": f"image not found ({gone})"}
    note = refine_notes(report.unreadable_images)  # what calibrate's report lists among the cameras to check
    assert list(note) == [camera] and note[camera].code == ReasonCode.KEYPOINTS_NOT_REFINED
    assert f"scene_02: image not found ({gone})" in note[camera].text
    ci = obs.camera_names.index(camera)
    lost = (obs.camera_index == ci) & (obs.point_index >= len(obs.scene_points_cm["scene_01"]))
    assert np.array_equal(placed.uv_px[lost], obs.uv_px[lost])
    first = obs.point_index < len(obs.scene_points_cm["scene_01"])  # the other scene is untouched by the loss
    assert np.array_equal(placed.uv_px[first], local[0].uv_px[first])


@pytest.mark.parametrize("make", [SerialExecutor, lambda: LocalProcessExecutor(2)], ids=["serial", "pool"])
def test_the_same_bits_in_series_and_in_a_process_pool(two_scenes, local, make):
    obs, capture = two_scenes
    with make() as executor:
        assert not is_remote(executor)  # calibrate refines in threads here (the same bits, no patches pickled)
        refined, report = refine_observations(obs, lambda s: capture / "scenes" / s, OPTIONS, executor=executor)
    assert np.array_equal(refined.uv_px, local[0].uv_px) and report.moved == local[1].moved
