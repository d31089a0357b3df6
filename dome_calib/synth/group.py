"""Synthetic groups of people in the dome, with truth: several bodies (1-10) moving as groups do.

Roles: ``walk`` (on a ring around the dome centre; walkers on neighbouring rings go opposite ways and pass each
other about half a metre apart), ``talk`` (standing in a conversation circle, facing its centre, gesturing and
turning the head), ``crouch`` (a talker who crouches down and gets up again), ``leave`` (a talker who walks out of
the dome), ``enter`` (someone who walks in from outside and takes a place in a conversation).

Each body reuses the walking body of :func:`dome_calib.synth.skeleton.walking_body_local_cm` (at its own gait
phase): its bone *directions* are blended with a standing pose (straight legs) and a crouching pose, and the
skeleton is rebuilt joint by joint with the person's own bone lengths (nominal lengths times a height scale), so
bone lengths are constant over time by construction. The pelvis height follows from the legs (lowest ankle 8 cm
above the floor). Positions, facings and poses are analytic in universal time: any stream is sampled at its own
frame times.

Layouts are drawn from ``seed`` and redrawn until every two body centres stay >= 50 cm apart (sampled every
20 ms) over the whole duration; ids are 0..n-1, one per person, never reused. A person is ``present`` while the
body centre is within :data:`CAPTURE_RADIUS_CM` of the dome axis: the dome's sphere (radius 274.5 cm, centre
140 cm above the floor) meets the floor at 236 cm, so someone beyond 230 cm is walking out through the door.

World: Panoptic (origin at the floor centre, y down, cm). A heading angle ``h`` means forward = (cos h, 0, sin h).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from dome_calib.errors import DomeCalibError
from dome_calib.synth.skeleton import walking_body_local_cm

logger = logging.getLogger(__name__)

CAPTURE_RADIUS_CM = 230.0
#: Body centres of two people never come closer than this (the layouts keep 50 cm, sampled every 20 ms).
MIN_CENTRE_DISTANCE_CM = 45.0
LAYOUT_CLEARANCE_CM = 50.0
OUTSIDE_RADIUS_CM = 320.0  # where leavers go and enterers come from
ANKLE_HEIGHT_CM = 8.0
SCENARIOS = ("walk_past", "conversation", "crouch", "leave", "mixed", "small_area")
ROLES = ("walk", "talk", "crouch", "leave", "enter")
_MIXED_ROLES = ["walk", "walk", "talk", "talk", "crouch", "leave", "enter", "talk", "walk", "talk"]
#: "small_area" (a 3 x 3 m room, :mod:`dome_calib.synth.rig`): a conversation, one walking round it on a ring of
#: this radius (cm), one crouching.
_SMALL_AREA_ROLES = ["talk", "talk", "walk", "crouch", "talk", "talk"]
SMALL_AREA_RING_CM = (100.0, 120.0)

#: Parent of each joints19 joint in the kinematic tree (-1: the body centre, the root); _FK_ORDER lists parents first.
PARENT19 = np.array([2, 0, -1, 0, 3, 4, 2, 6, 7, 0, 9, 10, 2, 12, 13, 1, 15, 1, 17])
_FK_ORDER = [0, 1, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18]
_REST_LOCAL_CM = walking_body_local_cm(np.zeros(1))[0]  # t = 0: arms down, no stride, head straight
#: (19,) bone length to the parent of each joint (0 for the root) of the nominal (scale 1, ~1.70 m) body, cm.
NOMINAL_BONE_CM = np.where(PARENT19 >= 0, np.linalg.norm(_REST_LOCAL_CM - _REST_LOCAL_CM[np.maximum(PARENT19, 0)],
                                                         axis=-1), 0.0)
_LEGS = [(7, 6), (8, 7), (13, 12), (14, 13)]  # (joint, parent): thighs and shins
_ARMS = [(4, 3), (5, 4), (10, 9), (11, 10)]


class GroupError(DomeCalibError, ValueError):
    """Options that describe no group (unknown scenario, too many people, no layout found)."""


@dataclass(kw_only=True)
class GroupOptions:
    """What the group does. ``start_ms``: universal time of the start; the layout covers ``duration_ms``."""

    n_people: int = 5  # 1..10 (small_area: 1..6)
    duration_ms: float = 4000.0
    start_ms: float = 0.0
    scenario: str = "mixed"  # "walk_past", "conversation", "crouch", "leave", "mixed" (all of them), "small_area"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.scenario not in SCENARIOS:
            raise GroupError(f"scenario {self.scenario!r} is unknown (known: {', '.join(SCENARIOS)})")
        most = max_people(self.scenario)
        if not 1 <= self.n_people <= most:
            raise GroupError(f"n_people={self.n_people} but expected 1..{most} for scenario {self.scenario!r}")
        if not self.duration_ms > 0:
            raise GroupError(f"duration_ms={self.duration_ms} but expected > 0")


@dataclass(frozen=True, kw_only=True)
class PersonPlan:
    """One person's motion, times relative to the group's start (ms).

    Either ``ring`` = (radius_cm, omega_rad_s, angle0_rad): walking around the dome axis; or ``waypoints_ms`` (K,)
    and ``waypoints_cm`` (K, 2) (x, z): standing at a waypoint while two consecutive ones are equal, walking (eased
    in and out) between different ones. ``facing_rad``: heading while standing; ``crouch_ms`` = (down, up):
    crouched in between (0.7 s to go down, 0.7 s to get up); ``scale``: bone lengths / nominal;
    ``gait_offset_ms``: the person's phase of the walking body's motion.
    """

    id: int
    role: str
    scale: float = 1.0
    gait_offset_ms: float = 0.0
    ring: tuple[float, float, float] | None = None
    waypoints_ms: tuple[float, ...] = (0.0,)
    waypoints_cm: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    facing_rad: float = 0.0
    crouch_ms: tuple[float, float] | None = None

    def root_xz(self, t_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T,) relative ms -> ((T, 2) body centre (x, z) cm, (T,) heading rad, (T,) walking weight 0..1)."""
        t = np.asarray(t_ms, dtype=float)
        if self.ring is not None:
            radius, omega, angle0 = self.ring
            a = angle0 + omega * t / 1000.0
            xz = radius * np.stack([np.cos(a), np.sin(a)], -1)
            return xz, a + math.copysign(math.pi / 2, omega), np.ones_like(t)
        wt = np.asarray(self.waypoints_ms, dtype=float)
        wp = np.asarray(self.waypoints_cm, dtype=float).reshape(-1, 2)
        if len(wt) == 1:
            return np.broadcast_to(wp[0], (len(t), 2)).copy(), np.full(len(t), self.facing_rad), np.zeros_like(t)
        k = np.clip(np.searchsorted(wt, t, side="right") - 1, 0, len(wt) - 2)
        span = wt[k + 1] - wt[k]
        u = np.clip((t - wt[k]) / span, 0.0, 1.0)
        ease = u * u * (3.0 - 2.0 * u)
        d = wp[k + 1] - wp[k]
        xz = wp[k] + ease[:, None] * d
        length = np.linalg.norm(d, axis=-1)
        speed_cm_s = length * 6.0 * u * (1.0 - u) / span * 1000.0
        walk = np.clip(speed_cm_s / 50.0, 0.0, 1.0)
        seg_heading = np.arctan2(d[:, 1], d[:, 0])
        turn = (seg_heading - self.facing_rad + np.pi) % (2 * np.pi) - np.pi
        return xz, self.facing_rad + np.where(length > 0, walk * turn, 0.0), walk

    def crouch_weight(self, t_ms: np.ndarray) -> np.ndarray:
        """(T,) relative ms -> (T,) 0 (standing) .. 1 (crouched)."""
        if self.crouch_ms is None:
            return np.zeros(np.shape(t_ms))
        down, up = self.crouch_ms
        t = np.asarray(t_ms, dtype=float)
        u = np.clip(np.minimum((t - down) / 700.0, (up - t) / 700.0), 0.0, 1.0)
        return u * u * (3.0 - 2.0 * u)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


