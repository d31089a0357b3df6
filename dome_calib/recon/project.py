"""Project world points into any set of the bundle's views: VGA, HD, Kinect colour and Kinect depth cameras.

A :class:`ViewSet` stacks the cameras a stage works with (keyed by name; arrays only inside). Kinect depth
cameras are views too, named by their node (``KINECTNODE3``): their pose is the dome bundle's colour camera
(``50_03``, world -> colour, cm) followed by ``inv(KinectSensor.color_from_depth)`` (colour -> depth, metres,
scaled to cm), their lens is ``K_depth`` / ``dist_depth`` and their image 512 x 424.

The hot loops of triangulation call :func:`transform_points` and :func:`project_lean` (the camera model of
:func:`dome_calib.camera.project` with the lens-range limit cached per view); both are tested equal to
:mod:`dome_calib.camera`.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from dome_calib.bundle import Bundle, KinectSensor
from dome_calib.camera import MIN_DEPTH, distort, max_valid_radius2
from dome_calib.jit import njit
from dome_calib.recon.errors import ReconError

CM_PER_M = 100.0
_NODE_RE = re.compile(r"^KINECTNODE(\d+)$")


def kinect_color_name(node: str) -> str:
    """Kinect node name -> its colour camera's name in the dome bundle: ``KINECTNODE3`` -> ``50_03``."""
    match = _NODE_RE.match(node)
    if not match:
        raise ReconError(f"{node!r} is not a Kinect node name (expected KINECTNODE<n>)")
    return f"50_{int(match.group(1)):02d}"


def kinect_sensor(bundle: Bundle, node: str) -> KinectSensor:
    """The bundle's :class:`KinectSensor` of ``node``; ReconError if the bundle has no such Kinect calibration."""
    if bundle.kinect is None:
        raise ReconError(f"bundle {bundle.seq}: no kcalibration_{bundle.seq}.json (Kinect calibration) in the bundle")
    if node not in bundle.kinect.sensors:
        raise ReconError(f"bundle {bundle.seq}: no Kinect sensor {node} in kcalibration (has "
                         f"{', '.join(sorted(bundle.kinect.sensors)) or 'none'})")
    return bundle.kinect.sensors[node]


