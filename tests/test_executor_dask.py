"""The Dask executor without separate processes: placement by worker name, per-stage tallies, bytes, and the
one-line errors (bad address, unreachable scheduler, malformed capture.json nodes). The real multi-process
cluster is in test_dask_cluster.py (slow)."""
from __future__ import annotations

import json
import socket

import numpy as np
import pytest

from dome_calib.pipeline.capture import capture_nodes
from dome_calib.pipeline.cluster import node_image_path
from dome_calib.errors import CaptureError, DomeCalibError
from dome_calib.executor.dask import DaskExecutor, Route, payload_bytes


def square(x: int) -> int:
    return x * x


def fails_on_three(x: int) -> int:
    if x == 3:
        raise ValueError("three")
    return x


def worker_of_parity(x: int) -> int:
    return x % 2  # a LocalCluster names its workers 0, 1, ...


@pytest.fixture(scope="module")
def local_client():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as lc, \
            Client(lc, set_as_default=False) as client:
        yield client


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_map_pins_items_to_the_named_worker_and_counts_them(local_client):
    ex = DaskExecutor("inproc://local", client=local_client, routes={square: Route(worker_of=worker_of_parity)})
    items = list(range(10))
    assert sorted(ex.map(square, items)) == sorted(x * x for x in items)
    stats = ex.stats_dict()["stages"]["square"]
    assert stats["tasks"] == 10
    assert stats["workers"] == {"0": 5, "1": 5}  # even items on worker 0, odd on worker 1, none elsewhere


def test_task_error_reaches_the_caller_after_its_retries(local_client):
    ex = DaskExecutor("inproc://local", client=local_client, retries=1)
    with pytest.raises(ValueError, match="three"):
        list(ex.map(fails_on_three, range(5)))


def test_payload_bytes_counts_arrays_in_containers():
    a = np.zeros((100, 128), np.uint8)
    assert payload_bytes(("cam", a, {"k": a})) >= 2 * a.nbytes
    assert payload_bytes(a) == a.nbytes


def test_bad_scheduler_address_is_one_line():
    with pytest.raises(DomeCalibError, match="tcp://HOST:PORT"):
        DaskExecutor("node07:8786")


def test_unreachable_scheduler_is_one_line_within_the_timeout():
    with pytest.raises(DomeCalibError, match="cannot connect") as exc:
        DaskExecutor(f"tcp://127.0.0.1:{_free_port()}", connect_timeout_s=0.5)
    assert "\n" not in str(exc.value)


def test_calibrate_cli_unreachable_scheduler(tmp_path, dome_calib_cli, monkeypatch):
    import dome_calib.executor.dask as executor_dask

    monkeypatch.setattr(executor_dask, "CONNECT_TIMEOUT_S", 0.5)
    cap = tmp_path / "cap"
    (cap / "scenes" / "scene_01").mkdir(parents=True)
    (cap / "capture.json").write_text(json.dumps({"scenes": ["scene_01"], "cameras": ["01_01"]}))
    res = dome_calib_cli("calibrate", cap, "-o", tmp_path / "out", "--scheduler", f"tcp://127.0.0.1:{_free_port()}")
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "cannot connect" in lines[0], res.stderr
    assert not (tmp_path / "out").exists()


def test_capture_nodes_read_and_checked(tmp_path):
    meta = tmp_path / "capture.json"
    cams = ["07_01", "07_02"]
    meta.write_text(json.dumps({"scenes": ["s1"], "cameras": cams, "nodes": {"node07": ["07_02", "07_01"]}}))
    assert capture_nodes(tmp_path) == {"node07": ["07_01", "07_02"]}
    meta.write_text(json.dumps({"scenes": ["s1"], "cameras": cams, "nodes": {"node07": ["07_01"], "node08": ["07_01"]}}))
    with pytest.raises(CaptureError, match=r"capture.json: nodes.node08\[0\]: camera 07_01 is listed under nodes "
                                           "node07 and node08"):
        capture_nodes(tmp_path)
    meta.write_text(json.dumps({"scenes": ["s1"], "cameras": cams, "nodes": ["07_01"]}))
    with pytest.raises(CaptureError, match=r"capture.json: nodes: expected an object mapping names to lists of camera "
                                           r"names .*, got \["):
        capture_nodes(tmp_path)
    meta.write_text(json.dumps({"scenes": ["s1"], "cameras": cams, "nodes": {"node07": ["07_03"]}}))
    with pytest.raises(CaptureError, match=r"nodes.node07\[0\]: camera 07_03 is not among the file's cameras"):
        capture_nodes(tmp_path)
    meta.write_text(json.dumps({"scenes": ["s1"], "cameras": cams}))
    assert capture_nodes(tmp_path) == {}


def test_node_image_path_uses_the_nodes_own_folder(monkeypatch):
    head = "/data/capture"
    monkeypatch.delenv("DOME_CALIB_CAPTURE_ROOT", raising=False)
    assert node_image_path(head, "/data/capture/scenes/s1/07_01.png") == "/data/capture/scenes/s1/07_01.png"
    monkeypatch.setenv("DOME_CALIB_CAPTURE_ROOT", "/local/cap")
    assert node_image_path(head, "/data/capture/scenes/s1/07_01.png") == "/local/cap/scenes/s1/07_01.png"
    assert node_image_path(head, "/elsewhere/x.png") == "/elsewhere/x.png"


def test_an_image_missing_on_its_node_is_a_per_camera_failure(tmp_path, monkeypatch):
    from dome_calib.pipeline.cluster import ProvenImageTask
    from projector.features import FeatureOptions

    monkeypatch.setenv("DOME_CALIB_CAPTURE_ROOT", str(tmp_path / "node07"))
    task = ProvenImageTask(head_capture="/data/capture", pinned=frozenset({"07_01"}))
    proven = task(("07_01", "/data/capture/scenes/s1/07_01.png", FeatureOptions()))
    res = proven.result
    assert proven.evidence is None and res.camera == "07_01" and res.keypoints is None
    assert res.failure.startswith("image not found on this worker") and "node07/scenes/s1/07_01.png" in res.failure