_STAND = {7: [0.0, 1.0, 0.0], 8: [0.0, 1.0, 0.0], 13: [0.0, 1.0, 0.0], 14: [0.0, 1.0, 0.0]}
_CROUCH = {7: [0.0, 0.45, 1.0], 8: [0.0, 1.0, -0.35], 13: [0.0, 0.45, 1.0], 14: [0.0, 1.0, -0.35],
           0: [0.0, -1.0, 0.45], 4: [-0.2, 1.0, 0.5], 5: [0.0, 0.2, 1.0], 10: [0.2, 1.0, 0.5], 11: [0.0, 0.2, 1.0]}


def body_local_cm(plan: PersonPlan, univ_time_ms: np.ndarray, walk: np.ndarray, crouch: np.ndarray) -> np.ndarray:
    """(T,) times, (T,) walking and crouching weights -> (T, 19, 3) joints in the body frame (lateral, down,
    forward), cm, origin on the floor below the body centre; bone lengths ``scale * NOMINAL_BONE_CM``."""
    pose = walking_body_local_cm(np.asarray(univ_time_ms, dtype=float) + plan.gait_offset_ms)
    bones = _unit(pose - pose[:, np.maximum(PARENT19, 0)] + (PARENT19 < 0)[:, None])  # root row: unused
    stand = bones.copy()
    for j, d in _STAND.items():
        stand[:, j] = _unit(np.asarray(d))
    crouched = stand.copy()
    for j, d in _CROUCH.items():
        crouched[:, j] = _unit(np.asarray(d))
    w, c = walk[:, None, None], crouch[:, None, None]
    blend = _unit((1.0 - c) * (w * bones + (1.0 - w) * stand) + c * crouched)
    out = np.zeros_like(pose)
    lengths = plan.scale * NOMINAL_BONE_CM
    for j in _FK_ORDER:
        out[:, j] = out[:, PARENT19[j]] + lengths[j] * blend[:, j]
    out[..., 1] -= np.maximum(out[:, 8, 1], out[:, 14, 1])[:, None] + ANKLE_HEIGHT_CM * plan.scale
    return out


