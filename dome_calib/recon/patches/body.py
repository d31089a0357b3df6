"""The body over time refined with the parts' rigid motions: a further term of the temporal fit.

A part's motion from one reference time to the next (:mod:`~dome_calib.recon.patches.motion`) carries the joints at
its bone's ends (:data:`TIED_JOINTS`; the head: the whole face): a joint ``X_j`` of a part with motion ``(R, t)``
from time k to k+1 should satisfy ``X_j(k+1) = R X_j(k) + t``. The body over time
(:func:`~dome_calib.recon.people.temporal.refine_tracks`) takes each such tie as the quadratic term

    |X_j(k+1) - R X_j(k) - t|^2 / sigma^2

with ``sigma`` how well the motion carries that joint (:func:`~dome_calib.recon.patches.motion.point_sigma_cm`:
``floor_cm`` and the fit's residual over its number of patches, grown with the joint's lever arm from the patches'
centroid), so a part seen by many patches that move together ties its joints tightly and a poor fit barely at all.
Ties with ``sigma > max_sigma_cm`` are not given. The term is linear in the joints: it joins the time chains'
matrix (a tie couples a joint's consecutive times, inside the chains' band) and the fit stays one linear solve per
round. A joint carried by several parts (the elbow by the upper arm and the forearm) gets each part's tie.

Joints the detections miss are then carried across the gap by the ties: :meth:`JointTies.gap_variance` replaces the
smoothness prior's growth ``q d^3 / 3`` from the nearest measured time by the sum of the tie variances of the tied
steps from a measured time plus the prior's growth over the untied time between (the smaller side), so a joint
filled by the patches is put out while its variance stays below the temporal stage's ``max_sigma_cm``.

**Wrong joints flagged** (:func:`flag_joints`): a per-frame joint farther than ``flag_min_cm`` from the body refined
with the patches where that body is sure of its joint (``c``, the probability that it lies within 5 cm, at least
``flag_min_confidence``).

Without ties nothing of the temporal fit changes (the term is absent).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from dome_calib import ties
from dome_calib.options import UnitInterval, options
from dome_calib.recon.patches.motion import MotionOptions, PartMotions, part_motions, point_sigma_cm
from dome_calib.recon.patches.parts import BONES, PartLabels, PartOptions, label_parts
from dome_calib.schema import PosFinite

#: Per bone of :data:`BONES`, the joints19 it carries: its two ends; the head (neck to the ears' midpoint) carries the
#: whole face, a rigid skull: the neck, the ears, the nose and the eyes.
TIED_JOINTS = [(a, b) if b >= 0 else (a, 16, 18, 1, 15, 17) for _, a, b in BONES]


@options
class TieOptions:
    """How part motions tie the joints (module docstring)."""

    floor_cm: PosFinite = 0.3
    max_sigma_cm: PosFinite = 2.0
    flag_min_cm: PosFinite = 5.0
    flag_min_confidence: UnitInterval = 0.95


@dataclass(frozen=True)
class JointTies:
    """K ties: track_id (K,), joint (K,) joints19 index, from_ms, to_ms (K,) the two consecutive times,
    R (K, 3, 3), t_cm (K, 3) (``X(to) = R X(from) + t``), sigma_cm (K,) per axis."""

    track_id: np.ndarray
    joint: np.ndarray
    from_ms: np.ndarray
    to_ms: np.ndarray
    R: np.ndarray
    t_cm: np.ndarray
    sigma_cm: np.ndarray

    def __len__(self) -> int:
        return len(self.joint)

    def between(self, first_ms: float, last_ms: float) -> JointTies:
        """The ties whose both times lie in [first_ms, last_ms] (a window's fitted span)."""
        keep = (self.from_ms >= first_ms) & (self.to_ms <= last_ms)
        return JointTies(*(getattr(self, f)[keep] for f in JointTies.__dataclass_fields__))

    def _matched(self, lay, times_ms: np.ndarray, bodies) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ties inside a temporal layout: (which ties, point index at ``from``, point index at ``to``)."""
        t = np.asarray(times_ms, dtype=float)
        ids = np.unique(np.concatenate([b.ids for b in bodies] + [np.zeros(0, np.int64)]))
        row = np.full((max(len(ids), 1), len(t)), -1)
        row[lay.bf_track, lay.bf_k] = np.arange(len(lay.bf_k))
        tr = np.clip(np.searchsorted(ids, self.track_id), 0, max(len(ids) - 1, 0))
        k0 = np.clip(np.searchsorted(t, self.from_ms), 0, len(t) - 1)
        k1 = np.clip(np.searchsorted(t, self.to_ms), 0, len(t) - 1)
        ok = (len(ids) > 0) & (ids[tr] == self.track_id) if len(ids) else np.zeros(len(self), bool)
        ok &= (t[k0] == self.from_ms) & (t[k1] == self.to_ms)
        f0, f1 = np.where(ok, row[tr, k0], -1), np.where(ok, row[tr, k1], -1)
        i0 = np.where(f0 >= 0, lay.var[np.maximum(f0, 0), self.joint], -1)
        i1 = np.where(f1 >= 0, lay.var[np.maximum(f1, 0), self.joint], -1)
        use = np.flatnonzero((i0 >= 0) & (i1 >= 0))
        return use, i0[use], i1[use]

    def system(self, lay, times_ms: np.ndarray, bodies) -> tuple[sp.csr_matrix, np.ndarray]:
        """The ties as ``sum w |A x - t|^2`` over a temporal layout's points: (H = sum w A^T A as an (n, n) sparse
        matrix, b = sum w A^T t as (n_var, 3)); the cost's gradient is ``H x - b``."""
        n = 3 * lay.n_var
        use, i0, i1 = self._matched(lay, times_ms, bodies)
        w = 1.0 / self.sigma_cm[use] ** 2
        R, t = self.R[use], self.t_cm[use]
        eye = np.broadcast_to(np.eye(3), R.shape)
        rows, cols, vals = [], [], []
        for a, c, M in ((i1, i1, eye), (i0, i0, np.einsum("kji,kjl->kil", R, R)), (i1, i0, -R),
                        (i0, i1, -np.transpose(R, (0, 2, 1)))):
            r = (3 * a)[:, None, None] + np.arange(3)[None, :, None]
            q = (3 * c)[:, None, None] + np.arange(3)[None, None, :]
            rows.append(np.broadcast_to(r, M.shape).ravel())
            cols.append(np.broadcast_to(q, M.shape).ravel())
            vals.append((w[:, None, None] * M).ravel())
        H = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
        b = np.zeros((lay.n_var, 3))
        wt = w[:, None] * t
        for c in range(3):
            b[:, c] += np.bincount(i1, weights=wt[:, c], minlength=lay.n_var)
        b -= _rows_sum(i0, np.einsum("kji,kj->ki", R, wt), lay.n_var)
        return H, b

    def gap_variance(self, lay, X0: np.ndarray, times_ms: np.ndarray, bodies, base: np.ndarray,
                     q: np.ndarray) -> np.ndarray:
        """(n_var,) the variance a joint the per-frame triangulation missed gains from a measured time: from each
        side, the sum of the tie variances of the tied steps between (each step's ties combined: 1 / sum 1 /
        sigma^2) plus the smoothness prior's ``q d^3 / 3`` over the untied time ``d`` between; the smaller side,
        and never more than ``base`` (the prior's alone, from the nearest measured time). q (19,) cm^2/s^3."""
        use, i0, i1 = self._matched(lay, times_ms, bodies)
        step_info = np.zeros(lay.n_var)  # information of the step from point i0 to the next
        np.add.at(step_info, i0, 1.0 / self.sigma_cm[use] ** 2)
        out = base.copy()
        have = np.isfinite(X0).all(-1)
        t_s = np.asarray(times_ms, dtype=float)[lay.bf_k] / 1000.0
        for tr in np.unique(lay.bf_track):
            rows = np.flatnonzero(lay.bf_track == tr)
            dt = np.diff(t_s[rows])
            for j in np.flatnonzero((lay.var[rows] >= 0).any(0)):
                v = lay.var[rows, j]
                seen = have[rows, j]
                info = step_info[v[:-1]]
                tie_var = np.where(info > 0, 1.0 / np.where(info > 0, info, 1.0), 0.0)
                untied = np.where(info > 0, 0.0, dt)
                side = []
                for order in (np.arange(len(v)), np.arange(len(v))[::-1]):
                    acc_var, acc_d, started = 0.0, 0.0, False
                    got = np.full(len(v), np.inf)
                    for a, i in enumerate(order):
                        if seen[i]:
                            acc_var, acc_d, started = 0.0, 0.0, True
                        elif started:
                            k = min(i, order[a - 1])  # the step between i and the previous time in this order
                            acc_var, acc_d = acc_var + tie_var[k], acc_d + untied[k]
                        if started:
                            got[i] = acc_var + q[j] * acc_d ** 3 / 3.0
                    side.append(got)
                out[v] = np.minimum(out[v], np.minimum(*side))
        return out


