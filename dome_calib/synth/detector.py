"""An OpenPose-like 2D detector on every VGA, HD and Kinect colour stream at its own frame times, for a synthetic
group (:mod:`dome_calib.synth.group`), with OpenPose's failure modes:

- pixel noise: OpenPose sees each image scaled to ``net_height_px`` (368) rows, so its error is a few network pixels
  (``noise_px``), growing as the person gets small in the network's input (doubling at ``noise_small_px`` rows),
  then scaled back to the image (an HD image has ~3x the VGA noise in pixels);
- misses: a base rate, far more for joints hidden by a body (:mod:`dome_calib.synth.body_volume`, the person's own
  included), more near the image border; joints outside the image are missing (a person cut by the border is still
  detected when ``min_joints`` joints remain, unless ``truncate_border`` is off: then it is not detected at all);
- hidden joints that are detected anyway are noisier (``occluded_noise``) and have low confidence;
- left/right swaps: of the whole body (``swap_lr``), or of one limb pair, both arms' or both legs' lower joints
  (``swap_limb``);
- a neighbour's limb: with ``neighbour_limb``, a person whose limb end (wrist, ankle) lies within
  ``neighbour_near`` x its height of another person's same joint in the image gets that person's limb (elbow and
  wrist, or knee and ankle);
- false people: Poisson(``false_people_per_view``) per image (at most 3), random partial skeletons (two chains of
  joints) at a random place and size, confidence 0.05-0.35;
- confidence: higher for big, visible people, low for hidden joints, lower near the border.

Each image's detections come in random order (no identity). Pixels follow OpenCV's convention (pixel centres at
integers), as OpenPose's; they are quantised to 0.001 px and confidences to 1e-4, so JSON round trips are exact.

Determinism: every random number of one image comes from ``np.random.default_rng([seed, crc32(camera name),
frame])``, so a camera's detections do not depend on which other cameras or frames are asked for. Without sync
tables all cameras share one clock: frame k at universal time k * 40 ms (:func:`shared_clock`).
"""
from __future__ import annotations

import json
import logging
import zlib
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle, CameraType, SyncTable
from dome_calib.errors import DomeCalibError
from dome_calib.io_utils import atomic_folder
from dome_calib.recon.body_models import JOINT_NAMES, from_joints19, parse_body_model
from dome_calib.recon.project import project_points, view_set
from dome_calib.recon.streams import stream_of_camera
from dome_calib.synth.body_volume import occluded_joints
from dome_calib.synth.group import GroupTruth
from dome_calib.synth.skeleton import MIRROR19, walking_body_local_cm

logger = logging.getLogger(__name__)

SHARED_PERIOD_MS = 40.0
NOMINAL_HEIGHT_CM = 170.0
MAX_FALSE_PEOPLE = 3
_LIMBS = np.array([[4, 5], [10, 11], [7, 8], [13, 14]])  # l arm, r arm, l leg, r leg: (middle, end)
_SWAP_PAIRS = [np.array([4, 5, 10, 11]), np.array([7, 8, 13, 14])]  # arms' / legs' lower joints
_CHAINS = [[0, 1, 15, 16, 17, 18], [3, 4, 5], [9, 10, 11], [6, 7, 8], [12, 13, 14], [0, 2, 3, 9, 6, 12]]
_DETECT_CHUNK_IMAGES = 4000


class DetectorError(DomeCalibError, ValueError):
    """A camera the detector cannot see through (unknown, not a colour camera, no sync table)."""


