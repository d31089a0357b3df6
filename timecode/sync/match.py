"""Which frames of other streams match a frame: the lookup consumers need on top of :class:`SyncTable`.

Matching is by universal time only: the sync tables already carry each Kinect's colour/depth exposure timing, so
no constant colour shift (the public toolbox's 6.25 ms) and no frame-index offset (its "+2") is needed. Each match
says which frame and by how much: ``dt_ms = matched frame time - query frame time``.

Example:
    >>> m = match_hd_to_kinect(bundle.sync, hd_index=[5100, 5101], node="KINECTNODE3")
    >>> m.color_index, m.color_dt_ms   # nearest colour frames and their time differences (ms)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.bundle import SyncTable, SyncTables


@dataclass(kw_only=True)
class FrameMatch:
    """Nearest frames of one stream to query times: ``index`` (N,), ``dt_ms`` (N,) = frame time - query time.
    ``within`` (N,) is False where the query lies outside the stream's span (the nearest frame is its first or
    last one and the difference says how far)."""

    index: np.ndarray
    dt_ms: np.ndarray
    within: np.ndarray


@dataclass(kw_only=True)
class KinectMatch:
    """For HD frames ``hd_index`` (N,): the matching colour and depth frames of one Kinect node."""

    node: str
    hd_index: np.ndarray
    color: FrameMatch
    depth: FrameMatch


def match_time(table: SyncTable, univ_time_ms: np.ndarray | float) -> FrameMatch:
    """Nearest frame of ``table`` to each universal time (ms), with the time difference and an in-span flag."""
    t = np.asarray(univ_time_ms, dtype=float)
    index, dt = table.nearest(t)
    within = (t >= table.univ_time_ms[0]) & (t <= table.univ_time_ms[-1])
    return FrameMatch(index=np.asarray(index), dt_ms=np.asarray(dt), within=np.asarray(within))


def match_hd_to_kinect(sync: SyncTables, hd_index: np.ndarray | int, node: str, *,
                       hd_stream: str = "hd") -> KinectMatch:
    """The colour and depth frames of Kinect ``node`` nearest in universal time to HD frames ``hd_index``.

    Raises KeyError naming the stream or node the tables lack, or the first HD frame index they do not hold.
    """
    if hd_stream not in sync.streams:
        raise KeyError(f"sync tables have no stream {hd_stream!r} (have: {', '.join(sync.streams) or 'none'})")
    if node not in sync.kinect_color or node not in sync.kinect_depth:
        have = ", ".join(sorted(set(sync.kinect_color) & set(sync.kinect_depth))) or "none"
        raise KeyError(f"sync tables have no Kinect {node!r} colour and depth streams (have: {have})")
    hd = np.asarray(hd_index)
    t = sync.streams[hd_stream].times_of(hd)
    return KinectMatch(node=node, hd_index=hd, color=match_time(sync.kinect_color[node], t),
                       depth=match_time(sync.kinect_depth[node], t))


def match_hd_to_all_kinects(sync: SyncTables, hd_index: np.ndarray | int, *,
                            hd_stream: str = "hd") -> dict[str, KinectMatch]:
    """:func:`match_hd_to_kinect` for every node that has both colour and depth tables, keyed by node name."""
    nodes = sorted(set(sync.kinect_color) & set(sync.kinect_depth), key=lambda n: (len(n), n))
    return {n: match_hd_to_kinect(sync, hd_index, n, hd_stream=hd_stream) for n in nodes}


def frames_at(sync: SyncTables, univ_time_ms: np.ndarray | float) -> dict[str, FrameMatch]:
    """Nearest frame of every stream to universal time(s): keys "vga", "hd", "KINECTNODE1/color", ..."""
    tables: dict[str, SyncTable] = dict(sync.streams)
    tables.update({f"{n}/color": t for n, t in sync.kinect_color.items()})
    tables.update({f"{n}/depth": t for n, t in sync.kinect_depth.items()})
    return {name: match_time(table, univ_time_ms) for name, table in tables.items()}
