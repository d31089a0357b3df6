"""The white tent: a closed union of two cones and an ellipsoid (about 2 m across, 2 m high), plus the floor.

Everything is analytic so that rays can be intersected exactly and fast (vectorised quadratics). The tent is
defined in its own frame (origin on the floor at the tent's centre, y down like the world, cm) and placed in the
world by a rotation about the vertical axis and a translation on the floor: ``X_world = R_y(yaw) X_tent + T``.

The union of convex solids is hit first where a ray first ENTERS any of them (rays start outside the tent),
so the first hit of the union is the minimum over the primitives' entry distances.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib import exact

FLOOR_RADIUS_CM = 260.0
TENT_ALBEDO = 0.9
FLOOR_ALBEDO = 0.3
_EPS = 1e-9


@dataclass(frozen=True, kw_only=True)
class Cone:
    """Solid right circular cone standing on the floor: apex ``height_cm`` above the floor at (x, z), base radius."""

    x_cm: float
    z_cm: float
    height_cm: float
    radius_cm: float


@dataclass(frozen=True, kw_only=True)
class Ellipsoid:
    """Axis-aligned solid ellipsoid (tent frame). ``centre_cm`` (3,), ``radii_cm`` (3,)."""

    centre_cm: tuple[float, float, float]
    radii_cm: tuple[float, float, float]


#: The tent's shape in its own frame: a 2 m tall egg (1.6 m x 1.3 m), a 1.6 m side teepee and a bulge.
#: About 2.0 m x 1.5 m across. The egg sinks 10 cm below the floor (the floor hides that part).
TENT_CONES = (Cone(x_cm=-55.0, z_cm=-35.0, height_cm=160.0, radius_cm=50.0),)
TENT_ELLIPSOIDS = (Ellipsoid(centre_cm=(0.0, -95.0, 0.0), radii_cm=(80.0, 105.0, 65.0)),
                   Ellipsoid(centre_cm=(55.0, -50.0, 30.0), radii_cm=(40.0, 45.0, 38.0)))


def yaw_matrix(yaw_rad: float) -> np.ndarray:
    """(3, 3) rotation about the world's vertical (y) axis."""
    c, s = exact.cos(yaw_rad), exact.sin(yaw_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True, kw_only=True)
class TentPose:
    """Placement of the tent in one scene: yaw about the vertical (rad) and floor position (x, z) cm."""

    yaw_rad: float
    x_cm: float
    z_cm: float

    @property
    def R(self) -> np.ndarray:
        return yaw_matrix(self.yaw_rad)

    @property
    def T_cm(self) -> np.ndarray:
        return np.array([self.x_cm, 0.0, self.z_cm])

    def to_world(self, X_tent: np.ndarray) -> np.ndarray:
        return exact.matvec3(self.R, X_tent) + self.T_cm

    def to_tent(self, X_world: np.ndarray) -> np.ndarray:
        return exact.matvec3(exact.transpose3(self.R), X_world - self.T_cm)


def scene_poses(n_scenes: int, seed: int) -> list[TentPose]:
    """Seeded tent placements: scene 1 at the centre, others 20-45 cm away, any yaw."""
    rng = np.random.default_rng([seed, 7])
    poses = []
    for i in range(n_scenes):
        radius = 0.0 if i == 0 else rng.uniform(20.0, 45.0)
        angle = rng.uniform(0.0, 2 * np.pi)
        poses.append(TentPose(yaw_rad=float(rng.uniform(0.0, 2 * np.pi)) if i else 0.3,
                              x_cm=float(radius * exact.cos(angle)), z_cm=float(radius * exact.sin(angle))))
    return poses


def _roots(a, b, c) -> tuple[np.ndarray, np.ndarray]:
    """Both roots (lo <= hi) of a s^2 + b s + c = 0, NaN where there is none (numerically stable form)."""
    disc = b * b - 4.0 * a * c
    sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
    q = -0.5 * (b + np.copysign(sq, b))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1, r2 = q / a, c / q
    return np.fmin(r1, r2), np.fmax(r1, r2)


def _cone_hit(ox, oy, oz, dx, dy, dz, cone: Cone) -> np.ndarray:
    """Entry distance of rays (tent-frame components) into a solid cone; inf for a miss."""
    k2 = (cone.radius_cm / cone.height_cm) ** 2
    px, py, pz = ox - cone.x_cm, oy + cone.height_cm, oz - cone.z_cm  # py: depth below the apex
    a = dx * dx + dz * dz - k2 * dy * dy
    b = 2.0 * (px * dx + pz * dz - k2 * py * dy)
    c = px * px + pz * pz - k2 * py * py
    lo, hi = _roots(a, b, c)
    out = np.full(ox.shape, np.inf)
    for r in (hi, lo):  # lo last so that it wins where both are valid
        y = py + r * dy
        out = np.where((r > 1e-6) & (y >= 0.0) & (y <= cone.height_cm), r, out)
    return out


