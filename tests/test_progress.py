"""Progress at the edge: the stages' ``progress(done, total)`` callbacks and the one helper that draws the bars."""
from __future__ import annotations

from dome_calib.cli.progress import ProgressBars
from dome_calib.progress import counting, task_progress


def test_counting_reports_running_totals():
    seen = []
    with counting(lambda done, total: seen.append((done, total)), 7) as advance:
        advance(2)  # reused before any work
        advance(1)
        advance(4)
    assert seen == [(2, 7), (3, 7), (7, 7)]
    with counting(None, 3) as advance:  # nobody watches: nothing to call
        advance(3)


def test_task_progress_names_the_task():
    made = []
    assert task_progress(None, "features scene_01") is None
    callback = task_progress(lambda description: made.append(description) or (lambda d, t: None), "matching s")
    assert made == ["matching s"] and callable(callback)


def _task(bars: ProgressBars, index: int):
    return bars._display.tasks[index]  # rich's task: what the bar shows


def test_bars_follow_the_callbacks():
    with ProgressBars(enabled=True, transient=True) as bars:
        progress = bars.task("features scene_01")
        progress(3, 10)
        assert (_task(bars, 0).completed, _task(bars, 0).total) == (3, 10)
        step = bars.steps(3, "decoding")
        step("VGA clock")
        step("HD clock")
        assert (_task(bars, 1).description, _task(bars, 1).completed) == ("HD clock", 1)
        tick = bars.counter("detecting boards", 5)
        tick()
        tick()
        assert (_task(bars, 2).completed, _task(bars, 2).total) == (2, 5)
        assert bars.tasks == bars.task


def test_no_bars_without_a_terminal():
    bars = ProgressBars(enabled=False)
    with bars:
        assert bars.tasks is None  # the stages are given no callback and report nothing
        bars.task("still safe")(1, 2)
