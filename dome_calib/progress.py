"""How the stages report progress: a callback ``progress(done, total)``, called as work finishes (as
:func:`timecode.decode.decoder.decode_file` does). A run of several stages (calibrate, session, demo) is given a
:data:`ProgressTasks`: called with a task's description ("features scene_01"), it returns that task's callback.
The bars are drawn at the edge, by the CLI (:mod:`dome_calib.cli.progress`); the library draws nothing.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: ``progress(done, total)``: units done so far and the total (images, pairs, times, samples, ...)
Progress = Callable[[int, int], None]
#: ``tasks(description) -> progress``: a new task, named for the display, and its :data:`Progress` callback
ProgressTasks = Callable[[str], Progress]


def task_progress(tasks: ProgressTasks | None, description: str) -> Progress | None:
    """The callback of a new task ``description``, or None when nobody watches (``tasks`` is None)."""
    return tasks(description) if tasks is not None else None


@contextmanager
def counting(progress: Progress | None, total: int) -> Iterator[Callable[[int], None]]:
    """``advance(n)`` for a stage that counts its units as they end: each call reports ``progress(done, total)``
    (nothing when ``progress`` is None)."""
    done = [0]

    def advance(n: int) -> None:
        done[0] += n
        if progress is not None:
            progress(done[0], total)

    yield advance
