"""Issue 37, the cluster: paths reach the workers absolute (a relative CAPTURE or -o, the natural way to type them,
would be read in the workers' own working folders), and a scheduler lost mid-run is one line naming it."""
from __future__ import annotations

import time

import pytest

import dome_calib.pipeline.full as pipeline
from dome_calib.errors import DomeCalibError

from .report_data import NO_PLOTS  # the test reads no plot
from .test_calibrate import capture, stand_in_stages  # noqa: F401  (fixtures)


def test_relative_capture_output_and_work_reach_the_stages_absolute(tmp_path, capture, stand_in_stages, monkeypatch):
    cap, _ = capture
    stand_in = pipeline.run_sfm_stage
    seen = {}

    def sfm(capture_dir, work_dir, **kw):
        seen.update(capture=capture_dir, work=work_dir)
        return stand_in(capture_dir, work_dir, **kw)

    monkeypatch.setattr(pipeline, "run_sfm_stage", sfm)
    monkeypatch.chdir(tmp_path)
    result = pipeline.run_calibration(cap.relative_to(tmp_path), "out",
                                      pipeline.CalibrateOptions(progress=None, work_dir="w", report=NO_PLOTS))
    assert seen["capture"].is_absolute() and seen["capture"] == cap
    assert seen["work"].is_absolute() and seen["work"].parent == tmp_path / "w"
    assert result.bundle_dir == tmp_path / "out" and (tmp_path / "out").is_dir()


def _slow(x: int) -> int:
    time.sleep(0.2)
    return x


def test_a_scheduler_lost_mid_run_is_one_line_naming_it():
    from distributed import Client, LocalCluster

    from dome_calib.executor.dask import DaskExecutor

    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
    client = Client(cluster, set_as_default=False)
    try:
        ex = DaskExecutor(cluster.scheduler_address, client=client)
        results = ex.map(_slow, range(40))
        assert next(results) is not None
        cluster.close()  # the scheduler and its worker go away
        with pytest.raises(DomeCalibError, match=f"the scheduler at {cluster.scheduler_address} went away"):
            list(results)
    finally:
        client.close()
        cluster.close()


def test_a_task_error_is_not_taken_for_a_lost_scheduler():
    from distributed import Client, LocalCluster

    from dome_calib.executor.dask import DaskExecutor

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        ex = DaskExecutor(cluster.scheduler_address, client=client, retries=0)
        with pytest.raises(ZeroDivisionError):
            list(ex.map(_inverse, [1, 0]))


def _inverse(x: int) -> float:
    return 1 / x
