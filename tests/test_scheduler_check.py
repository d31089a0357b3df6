"""Remote work verified, not assumed (issue 42): a ``--scheduler`` address is checked in a bounded handshake before
any work (nothing listening, a server that accepts and says nothing, an HTTP server, a Dask worker: one line naming
the address, nothing written), and every image a worker reads comes back with its size and SHA-256, compared on
this machine before its features are used. Real local Dask workers (a LocalCluster in this process) and real
servers on loopback; the real multi-process cluster is in test_dask_cluster.py (slow)."""
from __future__ import annotations

import http.server
import json
import socket
import threading
import time

import cv2
import numpy as np
import pytest

from dome_calib.errors import DomeCalibError

from .cli_runner import run_in_process

HANDSHAKE_S = 3.0  # the check's bound in these tests (10 s in a run)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def silent_server():
    """Accepts connections and says nothing."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    held = []

    def accept():
        while True:
            try:
                held.append(server.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    server.close()
    for conn in held:
        conn.close()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # its log would land on this process's stderr
        pass


@pytest.fixture
def http_server():
    """A real HTTP server (as the Dask dashboard would be, on the port a user might give by mistake)."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


@pytest.fixture(scope="module")
def local_cluster():
    """A scheduler and one worker in this process, over TCP on loopback."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        yield cluster, client


def _capture(folder):
    (folder / "scenes" / "s1").mkdir(parents=True)
    (folder / "capture.json").write_text(json.dumps({"scenes": ["s1"], "cameras": ["01_01"]}))
    return folder


@pytest.mark.parametrize("kind, words", [
    ("closed port", "cannot connect (Connection refused)"),
    ("silent", "accepts connections but sends nothing: not a Dask scheduler"),
    ("http", "speaks HTTP, not Dask's protocol"),
    ("worker", "is a Dask Worker, not a scheduler"),
])
def test_an_address_that_is_no_scheduler_is_one_line_within_the_bound_and_nothing_is_written(
        kind, words, tmp_path, monkeypatch, capsys, silent_server, http_server, local_cluster):
    import dome_calib.executor.dask as executor_dask
    from dome_calib.cli import main

    monkeypatch.setattr(executor_dask, "HANDSHAKE_TIMEOUT_S", HANDSHAKE_S)
    cluster, client = local_cluster
    address = {"closed port": f"tcp://127.0.0.1:{_free_port()}", "silent": silent_server, "http": http_server,
               "worker": next(iter(client.scheduler_info()["workers"]))}[kind]
    cap = _capture(tmp_path / "cap")
    t0 = time.monotonic()
    done = run_in_process(main, "dome-calib", ["calibrate", cap, "-o", tmp_path / "out", "--scheduler", address],
                          monkeypatch, capsys)
    seconds = time.monotonic() - t0
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    assert lines[0].startswith(f"dome-calib: error: scheduler {address}: ") and words in lines[0], lines[0]
    assert seconds < 30, seconds  # the command's start-up included
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.work").exists()  # checked before any work


@pytest.mark.parametrize("kind", ["silent", "http", "scheduler"])
def test_the_check_itself_ends_within_its_bound(kind, silent_server, http_server, local_cluster):
    from dome_calib.executor.dask import probe_scheduler

    cluster, _ = local_cluster
    address = {"silent": silent_server, "http": http_server, "scheduler": cluster.scheduler_address}[kind]
    t0 = time.monotonic()
    if kind == "scheduler":
        probe_scheduler(address, HANDSHAKE_S)  # no error: it is one
    else:
        with pytest.raises(DomeCalibError, match=f"scheduler {address}: "):
            probe_scheduler(address, HANDSHAKE_S)
    assert time.monotonic() - t0 < HANDSHAKE_S + 1.0


def _png(path, seed):
    path.parent.mkdir(parents=True, exist_ok=True)
    image = (np.random.default_rng(seed).random((120, 160)) * 255).astype(np.uint8)
    cv2.imwrite(str(path), cv2.GaussianBlur(image, (5, 5), 1.5))


def test_each_image_a_worker_reads_is_proven_before_its_features_are_used(tmp_path, monkeypatch, local_cluster):
    """Two cameras: 01_01 on the shared path (this machine's file is the reference), 01_02 pinned to a capture
    node whose copy differs from capture.json's "images" entry: its features never reach the caller, and the
    error names the worker and the image."""
    from dome_calib.capture_checks import file_sha256
    from dome_calib.executor.dask import DaskExecutor, Route
    from dome_calib.pipeline.cluster import ImageCheck, ProvenImageTask
    from projector.features import FeatureOptions, extract_image

    cluster, client = local_cluster
    cap, node = tmp_path / "cap", tmp_path / "node"
    for cam, seed in (("01_01", 1), ("01_02", 2)):
        _png(cap / "scenes" / "s1" / f"{cam}.png", seed)
    _png(node / "scenes" / "s1" / "01_02.png", 2)
    listed = {"s1/01_02": (node.joinpath("scenes/s1/01_02.png").stat().st_size,
                           file_sha256(node / "scenes" / "s1" / "01_02.png"))}
    monkeypatch.setenv("DOME_CALIB_CAPTURE_ROOT", str(node))  # the worker runs in this process
    worker = str(next(iter(client.scheduler_info()["workers"].values()))["name"])

    def run(check):
        route = Route(worker_of=lambda item: None, task_fn=ProvenImageTask(str(cap), frozenset({"01_02"})),
                      verify=check)
        ex = DaskExecutor(cluster.scheduler_address, client=client, routes={extract_image: route})
        items = [(c, str(cap / "scenes" / "s1" / f"{c}.png"), FeatureOptions()) for c in ("01_01", "01_02")]
        return {r.camera: r for r in ex.map(extract_image, items)}

    check = ImageCheck(cap, {"01_02"}, listed)
    got = run(check)
    assert sorted(got) == ["01_01", "01_02"] and all(r.keypoints is not None for r in got.values())
    assert (check.verified, check.unverified) == (2, 0)

    _png(node / "scenes" / "s1" / "01_02.png", 3)  # the node's copy is another picture
    with pytest.raises(DomeCalibError) as err:
        run(ImageCheck(cap, {"01_02"}, listed))
    message = str(err.value)
    assert message.startswith(f"worker {worker}: {cap / 'scenes' / 's1' / '01_02.png'}: not the image ")
    assert "capture.json lists for it" in message and "stopped before its features were used" in message

    unlisted = ImageCheck(cap, {"01_02"}, {})  # no "images" in capture.json: the node's image cannot be checked
    run(unlisted)
    assert (unlisted.verified, unlisted.unverified) == (1, 1)


def test_a_shared_path_worker_that_reads_other_bytes_is_named(tmp_path):
    from dome_calib.pipeline.cluster import ImageCheck, fingerprint
    from projector.features import FeatureOptions

    cap = tmp_path / "cap"
    _png(cap / "scenes" / "s1" / "01_01.png", 1)
    path = cap / "scenes" / "s1" / "01_01.png"
    check = ImageCheck(cap, set(), {})
    check(("01_01", str(path), FeatureOptions()), "w1", fingerprint(path))
    with pytest.raises(DomeCalibError, match=r"worker w2: .*01_01.png: not the image this machine reads there "
                                             r"\(12 bytes, SHA-256 000000000000\.\.\.; expected"):
        check(("01_01", str(path), FeatureOptions()), "w2", (12, "0" * 64))
    with pytest.raises(DomeCalibError, match=r"worker w3: .*01_01.png: not the image this machine reads there "
                                             r"\(no such file;"):
        check(("01_01", str(path), FeatureOptions()), "w3", None)
