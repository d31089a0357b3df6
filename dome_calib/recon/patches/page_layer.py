"""The people page's patch layer: the patch trajectory stream's live patches at each reference time, coloured by
the body part they were given (:mod:`.parts`), as plain data for the page (:mod:`dome_calib.pages` inlines it, the
one module through which every page's data goes; the page puts the part names in as text).

Packing (the people page's own): centres as little-endian int16 millimetres (a patch beyond +-32.767 m of the
origin is left out and counted in ``notes``), part as int8 (an index into ``parts``; -1: no part), person as int16
(the position of the person in the skeleton array the parts were given with; -1: none); per reference time the
count of patches shown, in time order, then patch-id order. A stream with more patch-times than ``max_points`` shows
one patch in k (by id, k = ceil(patch-times / max_points): about ``max_points`` patch-times), and says so in
``notes``.
"""
from __future__ import annotations

import numpy as np

from dome_calib.pages import pack_b64
from dome_calib.recon.patches.model import PatchTrajectories
from dome_calib.recon.patches.parts import BONES, PartLabels

#: One colour per part of :data:`~dome_calib.recon.patches.parts.BONES` (left warm, right cool), and for none.
PART_COLOURS = ["#8c8c8c", "#e8c547", "#b07aa1", "#9c755f", "#f28e2b", "#4e79a7", "#ff9d5c", "#76b7b2",
                "#e15759", "#59a14f", "#ff6b6b", "#8cd17d"]
NO_PART_COLOUR = "#d0d0d0"
MAX_POINTS = 400_000
_LIMIT_MM = 32767


def patch_layer(traj: PatchTrajectories, labels: PartLabels | None = None, *, max_points: int = MAX_POINTS) -> dict:
    """The page data of ``traj`` (N patches over T reference times) with ``labels`` (N,) (None: no parts).

    Example:
        >>> data["patches"] = patch_layer(traj, label_parts(traj.X_cm[:, :, 0], traj.normal, traj.alive, joints))
    """
    N, T = traj.alive.shape
    if labels is not None and len(labels.bone) != N:
        raise ValueError(f"patch_layer: {len(labels.bone)} labels for {N} patches")
    order = np.argsort(traj.ids, kind="stable")
    total = int(traj.alive.sum())
    step = max(1, -(-total // max_points)) if max_points > 0 else 1
    shown = order[::step]
    alive = traj.alive[shown]  # (n, T)
    mm = np.rint(traj.X_cm[shown][:, :, 0] * 10.0)  # (n, T, 3)
    inside = alive & np.all(np.isfinite(mm) & (np.abs(mm) <= _LIMIT_MM), axis=-1)
    beyond = int((alive & ~inside).sum())
    ti, pi = np.nonzero(inside.T)  # time-major, then patch order
    bone = labels.bone[shown] if labels is not None else np.full(len(shown), -1)
    person = labels.person[shown] if labels is not None else np.full(len(shown), -1)
    notes = []
    if step > 1:
        notes.append(f"one patch in {step} shown ({len(shown)} of {N}: {total} patch-times over {max_points})")
    if beyond:
        notes.append(f"{beyond} patch-times beyond 32.7 m of the origin are not drawn")
    return {"times_ms": np.round(traj.times_ms, 3).tolist(),
            "counts": pack_b64(np.bincount(ti, minlength=T), "<u4"),
            "xyz": pack_b64(mm[pi, ti], "<i2"),
            "part": pack_b64(bone[pi], "<i1"),
            "person": pack_b64(person[pi], "<i2"),
            "parts": [name for name, _, _ in BONES], "colours": PART_COLOURS, "no_part_colour": NO_PART_COLOUR,
            "patches": int(len(shown)), "of_patches": int(N), "labelled": labels is not None, "notes": notes}