def _ellipsoid_hit(ox, oy, oz, dx, dy, dz, ell: Ellipsoid) -> np.ndarray:
    """Entry distance of rays starting outside into a solid ellipsoid; inf for a miss."""
    (cx, cy, cz), (rx, ry, rz) = ell.centre_cm, ell.radii_cm
    px, py, pz = (ox - cx) / rx, (oy - cy) / ry, (oz - cz) / rz
    qx, qy, qz = dx / rx, dy / ry, dz / rz
    a = qx * qx + qy * qy + qz * qz
    b = 2.0 * (px * qx + py * qy + pz * qz)
    c = px * px + py * py + pz * pz - 1.0
    lo, _ = _roots(a, b, c)
    return np.where(lo > 1e-6, lo, np.inf)


def tent_normals(X_tent: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Outward unit normals (N, 3) at tent-frame surface points, ``which`` = primitive index (cones first)."""
    n = np.zeros_like(X_tent)
    for i, cone in enumerate(TENT_CONES):
        m = which == i
        k2 = (cone.radius_cm / cone.height_cm) ** 2
        p = X_tent[m]
        n[m] = np.stack([p[:, 0] - cone.x_cm, -k2 * (p[:, 1] + cone.height_cm), p[:, 2] - cone.z_cm], axis=1)
    for j, ell in enumerate(TENT_ELLIPSOIDS):
        m = which == len(TENT_CONES) + j
        n[m] = (X_tent[m] - np.asarray(ell.centre_cm)) / np.asarray(ell.radii_cm) ** 2
    return n / np.maximum(exact.norm3(n), _EPS)[:, None]


def _bounding_sphere() -> tuple[np.ndarray, float]:
    """A sphere (tent frame) containing the whole tent: rays that miss it skip the primitives."""
    lo = np.min([[c.x_cm - c.radius_cm, -c.height_cm, c.z_cm - c.radius_cm] for c in TENT_CONES]
                + [np.subtract(e.centre_cm, e.radii_cm) for e in TENT_ELLIPSOIDS], axis=0)
    hi = np.max([[c.x_cm + c.radius_cm, 0.0, c.z_cm + c.radius_cm] for c in TENT_CONES]
                + [np.add(e.centre_cm, e.radii_cm) for e in TENT_ELLIPSOIDS], axis=0)
    return (lo + hi) / 2, float(exact.norm3(hi - lo) / 2 + 1.0)


_BOUND_CENTRE, _BOUND_RADIUS = _bounding_sphere()


def intersect_tent(o_tent: np.ndarray, d_tent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays with the tent (tent frame). o (N, 3) or (3,), d (N, 3) unit directions.

    Returns (s (N,) ray parameter, inf for a miss; which (N,) primitive index, -1 for a miss).
    """
    d_tent = np.asarray(d_tent, dtype=float)
    o_tent = np.broadcast_to(np.asarray(o_tent, dtype=float), d_tent.shape)
    n = len(d_tent)
    # cull rays that miss the bounding sphere
    to_c = _BOUND_CENTRE - o_tent
    along = exact.dot3(to_c, d_tent)
    perp2 = exact.dot3(to_c, to_c) - along * along
    idx = np.flatnonzero((perp2 < _BOUND_RADIUS**2) & (along > -_BOUND_RADIUS))
    s = np.full(n, np.inf)
    which = np.full(n, -1)
    if len(idx) == 0:
        return s, which
    o, d = o_tent[idx], d_tent[idx]
    comps = (o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2])
    hits = [_cone_hit(*comps, c) for c in TENT_CONES] + [_ellipsoid_hit(*comps, e) for e in TENT_ELLIPSOIDS]
    stack = np.stack(hits)
    w = np.argmin(stack, axis=0)
    s_sub = np.take_along_axis(stack, w[None], axis=0)[0]
    s[idx] = s_sub
    which[idx] = np.where(np.isfinite(s_sub), w, -1)
    return s, which


@dataclass(frozen=True)
class Hits:
    """First surface hit of N rays (world frame). ``kind``: 0 none, 1 tent, 2 floor."""

    s: np.ndarray  # (N,) ray parameter (distance for unit directions), inf if none
    X_cm: np.ndarray  # (N, 3) world points (NaN where no hit)
    normal: np.ndarray  # (N, 3) world outward unit normals
    kind: np.ndarray  # (N,) uint8
    albedo: np.ndarray  # (N,) float