@dataclass(frozen=True)
class GroupTruth:
    """The people of a synthetic group; ``ids`` stable, one per person, never reused (plans in id order)."""

    ids: list[int]
    plans: tuple[PersonPlan, ...] = field(default=())
    start_ms: float = 0.0
    duration_ms: float = 0.0

    def joints_cm(self, univ_time_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T,) ms -> ((T, P, 19, 3) Panoptic joints19 positions, world cm; (T, P) bool: inside the dome)."""
        t_univ = np.atleast_1d(np.asarray(univ_time_ms, dtype=float))
        t = t_univ - self.start_ms
        X = np.zeros((len(t), len(self.plans), 19, 3))
        present = np.zeros((len(t), len(self.plans)), dtype=bool)
        for p, plan in enumerate(self.plans):
            xz, heading, walk = plan.root_xz(t)
            local = body_local_cm(plan, t_univ, walk, plan.crouch_weight(t))
            fwd = np.stack([np.cos(heading), np.zeros_like(t), np.sin(heading)], -1)
            right = np.stack([np.sin(heading), np.zeros_like(t), -np.cos(heading)], -1)  # fwd x up, up = -y
            root = np.stack([xz[:, 0], np.zeros_like(t), xz[:, 1]], -1)
            X[:, p] = (root[:, None] + local[..., 0:1] * right[:, None] + local[..., 2:3] * fwd[:, None])
            X[:, p, :, 1] += local[..., 1]
            present[:, p] = np.hypot(X[:, p, 2, 0], X[:, p, 2, 2]) <= CAPTURE_RADIUS_CM
        return X, present

    def centres_xz(self, univ_time_ms: np.ndarray) -> np.ndarray:
        """(T,) ms -> (T, P, 2) body-centre ground positions (x, z), cm (cheap: no skeleton)."""
        t = np.atleast_1d(np.asarray(univ_time_ms, dtype=float)) - self.start_ms
        return np.stack([plan.root_xz(t)[0] for plan in self.plans], 1)


def max_people(scenario: str) -> int:
    """How many people a scenario holds (10; small_area: 6)."""
    return len(_SMALL_AREA_ROLES) if scenario == "small_area" else 10


def roles_of(scenario: str, n_people: int) -> list[str]:
    """The role of each person (id order) in a scenario."""
    if scenario == "mixed":
        return _MIXED_ROLES[:n_people]
    if scenario == "small_area":
        return _SMALL_AREA_ROLES[:n_people]
    if scenario == "walk_past":
        return ["walk"] * n_people
    if scenario == "conversation":
        return ["talk"] * n_people
    if scenario == "crouch":
        return (["crouch"] + ["talk"] * (n_people - 1))[:n_people]
    return (["leave", "enter"] + ["talk"] * (n_people - 2))[:n_people]


def _draw_layout(roles: list[str], duration_ms: float, rng: np.random.Generator,
                 ring_cm: tuple[float, float] = (150.0, 160.0)) -> list[PersonPlan]:
    D = duration_ms
    scale = rng.uniform(0.9, 1.1, len(roles))
    gait = rng.uniform(0.0, 4000.0, len(roles))  # stride (1.1 s) and the slow arm gesture (4 s) out of step
    plans: dict[int, PersonPlan] = {}
    # Walkers: two rings, odd walkers the other way round on the outer ring; the first two meet mid-way.
    walkers = [i for i, r in enumerate(roles) if r == "walk"]
    r_inner, gap = rng.uniform(*ring_cm), rng.uniform(48.0, 58.0)
    speed = rng.uniform(75.0, 100.0, 2)
    omega = [speed[0] / r_inner, -speed[1] / (r_inner + gap)]
    a0 = rng.uniform(0, 2 * np.pi)
    t_meet_s = rng.uniform(0.35, 0.65) * D / 1000.0
    start = [a0, a0 + (omega[0] - omega[1]) * t_meet_s]
    for k, i in enumerate(walkers):
        ring, n_on_ring = k % 2, (len(walkers) - k % 2 + 1) // 2
        angle = start[ring] + 2 * np.pi * (k // 2) / n_on_ring
        plans[i] = PersonPlan(id=i, role="walk", scale=scale[i], gait_offset_ms=gait[i],
                              ring=(r_inner + ring * gap, omega[ring], angle))
    # Standing people in conversation circles of <= 4 (the enterer takes the leaver's place, or a place of its own).
    standing = [i for i, r in enumerate(roles) if r in ("talk", "crouch", "leave")]
    enterer = [i for i, r in enumerate(roles) if r == "enter"]
    slots = len(standing) + (0 if any(roles[i] == "leave" for i in standing) else len(enterer))
    n_groups = max(1, math.ceil(slots / 4))
    axis = rng.uniform(0, 2 * np.pi)
    spots, centres = [], []
    for g in range(n_groups):
        size = slots // n_groups + (1 if g < slots % n_groups else 0)
        off = 0.0 if n_groups == 1 else rng.uniform(48.0, 60.0) if n_groups == 2 else rng.uniform(72.0, 85.0)
        a_g = axis + 2 * np.pi * g / n_groups
        centre = np.array([np.cos(a_g), np.sin(a_g)]) * off + rng.normal(0.0, 8.0, 2)
        radius = 0.0 if size == 1 else rng.uniform(36.0, 46.0)
        rot = rng.uniform(0, 2 * np.pi)
        for m in range(size):
            a = rot + 2 * np.pi * m / size + rng.uniform(-0.15, 0.15)
            spots.append((centre + radius * np.array([np.cos(a), np.sin(a)]), centre))
            centres.append(centre)
    spot_of = dict(zip(standing + ([] if slots == len(standing) else enterer), range(slots)))
    leave_spot, left_ms = None, 0.0  # the leaver's place, and when the leaver is ~80 % of the way out
    for i in standing + enterer:
        role = roles[i]
        if role == "enter":
            k = leave_spot if leave_spot is not None else spot_of[i]
        else:
            k = spot_of[i]
        xz, centre = spots[k]
        to_centre = centre - xz
        facing = (float(np.arctan2(to_centre[1], to_centre[0])) if np.linalg.norm(to_centre) > 1.0
                  else rng.uniform(0, 2 * np.pi)) + rng.uniform(-0.25, 0.25)
        kw: dict = dict(id=i, role=role, scale=scale[i], gait_offset_ms=gait[i], facing_rad=facing)
        if role in ("talk", "crouch"):
            kw.update(waypoints_ms=(0.0,), waypoints_cm=(tuple(xz),))
            if role == "crouch":
                kw["crouch_ms"] = (rng.uniform(0.15, 0.3) * D, rng.uniform(0.65, 0.85) * D)
        elif role == "leave":
            leave_spot = k
            out_dir = xz / max(np.linalg.norm(xz), 1e-6) if np.linalg.norm(xz) > 20 else np.array([1.0, 0.0])
            out = out_dir * OUTSIDE_RADIUS_CM
            t0 = rng.uniform(0.1, 0.25) * D
            walk_ms = np.linalg.norm(out - xz) / 0.09
            left_ms = t0 + 0.7 * walk_ms
            kw.update(waypoints_ms=(t0, t0 + walk_ms), waypoints_cm=(tuple(xz), tuple(out)))
        else:  # enter: from outside, at an angle to the place's own direction, to the place
            az = np.arctan2(xz[1], xz[0]) + rng.choice([-1, 1]) * rng.uniform(0.5, 1.2)
            origin = OUTSIDE_RADIUS_CM * np.array([np.cos(az), np.sin(az)])
            t1 = max(rng.uniform(0.8, 0.95) * D, left_ms + rng.uniform(0.0, 500.0))  # arrives when the place is free
            kw.update(waypoints_ms=(t1 - np.linalg.norm(origin - xz) / 0.09, t1),
                      waypoints_cm=(tuple(origin), tuple(xz)))
        plans[i] = PersonPlan(**kw)
    return [plans[i] for i in range(len(roles))]


def make_group(options: GroupOptions) -> GroupTruth:
    """Draw a group from ``options.seed`` (layouts redrawn until every two body centres keep
    :data:`LAYOUT_CLEARANCE_CM`, sampled every 20 ms over the duration).

    Example:
        >>> truth = make_group(GroupOptions(n_people=5, scenario="mixed", seed=1))
        >>> X_cm, present = truth.joints_cm(np.array([0.0, 40.0]))  # (2, 5, 19, 3), (2, 5)
    """
    o = options
    roles = roles_of(o.scenario, o.n_people)
    grid_ms = np.arange(0.0, o.duration_ms + 20.0, 20.0)
    for attempt in range(2000):
        rng = np.random.default_rng([o.seed, attempt])
        plans = _draw_layout(roles, o.duration_ms, rng, SMALL_AREA_RING_CM if o.scenario == "small_area" else
                             (150.0, 160.0))
        truth = GroupTruth(ids=[p.id for p in plans], plans=tuple(plans), start_ms=o.start_ms,
                           duration_ms=o.duration_ms)
        if len(plans) < 2 or min_centre_distance_cm(truth, grid_ms + o.start_ms) >= LAYOUT_CLEARANCE_CM:
            logger.debug("group layout after %d draws", attempt + 1)
            return truth
    raise GroupError(f"no layout of {o.n_people} people for scenario {o.scenario!r} keeps "
                     f"{LAYOUT_CLEARANCE_CM:g} cm between body centres (seed {o.seed})")


def min_centre_distance_cm(truth: GroupTruth, univ_time_ms: np.ndarray) -> float:
    """Smallest ground distance between two body centres at the given times, cm (inf for one person)."""
    xz = truth.centres_xz(univ_time_ms)
    P = xz.shape[1]
    if P < 2:
        return math.inf
    i, j = np.triu_indices(P, 1)
    return float(np.min(np.linalg.norm(xz[:, i] - xz[:, j], axis=-1)))
