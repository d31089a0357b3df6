"""Every progress display of the commands (`dome-calib`, `timecode`): one rich display on stderr with a bar per
task, moved by the stages' ``progress(done, total)`` callbacks (:mod:`dome_calib.progress`). Silent when stderr
is not a terminal (a log file, tests), so a run's output is the same either way.

    with ProgressBars() as bars:
        summary = triangulate_file(..., progress=bars.task("triangulating times"))
        result = run_calibration(..., CalibrateOptions(progress=bars.tasks))  # a bar per stage and scene
"""
from __future__ import annotations

import sys
from collections.abc import Callable

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from dome_calib.progress import Progress as ProgressCallback
from dome_calib.progress import ProgressTasks


class ProgressBars:
    """A live display of bars (description, bar, done/total, elapsed time); a context manager.

    Args:
        enabled: draw the bars (default: when stderr is a terminal).
        transient: remove the bars when the display stops (default: keep them, as a record of the run).
    """

    def __init__(self, enabled: bool | None = None, *, transient: bool = False) -> None:
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._display = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), console=Console(stderr=True), transient=transient,
                                 disable=not self.enabled)

    def __enter__(self) -> ProgressBars:
        self._display.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._display.stop()

    @property
    def tasks(self) -> ProgressTasks | None:
        """What a run of several stages is given (``CalibrateOptions.progress``): :meth:`task`, or None when the
        bars are not drawn (the stages then report nothing)."""
        return self.task if self.enabled else None

    def task(self, description: str) -> ProgressCallback:
        """A new bar named ``description`` (its total unknown until the first call) and its ``progress(done,
        total)`` callback."""
        task_id = self._display.add_task(description, total=None)

        def progress(done: int, total: int) -> None:
            self._display.update(task_id, completed=done, total=total)

        return progress

    def steps(self, total: int, description: str = "") -> Callable[[str], None]:
        """A bar of ``total`` named steps, for a stage that says what it starts (``step(what)`` before each step):
        the bar shows the step's name and how many came before it."""
        task_id = self._display.add_task(description, total=total)
        done = [0]

        def step(what: str) -> None:
            self._display.update(task_id, description=what, completed=done[0])
            done[0] += 1

        return step

    def counter(self, description: str, total: int) -> Callable[[], None]:
        """A bar of ``total`` units for a stage that is told of each unit as it ends (``tick()``)."""
        progress = self.task(description)
        done = [0]
        progress(0, total)

        def tick() -> None:
            done[0] += 1
            progress(done[0], total)

        return tick
