"""The dome's design layout: where every camera is meant to be, by name (production: calibrate starts from it
without a prior, and the world frame falls back to it).

:func:`nominal_dome` builds the dome from the paper's description (a geodesic dome 5.49 m across whose centre is
1.40 m above the floor; 20 hexagonal panels of 24 VGA cameras; 31 HD cameras, 20 of them at panel centres; 10 Kinect
colour cameras in two rings of five at 1 m and 2.6 m; every camera aimed at the dome centre). The paper does not
give panel angles, so the panel ring latitudes and azimuths below were measured once from the real calibration
``calibration_160906_band1.json`` (4 rings of 5 panels, 5-fold symmetric). Intrinsics and distortion are drawn
(seeded) around the real file's per-type statistics (:data:`INTRINSICS_STATS`).

World frame: Panoptic (origin at the floor centre, y DOWN, cm); ``x_cam = R @ X_world + t_cm``.
The dome as built, a dome taken from a real file and the projectors are synthetic: :mod:`dome_calib.synth.dome`.
"""
from __future__ import annotations

import logging
from enum import StrEnum

import numpy as np

from dome_calib.bundle import NOMINAL_RESOLUTION, Bundle, Camera, CameraType
from dome_calib.camera import intr_to_K
from dome_calib.errors import DomeCalibError
from dome_calib import exact
from dome_calib.ties import LENGTH_QUANTUM_CM, order_by

logger = logging.getLogger(__name__)

DOME_DIAMETER_CM = 549.0
DOME_RADIUS_CM = DOME_DIAMETER_CM / 2
CENTRE_HEIGHT_CM = 140.0
#: Dome centre in the world frame (y down: 1.40 m above the floor).
DOME_CENTRE_CM = np.array([0.0, -CENTRE_HEIGHT_CM, 0.0])
MOUNT_INSET_CM = 2.0  # camera centres sit this far inside the sphere
KINECT_INSET_CM = 7.0
KINECT_HEIGHTS_CM = (100.0, 260.0)
KINECT_RING_AZIMUTH_DEG = (32.0, 64.0)

#: Panel rings (latitude deg above the dome centre, azimuth of sector 0 deg, panel number of sector 0, step).
#: Sector k of a ring has azimuth ``az0 - 72 k`` and panel number ``first + step * k``. Measured from the real dome.
PANEL_RINGS = ((3.7, -103.1, 1, 3), (13.1, -77.3, 2, 3), (22.4, -123.6, 3, 3), (-3.1, -56.9, 16, 1))
#: HD cameras not at panel centres: (latitude deg, azimuth of the first deg, count).
HD_EXTRA_RINGS = ((40.0, -2.8, 5), (47.8, 32.6, 5), (-12.7, 133.2, 1))


#: Per-type intrinsics statistics of the real dome (mean, std) from calibration_160906_band1.json.
#: f: focal px; c: principal point offset from the image centre px; dist: [k1, k2, p1, p2, k3] mean and std.
INTRINSICS_STATS = {
    CameraType.VGA: dict(f=(745.4, 1.5), c=((49.2, 13.4), (-9.0, 12.4)),
                         dist=((-0.321, 0.049, -1.3e-4, 1.5e-4, 0.081), (0.011, 0.06, 7.4e-4, 8.0e-4, 0.1))),
    CameraType.HD: dict(f=(1476.0, 116.0), c=((-16.2, 8.8), (18.3, 7.4)),
                        dist=((-0.266, 0.190, -2.1e-4, 4.6e-4, -0.023), (0.03, 0.014, 2.5e-4, 3.5e-4, 0.054))),
    CameraType.KINECT_COLOR: dict(f=(1054.7, 3.6), c=((-2.6, 12.5), (0.2, 10.7)),
                                  dist=((0.050, -0.0587, 2.0e-4, 7.7e-5, 0.0142),
                                        (0.0044, 0.0074, 3.3e-4, 5.3e-4, 0.0044))),
}
AIM_JITTER_CM = 8.0
ROLL_JITTER_DEG = 2.0
PIXEL_ASPECT_STD = 1.5e-4  # fy / fx - 1


class Preset(StrEnum):
    TINY = "tiny"  # 4 VGA of each of panels 1 and 13, 5 HD and 3 Kinect colour on and above the arc between them
    PANEL = "panel"  # panels 1-2 (48 VGA), 8 HD, 4 Kinect colour
    FULL = "full"  # every camera