def _rows_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    return np.stack([np.bincount(index, weights=values[:, c], minlength=n) for c in range(values.shape[1])], 1)


def joint_ties(motions: PartMotions, track_ids: np.ndarray, times_ms: np.ndarray, joints_cm: np.ndarray,
               options: TieOptions | None = None) -> JointTies:
    """Part motions -> the ties of their joints.

    Args:
        motions: from :func:`~dome_calib.recon.patches.motion.part_motions`, ``person`` indexing ``track_ids``.
        track_ids: (P,) the track id of each person of the skeleton the patches were labelled with.
        times_ms: (T,) the reference times (``motions.step`` k: from times[k] to times[k+1]).
        joints_cm: (T, P, 19, 3) that skeleton (the joints' lever arms from the patches).
    """
    o = options or TieOptions()
    J = _interpolated(np.asarray(joints_cm, dtype=float), np.asarray(times_ms, dtype=float))
    m_idx, joint = [], []
    for b, js in enumerate(TIED_JOINTS):
        on = np.flatnonzero(motions.bone == b)
        for j in js:
            m_idx.append(on)
            joint.append(np.full(len(on), j))
    m = np.concatenate(m_idx + [np.zeros(0, np.int64)]).astype(np.int64)
    joint = np.concatenate(joint + [np.zeros(0, np.int64)]).astype(np.int64)
    k, p = motions.step[m], motions.person[m]
    X = J[k, p, joint]
    sub = PartMotions(*(getattr(motions, f)[m] for f in PartMotions.__dataclass_fields__))
    sigma = point_sigma_cm(sub, X, o.floor_cm)
    keep = np.isfinite(sigma) & ties.at_most(sigma, o.max_sigma_cm, ties.LENGTH_QUANTUM_CM)
    t = np.asarray(times_ms, dtype=float)
    return JointTies(track_id=np.asarray(track_ids)[p[keep]], joint=joint[keep], from_ms=t[k[keep]],
                     to_ms=t[k[keep] + 1], R=motions.R[m[keep]], t_cm=motions.t_cm[m[keep]], sigma_cm=sigma[keep])