def intersect_scene(o_world: np.ndarray, d_world: np.ndarray, pose: TentPose, *, floor: bool = True) -> Hits:
    """First hit of world rays (o (N, 3) or (3,), d (N, 3)) with the placed tent and the floor disk."""
    d_world = np.asarray(d_world, dtype=float)
    o_world = np.broadcast_to(np.asarray(o_world, dtype=float), d_world.shape)
    o_t, d_t = pose.to_tent(o_world), exact.matvec3(exact.transpose3(pose.R), d_world)
    s, which = intersect_tent(o_t, d_t)
    kind = np.where(which >= 0, 1, 0).astype(np.uint8)
    if floor:
        dy = d_world[:, 1]
        s_floor = np.where(dy > _EPS, -o_world[:, 1] / np.where(dy > _EPS, dy, 1.0), np.inf)
        xf = o_world[:, 0] + s_floor * d_world[:, 0]
        zf = o_world[:, 2] + s_floor * d_world[:, 2]
        s_floor = np.where((s_floor > 0) & (xf * xf + zf * zf < FLOOR_RADIUS_CM**2), s_floor, np.inf)
        use_floor = s_floor < s
        s = np.where(use_floor, s_floor, s)
        kind = np.where(use_floor, 2, kind).astype(np.uint8)
    X = o_world + np.where(np.isfinite(s), s, np.nan)[:, None] * d_world
    normal = np.zeros_like(X)
    tent = kind == 1
    if tent.any():
        normal[tent] = exact.matvec3(pose.R, tent_normals(pose.to_tent(X[tent]), which[tent]))
    normal[kind == 2] = (0.0, -1.0, 0.0)
    albedo = np.select([kind == 1, kind == 2], [TENT_ALBEDO, FLOOR_ALBEDO], 0.0)
    return Hits(s=s, X_cm=X, normal=normal, kind=kind, albedo=albedo)


def inside_tent(X_tent: np.ndarray, margin_cm: float = 0.0) -> np.ndarray:
    """(N,) bool: tent-frame points strictly inside some primitive by more than ``margin_cm`` (approximately)."""
    inside = np.zeros(len(X_tent), bool)
    for cone in TENT_CONES:
        below_apex = X_tent[:, 1] + cone.height_cm
        r = np.hypot(X_tent[:, 0] - cone.x_cm, X_tent[:, 2] - cone.z_cm)
        r_max = cone.radius_cm * below_apex / cone.height_cm
        inside |= (below_apex > margin_cm) & (r < r_max - margin_cm)
    for ell in TENT_ELLIPSOIDS:
        p = (X_tent - np.asarray(ell.centre_cm)) / (np.asarray(ell.radii_cm) - margin_cm)
        inside |= np.sum(p * p, axis=1) < 1.0
    return inside


def tent_mesh(pose: TentPose, *, step_cm: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the tent's outer surface in the world frame: (vertices_cm (V, 3), faces (F, 3) int).

    Every vertex lies exactly on the analytic surface; parts of a primitive inside another are removed (small
    gaps remain along the seams). The floor-level base is included so the surface is closed where it exists.
    """
    verts, faces = [], []

    def grid(P: np.ndarray) -> None:  # P (nu, nv, 3) closed in u
        nu, nv = P.shape[:2]
        base = sum(len(v) for v in verts)
        idx = base + np.arange(nu * nv).reshape(nu, nv)
        i0, i1 = idx, np.roll(idx, -1, axis=0)
        a, b, c, d = i0[:, :-1], i1[:, :-1], i1[:, 1:], i0[:, 1:]
        faces.append(np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]))
        verts.append(P.reshape(-1, 3))

    for cone in TENT_CONES:
        nu = max(12, int(2 * np.pi * cone.radius_cm / step_cm))
        nv = max(4, int(np.hypot(cone.radius_cm, cone.height_cm) / step_cm))
        th = np.linspace(0, 2 * np.pi, nu, endpoint=False)[:, None]
        f = np.linspace(0.0, 1.0, nv)[None, :]  # 0 apex .. 1 base
        r = cone.radius_cm * f
        y = -cone.height_cm * (1.0 - f)
        grid(np.stack([cone.x_cm + r * exact.cos(th), y + 0 * th, cone.z_cm + r * exact.sin(th)], -1))
        f_base = np.linspace(1.0, 0.0, max(3, int(cone.radius_cm / step_cm)))[None, :]
        grid(np.stack([cone.x_cm + cone.radius_cm * f_base * exact.cos(th), 0 * f_base + 0 * th,
                       cone.z_cm + cone.radius_cm * f_base * exact.sin(th)], -1))
    for ell in TENT_ELLIPSOIDS:
        rx, ry, rz = ell.radii_cm
        nu = max(12, int(2 * np.pi * max(rx, rz) / step_cm))
        nv = max(6, int(np.pi * ry / step_cm))
        th = np.linspace(0, 2 * np.pi, nu, endpoint=False)[:, None]
        ph = np.linspace(0, np.pi, nv)[None, :]
        (s_ph, c_ph), (s_th, c_th) = exact.sincos(ph), exact.sincos(th)
        grid(np.stack([ell.centre_cm[0] + rx * s_ph * c_th, ell.centre_cm[1] - ry * c_ph + 0 * th,
                       ell.centre_cm[2] + rz * s_ph * s_th], -1))
    V = np.concatenate(verts)
    F = np.concatenate(faces)
    keep = ~inside_tent(V, margin_cm=0.05) & (V[:, 1] <= 1e-9)  # ellipsoid parts below the floor are cut
    F = F[keep[F].all(axis=1)]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    used = np.unique(F)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    return pose.to_world(V[used]), remap[F]
