"""The Kinects' depth as a witness: a joint in free space, where a depth sensor sees through, is not a joint.

The Panoptic Studio's second stage checks its 3D proposals against the Kinects' depth: a point that lies in front
of the surface a sensor measured along the same ray is in empty air (the sensor saw past it) and cannot be on a
body. Here, for every joint of every body at a time and every Kinect whose depth frame is nearest that time
(within ``max_offset_ms``):

1. the joint goes into the depth camera (:func:`~dome_calib.recon.project.view_set` with the Kinect's depth view:
   the colour camera's pose, then the depth-colour calibration) -> pixel ``(u, v)`` and depth ``z``;
2. the sensor's surface near it: the nearest valid reading (bias and scale of the sensor's model undone, as
   :func:`~dome_calib.recon.depth.correct_depth_mm` does) within ``joint_cm`` of the joint's ray (a disc of
   ``fx * joint_cm / z`` pixels): a right joint a little off, or inside a thin limb whose silhouette it misses by
   a pixel, still finds its limb there;
3. the sensor **sees through** the joint if even that nearest reading lies beyond the joint by more than the margin
   ``n_sigma * sigma_mm(z) + joint_cm`` (``sigma_mm(z) = sigma_1m_mm * (a + b z^2)``: the sensor's axial noise at
   that depth, Kinect v2; ``joint_cm``: a right joint's own error along the ray, and a face joint on the skin).
   Joints outside a sensor's image, behind it, or with no reading near them (out of range, 0 in the frame) get no
   verdict from that sensor.

A joint that ``min_sensors`` sensors see through is rejected (confidence -1, as the joint check drops joints); a
body left with too few joints is dropped by :func:`~dome_calib.recon.people.bodies.build_bodies` as any other. A
joint behind a surface (hidden from the sensor) is never judged: only free space is evidence.

:func:`judge_joints` is the pure stage (bodies, depth frames, calibrations -> verdicts); :class:`DepthWitness`
binds a bundle's Kinects and a depth folder (:func:`~dome_calib.recon.depth.depth_folder_reader`) for the run.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.options import AtLeast, options
from dome_calib.recon.depth import DepthFolder
from dome_calib.recon.errors import ReconError
from dome_calib.recon.project import ViewSet, kinect_color_name, kinect_sensor, project_points, view_set
from dome_calib.schema import NonNegFinite

MM_PER_CM = 10.0
_MAX_RADIUS_PX = 12


@options
class DepthWitnessOptions:
    """sigma_1m_mm, sigma_a, sigma_b: the axial depth noise ``sigma_1m_mm * (sigma_a + sigma_b * z_m^2)`` (Kinect v2
    about 1.4 mm at 1 m and 4-5 mm at 4 m); n_sigma: how many of them a reading may lie beyond a joint; joint_cm: a
    right joint's own error (along the ray and across it); min_sensors: sensors that must see through a joint to
    reject it; max_offset_ms: a depth frame farther in time than this from the body's time is not used."""

    sigma_1m_mm: NonNegFinite = 1.4
    sigma_a: NonNegFinite = 0.8
    sigma_b: NonNegFinite = 0.2
    n_sigma: NonNegFinite = 4.0
    joint_cm: NonNegFinite = 5.0
    min_sensors: AtLeast(1) = 1
    max_offset_ms: NonNegFinite = 20.0

    def sigma_mm(self, z_mm: np.ndarray) -> np.ndarray:
        """Axial noise (mm) of a reading at depth ``z_mm``."""
        z_m = np.asarray(z_mm, dtype=float) / 1000.0
        return self.sigma_1m_mm * (self.sigma_a + self.sigma_b * z_m * z_m)


@dataclass(frozen=True)
class DepthVerdicts:
    """Per joint of P bodies: judged (P, 19) sensors that gave a verdict; seen_through (P, 19) sensors that see
    through it; reject (P, 19) bool (seen through by at least ``min_sensors``); gap_cm (P, 19) the largest depth
    (cm) by which a sensor's nearest reading lies beyond the joint (NaN: no verdict)."""

    judged: np.ndarray
    seen_through: np.ndarray
    reject: np.ndarray
    gap_cm: np.ndarray