def ties_from_patches(X_cm: np.ndarray, normal: np.ndarray, alive: np.ndarray, times_ms: np.ndarray, bodies,
                      options: TieOptions | None = None, part_options: PartOptions | None = None,
                      motion_options: MotionOptions | None = None) -> tuple[JointTies, PartLabels, PartMotions]:
    """The stage's one entry: patch trajectories and the body over time alone -> the ties for the fit with them.

    Args:
        X_cm: (N, T, 3, 3) the patches' centres and plane points at the reference times ``times_ms`` (T,).
        normal: (N, T, 3); alive: (N, T).
        bodies: the body over time at those times (one :class:`~dome_calib.recon.people.bodies.Bodies` per time,
            track ids >= 0): the skeleton the patches are labelled with.
    Returns:
        (ties, the patches' labels (person: index into the sorted track ids), the part motions).
    """
    ids = np.unique(np.concatenate([b.ids for b in bodies] + [np.zeros(0, np.int64)]))
    J = np.full((len(bodies), len(ids), 19, 3), np.nan)
    for k, b in enumerate(bodies):
        J[k, np.searchsorted(ids, b.ids)] = b.X_cm
    labels = label_parts(X_cm[:, :, 0], normal, alive, J, part_options)
    motions = part_motions(X_cm, alive, labels.person, labels.bone, motion_options)
    return joint_ties(motions, ids, times_ms, J, options), labels, motions


def _interpolated(J: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(T, P, 19, 3) joints with gaps -> each (person, joint) interpolated linearly over time where it has any."""
    out = J.copy()
    have = np.isfinite(J).all(-1)
    for p, j in zip(*np.nonzero(have.any(0) & ~have.all(0))):
        h = have[:, p, j]
        for c in range(3):
            out[~h, p, j, c] = np.interp(t[~h], t[h], J[h, p, j, c])
    return out


def flag_joints(X_frame_cm: np.ndarray, X_refined_cm: np.ndarray, confidence: np.ndarray,
                options: TieOptions | None = None) -> np.ndarray:
    """(..., 19, 3) per-frame joints, the body refined with the patches and (..., 19) its confidence ``c`` (the
    probability that the joint lies within 5 cm) -> (..., 19) bool: per-frame joints farther than ``flag_min_cm``
    from a refined joint with ``c >= flag_min_confidence`` (module docstring)."""
    o = options or TieOptions()
    d = np.linalg.norm(np.asarray(X_frame_cm) - np.asarray(X_refined_cm), axis=-1)
    return (np.isfinite(d) & ties.above(d, o.flag_min_cm, ties.LENGTH_QUANTUM_CM)
            & ties.at_least(confidence, o.flag_min_confidence, ties.UNIT_QUANTUM))
