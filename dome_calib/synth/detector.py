"""An OpenPose-like 2D detector on every VGA, HD and Kinect colour stream at its own frame times, for a synthetic
group (:mod:`dome_calib.synth.group`), erring as real OpenPose output does, with errors that last
(:mod:`dome_calib.synth.detector_model` holds the options, measured on real output; their statistics:
:mod:`dome_calib.synth.detector_stats`):

- pixel noise relative to the person's height, per joint, growing for people small in the 368-row network input;
  per (camera, person, joint) a constant bias, an exponentially correlated part (tau ~100 ms) and a little white
  noise; hidden joints that are detected anyway are noisier;
- outliers: episodes in which one joint sits off by a drawn size in a held direction (wrists most often);
- misses: episodes, at one rate for visible joints, another for joints the person's own body hides (face turned
  away), another for joints another person hides (:mod:`dome_calib.synth.body_volume`); more near the image
  border; joints outside the image are missing (a person cut by the border is still detected when ``min_joints``
  remain, unless ``truncate_border`` is off: then not at all);
- left/right swaps of the whole body or of one limb pair (both arms' or both legs' lower joints), held for an
  episode; a neighbour's limb (elbow and wrist, or knee and ankle) when a limb end lies within ``neighbour_near``
  x height of another person's same joint, held for an episode;
- false people: up to 3 per image, each a partial skeleton held in place for an episode (with jitter);
- a coordinate written as exactly 0 for an episode (a quirk of real files);
- confidence drawn from measured tables (visible, hidden, outlier joints) through a correlated latent, a few above
  1, lower near the border and for small people.

Each image's detections come in random order (no identity). Pixels follow OpenCV's convention (pixel centres at
integers), as OpenPose's; they are quantised to 0.001 px and confidences to 1e-4, so JSON round trips are exact.

Determinism: every random number of a camera comes from generators keyed ``[seed, crc32(camera name), kind]``
(:mod:`dome_calib.synth.detector_episodes`), drawn in the order of its stream's frames from an anchor 1 s before
the group's start: a camera's detections do not depend on which other cameras, frames or chunks are asked for.
Without sync tables all cameras share one clock: frame k at universal time k * 40 ms (:func:`shared_clock`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from dome_calib.bundle import Bundle, CameraType, SyncTable
from dome_calib.errors import DomeCalibError
from dome_calib.recon.project import project_points, view_set
from dome_calib.recon.streams import stream_of_camera
from dome_calib.synth.body_volume import occluders
from dome_calib.synth.detector_episodes import ANCHOR_LEAD_MS, Episodes, ar_step, camera_key, draw_episodes
from dome_calib.synth.detector_model import (CONF_PERCENTILES, DetectionCounts, DetectorError, DetectorModel,
                                             Lognormal)
from dome_calib.synth.group import GroupTruth
from dome_calib.synth.openpose_write import NAMINGS, openpose_document, openpose_file_name, write_openpose_folder
from dome_calib.synth.skeleton import FEET, JOINTS19, MIRROR19, feet_cm, walking_body_local_cm

logger = logging.getLogger(__name__)

__all__ = ["NAMINGS", "DetectionCounts", "DetectorError", "DetectorModel", "Lognormal", "openpose_document",
           "openpose_file_name", "shared_clock", "synth_detections", "write_openpose_folder"]

SHARED_PERIOD_MS = 40.0
NOMINAL_HEIGHT_CM = 170.0
MAX_FALSE_PEOPLE = 3
_LIMBS = np.array([[4, 5], [10, 11], [7, 8], [13, 14]])  # l arm, r arm, l leg, r leg: (middle, end)
_SWAP_PAIRS = [np.array([4, 5, 10, 11]), np.array([7, 8, 13, 14])]  # arms' / legs' lower joints
_CHAINS = [[0, 1, 15, 16, 17, 18], [3, 4, 5], [9, 10, 11], [6, 7, 8], [12, 13, 14], [0, 2, 3, 9, 6, 12]]
_DETECT_CHUNK_IMAGES = 4000
# the random streams of a camera: per-frame normals and uniforms, the constant biases, one per error kind
_NOISE, _UNIFORM, _BIAS = 1, 2, 3
_KINDS = {"outlier": (10, 2), "miss": (11, 0), "miss_self": (12, 0), "miss_others": (13, 0), "zero": (14, 0),
          "swap_whole": (15, 0), "swap_limb": (16, 1), "neighbour": (17, 1), "false": (18, 25)}  # (kind, attrs)
_JOINT_KINDS = ("outlier", "miss", "miss_self", "miss_others", "zero")  # rows (person, joint); others: person, slot


def shared_clock(start_ms: float, duration_ms: float) -> SyncTable:
    """The one clock of a bundle without sync tables: frame k at universal time k * 40 ms, over the span."""
    k = np.arange(int(np.ceil(start_ms / SHARED_PERIOD_MS)), int(np.floor((start_ms + duration_ms)
                                                                          / SHARED_PERIOD_MS)) + 1)
    return SyncTable(index=k.astype(np.int64), univ_time_ms=k * SHARED_PERIOD_MS)


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


def _rates(m: DetectorModel, P: int) -> dict[str, tuple[np.ndarray, Lognormal]]:
    """Per error kind: (rows' rates, durations); rows: (person, joint) for joint kinds, people, false-person slots."""
    joint = lambda r: np.tile(np.broadcast_to(r, (19,)), P)  # noqa: E731
    person = lambda r: np.full(P, r)  # noqa: E731
    return {"outlier": (joint(m.outlier_rate19()), m.outlier_ms),
            "miss": (joint(m.miss_base), m.miss_ms), "miss_self": (joint(m.miss_self19()), m.miss_self_ms),
            "miss_others": (joint(m.miss_occluded), m.miss_self_ms),
            "zero": (joint(m.zero_coordinate), m.zero_ms),
            "swap_whole": (person(m.swap_lr), m.swap_ms), "swap_limb": (person(m.swap_limb), m.swap_ms),
            "neighbour": (person(m.neighbour_limb), m.neighbour_ms),
            "false": (np.full(MAX_FALSE_PEOPLE, min(m.false_people_per_view / MAX_FALSE_PEOPLE, 0.999)),
                      m.false_ms)}


@dataclass
class _Stream:
    """One stream's cameras: their generators, constant biases, correlated states and episodes."""

    noise: list[np.random.Generator]
    uniform: list[np.random.Generator]
    bias: np.ndarray  # (V, P, 19, 3) unit normals: x, y, confidence
    episodes: dict[str, Episodes]
    ar: np.ndarray | None = None  # (V, P, 19, 3) the correlated unit processes at the last frame
    last_ms: float = 0.0


def _open_stream(m: DetectorModel, cams: list[str], P: int, anchor_ms: float, end_ms: float) -> _Stream:
    keys = [camera_key(m.seed, c) for c in cams]
    rates = _rates(m, P)
    episodes: dict[str, Episodes] = {}
    for name, (kind, n_attrs) in _KINDS.items():
        rate, durations = rates[name]
        episodes[name] = Episodes.stack([draw_episodes(k, kind, rate, durations, anchor_ms, end_ms, n_attrs)
                                         for k in keys])
    bias = np.stack([np.random.default_rng([*k, _BIAS]).standard_normal((P, 19, 3)) for k in keys])
    return _Stream(noise=[np.random.default_rng([*k, _NOISE]) for k in keys],
                   uniform=[np.random.default_rng([*k, _UNIFORM]) for k in keys], bias=bias, episodes=episodes)


def synth_detections(bundle: Bundle, truth: GroupTruth, *, cameras: list[str] | None = None,
                     univ_time_ms: tuple[float, float] | None = None, model: DetectorModel | None = None,
                     counts: DetectionCounts | None = None, with_ids: bool = False
                     ) -> dict[str, dict[int, np.ndarray]] | tuple[dict[str, dict[int, np.ndarray]],
                                                                    dict[str, dict[int, np.ndarray]]]:
    """OpenPose-like detections of ``truth`` in each camera at its own stream's frame times.

    Args:
        cameras: VGA, HD or Kinect colour cameras of ``bundle`` (default: all of them).
        univ_time_ms: (start, end) universal times (ms); default the group's span. The start may lie at most
            :data:`~dome_calib.synth.detector_episodes.ANCHOR_LEAD_MS` before the group's (the errors' anchor).
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
    anchor = truth.start_ms - ANCHOR_LEAD_MS
    if lo < anchor:
        raise DetectorError(f"univ_time_ms starts at {lo:g} ms, more than {ANCHOR_LEAD_MS:g} ms before the group "
                            f"({truth.start_ms:g} ms), where the detector's error states start")
    height_cm = NOMINAL_HEIGHT_CM * np.array([p.scale for p in truth.plans])
    out: dict[str, dict[int, np.ndarray]] = {n: {} for n in names}
    ids_out: dict[str, dict[int, np.ndarray]] = {n: {} for n in names}
    person_ids = np.array(truth.ids, dtype=np.int64)
    P = len(truth.plans)
    for stream_name, (table, cams) in sorted(_stream_tables(bundle, names, anchor, hi).items()):
        keep = (table.univ_time_ms >= anchor) & (table.univ_time_ms <= hi)
        frames, times = table.index[keep], table.univ_time_ms[keep]
        if not np.any(times >= lo):
            continue
        vs = view_set(bundle, cams)
        V = len(cams)
        st = _open_stream(model, cams, P, anchor, hi)
        step = max(1, _DETECT_CHUNK_IMAGES // max(V * max(P, 1), 1))
        for f0 in range(0, len(frames), step):
            sl = slice(f0, min(f0 + step, len(frames)))
            t_chunk, nf = times[sl], len(times[sl])
            Z = np.stack([g.standard_normal((nf, P * 19 * 6 + MAX_FALSE_PEOPLE * 38)) for g in st.noise], 1)
            U = np.stack([g.random((nf, P * 38 + P + MAX_FALSE_PEOPLE)) for g in st.uniform], 1)
            ar = np.empty((nf, V, P, 19, 3))
            for k in range(nf):  # the correlated parts, frame by frame: x, y with the noise's tau, c with its own
                z = Z[k, :, :P * 57].reshape(V, P, 19, 3)
                dt = t_chunk[k] - st.last_ms
                prev = st.ar
                st.ar = np.concatenate([ar_step(None if prev is None else prev[..., :2], z[..., :2], dt,
                                                model.noise_tau_ms),
                                        ar_step(None if prev is None else prev[..., 2:], z[..., 2:], dt,
                                                model.conf_tau_ms)], -1)
                st.last_ms = float(t_chunk[k])
                ar[k] = st.ar
            wanted = t_chunk >= lo
            if not wanted.any():
                continue
            w = np.flatnonzero(wanted)
            Xf, pf = truth.joints_cm(t_chunk[w])
            n_f = len(w)
            proj = project_points(vs, Xf.reshape(-1, 3))
            uv = proj.uv_px.reshape(V, n_f, P, 19, 2).transpose(1, 0, 2, 3, 4)
            inside = proj.visible.reshape(V, n_f, P, 19).transpose(1, 0, 2, 3)
            front = proj.in_front.reshape(V, n_f, P, 19).transpose(1, 0, 2, 3)
            depth = proj.depth_cm.reshape(V, n_f, P, 19)[..., 2].transpose(1, 0, 2)  # body centre
            occ = [occluders(vs.center_cm, Xf[k], pf[k]) for k in range(n_f)]
            h_px = vs.intr[None, :, 1:2] * height_cm[None, None] / np.maximum(depth, 1.0)
            fr = frames[sl][w]
            images = [(cams[v], int(fr[k])) for k in range(n_f) for v in range(V)]
            n = n_f * V
            t_img = np.repeat(t_chunk[w], V)
            v_img = np.tile(np.arange(V), n_f)
            states = {}
            for name, bank in st.episodes.items():
                R = bank.n_rows // V
                on, idx = bank.state(v_img[:, None] * R + np.arange(R)[None], t_img[:, None])
                attrs = (bank.attrs[np.maximum(idx, 0)] if len(bank.row)
                         else np.zeros(idx.shape + (bank.attrs.shape[1],)))
                states[name] = (on, np.where(on[..., None], attrs, 0.0))
            geometry = _Geometry(uv=uv.reshape(n, P, 19, 2), inside=inside.reshape(n, P, 19),
                                 front=front.reshape(n, P, 19),
                                 occ_self=np.stack([o[0] for o in occ], 0).reshape(n, P, 19),
                                 occ_other=np.stack([o[1] for o in occ], 0).reshape(n, P, 19),
                                 present=np.repeat(pf, V, axis=0), h_px=h_px.reshape(n, P),
                                 wh=np.tile(vs.resolution.astype(float), (n_f, 1)))
            draws = _Draws(ar=ar[w].reshape(n, P, 19, 3), bias=np.tile(st.bias, (n_f, 1, 1, 1, 1)).reshape(n, P, 19, 3),
                           z=Z[w].reshape(n, -1)[:, P * 57:], u=U[w].reshape(n, -1), states=states)
            dets, who, c = _detect(model, geometry, draws)
            for (cam, frame), d, wi in zip(images, dets, who):
                out[cam][frame] = d
                ids_out[cam][frame] = np.where(wi >= 0, person_ids[np.maximum(wi, 0)], -1)
            if counts is not None:
                counts.add(c)
    return (out, ids_out) if with_ids else out


def feet_detections(bundle: Bundle, truth: GroupTruth, detections: dict[str, dict[int, np.ndarray]],
                    ids: dict[str, dict[int, np.ndarray]]) -> dict[str, dict[int, np.ndarray]]:
    """BODY_25's six foot joints for detections of ``truth`` (:func:`synth_detections` with ``with_ids``): each foot
    joint of a true person is its ankle's detection moved by the true foot's offset from the true ankle in that
    image (:func:`~dome_calib.synth.skeleton.feet_cm`), with the ankle's confidence; nothing where the ankle was not
    detected and for false people. The foot shares its ankle's error (the detector draws no error of its own for
    it, so every other detection, and every figure measured on them, stays as it was). Returns camera -> frame ->
    (N, 6, 3) in :data:`~dome_calib.synth.skeleton.FEET`'s order."""
    out: dict[str, dict[int, np.ndarray]] = {}
    person_of = {int(pid): p for p, pid in enumerate(truth.ids)}
    ankles = [JOINTS19.index("l_ankle")] * 3 + [JOINTS19.index("r_ankle")] * 3
    lo, hi = truth.start_ms - ANCHOR_LEAD_MS, truth.start_ms + truth.duration_ms
    for _, (table, cams) in sorted(_stream_tables(bundle, sorted(detections), lo, hi).items()):
        time_of = dict(zip(table.index.tolist(), table.univ_time_ms.tolist()))
        for cam in cams:
            vs = view_set(bundle, [cam])
            out[cam] = {}
            for frame, det in detections[cam].items():
                feet = np.zeros((len(det), len(FEET), 3))
                mine = np.flatnonzero(ids[cam][frame] >= 0)
                if len(mine):
                    X = truth.joints_cm(np.array([time_of[int(frame)]]))[0][0]  # (P, 19, 3)
                    P = [person_of[int(i)] for i in ids[cam][frame][mine]]
                    pts = np.concatenate([X[P][:, ankles], feet_cm(X[P])], axis=1)  # (n, 12, 3)
                    uv = project_points(vs, pts.reshape(-1, 3)).uv_px[0].reshape(len(P), 12, 2)
                    ankle = det[mine][:, ankles]  # (n, 6, 3)
                    seen = (ankle[..., 2] > 0) & np.isfinite(uv).all(-1).all(-1)[:, None]
                    feet[mine] = np.where(seen[..., None], np.concatenate(
                        [ankle[..., :2] + uv[:, 6:] - uv[:, :6], ankle[..., 2:]], axis=-1), 0.0)
                feet[..., :2] = np.round(feet[..., :2], 3)  # as the detector rounds its pixels
                out[cam][int(frame)] = feet
    return out