@dataclass(frozen=True)
class DepthSensors:
    """The Kinect depth cameras of a bundle as views (``KINECTNODE<n>``) with their sensors' depth model."""

    views: ViewSet
    bias_mm: np.ndarray
    scale: np.ndarray

    @staticmethod
    def of(bundle: Bundle, nodes: list[str] | None = None) -> DepthSensors:
        """Every Kinect of the bundle with a depth calibration and a colour camera (or ``nodes``)."""
        if bundle.kinect is None:
            raise ReconError(f"bundle {bundle.seq}: no Kinect calibration (kcalibration_{bundle.seq}.json): the "
                             "depth witness needs one")
        if nodes is None:
            nodes = sorted((n for n in bundle.kinect.sensors if kinect_color_name(n) in bundle.cameras),
                           key=lambda n: (len(n), n))
        if not nodes:
            raise ReconError(f"bundle {bundle.seq}: no Kinect has both a depth calibration and its colour camera "
                             f"(50_xx) in the calibration: no depth sensor to witness with")
        sensors = [kinect_sensor(bundle, n) for n in nodes]
        return DepthSensors(views=view_set(bundle, list(nodes)),
                            bias_mm=np.array([s.depth_bias_mm for s in sensors], dtype=float),
                            scale=np.array([s.depth_scale for s in sensors], dtype=float))


def judge_joints(X_cm: np.ndarray, frames: dict[str, np.ndarray], sensors: DepthSensors,
                 options: DepthWitnessOptions | None = None) -> DepthVerdicts:
    """Which joints the depth sensors see through (see the module docstring).

    Args:
        X_cm: (P, 19, 3) joints of the bodies at one time, world cm (NaN = missing).
        frames: Kinect node -> its (H, W) uint16 depth frame (mm, 0 = no reading) nearest the time; sensors without
            a frame give no verdicts.
        sensors: :meth:`DepthSensors.of` the bundle.
    Returns:
        :class:`DepthVerdicts`.
    Example:
        >>> v = judge_joints(bodies.X_cm, {"KINECTNODE1": depth}, DepthSensors.of(bundle))
        >>> bodies.X_cm[v.reject]  # joints in free space
    """
    o = options or DepthWitnessOptions()
    X = np.asarray(X_cm, dtype=float).reshape(-1, 19, 3)
    P = len(X)
    judged = np.zeros((P, 19), dtype=np.int64)
    through = np.zeros((P, 19), dtype=np.int64)
    gap = np.full((P, 19), np.nan)
    have = np.all(np.isfinite(X), axis=-1).reshape(-1)
    if P == 0 or not have.any():
        return DepthVerdicts(judged=judged, seen_through=through, reject=through >= o.min_sensors, gap_cm=gap)
    names = sensors.views.names
    use = [i for i, n in enumerate(names) if n in frames]
    proj = project_points(sensors.views.at(use), np.where(have[:, None], X.reshape(-1, 3), 0.0))
    r = np.arange(-_MAX_RADIUS_PX, _MAX_RADIUS_PX + 1)
    du, dv = np.meshgrid(r, r)
    disc2 = (du * du + dv * dv).ravel()
    du, dv = du.ravel(), dv.ravel()
    for k, i in enumerate(use):
        depth = np.asarray(frames[names[i]])
        w, h = sensors.views.resolution[i]
        if depth.shape != (h, w):
            raise ReconError(f"{names[i]}: depth frame has shape {depth.shape} but the calibration says {h} x {w} "
                             "(rows x cols)")
        z_cm = proj.depth_cm[k]
        ok = have & proj.in_front[k] & proj.visible[k]
        if not ok.any():
            continue
        j = np.flatnonzero(ok)
        u, v = np.rint(proj.uv_px[k, j, 0]).astype(np.int64), np.rint(proj.uv_px[k, j, 1]).astype(np.int64)
        radius = np.clip(sensors.views.intr[i, 0] * o.joint_cm / z_cm[j], 1.0, _MAX_RADIUS_PX)
        uu, vv = u[:, None] + du[None], v[:, None] + dv[None]
        inside = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h) & (disc2[None] <= radius[:, None] ** 2)
        raw = np.where(inside, depth[np.clip(vv, 0, h - 1), np.clip(uu, 0, w - 1)], 0).astype(float)
        read = raw > 0
        true_mm = (raw - sensors.bias_mm[i]) / (1.0 + sensors.scale[i])
        nearest_mm = np.min(np.where(read, true_mm, np.inf), axis=1)
        seen = np.isfinite(nearest_mm)
        beyond_cm = (nearest_mm - MM_PER_CM * z_cm[j]) / MM_PER_CM
        margin_cm = o.n_sigma * o.sigma_mm(nearest_mm) / MM_PER_CM + o.joint_cm
        jj = j[seen]
        judged.reshape(-1)[jj] += 1
        through.reshape(-1)[jj] += (beyond_cm[seen] > margin_cm[seen]).astype(np.int64)
        flat_gap = gap.reshape(-1)
        flat_gap[jj] = np.fmax(flat_gap[jj], beyond_cm[seen])
    return DepthVerdicts(judged=judged, seen_through=through, reject=through >= o.min_sensors, gap_cm=gap)


