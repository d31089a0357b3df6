"""The detections a run has read, kept beside it so that its later passes do not parse the JSON again.

``reconstruct`` reads a session's OpenPose files in four passes: the per-frame bodies (chunks), the bridging of the
tracks' gaps, the body over time (windows) and the detector's extra joints (:mod:`~dome_calib.recon.people.extras`).
Each reads only the frames that bracket its own times, so a long session is never in memory; parsed and checked
again, the same files cost the body over time two thirds of its time (10,230 files: 1.8 of the windows' 2.2 s). The
first pass to read a frame keeps what it read in a folder of the run (``.npz`` files of a stream's 64 frames: for
every camera and frame its (N, 19 + E, 3) joints19 and the model's E extra joints, float32 as the streams hold them);
a later pass takes the frames it finds there and reads only the others, so a stream is filled with the very numbers
(and the same people per frame) it would have got from the files: the result does not depend on the cache, and each
file is read once.

The folder belongs to one run and to one machine (``dome_calib.io_utils.run_temp_folder(PREFIX)``: a temporary
folder named with the run's owner tag, removed when the run ends, also on an interrupt; one a killed run left behind
is removed by the next run on the machine, once that run is provably over). On a cluster whose workers may be other
machines (``executor.is_remote``) nothing is kept and every pass reads its files.

The run's people page takes its detections from there too (:class:`KeptDetections`): it shows the values the run
used (float32), and a file is read by the page only where the run kept no frame of it.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The run folders' name: this prefix, then the run's owner tag (:func:`dome_calib.io_utils.run_temp_folder`).
PREFIX = "dome-calib-detections-"


def _name(stream: int, frames: np.ndarray) -> str:
    return f"s{stream}.{int(frames.min())}-{int(frames.max())}."


#: Frames per kept file: a later pass loads whole files, so a file holds few frames (the full dome's 521 cameras x
#: 8 people: ~15 MB for 64 frames).
FRAMES_PER_FILE = 64


def store(folder: Path, stream: int, cameras: list[str], people: dict[str, dict[int, np.ndarray]]) -> None:
    """Keep one pass's reading of stream ``stream`` (its index among the source's layouts): camera -> {frame -> (N,
    J, 3)} (J: 19, or 19 + the model's extra joints), ``FRAMES_PER_FILE`` frames a file. Each written to a temporary name, then renamed: a reader sees a whole
    file or none."""
    rows = [(f, v, p) for v, n in enumerate(cameras) for f, p in people.get(n, {}).items()]
    if not rows:
        return
    rows.sort(key=lambda r: (r[0], r[1]))
    J = np.shape(rows[0][2])[1]  # 19, or 19 + the model's extra joints (one reading of the run: all alike)
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
                     kp=np.concatenate([np.asarray(p, dtype=np.float32).reshape(-1, J, 3) for _, _, p in part]))
        os.replace(tmp, tmp[: -len(".tmp")] + ".npz")


def load(folder: Path, stream: int, cameras: list[str], frames: np.ndarray) -> dict[tuple[str, int], np.ndarray]:
    """What earlier passes kept of stream ``stream`` at ``frames``: (camera, frame) -> (N, J, 3) float32."""
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


@dataclass(frozen=True)
class KeptDetections:
    """A run's kept detections read by camera, for what is written beside the people (the people page): ``folder``
    (the run's, alive while they are written), ``streams`` (each stream's cameras, in the source's layout order)."""

    folder: Path
    streams: list[list[str]]

    def of_camera(self, camera: str, frames: np.ndarray) -> dict[int, np.ndarray]:
        """frame -> (N, 19, 3) joints19 of ``camera`` at those of ``frames`` the run kept (float32 as kept, given as
        float64); a frame it did not keep is absent."""
        for i, cameras in enumerate(self.streams):
            if camera in cameras:
                kept = load(self.folder, i, cameras, np.asarray(frames, dtype=np.int64))
                return {f: p[:, :19].astype(float) for (n, f), p in kept.items() if n == camera}
        return {}