def depth_from_world(bundle: Bundle, node: str) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t_cm (3,)) of the Kinect depth camera: x_depth_cm = R @ X_world_cm + t_cm.

    Chain: world -> colour camera (dome bundle camera 50_xx, cm) -> depth camera (inverse of
    ``KinectSensor.color_from_depth``, metres -> cm).
    """
    sensor = kinect_sensor(bundle, node)
    color_name = kinect_color_name(node)
    if color_name not in bundle.cameras:
        raise ReconError(f"bundle {bundle.seq}: Kinect {node} needs colour camera {color_name}, which is not in the "
                         f"calibration file")
    color = bundle.cameras[color_name]
    depth_from_color = np.linalg.inv(sensor.color_from_depth)
    R_dc, t_dc_cm = depth_from_color[:3, :3], depth_from_color[:3, 3] * CM_PER_M
    return R_dc @ color.R, R_dc @ color.t_cm + t_dc_cm


@dataclass(frozen=True, kw_only=True)
class ViewSet:
    """Cameras stacked for the vectorised model, in ``names`` order.

    R (V, 3, 3) cam_from_world; t_cm (V, 3); intr (V, 4) [fx, fy, cx, cy] px; dist (V, 5); resolution (V, 2)
    (width, height) px; r2_max (V,) the lens's valid normalised radius squared (see ``max_valid_radius2``).
    """

    names: list[str]
    R: np.ndarray
    t_cm: np.ndarray
    intr: np.ndarray
    dist: np.ndarray
    resolution: np.ndarray
    r2_max: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.r2_max is None:
            object.__setattr__(self, "r2_max", max_valid_radius2(self.dist))

    @property
    def center_cm(self) -> np.ndarray:
        """(V, 3) camera centres in the world frame, cm."""
        return -np.einsum("vji,vj->vi", self.R, self.t_cm)

    def index_of(self, names: list[str]) -> np.ndarray:
        """Positions of ``names`` in this set; ReconError naming the first missing one."""
        where = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in where]
        if missing:
            raise ReconError(f"camera {missing[0]} is not in this view set")
        return np.array([where[n] for n in names], dtype=np.int64)

    def subset(self, names: list[str]) -> ViewSet:
        """The views ``names`` (in that order)."""
        return self.at(self.index_of(names))

    def at(self, positions) -> ViewSet:
        """The views at ``positions`` (in that order): :meth:`subset` without the look-up by name (a loop over a
        dome's cameras calls it per camera)."""
        i = np.asarray(positions, dtype=np.int64)
        return ViewSet(names=[self.names[k] for k in i], R=self.R[i], t_cm=self.t_cm[i], intr=self.intr[i],
                       dist=self.dist[i], resolution=self.resolution[i], r2_max=self.r2_max[i])


def view_set(bundle: Bundle, names: list[str] | None = None, *, kinect_depth: bool = False) -> ViewSet:
    """Stack the bundle's cameras (and Kinect depth cameras, named ``KINECTNODE<n>``) into a :class:`ViewSet`.

    Args:
        names: views in the order wanted; default all dome cameras by name, then (if ``kinect_depth``) every
            Kinect depth camera of the bundle's kcalibration.
    Example:
        >>> vs = view_set(bundle, ["00_00", "01_01", "KINECTNODE1"])
    """
    if names is None:
        names = sorted(bundle.cameras)
        if kinect_depth and bundle.kinect is not None:
            names += sorted(bundle.kinect.sensors, key=lambda n: (len(n), n))
    R, t, intr, dist, res = [], [], [], [], []
    for name in names:
        if name in bundle.cameras:
            cam = bundle.cameras[name]
            R.append(cam.R), t.append(cam.t_cm), intr.append(cam.intr), dist.append(cam.dist)
            res.append(cam.resolution)
        elif _NODE_RE.match(name):
            sensor = kinect_sensor(bundle, name)
            R_d, t_d = depth_from_world(bundle, name)
            K = sensor.K_depth
            R.append(R_d), t.append(t_d), intr.append([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
            dist.append(sensor.dist_depth), res.append(sensor.depth_size)
        else:
            raise ReconError(f"bundle {bundle.seq}: no camera named {name!r}")
    return ViewSet(names=list(names), R=np.stack(R).astype(float), t_cm=np.stack(t).astype(float),
                   intr=np.asarray(intr, dtype=float), dist=np.stack(dist).astype(float),
                   resolution=np.asarray(res, dtype=np.int64))


def transform_points(views: ViewSet, X_world: np.ndarray) -> np.ndarray:
    """(P, 3) world points -> (P, V, 3) camera-frame points ``R X + t``, each coordinate ``((R_0 a + R_1 b) + R_2 c)
    + t`` in that order (:mod:`dome_calib.rows`' rule, compiled): a point's bits do not depend on the points
    transformed beside it, unlike a BLAS product's rows (one point against 4,000: other last bits)."""
    X = np.ascontiguousarray(X_world, dtype=float).reshape(-1, 3)
    out = np.empty((len(X), len(views.names), 3))
    _transform(X, np.ascontiguousarray(views.R, dtype=float), np.ascontiguousarray(views.t_cm, dtype=float), out)
    return out


def project_lean(views: ViewSet, X_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, V, 3) camera-frame points -> ((P, V, 2) pixels, (P, V) in-lens mask); pixels NaN behind the camera."""
    z = X_cam[..., 2]
    in_front = z > MIN_DEPTH
    xn = X_cam[..., :2] / np.where(in_front, z, np.nan)[..., None]
    uv = distort(xn, views.dist) * views.intr[:, 0:2] + views.intr[:, 2:4]
    r2 = xn[..., 0] ** 2 + xn[..., 1] ** 2
    return uv, in_front & (r2 <= views.r2_max)


@dataclass(frozen=True)
class ProjectedPoints:
    """Projection of P world points into V named views.

    uv_px (V, P, 2) OpenCV pixels (NaN behind the camera); depth_cm (V, P) z in the camera frame;
    in_front, in_lens, visible (V, P) bool; visible = in front, inside the lens's valid range and inside the image.
    """

    names: list[str]
    uv_px: np.ndarray
    depth_cm: np.ndarray
    in_front: np.ndarray
    in_lens: np.ndarray
    visible: np.ndarray


def project_points(views: ViewSet, X_world: np.ndarray) -> ProjectedPoints:
    """Project (P, 3) world points (cm) into every view of ``views``, with visibility.

    Example:
        >>> p = project_points(view_set(bundle, kinect_depth=True), joints_cm)
        >>> p.uv_px[p.names.index("00_03")]
    """
    X = np.asarray(X_world, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ReconError(f"points have shape {X.shape} but expected (P, 3)")
    X_cam = transform_points(views, X)
    uv, in_lens = project_lean(views, X_cam)
    wh = views.resolution.astype(float)
    inside = np.all((uv >= -0.5) & (uv <= wh - 0.5), axis=-1)
    tr = (1, 0)
    return ProjectedPoints(
        names=list(views.names), uv_px=uv.transpose(1, 0, 2), depth_cm=X_cam[..., 2].transpose(tr),
        in_front=(X_cam[..., 2] > MIN_DEPTH).transpose(tr), in_lens=in_lens.transpose(tr),
        visible=(in_lens & inside).transpose(tr),
    )


def project_view(views: ViewSet, v: int, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) world points (cm) into the one view at position ``v`` -> ((P, 2) pixels, (P,) visible): the bits of
    ``project_points(views.at([v]), X_world)``'s ``uv_px[0]`` and ``visible[0]`` (its transform, then its lens model
    and image test operation for operation in one compiled pass, without the (P, 1, ...) temporaries): for loops
    that project many points into one camera at a time (the patch stage's visibility and tracking)."""
    X = np.asarray(X_world, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ReconError(f"points have shape {X.shape} but expected (P, 3)")
    uv = np.empty((len(X), 2))
    visible = np.empty(len(X), bool)
    wh = views.resolution[v].astype(float)
    _view_and_image(np.ascontiguousarray(X), np.ascontiguousarray(views.R[v], dtype=float),
                    np.ascontiguousarray(views.t_cm[v], dtype=float), np.ascontiguousarray(views.dist[v], dtype=float),
                    np.ascontiguousarray(views.intr[v], dtype=float), float(views.r2_max[v]), wh[0] - 0.5,
                    wh[1] - 0.5, uv, visible)
    return uv, visible


def project_view_rows(views: ViewSet, v: int, X_world: np.ndarray, rows: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Groups of points (N, G, 3) world cm, the groups ``rows`` (R,) of them, into the one view at position ``v`` ->
    ((R, G, 2) pixels, (R,) whether the whole group is visible); a group's pixels are computed up to its first
    point that is not (the rest are NaN). :func:`project_view` without gathering the rows first (the same bits as
    it and :func:`project_points`, none from the machine's BLAS): for the patch stage's squares."""
    X = np.ascontiguousarray(X_world, dtype=float)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ReconError(f"points have shape {X.shape} but expected (N, G, 3)")
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    uv = np.full((len(rows), X.shape[1], 2), np.nan)
    whole = np.empty(len(rows), bool)
    wh = views.resolution[v].astype(float)
    _group_view(X, rows, np.ascontiguousarray(views.R[v], dtype=float), np.ascontiguousarray(views.t_cm[v], dtype=float),
                np.ascontiguousarray(views.dist[v], dtype=float), np.ascontiguousarray(views.intr[v], dtype=float),
                float(views.r2_max[v]), wh[0] - 0.5, wh[1] - 0.5, uv, whole)
    return uv, whole


@njit(nogil=True, boundscheck=False, inline="always")
def _lens_point(x0, x1, z, dist, intr, r2_max, u_max, v_max):  # pragma: no cover - compiled
    """One camera-frame point -> (u, v, visible): :func:`project_lean` and :func:`project_points`' image test, every
    operation of the numpy code in the same order in float64 (numba contracts nothing without fastmath)."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    front = z > MIN_DEPTH
    if front:
        x, y = x0 / z, x1 / z
    else:
        x, y = np.nan, np.nan
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    u, w = xd * intr[0] + intr[2], yd * intr[1] + intr[3]
    return u, w, front and r2 <= r2_max and u >= -0.5 and u <= u_max and w >= -0.5 and w <= v_max


@njit(nogil=True, boundscheck=False, inline="always")
def _camera_point(a, b, c, R, t):  # pragma: no cover - compiled
    """One world point -> its camera-frame (x, y, z): each ``((R_0 a + R_1 b) + R_2 c) + t`` in that order, the one
    order of :func:`transform_points`, :func:`project_view` and :func:`project_view_rows` (dome_calib.rows)."""
    return (a * R[0, 0] + b * R[0, 1] + c * R[0, 2] + t[0], a * R[1, 0] + b * R[1, 1] + c * R[1, 2] + t[1],
            a * R[2, 0] + b * R[2, 1] + c * R[2, 2] + t[2])


@njit(nogil=True, boundscheck=False)
def _transform(X, R, t, out):  # pragma: no cover - compiled
    """:func:`_camera_point` of (P, 3) points into (V, 3, 3) rotations and (V, 3) translations -> (P, V, 3)."""
    for i in range(X.shape[0]):
        for v in range(R.shape[0]):
            out[i, v, 0], out[i, v, 1], out[i, v, 2] = _camera_point(X[i, 0], X[i, 1], X[i, 2], R[v], t[v])


@njit(nogil=True, boundscheck=False)
def _view_and_image(X, R, t, dist, intr, r2_max, u_max, v_max, uv, visible):  # pragma: no cover - compiled
    """:func:`_camera_point` then :func:`_lens_point` of (P, 3) world points in one view."""
    for i in range(X.shape[0]):
        x0, x1, z = _camera_point(X[i, 0], X[i, 1], X[i, 2], R, t)
        uv[i, 0], uv[i, 1], visible[i] = _lens_point(x0, x1, z, dist, intr, r2_max, u_max, v_max)


@njit(nogil=True, boundscheck=False)
def _group_view(X, rows, R, t, dist, intr, r2_max, u_max, v_max, uv, whole):  # pragma: no cover - compiled
    """:func:`project_view_rows`' loop: each group until its first point out of view."""
    for r in range(rows.shape[0]):
        n = rows[r]
        whole[r] = True
        for g in range(X.shape[1]):
            x0, x1, z = _camera_point(X[n, g, 0], X[n, g, 1], X[n, g, 2], R, t)
            uv[r, g, 0], uv[r, g, 1], ok = _lens_point(x0, x1, z, dist, intr, r2_max, u_max, v_max)
            if not ok:
                whole[r] = False
                break


def project_bundle(bundle: Bundle, X_world: np.ndarray, names: list[str] | None = None, *,
                   kinect_depth: bool = False) -> ProjectedPoints:
    """Shortcut: :func:`project_points` into ``view_set(bundle, names, kinect_depth=kinect_depth)``."""
    return project_points(view_set(bundle, names, kinect_depth=kinect_depth), X_world)