@dataclass(kw_only=True)
class DetectorModel:
    """Rates of OpenPose's failure modes (defaults: realistic for the dome; see the module docstring)."""

    noise_px: float = 1.5  # std per coordinate, network input pixels, for a large well-seen person
    net_height_px: float = 368.0
    noise_small_px: float = 120.0  # person height (network pixels) at which the noise doubles
    occluded_noise: float = 3.0
    miss_base: float = 0.03
    miss_occluded: float = 0.6
    miss_border_px: float = 20.0  # the border zone, image pixels
    miss_border: float = 0.5  # extra miss probability on the border itself (falls linearly to 0 across the zone)
    swap_lr: float = 0.01
    swap_limb: float = 0.03
    neighbour_limb: float = 0.2
    neighbour_near: float = 0.25
    false_people_per_view: float = 0.05
    min_joints: int = 4
    truncate_border: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("miss_base", "miss_occluded", "miss_border", "swap_lr", "swap_limb", "neighbour_limb"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise DetectorError(f"detector model: {name}={value} but expected a probability in [0, 1]")
        for name in ("noise_px", "noise_small_px", "occluded_noise", "miss_border_px", "false_people_per_view",
                     "neighbour_near"):
            if not getattr(self, name) >= 0.0:
                raise DetectorError(f"detector model: {name}={getattr(self, name)} but expected >= 0")
        if self.net_height_px <= 0 or self.min_joints < 1:
            raise DetectorError("detector model: net_height_px must be > 0 and min_joints >= 1")


@dataclass(kw_only=True)
class DetectionCounts:
    """What the detector did (summed over images): the observed rates of each failure mode.

    joints_* count joints of present people in front of the camera and inside the image; people_in_view: present
    people with at least one such joint; people_cut: of those, cut by the image border.
    """

    images: int = 0
    people_in_view: int = 0
    people_cut: int = 0
    people_detected: int = 0
    people_cut_detected: int = 0
    joints_visible: int = 0  # not hidden, outside the border zone
    joints_visible_detected: int = 0
    joints_hidden: int = 0
    joints_hidden_detected: int = 0
    joints_border: int = 0  # not hidden, inside the border zone
    joints_border_detected: int = 0
    swaps_whole: int = 0
    swaps_limb: int = 0
    neighbour_eligible: int = 0
    neighbour_limbs: int = 0
    false_people: int = 0

    def rates(self) -> dict[str, float]:
        """The observed rates (NaN where nothing was eligible)."""
        def r(a: int, b: int) -> float:
            return a / b if b else float("nan")
        return {"miss_visible": 1 - r(self.joints_visible_detected, self.joints_visible),
                "miss_hidden": 1 - r(self.joints_hidden_detected, self.joints_hidden),
                "miss_border_zone": 1 - r(self.joints_border_detected, self.joints_border),
                "hidden_share": r(self.joints_hidden, self.joints_hidden + self.joints_visible + self.joints_border),
                "people_detected": r(self.people_detected, self.people_in_view),
                "cut_people_detected": r(self.people_cut_detected, self.people_cut),
                "swap_whole": r(self.swaps_whole, self.people_in_view),
                "swap_limb": r(self.swaps_limb, self.people_in_view),
                "neighbour_limb_eligible": r(self.neighbour_eligible, self.people_in_view),
                "neighbour_limb": r(self.neighbour_limbs, self.neighbour_eligible),
                "false_people_per_view": r(self.false_people, self.images)}

    def add(self, other: DetectionCounts) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))


def shared_clock(start_ms: float, duration_ms: float) -> SyncTable:
    """The one clock of a bundle without sync tables: frame k at universal time k * 40 ms, over the span."""
    k = np.arange(int(np.ceil(start_ms / SHARED_PERIOD_MS)), int(np.floor((start_ms + duration_ms)
                                                                          / SHARED_PERIOD_MS)) + 1)
    return SyncTable(index=k.astype(np.int64), univ_time_ms=k * SHARED_PERIOD_MS)


def image_rng(seed: int, camera: str, frame: int) -> np.random.Generator:
    """The generator of one image's random numbers: ``default_rng([seed, crc32(camera), frame])``."""
    return np.random.default_rng([int(seed), zlib.crc32(camera.encode("utf-8")), int(frame)])


def _front_template() -> np.ndarray:
    """(19, 2) the walking body at rest seen from the front (x right in the image, y down), height 1, centred."""
    rest = walking_body_local_cm(np.zeros(1))[0][:, :2]
    rest = rest - 0.5 * (rest.max(0) + rest.min(0))
    return rest / np.ptp(rest[:, 1])


#: The false people's template (image x right, y down, height 1).
_TEMPLATE = _front_template()


def _stream_tables(bundle: Bundle, cameras: list[str], start_ms: float, end_ms: float
                   ) -> dict[str, tuple[SyncTable, list[str]]]:
    out: dict[str, tuple[SyncTable, list[str]]] = {}
    shared = shared_clock(start_ms, end_ms - start_ms) if bundle.sync is None else None
    for name in cameras:
        cam = bundle.cameras.get(name)
        if cam is None:
            raise DetectorError(f"bundle {bundle.seq}: no camera named {name!r}")
        if cam.type not in (CameraType.VGA, CameraType.HD, CameraType.KINECT_COLOR):
            raise DetectorError(f"camera {name}: type {cam.type} is not a colour camera the detector runs on")
        if shared is not None:
            stream, table = "shared", shared
        else:
            try:
                stream, table = stream_of_camera(bundle, name)
            except DomeCalibError as exc:
                raise DetectorError(str(exc)) from None
        out.setdefault(stream, (table, []))[1].append(name)
    return out


