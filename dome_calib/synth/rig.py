"""A few-camera rig, as most multi-camera users have: 5 HD-like cameras around a 3 x 3 m area at about head
height, looking at its centre, and a group of 3-4 people close together in it (a conversation, one walking round
it, one crouching: :func:`dome_calib.synth.group.make_group`, scenario ``small_area``). People near a camera are
cut by its image border (feet first), so everyone is partly outside some view some of the time.

    from dome_calib.synth.rig import RigOptions, few_camera_rig, rig_group
    bundle = few_camera_rig(RigOptions(seed=0))                     # cameras 00_00..00_04 (HD), sync tables
    truth = rig_group(bundle, n_people=4, seed=0)                   # the group, over the rig's span
    det = synth_detections(bundle, truth, model=DetectorModel(seed=0))

Cameras: evenly spread round a circle of ``radius_cm`` about the area's centre (the floor origin, Panoptic world:
y down, cm), each moved by ``place_jitter_cm`` and turned by ``aim_jitter_deg`` from the seed, at ``height_cm``
above the floor, aimed at the centre ``aim_height_cm`` above the floor; ``resolution`` (1920 x 1080), a focal
length from ``hfov_deg`` (70 deg: 1371 px), a mild barrel distortion. One stream, ``hd``, at ``fps``
(30000/1001) over ``start_ms`` .. ``start_ms + duration_ms``, every camera on it (a genlocked rig).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from dome_calib.bundle import Bundle, Camera, CameraType, SyncTables
from dome_calib.layout import look_at
from dome_calib.rotation import rotvec_to_matrix
from dome_calib.synth.detector_episodes import ANCHOR_LEAD_MS
from dome_calib.synth.detector_model import DetectorError
from dome_calib.synth.group import GroupOptions, GroupTruth, make_group
from dome_calib.synth.skeleton import HD_FPS, clock_table

#: The rig's group starts this long after the sync tables do (the detector's error states start 1 s before it).
GROUP_MARGIN_MS = ANCHOR_LEAD_MS + 100.0


@dataclass(kw_only=True)
class RigOptions:
    """Where the cameras stand and what they see (defaults: the 5-camera rig of the benches)."""

    n_cameras: int = 5
    radius_cm: float = 250.0  # the 3 x 3 m area's corners are 212 cm from its centre
    height_cm: float = 170.0
    aim_height_cm: float = 90.0
    resolution: tuple[int, int] = (1920, 1080)
    hfov_deg: float = 70.0
    k1: float = -0.05
    place_jitter_cm: float = 20.0
    aim_jitter_deg: float = 2.0
    fps: Fraction = HD_FPS
    start_ms: float = 0.0
    duration_ms: float = 12_000.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 2 <= self.n_cameras <= 31:
            raise DetectorError(f"rig: n_cameras={self.n_cameras} but expected 2..31 (named 00_00..00_30)")
        if not (self.radius_cm > 0 and 0 < self.hfov_deg < 170 and self.duration_ms > 2 * GROUP_MARGIN_MS):
            raise DetectorError("rig: radius_cm > 0, 0 < hfov_deg < 170 and duration_ms > "
                                f"{2 * GROUP_MARGIN_MS:g} are required")


def few_camera_rig(options: RigOptions | None = None) -> Bundle:
    """The rig's cameras (HD, named ``00_00``..) and its one sync stream ``hd``.

    Example:
        >>> bundle = few_camera_rig(RigOptions(n_cameras=5, seed=3))
        >>> sorted(bundle.cameras), bundle.sync.streams["hd"].index[:3]
    """
    o = options or RigOptions()
    rng = np.random.default_rng([o.seed, 5150])
    w, h = o.resolution
    f = 0.5 * w / math.tan(math.radians(o.hfov_deg) / 2)
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    cameras = {}
    for k in range(o.n_cameras):
        angle = 2 * math.pi * k / o.n_cameras + rng.uniform(-0.1, 0.1)
        centre = np.array([o.radius_cm * math.cos(angle), -o.height_cm, o.radius_cm * math.sin(angle)])
        centre += rng.normal(0.0, o.place_jitter_cm / math.sqrt(3), 3) * np.array([1.0, 0.3, 1.0])
        target = np.array([0.0, -o.aim_height_cm, 0.0])
        pan, tilt = rng.normal(0.0, math.radians(o.aim_jitter_deg), 2)
        R = rotvec_to_matrix(np.array([tilt, pan, 0.0])) @ look_at(centre, target, math.radians(rng.normal(0.0, 0.5)))
        name = f"00_{k:02d}"
        cameras[name] = Camera(name=name, type=CameraType.HD, resolution=(w, h), K=K.copy(),
                               dist=np.array([o.k1, 0.0, 0.0, 0.0, 0.0]), R=R, t_cm=-R @ centre, panel=0, node=k)
    sync = SyncTables(streams={"hd": clock_table(o.fps, start_ms=o.start_ms, duration_ms=o.duration_ms)})
    return Bundle(seq=f"rig{o.n_cameras}", cameras=cameras, sync=sync,
                  calib_data_source=f"dome_calib.synth.rig, {o.n_cameras} cameras, seed {o.seed}")


def rig_span_ms(bundle: Bundle) -> tuple[float, float]:
    """(start_ms, duration_ms) of a group in the rig: its sync table's span less :data:`GROUP_MARGIN_MS` at the
    start (the detector's errors start 1 s before the group) and 100 ms at the end."""
    t = bundle.sync.streams["hd"].univ_time_ms
    start = float(t[0]) + GROUP_MARGIN_MS
    return start, float(t[-1]) - 100.0 - start


def rig_group(bundle: Bundle, *, n_people: int = 4, seed: int = 0, scenario: str = "small_area") -> GroupTruth:
    """The rig's group: ``n_people`` (3-4 for the benches) close together, over the rig's span
    (:func:`rig_span_ms`)."""
    start, duration = rig_span_ms(bundle)
    return make_group(GroupOptions(n_people=n_people, scenario=scenario, start_ms=start, duration_ms=duration,
                                   seed=seed))
