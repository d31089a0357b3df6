"""`dome-calib synth` renders through the project's executor: the same PNG bytes in this process and on a Dask
cluster of separate worker processes (each prepares the scenes from the seed itself); an
unreachable scheduler is one line, exit 1, nothing written. About 15 s of CPU (a LocalCluster of 2 processes,
each importing the stack and preparing the scene)."""
from __future__ import annotations

import json
import socket

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dome_calib.executor import in_order
from dome_calib.synth.capture import SynthOptions, synthesize

CAMERAS = ["01_01", "13_01"]  # two VGA images, one per worker: a second or two each


def _pngs(capture) -> dict[str, bytes]:
    return {p.relative_to(capture).as_posix(): p.read_bytes() for p in sorted((capture / "scenes").rglob("*.png"))}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # ~10 s: a Dask cluster's start; test_executor_dask and test_calibrate keep Dask in the default run
def test_a_dask_cluster_renders_the_same_bytes_as_this_process(tmp_path):
    from distributed import Client, LocalCluster

    from dome_calib.executor.dask import DaskExecutor

    options = SynthOptions(preset="tiny", n_scenes=1, seed=3, cameras=CAMERAS, workers=1)
    local = synthesize(tmp_path / "local", options)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      worker_dashboard_address=":0") as lc, \
            Client(lc, set_as_default=False) as client:
        ex = DaskExecutor(lc.scheduler_address, client=client)
        remote = synthesize(tmp_path / "dask", options, executor=ex)
        stats = ex.stats_dict()["stages"]["render_camera"]
    expected = _pngs(tmp_path / "local")
    assert len(expected) == len(CAMERAS) == local.n_images == remote.n_images
    assert _pngs(tmp_path / "dask") == expected  # byte for byte
    assert stats["tasks"] == len(CAMERAS) and sum(stats["workers"].values()) == len(CAMERAS)
    assert stats["bytes_back"] >= sum(len(b) for b in expected.values())  # the PNGs came back to this process
    meta = json.loads((tmp_path / "dask" / "capture.json").read_text())
    assert meta["cameras"] == CAMERAS and meta["seconds"]["prepare_scenes"] > 0


def test_synth_cli_unreachable_scheduler_is_one_line_and_writes_nothing(tmp_path, dome_calib_cli, monkeypatch):
    import dome_calib.executor.dask as executor_dask

    monkeypatch.setattr(executor_dask, "CONNECT_TIMEOUT_S", 0.5)
    res = dome_calib_cli("synth", tmp_path / "cap", "--preset", "tiny", "--scenes", "1",
                         "--scheduler", f"tcp://127.0.0.1:{_free_port()}")
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "cannot connect" in lines[0], res.stderr
    assert list(tmp_path.iterdir()) == []  # no capture, no staging folder


@given(st.permutations(list(range(12))))
def test_in_order_yields_by_key_whatever_the_completion_order(arrival):
    keys = [f"k{i:02d}" for i in range(12)]
    arrived = [(keys[i], i * i) for i in arrival]
    assert list(in_order(iter(arrived), keys, lambda r: r[0])) == [(k, i * i) for i, k in enumerate(keys)]


def test_in_order_refuses_a_lost_or_unknown_result():
    keys = ["a", "b", "c", "d"]
    with pytest.raises(RuntimeError, match="no result for 'b'"):
        list(in_order(iter([("a", 1), ("c", 3)]), keys, lambda r: r[0]))
    with pytest.raises(ValueError, match="unknown key 'x'"):
        list(in_order(iter([("x", 0)]), keys, lambda r: r[0]))