def synth_detections(bundle: Bundle, truth: GroupTruth, *, cameras: list[str] | None = None,
                     univ_time_ms: tuple[float, float] | None = None, model: DetectorModel | None = None,
                     counts: DetectionCounts | None = None, with_ids: bool = False
                     ) -> dict[str, dict[int, np.ndarray]] | tuple[dict[str, dict[int, np.ndarray]],
                                                                    dict[str, dict[int, np.ndarray]]]:
    """OpenPose-like detections of ``truth`` in each camera at its own stream's frame times.

    Args:
        cameras: VGA, HD or Kinect colour cameras of ``bundle`` (default: all of them).
        univ_time_ms: (start, end) universal times (ms); default the group's span.
        counts: filled with what the detector did (observed failure rates), if given.
        with_ids: also return, in the same shape and order, each detection's true person id (``truth.ids``;
            -1 = a false person), for oracles and benches (a detector gives no identity).
    Returns:
        camera name -> {that camera's own stream frame index (from the bundle's synctables / ksynctables, or
        :func:`shared_clock` when the bundle has none) -> (N, 19, 3) [x_px, y_px, confidence] in joints19 order
        (missed joint: [0, 0, 0])}, every frame of the span present (N = 0 when nobody is detected).
    Example:
        >>> det = synth_detections(bundle, make_group(GroupOptions(n_people=3)), cameras=["00_03"])
        >>> det["00_03"][frame].shape  # (N, 19, 3)
    """
    model = model or DetectorModel()
    names = sorted(cameras if cameras is not None else
                   [n for n, c in bundle.cameras.items()
                    if c.type in (CameraType.VGA, CameraType.HD, CameraType.KINECT_COLOR)])
    lo, hi = univ_time_ms if univ_time_ms is not None else (truth.start_ms, truth.start_ms + truth.duration_ms)
    height_cm = NOMINAL_HEIGHT_CM * np.array([p.scale for p in truth.plans])
    out: dict[str, dict[int, np.ndarray]] = {n: {} for n in names}
    ids_out: dict[str, dict[int, np.ndarray]] = {n: {} for n in names}
    person_ids = np.array(truth.ids, dtype=np.int64)
    for stream, (table, cams) in sorted(_stream_tables(bundle, names, lo, hi).items()):
        keep = (table.univ_time_ms >= lo) & (table.univ_time_ms <= hi)
        frames, times = table.index[keep], table.univ_time_ms[keep]
        if len(frames) == 0:
            continue
        vs = view_set(bundle, cams)
        X, present = truth.joints_cm(times)  # (F, P, 19, 3), (F, P)
        F, P = present.shape
        step = max(1, _DETECT_CHUNK_IMAGES // max(len(cams) * max(P, 1), 1))
        for f0 in range(0, F, step):
            sl = slice(f0, min(f0 + step, F))
            Xf, pf = X[sl], present[sl]
            nf = len(Xf)
            proj = project_points(vs, Xf.reshape(-1, 3))
            V = len(cams)
            uv = proj.uv_px.reshape(V, nf, P, 19, 2).transpose(1, 0, 2, 3, 4)
            inside = proj.visible.reshape(V, nf, P, 19).transpose(1, 0, 2, 3)
            front = proj.in_front.reshape(V, nf, P, 19).transpose(1, 0, 2, 3)
            depth = proj.depth_cm.reshape(V, nf, P, 19)[..., 2].transpose(1, 0, 2)  # body centre
            occ = np.stack([occluded_joints(vs.center_cm, Xf[k], pf[k]) for k in range(nf)])  # (nf, V, P, 19)
            h_px = vs.intr[None, :, 1:2] * height_cm[None, None] / np.maximum(depth, 1.0)
            images = [(cams[v], int(frames[f0 + k])) for k in range(nf) for v in range(V)]
            dets, who, c = _detect(model, images, uv.reshape(-1, P, 19, 2), inside.reshape(-1, P, 19),
                                   front.reshape(-1, P, 19), occ.reshape(-1, P, 19), np.repeat(pf, V, axis=0),
                                   h_px.reshape(-1, P), np.tile(vs.resolution.astype(float), (nf, 1)))
            for (cam, frame), d, w in zip(images, dets, who):
                out[cam][frame] = d
                ids_out[cam][frame] = np.where(w >= 0, person_ids[np.maximum(w, 0)], -1)
            if counts is not None:
                counts.add(c)
    return (out, ids_out) if with_ids else out


def _detect(model: DetectorModel, images: list[tuple[str, int]], uv: np.ndarray, inside: np.ndarray,
            front: np.ndarray, occ: np.ndarray, present: np.ndarray, h_px: np.ndarray, wh: np.ndarray
            ) -> tuple[list[np.ndarray], list[np.ndarray], DetectionCounts]:
    """The detector on n images at once: uv (n, P, 19, 2), inside/front/occ (n, P, 19), present (n, P), h_px
    (n, P) person heights, wh (n, 2) image sizes -> per image (N, 19, 3) detections (random order), per image (N,)
    person index (-1: false person), counts."""
    n, P = present.shape
    m = model
    FM = MAX_FALSE_PEOPLE
    n_u, n_z = P * 19 + 6 * P + 1 + FM * 26, P * 57 + FM * 38
    U, Z = np.empty((n, n_u)), np.empty((n, n_z))
    for i, (cam, frame) in enumerate(images):
        rng = image_rng(m.seed, cam, frame)
        U[i], Z[i] = rng.random(n_u), rng.standard_normal(n_z)
    u_miss = U[:, :P * 19].reshape(n, P, 19)
    u_p = U[:, P * 19:P * 25].reshape(n, P, 6)  # swap, limb swap, which pair, neighbour, which limb, order
    u_f = U[:, P * 25:]
    z_xy = Z[:, :P * 38].reshape(n, P, 19, 2)
    z_c = Z[:, P * 38:P * 57].reshape(n, P, 19)
    z_f = Z[:, P * 57:].reshape(n, FM, 19, 2)
    w, h = wh[:, 0][:, None, None], wh[:, 1][:, None, None]
    cand = present[..., None] & front & inside
    in_view = present & cand.any(-1)
    cut = in_view & (present[..., None] & front & ~inside).any(-1)
    uvz = np.where(cand[..., None], uv, 0.0)
    d_border = np.minimum.reduce([uvz[..., 0] + 0.5, uvz[..., 1] + 0.5, w - 0.5 - uvz[..., 0], h - 0.5 - uvz[..., 1]])
    near_border = np.clip(1.0 - d_border / max(m.miss_border_px, 1e-9), 0.0, 1.0) * (m.miss_border_px > 0)
    p_miss = 1.0 - (1.0 - m.miss_base) * (1.0 - occ * m.miss_occluded) * (1.0 - m.miss_border * near_border)
    detected = cand & (u_miss >= p_miss)
    found = detected.copy()  # the detector's own misses, before a neighbour's limb replaces joints
    img_h = wh[:, 1][:, None]
    h_net = np.maximum(h_px * m.net_height_px / img_h, 1.0)  # (n, P)
    sigma = m.noise_px * (img_h / m.net_height_px) * (1.0 + m.noise_small_px / h_net)
    sigma = sigma[..., None] * np.where(occ, m.occluded_noise, 1.0)
    xy = uv + sigma[..., None] * z_xy
    size_q = (h_net / (h_net + m.noise_small_px))[..., None]
    conf = np.where(occ, 0.15 + 0.2 * size_q, 0.45 + 0.45 * size_q) + 0.07 * z_c
    conf = np.clip(conf * (1.0 - 0.4 * near_border), 0.05, 1.0)
    # A neighbour's limb: the nearest other person whose same limb end is seen, near this one's.
    limb = np.minimum((u_p[..., 4] * 4).astype(int), 3)  # (n, P)
    end = _LIMBS[limb, 1]
    ii, pp = np.meshgrid(np.arange(n), np.arange(P), indexing="ij")
    mine = uvz[ii, pp, end]  # (n, P, 2)
    theirs = uvz[ii[..., None], np.arange(P)[None, None], end[..., None]]  # (n, P, Q, 2)
    seen = (cand & ~occ)[ii[..., None], np.arange(P)[None, None], end[..., None]]  # (n, P, Q)
    dist = np.linalg.norm(theirs - mine[:, :, None], axis=-1)
    ok = seen & (np.arange(P)[None, None] != np.arange(P)[None, :, None]) & cand[ii, pp, end][..., None]
    dist = np.where(ok, dist, np.inf)
    q = np.argmin(dist, axis=-1)
    eligible = in_view & (np.take_along_axis(dist, q[..., None], -1)[..., 0] < m.neighbour_near * h_px)
    borrow = eligible & (u_p[..., 3] < m.neighbour_limb)
    for k in range(2):
        j = _LIMBS[limb, k]  # (n, P)
        b_i, b_p = np.nonzero(borrow)
        jj, qq = j[b_i, b_p], q[b_i, b_p]
        valid = cand[b_i, qq, jj]  # the neighbour's middle joint may be out of the image
        xy[b_i, b_p, jj] = np.where(valid[:, None], uv[b_i, qq, jj] + sigma[b_i, b_p, jj, None]
                                    * z_xy[b_i, b_p, jj], 0.0)
        detected[b_i, b_p, jj] = valid
        conf[b_i, b_p, jj] = np.clip(0.45 + 0.45 * size_q[b_i, b_p, 0] + 0.07 * z_c[b_i, b_p, jj], 0.05, 1.0)
    rows = np.concatenate([xy, conf[..., None]], -1)
    rows = np.where(detected[..., None], rows, 0.0)
    limb_swap = in_view & (u_p[..., 1] < m.swap_limb)
    for which, pair in enumerate(_SWAP_PAIRS):
        sel = limb_swap & ((u_p[..., 2] < 0.5) == (which == 0))
        perm = np.arange(19)
        perm[pair] = MIRROR19[pair]
        rows[sel] = rows[sel][:, perm]
    whole = in_view & (u_p[..., 0] < m.swap_lr)
    rows[whole] = rows[whole][:, MIRROR19]
    n_det = (rows[..., 2] > 0).sum(-1)
    keep = in_view & (n_det >= m.min_joints) & (m.truncate_border | ~cut)
    false_rows, false_keep = _false_people(m, u_f, z_f, wh)
    rows = np.concatenate([rows, false_rows], 1)
    rows[..., :2] = np.round(rows[..., :2], 3)
    rows[..., 2] = np.round(rows[..., 2], 4)
    keep_all = np.concatenate([keep, false_keep], 1)
    order = np.argsort(np.concatenate([u_p[..., 5], u_f[:, 1 + FM * 25:1 + FM * 26]], 1), axis=1, kind="stable")
    picked = [order[i][keep_all[i, order[i]]] for i in range(n)]
    dets = [rows[i, k] for i, k in enumerate(picked)]
    who = [np.where(k < P, k, -1) for k in picked]  # person index, -1: false person
    not_hidden = cand & ~occ
    c = DetectionCounts(
        images=n, people_in_view=int(in_view.sum()), people_cut=int(cut.sum()), people_detected=int(keep.sum()),
        people_cut_detected=int((keep & cut).sum()),
        joints_visible=int((not_hidden & (near_border == 0)).sum()),
        joints_visible_detected=int((found & not_hidden & (near_border == 0)).sum()),
        joints_hidden=int((cand & occ).sum()), joints_hidden_detected=int((found & cand & occ).sum()),
        joints_border=int((not_hidden & (near_border > 0)).sum()),
        joints_border_detected=int((found & not_hidden & (near_border > 0)).sum()),
        swaps_whole=int(whole.sum()), swaps_limb=int(limb_swap.sum()), neighbour_eligible=int(eligible.sum()),
        neighbour_limbs=int(borrow.sum()), false_people=int(false_keep.sum()))
    return dets, who, c


def _false_people(m: DetectorModel, u: np.ndarray, z: np.ndarray, wh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 1 + 3 * 26) uniforms, (n, 3, 19, 2) normals, (n, 2) sizes -> ((n, 3, 19, 3) rows, (n, 3) reported:
    drawn and with at least ``min_joints`` joints in the image)."""
    n, FM = len(u), MAX_FALSE_PEOPLE
    lam = m.false_people_per_view
    # Poisson by inversion of its CDF, capped at MAX_FALSE_PEOPLE.
    pmf = np.exp(-lam) * np.array([lam ** k / np.prod(np.arange(1, k + 1)) for k in range(FM)])
    count = np.searchsorted(np.cumsum(pmf), u[:, 0], side="right")
    g = u[:, 1:1 + FM * 25].reshape(n, FM, 25)
    centre = g[..., 0:2] * wh[:, None]
    height = wh[:, 1][:, None] * (0.08 + 0.3 * g[..., 2])
    angle = (g[..., 3] - 0.5) * 0.6
    c, s = np.cos(angle), np.sin(angle)
    T = _TEMPLATE  # (19, 2)
    px = (c[..., None] * T[:, 0] - s[..., None] * T[:, 1]) * height[..., None] + centre[..., 0:1]
    py = (s[..., None] * T[:, 0] + c[..., None] * T[:, 1]) * height[..., None] + centre[..., 1:2]
    xy = np.stack([px, py], -1) + 0.03 * height[..., None, None] * z
    chain_a = np.minimum((g[..., 4] * 6).astype(int), 5)
    chain_b = np.minimum((g[..., 5] * 6).astype(int), 5)
    member = np.zeros((len(_CHAINS), 19), dtype=bool)
    for k, ch in enumerate(_CHAINS):
        member[k, ch] = True
    has = member[chain_a] | member[chain_b]
    w, h = wh[:, 0][:, None, None], wh[:, 1][:, None, None]
    has &= (xy[..., 0] >= -0.5) & (xy[..., 0] <= w - 0.5) & (xy[..., 1] >= -0.5) & (xy[..., 1] <= h - 0.5)
    conf = 0.05 + 0.3 * g[..., 6:25]
    rows = np.where(has[..., None], np.concatenate([xy, conf[..., None]], -1), 0.0)
    return rows, (np.arange(FM)[None] < count[:, None]) & (has.sum(-1) >= m.min_joints)


OPENPOSE_VERSION = 1.3
NAMINGS = ("openpose", "dotted")


def openpose_file_name(camera: str, frame: int, naming: str = "openpose") -> str:
    """``<camera>_<frame:012d>_keypoints.json`` (OpenPose's ``--write_json``) or ``<camera>.<frame:04d>.json``."""
    if naming == "openpose":
        return f"{camera}_{frame:012d}_keypoints.json"
    if naming == "dotted":
        return f"{camera}.{frame:04d}.json"
    raise DetectorError(f"naming {naming!r} is unknown (known: {', '.join(NAMINGS)})")


def openpose_document(people: np.ndarray, body_model: str = "BODY_25") -> dict:
    """(N, 19, 3) joints19 detections of one image -> OpenPose's JSON document (``--write_json``, version 1.3) in
    the body model's joint order (joints the model has and joints19 lacks, and missed joints: 0, 0, 0)."""
    model = parse_body_model(body_model)
    kp = from_joints19(np.asarray(people, dtype=float).reshape(-1, 19, 3), model)
    empty = {k: [] for k in ("face_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d",
                             "pose_keypoints_3d", "face_keypoints_3d", "hand_left_keypoints_3d",
                             "hand_right_keypoints_3d")}
    return {"version": OPENPOSE_VERSION, "people": [
        {"person_id": [-1], "pose_keypoints_2d": [0 if v == 0 else float(v) for v in person.reshape(-1)]} | empty
        for person in kp]}


def write_openpose_folder(folder: str | Path, detections: dict[str, dict[int, np.ndarray]], *,
                          body_model: str = "BODY_25", naming: str = "openpose") -> Path:
    """Write detections as OpenPose writes them: one sub-folder per camera, one JSON file per frame.

    Args:
        detections: as :func:`synth_detections` returns (camera -> frame -> (N, 19, 3) joints19).
        body_model: "BODY_25", "BODY_25B", "COCO_18" or "PANOPTIC19" (:mod:`dome_calib.recon.body_models`).
        naming: "openpose" (``<camera>_<frame:012d>_keypoints.json``) or "dotted" (``<camera>.<frame:04d>.json``).
    Returns:
        ``folder``, written as a whole (staged beside it, then renamed; an old folder is replaced).
    Example:
        >>> write_openpose_folder(tmp / "detections", synth_detections(bundle, truth), body_model="COCO_18")
    """
    parse_body_model(body_model)
    openpose_file_name("x", 0, naming)
    target = Path(folder)
    with atomic_folder(target) as staging:
        for camera in sorted(detections):
            sub = staging / camera
            sub.mkdir()
            for frame, people in sorted(detections[camera].items()):
                doc = openpose_document(people, body_model)
                (sub / openpose_file_name(camera, int(frame), naming)).write_text(
                    json.dumps(doc, separators=(",", ":")) + "\n", encoding="utf-8")
    logger.info("wrote %d cameras of %s detections to %s", len(detections), body_model, target)
    return target