@dataclass
class DepthWitness:
    """A bundle's Kinects, a depth folder and the options, for a run: :meth:`frames_at` the frames nearest a
    time, :meth:`keep` the joints of bodies at a time that no sensor sees through. Picklable (chunks on an
    executor each read their own frames)."""

    sensors: DepthSensors
    tables: dict[str, tuple[np.ndarray, np.ndarray]]  # node -> (frame index, univ time ms) of its depth stream
    folder: DepthFolder
    options: DepthWitnessOptions = field(default_factory=DepthWitnessOptions)

    @staticmethod
    def of(bundle: Bundle, folder: DepthFolder, options: DepthWitnessOptions | None = None) -> DepthWitness:
        """The bundle's Kinects that have a depth calibration, a colour camera, a depth sync table and frames in
        ``folder``; ReconError if none has all four."""
        if bundle.sync is None or not bundle.sync.kinect_depth:
            raise ReconError(f"bundle {bundle.seq}: no Kinect depth sync tables (ksynctables_{bundle.seq}.json, "
                             "kinect.depth): depth frames cannot be put on universal time")
        known = DepthSensors.of(bundle).views.names
        nodes = [n for n in known if n in bundle.sync.kinect_depth and n in folder.nodes]
        if not nodes:
            raise ReconError(f"{folder.root}: no Kinect has a depth calibration, a depth sync table and frames here "
                             f"(calibrated: {', '.join(known) or 'none'}; frames: {', '.join(folder.nodes)})")
        tables = {n: (bundle.sync.kinect_depth[n].index, bundle.sync.kinect_depth[n].univ_time_ms) for n in nodes}
        return DepthWitness(sensors=DepthSensors.of(bundle, nodes), tables=tables, folder=folder,
                            options=options or DepthWitnessOptions())

    def frames_at(self, univ_time_ms: float) -> dict[str, np.ndarray]:
        """Node -> the depth frame nearest ``univ_time_ms`` within ``max_offset_ms`` (nodes without one left out)."""
        out = {}
        for node, (index, times) in self.tables.items():
            k = int(np.argmin(np.abs(times - univ_time_ms))) if len(times) else -1
            if k < 0 or abs(times[k] - univ_time_ms) > self.options.max_offset_ms:
                continue
            frame = self.folder(node, int(index[k]))
            if frame is not None:
                out[node] = frame
        return out

    def keep(self, X_cm: np.ndarray, univ_time_ms: float) -> np.ndarray:
        """(P, 19) bool: the joints of the bodies ``X_cm`` (P, 19, 3) at a time that no sensor sees through."""
        return ~judge_joints(X_cm, self.frames_at(univ_time_ms), self.sensors, self.options).reject