@dataclass(frozen=True)
class _Geometry:
    """n images: uv (n, P, 19, 2); inside, front, occ_self, occ_other (n, P, 19); present (n, P); h_px (n, P)
    person heights; wh (n, 2) image sizes."""

    uv: np.ndarray
    inside: np.ndarray
    front: np.ndarray
    occ_self: np.ndarray
    occ_other: np.ndarray
    present: np.ndarray
    h_px: np.ndarray
    wh: np.ndarray


@dataclass(frozen=True)
class _Draws:
    """n images' random numbers: ar (n, P, 19, 3) correlated unit processes (x, y, c), bias (n, P, 19, 3), z (n, .)
    white normals, u (n, .) uniforms, states: kind -> ((n, rows) on, (n, rows, attrs))."""

    ar: np.ndarray
    bias: np.ndarray
    z: np.ndarray
    u: np.ndarray
    states: dict[str, tuple[np.ndarray, np.ndarray]]


def _table(table: tuple[float, ...], u: np.ndarray) -> np.ndarray:
    """Confidences at quantiles ``u`` (in [0, 1]) of a percentile table (linear between the percentiles)."""
    return np.interp(100.0 * u, CONF_PERCENTILES, table)


def _detect(m: DetectorModel, g: _Geometry, d: _Draws) -> tuple[list[np.ndarray], list[np.ndarray], DetectionCounts]:
    """The detector on n images at once -> per image (N, 19, 3) detections (random order), per image (N,) person
    index (-1: false person), counts."""
    n, P = g.present.shape
    FM = MAX_FALSE_PEOPLE
    st = {k: (on.reshape(n, P, 19), a.reshape(n, P, 19, -1)) if k in _JOINT_KINDS else
          (on.reshape(n, P), a.reshape(n, P, -1)) if k != "false" else (on, a) for k, (on, a) in d.states.items()}
    w_xy = d.z[:, :P * 38].reshape(n, P, 19, 2)
    w_c = d.z[:, P * 38:P * 57].reshape(n, P, 19)
    z_false = d.z[:, P * 57:].reshape(n, FM, 19, 2)
    u_border = d.u[:, :P * 19].reshape(n, P, 19)
    u_above = d.u[:, P * 19:P * 38].reshape(n, P, 19)
    u_order = d.u[:, P * 38:]
    w, h = g.wh[:, 0][:, None, None], g.wh[:, 1][:, None, None]
    cand = g.present[..., None] & g.front & g.inside
    in_view = g.present & cand.any(-1)
    cut = in_view & (g.present[..., None] & g.front & ~g.inside).any(-1)
    uvz = np.where(cand[..., None], g.uv, 0.0)
    d_border = np.minimum.reduce([uvz[..., 0] + 0.5, uvz[..., 1] + 0.5, w - 0.5 - uvz[..., 0], h - 0.5 - uvz[..., 1]])
    near_border = np.clip(1.0 - d_border / max(m.miss_border_px, 1e-9), 0.0, 1.0) * (m.miss_border_px > 0)
    other, own = g.occ_other, g.occ_self & ~g.occ_other
    hidden = other | own
    missed = np.where(other, st["miss_others"][0], np.where(own, st["miss_self"][0], st["miss"][0]))
    missed |= u_border < m.miss_border * near_border
    detected = cand & ~missed
    found = detected.copy()  # the detector's own misses, before a neighbour's limb replaces joints
    img_h = g.wh[:, 1][:, None]
    h_net = np.maximum(g.h_px * m.net_height_px / img_h, 1.0)  # (n, P)
    size_f = (1.0 + m.noise_small_px / h_net) / (1.0 + m.noise_small_px / m.noise_ref_net_px)
    rel = np.asarray(m.noise_rel19)[None, None] * size_f[..., None]  # (n, P, 19) sigma / height
    sigma = rel * g.h_px[..., None] * np.where(hidden, m.hidden_noise, 1.0)
    ou = max(1.0 - m.noise_bias_share - m.noise_white_share, 0.0)
    unit = (np.sqrt(m.noise_bias_share) * d.bias[..., :2] + np.sqrt(ou) * d.ar[..., :2]
            + np.sqrt(m.noise_white_share) * w_xy)
    xy = g.uv + sigma[..., None] * unit
    out_on, out_a = st["outlier"]  # (n, P, 19), (n, P, 19, 2)
    lo = ndtr(np.log(m.k_outlier * rel / m.outlier_size_rel.median) / max(m.outlier_size_rel.log_sd, 1e-9))
    u_size = np.clip(lo + out_a[..., 1] * (1.0 - lo), 1e-9, 1 - 1e-9)  # the lognormal above k_outlier sigmas
    size = m.outlier_size_rel.median * np.exp(m.outlier_size_rel.log_sd * ndtri(u_size)) * g.h_px[..., None]
    angle = 2 * np.pi * out_a[..., 0]
    xy += np.where(out_on, size, 0.0)[..., None] * np.stack([np.cos(angle), np.sin(angle)], -1)
    c_ou = max(1.0 - m.conf_bias_share - m.conf_white_share, 0.0)
    c_lat = ndtr(np.sqrt(m.conf_bias_share) * d.bias[..., 2] + np.sqrt(c_ou) * d.ar[..., 2]
                 + np.sqrt(m.conf_white_share) * w_c)
    conf = np.where(out_on, _table(m.conf_outlier, c_lat), np.where(hidden, _table(m.conf_hidden, c_lat),
                                                                      _table(m.conf_visible, c_lat)))
    size_q = h_net / (h_net + m.noise_small_px)
    size_c = np.minimum(1.0, size_q / (m.noise_ref_net_px / (m.noise_ref_net_px + m.noise_small_px)))
    conf = conf * size_c[..., None] * (1.0 - 0.4 * near_border)
    above = u_above < m.conf_above_1
    conf = np.where(above, 1.0 + 0.04 * u_above / max(m.conf_above_1, 1e-300), np.maximum(conf, 0.01))
    # A neighbour's limb: per limb, the nearest other person whose same limb end is seen, near this one's; in an
    # episode, the episode's limb if it is near one, else the next limb that is.
    ii, pp = np.meshgrid(np.arange(n), np.arange(P), indexing="ij")
    near_any = np.zeros((n, P, 4), dtype=bool)
    nearest = np.zeros((n, P, 4), dtype=np.int64)
    for lb in range(4):
        end = _LIMBS[lb, 1]
        theirs = uvz[:, None, :, end]  # (n, 1, Q, 2)
        dist = np.linalg.norm(theirs - uvz[:, :, None, end], axis=-1)  # (n, P, Q)
        ok = ((cand & ~hidden)[:, None, :, end] & (np.arange(P)[None, None] != np.arange(P)[None, :, None])
              & cand[:, :, end][..., None])
        dist = np.where(ok, dist, np.inf)
        nearest[..., lb] = np.argmin(dist, axis=-1) if P else 0
        near_any[..., lb] = np.take_along_axis(dist, nearest[..., lb:lb + 1], -1)[..., 0] < m.neighbour_near * g.h_px
    eligible = in_view & near_any.any(-1)
    first = np.minimum((st["neighbour"][1][..., 0] * 4).astype(int), 3)  # (n, P)
    turn = (first[..., None] + np.arange(4)) % 4  # the limbs in the order tried
    limb = np.take_along_axis(turn, np.argmax(np.take_along_axis(near_any, turn, -1), -1)[..., None], -1)[..., 0]
    q = np.take_along_axis(nearest, limb[..., None], -1)[..., 0]
    nb_on = st["neighbour"][0]
    borrow = eligible & nb_on
    for k in range(2):
        j = _LIMBS[limb, k]  # (n, P)
        b_i, b_p = np.nonzero(borrow)
        jj, qq = j[b_i, b_p], q[b_i, b_p]
        valid = cand[b_i, qq, jj]  # the neighbour's middle joint may be out of the image
        xy[b_i, b_p, jj] = np.where(valid[:, None], g.uv[b_i, qq, jj] + sigma[b_i, b_p, jj, None]
                                    * unit[b_i, b_p, jj], 0.0)
        detected[b_i, b_p, jj] = valid
        conf[b_i, b_p, jj] = _table(m.conf_visible, c_lat[b_i, b_p, jj]) * size_c[b_i, b_p]
    zero = st["zero"][0] & detected
    xy[..., 0] = np.where(zero, 0.0, xy[..., 0])
    rows = np.concatenate([xy, conf[..., None]], -1)
    rows = np.where(detected[..., None], rows, 0.0)
    limb_swap = in_view & st["swap_limb"][0]
    arms = st["swap_limb"][1][..., 0] < 0.5
    for which, pair in enumerate(_SWAP_PAIRS):
        sel = limb_swap & (arms == (which == 0))
        perm = np.arange(19)
        perm[pair] = MIRROR19[pair]
        rows[sel] = rows[sel][:, perm]
    whole = in_view & st["swap_whole"][0]
    rows[whole] = rows[whole][:, MIRROR19]
    n_det = (rows[..., 2] > 0).sum(-1)
    keep = in_view & (n_det >= m.min_joints) & (m.truncate_border | ~cut)
    false_rows, false_keep = _false_people(m, st["false"][0], st["false"][1], z_false, g.wh)
    rows = np.concatenate([rows, false_rows], 1)
    rows[..., :2] = np.round(rows[..., :2], 3)
    rows[..., 2] = np.where(rows[..., 2] > 0, np.maximum(np.round(rows[..., 2], 4), 1e-4), 0.0)
    keep_all = np.concatenate([keep, false_keep], 1)
    order = np.argsort(u_order, axis=1, kind="stable")
    picked = [order[i][keep_all[i, order[i]]] for i in range(n)]
    dets = [rows[i, k] for i, k in enumerate(picked)]
    who = [np.where(k < P, k, -1) for k in picked]  # person index, -1: false person
    visible = cand & ~hidden
    kept_det = keep[..., None] & detected
    c = DetectionCounts(
        images=n, people_in_view=int(in_view.sum()), people_cut=int(cut.sum()), people_detected=int(keep.sum()),
        people_cut_detected=int((keep & cut).sum()),
        joints_visible=int((visible & (near_border == 0)).sum()),
        joints_visible_detected=int((found & visible & (near_border == 0)).sum()),
        joints_hidden=int((cand & other).sum()), joints_hidden_detected=int((found & cand & other).sum()),
        joints_self=int((cand & own).sum()), joints_self_detected=int((found & cand & own).sum()),
        joints_border=int((visible & (near_border > 0)).sum()),
        joints_border_detected=int((found & visible & (near_border > 0)).sum()),
        joints_detected=int(kept_det.sum()), joints_outlier=int((kept_det & out_on & ~borrow[..., None]).sum()),
        joints_zero_coordinate=int((kept_det & zero).sum()), joints_above_1=int((kept_det & above).sum()),
        swaps_whole=int(whole.sum()), swaps_limb=int(limb_swap.sum()), neighbour_eligible=int(eligible.sum()),
        neighbour_limbs=int(borrow.sum()), false_people=int(false_keep.sum()))
    return dets, who, c


def _false_people(m: DetectorModel, on: np.ndarray, attrs: np.ndarray, z: np.ndarray, wh: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) slots on, (n, 3, 25) their episodes' uniforms, (n, 3, 19, 2) normals (jitter), (n, 2) sizes ->
    ((n, 3, 19, 3) rows, (n, 3) reported: on and with at least ``min_joints`` joints in the image)."""
    g = attrs
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
    conf = _table(m.conf_outlier, g[..., 6:25])
    rows = np.where(has[..., None], np.concatenate([xy, conf[..., None]], -1), 0.0)
    return rows, on & (has.sum(-1) >= m.min_joints)