def direction(lat_deg: float, az_deg: float) -> np.ndarray:
    """Unit vector from the dome centre at a latitude (up positive) and azimuth (atan2(z, x)), world frame."""
    lat, az = np.radians(lat_deg), np.radians(az_deg)
    return np.array([exact.cos(lat) * exact.cos(az), -exact.sin(lat), exact.cos(lat) * exact.sin(az)])


def look_at(center_cm: np.ndarray, target_cm: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """cam_from_world rotation (3, 3) of a camera at ``center_cm`` looking at ``target_cm``, image-down = world-down."""
    # in basic operations (dome_calib.exact): the synthetic truth is the same bits on every CPU
    z = exact.unit3(np.asarray(target_cm, dtype=float) - center_cm)
    down = np.array([0.0, 1.0, 0.0])
    y = down - z[1] * z  # (down . z) z
    if exact.norm3(y) < 1e-9:  # looking straight down or up
        y = np.array([0.0, 0.0, 1.0]) - z[2] * z
    y = exact.unit3(y)
    x = exact.cross3(y, z)
    c, s = exact.cos(roll_rad), exact.sin(roll_rad)
    x, y = c * x + s * y, -s * x + c * y
    return np.stack([x, y, z])


def _hexagon_nodes_cm() -> np.ndarray:
    """(24, 2) node offsets in a panel's tangent plane: an inner hexagon of 6 and an outer one of 18 (3 per side)."""
    angles = np.radians(np.arange(6) * 60.0 + 30.0)
    inner = 22.0 * np.stack([exact.cos(angles), exact.sin(angles)], axis=1)
    corners = 55.0 * np.stack([exact.cos(angles), exact.sin(angles)], axis=1)
    outer = [corners[i] + f * (corners[(i + 1) % 6] - corners[i]) for i in range(6) for f in (0.0, 1 / 3, 2 / 3)]
    return np.vstack([inner, np.array(outer)])


def _draw_intrinsics(rng: np.random.Generator, camera_type: CameraType) -> tuple[np.ndarray, np.ndarray]:
    stats = INTRINSICS_STATS[camera_type]
    w, h = NOMINAL_RESOLUTION[camera_type]
    f_mean, f_std = stats["f"]
    fx = float(np.clip(rng.normal(f_mean, f_std), f_mean - 2.5 * f_std, f_mean + 2.5 * f_std))
    fy = fx * (1.0 + rng.normal(0.0, PIXEL_ASPECT_STD))
    (cx_m, cx_s), (cy_m, cy_s) = stats["c"]
    cx = (w - 1) / 2 + float(np.clip(rng.normal(cx_m, cx_s), cx_m - 2.5 * cx_s, cx_m + 2.5 * cx_s))
    cy = (h - 1) / 2 + float(np.clip(rng.normal(cy_m, cy_s), cy_m - 2.5 * cy_s, cy_m + 2.5 * cy_s))
    mean, std = (np.array(v) for v in stats["dist"])
    # k2 and k3 are strongly anti-correlated in real fits; draw them small (0.3 std) so the lens stays monotonic
    scale = np.array([1.0, 0.3, 1.0, 1.0, 0.3])
    dist = mean + scale * std * np.clip(rng.normal(size=5), -2.0, 2.0)
    return intr_to_K(np.array([fx, fy, cx, cy])), dist


def _aimed_camera(rng: np.random.Generator, *, name: str, camera_type: CameraType, center_cm: np.ndarray,
                  panel: int, node: int) -> Camera:
    target = DOME_CENTRE_CM + rng.normal(0.0, AIM_JITTER_CM, size=3)
    R = look_at(center_cm, target, np.radians(rng.normal(0.0, ROLL_JITTER_DEG)))
    K, dist = _draw_intrinsics(rng, camera_type)
    return Camera(name=name, type=camera_type, resolution=NOMINAL_RESOLUTION[camera_type], K=K, dist=dist, R=R,
                  t_cm=-exact.matvec3(R, center_cm), panel=panel, node=node)


def panel_centres() -> dict[int, np.ndarray]:
    """Panel number (1..20) -> unit direction of the panel centre from the dome centre (world frame)."""
    out = {}
    for lat, az0, first, step in PANEL_RINGS:
        for k in range(5):
            out[first + step * k] = direction(lat, az0 - 72.0 * k)
    return dict(sorted(out.items()))


def all_nominal_cameras(seed: int) -> dict[str, Camera]:
    """Every camera of the nominal dome (480 VGA, 31 HD, 10 Kinect colour), drawn with ``seed``."""
    rng = np.random.default_rng([seed, 3])
    r_mount = DOME_RADIUS_CM - MOUNT_INSET_CM
    nodes = _hexagon_nodes_cm()
    cams: dict[str, Camera] = {}
    hd_dirs = []
    for panel, n in panel_centres().items():
        e1 = exact.unit3(exact.cross3(n, [0.0, 1.0, 0.0]))
        e2 = exact.cross3(n, e1)
        for node, (a, b) in enumerate(nodes, start=1):
            p = r_mount * n + a * e1 + b * e2
            p = DOME_CENTRE_CM + r_mount * p / exact.norm3(p)
            name = f"{panel:02d}_{node:02d}"
            cams[name] = _aimed_camera(rng, name=name, camera_type=CameraType.VGA, center_cm=p, panel=panel, node=node)
        hd_dirs.append(n)
    for lat, az0, count in HD_EXTRA_RINGS:
        hd_dirs += [direction(lat, az0 + 72.0 * k) for k in range(count)]
    for i, n in enumerate(hd_dirs):
        name = f"00_{i:02d}"
        cams[name] = _aimed_camera(rng, name=name, camera_type=CameraType.HD, center_cm=DOME_CENTRE_CM + r_mount * n,
                                   panel=0, node=i)
    r_kinect = DOME_RADIUS_CM - KINECT_INSET_CM
    for ring, (height, az0) in enumerate(zip(KINECT_HEIGHTS_CM, KINECT_RING_AZIMUTH_DEG)):
        dy = height - CENTRE_HEIGHT_CM
        horizontal = np.sqrt(r_kinect**2 - dy**2)
        for k in range(5):
            az = np.radians(az0 + 72.0 * k)
            p = np.array([horizontal * exact.cos(az), -height, horizontal * exact.sin(az)])
            node = 5 * ring + k + 1
            name = f"50_{node:02d}"
            cams[name] = _aimed_camera(rng, name=name, camera_type=CameraType.KINECT_COLOR, center_cm=p, panel=50,
                                       node=node)
    return cams


#: The tiny preset's two panels: one ring, 72 deg apart, so that its cameras see the tent over a wide arc and
#: focal length and distance separate (one panel alone sees it from one side, where they trade off).
TINY_PANELS = (1, 13)
TINY_VGA_PER_PANEL = 4
#: Where its HD and Kinect colour cameras are taken, as (fraction along the arc from the first panel to the
#: second, degrees lifted above it): the panels themselves, two points between them a little higher, and the
#: arc's middle high up, so that the tent is also seen from above.
TINY_HD_TARGETS = ((0.0, 0.0), (1 / 3, 10.0), (2 / 3, 10.0), (1.0, 0.0), (0.5, 35.0))
TINY_KINECT_TARGETS = ((0.0, 0.0), (1.0, 0.0), (0.5, 35.0))


def _arc_point_cm(a_cm: np.ndarray, b_cm: np.ndarray, fraction: float, lift_deg: float) -> np.ndarray:
    """The point ``fraction`` along the great-circle arc (about the dome centre) from ``a_cm`` to ``b_cm``, lifted
    ``lift_deg`` of latitude, on the sphere of their mean radius (world frame, cm)."""
    a, b = a_cm - DOME_CENTRE_CM, b_cm - DOME_CENTRE_CM
    ua, ub = exact.unit3(a), exact.unit3(b)
    angle = np.arccos(np.clip(exact.dot3(ua, ub), -1.0, 1.0))  # SVML on AVX-512 CPUs (tests/test_synth_exact.py)
    u = (exact.sin((1 - fraction) * angle) * ua + exact.sin(fraction * angle) * ub) / exact.sin(angle)
    lat, az = np.degrees(np.arcsin(-u[1] / exact.norm3(u))), np.degrees(np.arctan2(u[2], u[0]))
    return DOME_CENTRE_CM + 0.5 * (exact.norm3(a) + exact.norm3(b)) * direction(lat + lift_deg, az)


def _nearest(cands: list[Camera], point_cm: np.ndarray, n: int, taken: set[str] = frozenset()) -> list[str]:
    """Names of the ``n`` cameras of ``cands`` nearest ``point_cm``; distances compared to 1 um, equal ones by
    name (six ring cameras lie at one distance from a panel centre by design: their last bits differ between
    machines)."""
    cands = [c for c in cands if c.name not in taken]  # order_by breaks equal distances by name
    d = [float(np.linalg.norm(c.center_cm - point_cm)) for c in cands]
    return [cands[i].name for i in order_by(d, [c.name for c in cands], LENGTH_QUANTUM_CM)[:n]]


def select_preset(cameras: dict[str, Camera], preset: Preset | str) -> list[str]:
    """Camera names of a preset, chosen by geometry so that the same preset works on any layout (ties by name).

    tiny (16): the 4 VGA nearest the centre of each of panels 1 and 13 (one ring, 72 deg apart), and the HD and
    Kinect colour cameras nearest points on and above the arc between them (:data:`TINY_HD_TARGETS`,
    :data:`TINY_KINECT_TARGETS`), so the tent is seen over 72 deg of azimuth and 35 deg of elevation;
    panel (60): all VGA of panels 1 and 2, the 8 HD and 4 Kinect colour cameras nearest them;
    full: every camera.
    """
    preset = Preset(preset)
    if preset is Preset.FULL:
        return sorted(cameras)
    panels = TINY_PANELS if preset is Preset.TINY else (1, 2)
    vga = {p: [c for c in cameras.values() if c.type == CameraType.VGA and c.panel == p] for p in panels}
    empty = [p for p, cams in vga.items() if not cams]
    if empty:
        raise DomeCalibError(f"preset {preset}: the layout has no VGA cameras on panel {empty[0]}")
    hd = [c for c in cameras.values() if c.type == CameraType.HD]
    kinect = [c for c in cameras.values() if c.type == CameraType.KINECT_COLOR]
    if preset is Preset.PANEL:
        centre = np.mean([c.center_cm for p in panels for c in vga[p]], axis=0)
        names = [c.name for p in panels for c in vga[p]] + _nearest(hd, centre, 8) + _nearest(kinect, centre, 4)
        return sorted(names)
    centres = [np.mean([c.center_cm for c in vga[p]], axis=0) for p in panels]
    names = [n for p, centre in zip(panels, centres) for n in _nearest(vga[p], centre, TINY_VGA_PER_PANEL)]
    for cands, targets in ((hd, TINY_HD_TARGETS), (kinect, TINY_KINECT_TARGETS)):
        for fraction, lift_deg in targets:
            names += _nearest(cands, _arc_point_cm(*centres, fraction, lift_deg), 1, taken=set(names))
    return sorted(names)


def nominal_dome(preset: Preset | str = Preset.FULL, seed: int = 0) -> Bundle:
    """Ground-truth bundle of the nominal (paper) dome, restricted to a preset's cameras.

    Args:
        preset: "tiny" (16 cameras), "panel" (60) or "full" (521).
        seed: draws intrinsics, distortion, aim and roll jitter; the same seed gives the same cameras in every
            preset (a tiny camera is identical to the same-named full camera).
    Example:
        >>> bundle = nominal_dome("tiny", seed=0); sorted(bundle.cameras)[:2]
    """
    cams = all_nominal_cameras(seed)
    names = select_preset(cams, preset)
    return Bundle(seq="synth", cameras={n: cams[n] for n in names},
                  calib_data_source=f"dome_calib.synth nominal dome, preset {Preset(preset)}, seed {seed}")




#: A dome bundle's cameras sit on the design sphere: their median distance from the dome centre lies within this
#: factor of DOME_RADIUS_CM. A bundle in metres (every other tool's unit) is 100 x too small, in mm 10 x too large.
DOME_SCALE_TOLERANCE = 5.0


def check_dome_scale(cameras: dict[str, Camera], source: str) -> None:
    """DomeCalibError when the cameras cannot be a dome in centimetres: the median distance of their centres from
    the world origin (the floor centre; a unit-free point, unlike the dome centre 140 cm above it) is more than
    DOME_SCALE_TOLERANCE x off the design radius (a prior written in metres puts every camera ~2.7 "cm" from it).
    Refused, not converted: the unit is a guess until the file says."""
    if len(cameras) < 2:
        return
    centres = np.array([c.center_cm for c in cameras.values()])
    median = float(np.median(np.linalg.norm(centres, axis=1)))
    ratio = median / DOME_RADIUS_CM
    if 1 / DOME_SCALE_TOLERANCE <= ratio <= DOME_SCALE_TOLERANCE:
        return
    unit = ("metres" if 0.002 < ratio < 0.05 else "millimetres" if 3 < ratio < 30 else "another unit or frame")
    factor = "x 100" if unit == "metres" else "/ 10" if unit == "millimetres" else "into cm"
    raise DomeCalibError(f"{source}: its camera centres lie {median:.4g} from the world origin (median) where a "
                         f"dome in cm has about {DOME_RADIUS_CM:g}: t looks like {unit}; convert t {factor} (the Panoptic "
                         "bundle is in centimetres) and give it again")
