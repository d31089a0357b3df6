"""How well each camera agrees with the bodies: the per-camera tallies behind ``cameras.json``.

Per camera: the people it detected (with enough joints), the ones used by a reconstructed body, and a histogram of
the pixel distance between its used joints and the reconstructed joints. A camera that moved since calibration has
a large median and a small share used. Every tally is a count or a histogram of integer bins: summed over chunks of
times in any order, it is the same as over the whole session (each time counted once).

The per-frame tallies also hold each camera's pixel-noise histogram, from which the body over time measures the
detector's noise once over the whole session (:func:`~dome_calib.recon.people.temporal.noise_px_of`); the body over
time then gives its own verdict (:func:`tally_verdicts`), which replaces the per-frame histogram, and the offset
of each camera's inlier detections from the body (detection minus the body's joint projected, per image axis, in
histograms): their median is where the camera puts people against where the others put them; a camera that moved or
was re-aimed since calibration shifts its detections to one side, which the detector's noise does not
(:func:`~dome_calib.recon.people.scene_io.camera_report`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.recon.people.bodies import PeopleTriangulation
from dome_calib.recon.project import ViewSet
from dome_calib.recon.triangulate import reprojection_error_px

#: Histogram of reprojection errors per camera: bins of 0.1 px up to 200 px (the last bin holds everything above).
ERROR_BIN_PX = 0.1
ERROR_BINS = 2001
#: Histogram of each camera's pixel noise: bins of 0.05 px up to 30 px (farther is a swap or a neighbour, not noise).
NOISE_BIN_PX = 0.05
NOISE_MAX_PX = 30.0
NOISE_BINS = int(round(NOISE_MAX_PX / NOISE_BIN_PX))
#: Histogram of each camera's inlier offsets per image axis: bins of 0.25 px from -64 to +64 px (beyond: the end
#: bins; an inlier lies within 5 sigma of the camera's noise, and the median is what is read).
OFFSET_BIN_PX = 0.25
OFFSET_MAX_PX = 64.0
OFFSET_BINS = int(round(2 * OFFSET_MAX_PX / OFFSET_BIN_PX))


@dataclass
class CameraAgreement:
    """Per camera (``names`` order): detected (V,) people detected (with enough joints), used (V,) of them in a
    body, hist (V, ERROR_BINS) counts of |reprojection - detection| of the used joints in ERROR_BIN_PX bins;
    judged (V,) joint detections the body over time weighed, outvoted (V,) of them it put aside (see
    :mod:`~dome_calib.recon.people.temporal`); noise (V, NOISE_BINS) counts of the used joints' distances within
    NOISE_MAX_PX, each scaled by ``sqrt(2n / (2n - 3))`` for a joint fitted to n views (its 3 degrees of freedom
    taken from their 2n: the residuals are smaller than the noise), in NOISE_BIN_PX bins. depth_joints: joints the
    views agreed on that the Kinects' depth judged, depth_rejected: of them those it saw through (removed; see
    :mod:`~dome_calib.recon.people.depth_witness`): what removed people is told as what it is. offset (V, 2,
    OFFSET_BINS): counts of the body over time's inlier detections' offsets (detection minus the body's joint
    projected; u then v) in OFFSET_BIN_PX bins from -OFFSET_MAX_PX."""

    names: list[str]
    detected: np.ndarray
    used: np.ndarray
    hist: np.ndarray
    judged: np.ndarray
    outvoted: np.ndarray
    noise: np.ndarray
    depth_joints: int = 0
    depth_rejected: int = 0
    offset: np.ndarray = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.offset is None:
            self.offset = np.zeros((len(self.names), 2, OFFSET_BINS), np.int64)

    @classmethod
    def empty(cls, names: list[str]) -> CameraAgreement:
        V = len(names)
        return cls(names, np.zeros(V, np.int64), np.zeros(V, np.int64), np.zeros((V, ERROR_BINS), np.int64),
                   np.zeros(V, np.int64), np.zeros(V, np.int64), np.zeros((V, NOISE_BINS), np.int64))

    def add(self, other: CameraAgreement) -> None:
        self.detected += other.detected
        self.used += other.used
        self.hist += other.hist
        self.judged += other.judged
        self.outvoted += other.outvoted
        self.noise += other.noise
        self.depth_joints += other.depth_joints
        self.depth_rejected += other.depth_rejected
        self.offset += other.offset

    def with_verdicts(self, verdicts: CameraAgreement) -> CameraAgreement:
        """These tallies with the body over time's verdicts (:func:`tally_verdicts`): their histogram replaces the
        per-frame one, judged, outvoted and the offsets are theirs."""
        return CameraAgreement(self.names, self.detected, self.used, verdicts.hist, verdicts.judged,
                               verdicts.outvoted, self.noise, self.depth_joints, self.depth_rejected, verdicts.offset)

    def median_px(self) -> np.ndarray:
        """(V,) median reprojection error of each camera's used joints (NaN if none), to the bin centre."""
        n = self.hist.sum(1)
        cum = np.cumsum(self.hist, axis=1)
        k = np.argmax(cum >= (n[:, None] + 1) // 2, axis=1)
        return np.where(n > 0, (k + 0.5) * ERROR_BIN_PX, np.nan)

    def median_offset_px(self) -> tuple[np.ndarray, np.ndarray]:
        """(V, 2) the median offset of each camera's inlier detections per image axis (u, v; px, to the bin centre;
        NaN if none) and (V,) how many."""
        n = self.offset[:, 0].sum(1)
        k = np.argmax(np.cumsum(self.offset, axis=2) >= (n[:, None, None] + 1) // 2, axis=2)
        return np.where(n[:, None] > 0, (k + 0.5) * OFFSET_BIN_PX - OFFSET_MAX_PX, np.nan), n


def tally_agreement(views: ViewSet, kp: np.ndarray, tri: PeopleTriangulation, ok: np.ndarray, kept: np.ndarray, *,
                    min_joint_conf: float, min_common_joints: int) -> CameraAgreement:
    """The cameras' agreement over a batch: kp (T, V, N, 19, 3) every detection; tri, ok (B, 19) the joints kept,
    kept (B,) the people that became bodies. A person counts as detected with ``min_common_joints`` joints above
    ``min_joint_conf`` (what the association can use)."""
    agreement = CameraAgreement.empty(list(views.names))
    detected = (kp[..., 2] > min_joint_conf).sum(-1) >= min_common_joints  # (T, V, N)
    agreement.detected += detected.sum(axis=(0, 2))
    X_flat = np.where(ok.reshape(-1)[:, None], tri.X_cm.reshape(-1, 3), np.nan)
    uv = tri.uv_px
    err = reprojection_error_px(views, np.nan_to_num(X_flat), np.nan_to_num(uv))  # (B * 19, V)
    used_joint = np.isfinite(uv[..., 0]) & np.isfinite(X_flat).all(1)[:, None] & np.isfinite(err)
    used_joint &= np.repeat(kept, 19)[:, None]
    n = tri.n_inliers.reshape(-1).astype(float)[:, None]
    scaled = err * np.sqrt(2.0 * n / np.maximum(2.0 * n - 3.0, 1.0))
    noisy = used_joint & (n >= 2) & (scaled < NOISE_MAX_PX)
    for v in np.flatnonzero(used_joint.any(0)):
        b = np.minimum((err[used_joint[:, v], v] / ERROR_BIN_PX).astype(np.int64), ERROR_BINS - 1)
        agreement.hist[v] += np.bincount(b, minlength=ERROR_BINS)
        agreement.noise[v] += np.bincount((scaled[noisy[:, v], v] / NOISE_BIN_PX).astype(np.int64),
                                          minlength=NOISE_BINS)
    agreement.used += (tri.assigned[kept] >= 0).sum(0) if len(tri.assigned) else 0
    return agreement


def tally_verdicts(names: list[str], view: np.ndarray, residual_px: np.ndarray, outvoted: np.ndarray,
                   offset_px: np.ndarray | None = None) -> CameraAgreement:
    """The body over time's verdicts on M detections: (M,) views, distances to the final body (px; NaN: the joint
    is not put out, not judged), whether the body put the detection aside and (M, 2) the offsets (detection minus
    the body's joint projected; None: not tallied) -> hist, judged, outvoted, offset (of the inliers) per camera
    (detected, used and noise left 0)."""
    out = CameraAgreement.empty(names)
    view = view.astype(np.int64)
    ok = np.isfinite(residual_px)
    b = np.minimum((residual_px[ok] / ERROR_BIN_PX).astype(np.int64), ERROR_BINS - 1)
    out.hist += np.bincount(view[ok] * ERROR_BINS + b, minlength=len(names) * ERROR_BINS).reshape(-1, ERROR_BINS)
    out.judged += np.bincount(view[ok], minlength=len(names))
    out.outvoted += np.bincount(view[ok & outvoted], minlength=len(names))
    if offset_px is not None:
        inl = ok & ~outvoted & np.isfinite(offset_px).all(1)
        for a in range(2):
            b = np.clip(np.floor((offset_px[inl, a].astype(np.float64) + OFFSET_MAX_PX) / OFFSET_BIN_PX), 0,
                        OFFSET_BINS - 1).astype(np.int64)
            out.offset[:, a] += np.bincount(view[inl] * OFFSET_BINS + b,
                                            minlength=len(names) * OFFSET_BINS).reshape(-1, OFFSET_BINS)
    return out
