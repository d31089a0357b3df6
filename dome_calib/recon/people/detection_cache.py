"""The detections a run has read, kept beside it so that its later passes do not parse the JSON again.

``reconstruct`` reads a session's OpenPose files in three passes: the per-frame bodies (chunks), the bridging of the
tracks' gaps, and the body over time (windows). Each reads only the frames that bracket its own times, so a long
session is never in memory; parsed and checked again, the same files cost the body over time two thirds of its time
(10,230 files: 1.8 of the windows' 2.2 s). The first pass to read a frame keeps what it read in a folder of the run
(``.npz`` files of a stream's 64 frames: for every camera and frame its (N, 19, 3) joints19, float32 as the streams hold
them); a later pass takes the frames it finds there and reads only the others, so a stream is filled with the very
numbers (and the same people per frame) it would have got from the files: the result does not depend on the cache.

The folder belongs to one run and to one machine (:func:`run_folder`: a temporary folder named with the run's
process id, removed when the run ends, also on an interrupt; one a killed run left behind is removed by the next run
on the machine, once its process is gone). On a cluster whose workers may be other machines (``executor.is_remote``)
nothing is kept and every pass reads its files.
"""
from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np


logger = logging.getLogger(__name__)

#: The run folders' names: PREFIX, the process id, "-", tempfile's random part.
PREFIX = "dome-calib-detections-"
_OWNED = re.compile(re.escape(PREFIX) + r"(\d+)-")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive, and not ours to judge
        return True
    return True


def remove_left_behind(parent: Path) -> list[Path]:
    """Remove the run folders in ``parent`` whose process is gone (a run killed before it could remove its own);
    the folders removed."""
    removed = []
    for folder in sorted(parent.glob(PREFIX + "*")):
        match = _OWNED.match(folder.name)
        if match and folder.is_dir() and not _alive(int(match.group(1))):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    if removed:
        logger.info("removed %d kept-detection folder(s) of runs that ended without removing them", len(removed))
    return removed


@contextlib.contextmanager
def run_folder(parent: Path | None = None) -> Iterator[Path]:
    """A new folder for one run's kept detections in ``parent`` (default: the system's temporary folder), removed
    when the run ends; first, the folders of runs that are gone are removed."""
    parent = Path(parent or tempfile.gettempdir())
    remove_left_behind(parent)
    folder = Path(tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-", dir=parent))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _name(stream: int, frames: np.ndarray) -> str:
    return f"s{stream}.{int(frames.min())}-{int(frames.max())}."


#: Frames per kept file: a later pass loads whole files, so a file holds few frames (the full dome's 521 cameras x
#: 8 people: ~15 MB for 64 frames).
FRAMES_PER_FILE = 64


def store(folder: Path, stream: int, cameras: list[str], people: dict[str, dict[int, np.ndarray]]) -> None:
    """Keep one pass's reading of stream ``stream`` (its index among the source's layouts): camera -> {frame -> (N,
    19, 3)}, ``FRAMES_PER_FILE`` frames a file. Each written to a temporary name, then renamed: a reader sees a whole
    file or none."""
    rows = [(f, v, p) for v, n in enumerate(cameras) for f, p in people.get(n, {}).items()]
    if not rows:
        return
    rows.sort(key=lambda r: (r[0], r[1]))
    frames = np.array([f for f, _, _ in rows], dtype=np.int64)
    distinct = np.unique(frames)
    for start in range(0, len(distinct), FRAMES_PER_FILE):
        block = distinct[start: start + FRAMES_PER_FILE]
        part = [rows[k] for k in np.flatnonzero((frames >= block[0]) & (frames <= block[-1]))]
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=_name(stream, block), suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, camera=np.array([v for _, v, _ in part], dtype=np.int32),
                     frame=np.array([f for f, _, _ in part], dtype=np.int64),
                     count=np.array([len(p) for _, _, p in part], dtype=np.int64),
                     kp=np.concatenate([np.asarray(p, dtype=np.float32).reshape(-1, 19, 3) for _, _, p in part]))
        os.replace(tmp, tmp[: -len(".tmp")] + ".npz")


def load(folder: Path, stream: int, cameras: list[str], frames: np.ndarray) -> dict[tuple[str, int], np.ndarray]:
    """What earlier passes kept of stream ``stream`` at ``frames``: (camera, frame) -> (N, 19, 3) float32."""
    if not len(frames):
        return {}
    lo, hi, wanted = int(frames.min()), int(frames.max()), set(frames.tolist())
    out: dict[tuple[str, int], np.ndarray] = {}
    for path in sorted(folder.glob(f"s{stream}.*.npz")):
        first, last = (int(x) for x in path.name.split(".")[1].split("-"))
        if last < lo or first > hi:
            continue
        with np.load(path) as z:
            camera, frame, count, kp = z["camera"], z["frame"], z["count"], z["kp"]
        offsets = np.concatenate([[0], np.cumsum(count)])
        for k in np.flatnonzero(np.isin(frame, list(wanted))):
            out[(cameras[int(camera[k])], int(frame[k]))] = kp[offsets[k]: offsets[k + 1]]
    return out
