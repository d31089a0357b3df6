"""The edges of one channel kept for decoding, block by block, with memory bounded by a block where there is no LTC.

Noise (an unplugged input) crosses the edge finder's thresholds thousands of times a second; kept whole, a two-hour
recording's edges and the bit arrays decoded from them grew to gigabytes. A block whose edges hold no sync word
(forward or reverse, :func:`timecode.decode.bits.find_frames`), and whose neighbours hold none either, cannot hold any
part of a frame (a frame is 1/24 s, a block ~20 s): its edges are counted, then dropped. Blocks with LTC and their
neighbours are kept exactly, so the frames decoded are the same as from every edge.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from timecode.decode.bits import edge_stream, find_frames


def holds_sync_word(t: npt.NDArray[np.float64], rising: npt.NDArray[np.bool_], sample_rate: float) -> bool:
    """Whether the edges (sorted times in samples) hold at least one LTC sync word, forward or reverse."""
    if len(t) < 2 * 16:
        return False
    es = edge_stream(t, rising, sample_rate)
    return es is not None and len(find_frames(es).bits) > 0


@dataclass
class EdgeStore:
    """Per block (in order) the edges of its core and whether its window held a sync word; see the module."""

    blocks: list[tuple[npt.NDArray, ...]] = field(default_factory=list)
    has_sync: list[bool] = field(default_factory=list)
    n_edges: int = 0  # every edge of every core, kept or dropped

    def add(self, core: tuple[npt.NDArray, ...], holds_ltc: bool) -> None:
        self.blocks.append(core)
        self.has_sync.append(holds_ltc)
        self.n_edges += len(core[0])
        if len(self.blocks) >= 2:
            self._settle(len(self.blocks) - 2)

    def _settle(self, i: int) -> None:
        """Drop block i's edges when neither it nor a neighbour held a sync word."""
        near = self.has_sync[max(0, i - 1):i + 2]
        if not any(near) and len(self.blocks[i][0]):
            self.blocks[i] = tuple(np.empty(0, a.dtype) for a in self.blocks[i])  # not a view: frees the block

    def arrays(self) -> tuple[npt.NDArray, ...]:
        """(t, rising, amplitude, impulse) of the kept edges, concatenated in time order."""
        if self.blocks:
            self._settle(len(self.blocks) - 1)
            return tuple(np.concatenate(a) for a in zip(*self.blocks))
        return np.zeros(0), np.zeros(0, bool), np.zeros(0, np.float32), np.zeros(0, bool)
