"""The synthetic detector's memory: error states that last, drawn in universal time, the same for any request.

- **Episodes** (an error that is on for a while: a joint off, missed, a limb pair swapped...): per process an
  alternating renewal process, lognormal on-times (:class:`~dome_calib.synth.detector_model.Lognormal`, ms) and
  exponential off-times whose mean makes the share of time on equal to the rate
  (``mean_off = mean_on * (1 - rate) / rate``). It starts at an anchor :data:`ANCHOR_LEAD_MS` before the
  group's start, on with probability ``rate`` (then for a fresh on-time), and runs forward in blocks of
  :data:`BLOCK_CYCLES` cycles per process, each block drawn from ``default_rng([seed, crc32(camera), kind,
  block])`` for every process of the camera at once: the episodes up to a time never depend on how far a request
  reaches, on other cameras, or on chunking. Each episode carries ``n_attrs`` uniforms (which limb, which
  direction, how far...), held for the episode.
- **Correlated noise** (:func:`ar_step`): a unit Gaussian process with an exponential autocorrelation
  ``exp(-dt / tau)`` advanced frame by frame over the stream's own frame times from the anchor (the exact
  discretisation of an Ornstein-Uhlenbeck process at uneven times, dropped frames included).
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from dome_calib.synth.detector_model import Lognormal

#: How long before the group's start the error processes start (their state is drawn at the anchor).
ANCHOR_LEAD_MS = 1000.0
BLOCK_CYCLES = 16


def camera_key(seed: int, camera: str) -> list[int]:
    """The first two words of every random generator of one camera: ``[seed, crc32(camera)]``."""
    return [int(seed), zlib.crc32(camera.encode("utf-8"))]


@dataclass(frozen=True)
class Episodes:
    """Episodes of R processes, by row: ``row`` (E,), ``start_ms`` (E,), ``end_ms`` (E,) sorted by (row, start),
    ``attrs`` (E, A) uniforms; ``anchor_ms`` .. ``end_ms_max``: the span drawn."""

    row: np.ndarray
    start_ms: np.ndarray
    end_ms: np.ndarray
    attrs: np.ndarray
    n_rows: int
    anchor_ms: float
    span_ms: float

    def state(self, rows: np.ndarray, t_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n,) rows and (n,) times (broadcast) -> ((n,) on, (n,) episode index, -1 when off)."""
        rows, t = np.broadcast_arrays(np.asarray(rows, dtype=np.int64), np.asarray(t_ms, dtype=float))
        if len(self.row) == 0:
            return np.zeros(rows.shape, dtype=bool), np.full(rows.shape, -1, dtype=np.int64)
        big = self.span_ms + 1.0
        keys = self.row * big + (self.start_ms - self.anchor_ms)
        q = rows * big + np.clip(t - self.anchor_ms, 0.0, self.span_ms)
        i = np.searchsorted(keys, q, side="right") - 1
        ic = np.maximum(i, 0)
        on = (i >= 0) & (self.row[ic] == rows) & (t < self.end_ms[ic]) & (t >= self.start_ms[ic])
        return on, np.where(on, i, -1)

    @staticmethod
    def stack(parts: list[Episodes]) -> Episodes:
        """The rows of ``parts`` one after another (each part's rows renumbered after the previous'); the parts
        share their anchor and span."""
        offsets = np.cumsum([0] + [p.n_rows for p in parts[:-1]])
        return Episodes(row=np.concatenate([p.row + o for p, o in zip(parts, offsets)]),
                        start_ms=np.concatenate([p.start_ms for p in parts]),
                        end_ms=np.concatenate([p.end_ms for p in parts]),
                        attrs=np.concatenate([p.attrs for p in parts]), n_rows=int(sum(p.n_rows for p in parts)),
                        anchor_ms=parts[0].anchor_ms, span_ms=parts[0].span_ms)


def _on_times(rng: np.random.Generator, durations: Lognormal, shape: tuple[int, ...]) -> np.ndarray:
    return durations.median * np.exp(durations.log_sd * rng.standard_normal(shape))


def draw_episodes(key: list[int], kind: int, rate: np.ndarray, durations: Lognormal, anchor_ms: float,
                  end_ms: float, n_attrs: int = 0) -> Episodes:
    """The episodes of ``len(rate)`` processes (one camera's, of one kind) from ``anchor_ms`` until ``end_ms``.

    Args:
        key: :func:`camera_key`; kind: a number naming the error kind (each kind its own draws).
        rate: (R,) share of time on, in [0, 1).
    """
    rate = np.asarray(rate, dtype=float)
    R = len(rate)
    span = end_ms - anchor_ms
    active = rate > 0
    mean_off = np.where(active, durations.mean * (1.0 - rate) / np.where(active, rate, 1.0), np.inf)
    rng = np.random.default_rng([*key, kind, 0])
    first_on = (rng.random(R) < rate) & active
    first_len = _on_times(rng, durations, (R,))
    first_attrs = rng.random((R, n_attrs))
    rows, starts, ends, attrs = [np.flatnonzero(first_on)], [np.zeros(int(first_on.sum()))], \
        [first_len[first_on]], [first_attrs[first_on]]
    t = np.where(first_on, first_len, 0.0)  # time (after the anchor) each process's next off-time starts
    block = 1
    while np.any(active & (t < span)):
        rng = np.random.default_rng([*key, kind, block])
        off = rng.exponential(1.0, (R, BLOCK_CYCLES)) * mean_off[:, None]
        on = _on_times(rng, durations, (R, BLOCK_CYCLES))
        a = rng.random((R, BLOCK_CYCLES, n_attrs))
        end = t[:, None] + np.cumsum(off + on, axis=1)
        start = end - on
        keep = (start < span) & active[:, None]
        r_i, k_i = np.nonzero(keep)
        rows.append(r_i), starts.append(start[r_i, k_i]), ends.append(end[r_i, k_i]), attrs.append(a[r_i, k_i])
        t = np.where(active, end[:, -1], t)
        block += 1
    row = np.concatenate(rows)
    start = np.concatenate(starts)
    order = np.lexsort((start, row))
    return Episodes(row=row[order].astype(np.int64), start_ms=start[order] + anchor_ms,
                    end_ms=np.concatenate(ends)[order] + anchor_ms,
                    attrs=np.concatenate(attrs)[order].reshape(len(row), n_attrs), n_rows=R, anchor_ms=anchor_ms,
                    span_ms=span)


def empty_episodes(n_rows: int, anchor_ms: float, end_ms: float, n_attrs: int = 0) -> Episodes:
    """No episode in ``n_rows`` processes."""
    return Episodes(row=np.zeros(0, np.int64), start_ms=np.zeros(0), end_ms=np.zeros(0), attrs=np.zeros((0, n_attrs)),
                    n_rows=n_rows, anchor_ms=anchor_ms, span_ms=end_ms - anchor_ms)


def ar_step(state: np.ndarray | None, innovation: np.ndarray, dt_ms: float, tau_ms: float) -> np.ndarray:
    """One frame of a unit-variance process with autocorrelation ``exp(-dt / tau)``: ``rho * state + sqrt(1 -
    rho^2) * innovation`` (``state`` None: the first frame, the innovation itself)."""
    if state is None:
        return innovation
    rho = float(np.exp(-dt_ms / tau_ms)) if tau_ms > 0 else 0.0
    return rho * state + np.sqrt(1.0 - rho * rho) * innovation
