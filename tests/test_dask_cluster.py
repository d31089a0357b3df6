"""`calibrate --scheduler` on a real Dask cluster on this machine: a `dask scheduler` and two `dask worker`
processes on 127.0.0.1, each worker holding half of the cameras of a one-scene tiny capture in its own folder
(``DOME_CALIB_CAPTURE_ROOT``), the head holding only capture.json with ``"nodes"`` and ``"images"``. The bundle
equals the local pool's (features and the keypoint refinement's image work ran on the nodes), every image each
node read proven to be the listed one; a node whose copy of an image
differs stops the run naming it; a worker killed during feature extraction (its nanny restarts it under the same
name) costs a retry, not the calibration. About 90 s on 2 cores: marked slow (`pytest -m slow`)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from dome_calib.synth.capture import split_onto_nodes

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# the same database (written in name order, whatever finished first) and the same seeded solvers: the only
# difference left is GLOMAP's multithreaded mapping on the head, ~1e-11 cm in points, ~1e-12 mm in the centres
MAX_CENTER_DIFF_MM = 0.1
NODES = ("nodeA", "nodeB")


def _cli(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, **kw)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # its own session: the worker's nanny and its child together
        except ProcessLookupError:
            pass
    proc.wait(timeout=10)


@pytest.fixture(scope="module")
def split_capture(tmp_path_factory):
    """(full capture, head folder with capture.json + nodes only, {node: its image folder})."""
    base = tmp_path_factory.mktemp("dask")
    full = base / "capture"
    res = _cli("synth", full, "--preset", "tiny", "--scenes", "1", "--overwrite")
    assert res.returncode == 0, res.stderr
    head, folders = split_onto_nodes(full, base, NODES)
    return full, head, folders


@pytest.fixture(scope="module")
def cluster(split_capture, tmp_path_factory):
    """A scheduler and one worker per node on loopback (free ports); everything killed at the end."""
    _, _, folders = split_capture
    base = tmp_path_factory.mktemp("cluster")
    sched_file = base / "scheduler.json"
    procs: list[subprocess.Popen] = []
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    try:
        procs.append(subprocess.Popen([BIN / "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                                       "--no-dashboard", "--scheduler-file", sched_file],
                                      stdout=subprocess.DEVNULL, stderr=open(base / "scheduler.log", "w"),
                                      start_new_session=True, env=env))
        deadline = time.monotonic() + 30
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(sched_file.read_text())["address"]
        workers = {}
        for node, folder in folders.items():
            workers[node] = subprocess.Popen(
                [BIN / "dask", "worker", address, "--name", node, "--nthreads", "1", "--host", "127.0.0.1",
                 "--no-dashboard", "--local-directory", base / node],
                stdout=subprocess.DEVNULL, stderr=open(base / f"{node}.log", "w"), start_new_session=True,
                env={**env, "DOME_CALIB_CAPTURE_ROOT": str(folder)})
            procs.append(workers[node])
        yield address, workers
    finally:
        for p in reversed(procs):
            _stop(p)


@pytest.fixture(scope="module")
def local_bundle(split_capture, tmp_path_factory):
    full, _, _ = split_capture
    out = tmp_path_factory.mktemp("local") / "out"
    res = _cli("calibrate", full, "-o", out)
    assert res.returncode == 0, res.stderr
    return load_bundle(out)


def _same(bundle, reference) -> None:
    """Same camera names; every centre within MAX_CENTER_DIFF_MM of the reference's (both in the world frame)."""
    assert sorted(bundle.cameras) == sorted(reference.cameras)
    worst_mm = max(10.0 * float(np.linalg.norm(bundle.cameras[n].center_cm - reference.cameras[n].center_cm))
                   for n in reference.cameras)
    assert worst_mm < MAX_CENTER_DIFF_MM, worst_mm


@pytest.mark.slow
def test_scheduler_run_equals_the_local_pool_and_features_run_on_their_node(split_capture, cluster, local_bundle,
                                                                            tmp_path):
    _, head, _ = split_capture
    address, _ = cluster
    out = tmp_path / "out"
    res = _cli("calibrate", head, "-o", out, "--scheduler", address)
    assert res.returncode == 0, res.stderr
    stats = json.loads((tmp_path / "out.work" / "cluster.json").read_text())
    meta = json.loads((head / "capture.json").read_text())
    features = stats["stages"]["extract_image"]
    # every image was read on the node that holds it: tasks per worker = that node's cameras x scenes
    assert features["workers"] == {n: len(c) * len(meta["scenes"]) for n, c in meta["nodes"].items()}
    assert "features:" in res.stdout and "matching:" in res.stdout
    for fn in ("reference_patches", "align_image"):  # the keypoint refinement read the images on their nodes too
        assert stats["stages"][fn]["tasks"] > 0 and set(stats["stages"][fn]["workers"]) <= set(meta["nodes"])
    assert "refine (alignment):" in res.stdout
    n_images = len(meta["cameras"]) * len(meta["scenes"])
    assert stats["images_verified"] == {"verified": n_images, "unverified": 0}  # each proven to be the listed one
    assert f"images each worker read: {n_images} verified" in res.stdout
    _same(load_bundle(out), local_bundle)


@pytest.mark.slow
def test_a_node_whose_image_differs_from_the_listed_one_stops_the_run_naming_it(split_capture, cluster, tmp_path):
    import shutil

    _, head, folders = split_capture
    address, _ = cluster
    meta = json.loads((head / "capture.json").read_text())
    scene, cam, other = meta["scenes"][0], meta["nodes"][NODES[1]][0], meta["nodes"][NODES[1]][1]
    image = folders[NODES[1]] / "scenes" / scene / f"{cam}.png"
    kept = tmp_path / "kept.png"
    shutil.copy(image, kept)
    shutil.copy(image.with_name(f"{other}.png"), image)  # the node holds another camera's picture under this name
    try:
        res = _cli("calibrate", head, "-o", tmp_path / "out", "--scheduler", address)
    finally:
        shutil.copy(kept, image)
    lines = [ln for ln in res.stderr.splitlines() if "error" in ln]
    assert res.returncode == 1 and len(lines) == 1, res.stderr
    assert f"worker {NODES[1]}: " in lines[0] and f"{scene}/{cam}.png: not the image" in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_worker_killed_during_feature_extraction_costs_a_retry(split_capture, cluster, local_bundle, tmp_path):
    import psutil
    from distributed import Client

    _, head, _ = split_capture
    address, workers = cluster
    out = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-c", "from dome_calib.cli import main; main()", "calibrate", str(head),
                            "-o", str(out), "--scheduler", address], cwd=ROOT, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, start_new_session=True)
    killed = None
    try:
        with Client(address, timeout="5s", set_as_default=False) as client:
            deadline = time.monotonic() + 60
            while killed is None and time.monotonic() < deadline and run.poll() is None:
                info = client.scheduler_info(n_workers=-1)["workers"]
                addr_b = next(a for a, w in info.items() if w.get("name") == NODES[1])
                if client.processing().get(addr_b):  # nodeB is extracting features
                    child = psutil.Process(workers[NODES[1]].pid).children(recursive=True)
                    assert child, "the worker's nanny has no worker process"
                    child[0].kill()  # the worker dies mid-task; its nanny starts a new one named nodeB
                    killed = addr_b
                time.sleep(0.05)
        stdout, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait()
    assert killed is not None, "no feature task was seen on nodeB"
    assert run.returncode == 0, stderr
    _same(load_bundle(out), local_bundle)
