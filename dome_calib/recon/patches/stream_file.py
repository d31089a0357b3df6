"""The patch stream on disk: ``patches.parquet``, an Apache Parquet table any columnar reader opens without our code
(pandas ``read_parquet``, polars, R's arrow, DuckDB, Spark).

One row per patch and reference time at which the patch is alive, sorted by patch id then time:

| column | type | meaning |
|---|---|---|
| ``patch_id`` | int64 | ``cloud * 100000 + k`` (``k``: the patch's place in its seed cloud) |
| ``time_ms`` | float64 | universal time, ms (the reference stream's frame times) |
| ``seed_time_ms`` | float64 | the time its cloud was seeded |
| ``centre_{x,y,z}_cm`` | float64 | the patch centre, world cm (Panoptic frame: y down) |
| ``plane1_{x,y,z}_cm``, ``plane2_{x,y,z}_cm`` | float64 | its two plane points (3 cm from the centre, orthogonal) |
| ``normal_{x,y,z}`` | float64 | unit normal, towards the cameras that see it |
| ``visible_cameras`` | list<string> | the cameras that see it (the MAP visibility), by name |
| ``person_id`` | int64 | the id of the person (body3DScene ``id``) whose part it moves with; -1: none |
| ``part`` | string (null: none) | that body part (``recon.patches.parts.BONES``: torso, head, ..., r_shin) |

The file's key-value metadata ``dome_calib.patches`` holds a JSON object: ``format`` ("dome-calib patch stream"),
``version`` (1), ``units`` (positions cm, times ms), ``world`` (the Panoptic frame), ``cameras`` (every camera
of the stage, in order), ``parts`` (the part names), ``reference_stream``, ``patch_size_cm``, ``axis_cm`` and
(``reconstruct --images``) ``seeding``: ``method`` (sweep, features, skeleton), ``chosen`` ("given" by
``--patch-seeds``, or "auto" with ``neighbour_deg``, ``sweep_reach_deg`` and ``reason``).
Written with pyarrow (zstd compression), through the output's staging.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from dome_calib.recon.patches.model import PatchTrajectories
from dome_calib.recon.patches.parts import BONES, PartLabels

FILE_NAME = "patches.parquet"
METADATA_KEY = b"dome_calib.patches"
FORMAT = "dome-calib patch stream"
VERSION = 1
_AXES = ("x", "y", "z")


def patch_table(traj: PatchTrajectories, labels: PartLabels | None = None, person_ids: np.ndarray | None = None, *,
                reference_stream: str = "", size_cm: float = 6.0, axis_cm: float = 3.0,
                seeding: dict | None = None) -> pa.Table:
    """Trajectories (and their part labels; ``person_ids`` maps a label's person position to its id) -> the table
    of the module docstring."""
    n, t = np.nonzero(traj.alive)  # patch-major: sorted by patch, then time
    order = np.lexsort((traj.times_ms[t], traj.ids[n]))
    n, t = n[order], t[order]
    cols: dict[str, pa.Array] = {"patch_id": pa.array(traj.ids[n].astype(np.int64)),
                                 "time_ms": pa.array(traj.times_ms[t].astype(np.float64)),
                                 "seed_time_ms": pa.array(traj.seed_time_ms[n].astype(np.float64))}
    X = traj.X_cm[n, t]  # (R, 3, 3)
    for k, point in enumerate(("centre", "plane1", "plane2")):
        for a, axis in enumerate(_AXES):
            cols[f"{point}_{axis}_cm"] = pa.array(X[:, k, a].astype(np.float64))
    normal = traj.normal[n, t]
    for a, axis in enumerate(_AXES):
        cols[f"normal_{axis}"] = pa.array(normal[:, a].astype(np.float64))
    vis = traj.visible[n, t]
    offsets = np.concatenate([[0], np.cumsum(vis.sum(1))]).astype(np.int32)
    names = pa.array(list(traj.cameras), type=pa.string())
    cols["visible_cameras"] = pa.ListArray.from_arrays(pa.array(offsets), names.take(np.nonzero(vis)[1]))
    if labels is not None:
        pos, bone = labels.person[n], labels.bone[n]
        ids = np.asarray(person_ids if person_ids is not None else np.arange(max(int(pos.max(initial=-1)) + 1, 0)))
        person = np.where(pos >= 0, ids[np.maximum(pos, 0)] if len(ids) else -1, -1).astype(np.int64)
        part = pa.array([b[0] for b in BONES], type=pa.string()).take(pa.array(bone, mask=bone < 0))
    else:
        person, part = np.full(len(n), -1, np.int64), pa.nulls(len(n), type=pa.string())
    cols["person_id"] = pa.array(person)
    cols["part"] = part
    meta = {"format": FORMAT, "version": VERSION, "units": {"position": "cm", "time": "ms"},
            "world": "Panoptic: origin at the dome floor's centre, y down, cm",
            "cameras": list(traj.cameras), "parts": [b[0] for b in BONES], "reference_stream": reference_stream,
            "patch_size_cm": size_cm, "axis_cm": axis_cm}
    if seeding is not None:
        meta["seeding"] = seeding
    table = pa.table(cols)
    return table.replace_schema_metadata({METADATA_KEY: json.dumps(meta).encode("utf-8")})


def write_patch_table(path: str | Path, table: pa.Table) -> None:
    """Write the table to ``path`` (inside a staged output folder: the caller owns the rename)."""
    pq.write_table(table, str(path), compression="zstd")


def read_patch_metadata(path: str | Path) -> dict:
    """The file's ``dome_calib.patches`` metadata (units, world, cameras, parts)."""
    return json.loads(pq.read_schema(str(path)).metadata[METADATA_KEY])
