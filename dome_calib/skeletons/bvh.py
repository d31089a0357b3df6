"""BVH (the animation tools' skeleton file: Blender, MotionBuilder, Maya): one file per person, a skeleton whose
bone lengths are the person's and joint rotations that put its joints where ours are.

- Hierarchy: the body centre (``CHip``) is the root (6 channels: position, then rotation); every joint of the
  layout is a ``JOINT`` named by its marker name (as the TRC and C3D files). A joint with several children (the
  body centre, the neck, the nose) has one zero-offset branch joint per child (``CHip_LHip``, ``Neck_LShoulder``,
  ...), as the CMU motion-capture BVH files have ``LHipJoint``: one rotation per bone, so every bone can point
  where the person's does. Rotation channels ``Zrotation Xrotation Yrotation`` (R = Rz Rx Ry, degrees).
- Rest pose (all rotations zero): a T pose facing +z, the person's left at +x; each ``OFFSET`` is the person's
  bone length (the median over the frames where both its joints are reconstructed) along that pose.
- Rotations: the root's is the pelvis frame (hips across, body centre to neck up); each bone's is the smallest
  turn, in its parent's frame, from its rest direction to the person's (its twist about itself is not observed
  and is not made up).
- Units: metres by default (:data:`UNIT_PER_CM`; ``--unit cm`` or ``mm`` for tools that read BVH in those): BVH
  files carry no unit and Blender's importer (``import_anim.bvh``, scale 1) takes one unit as one metre, so a file
  in cm made a person 163 m tall there.
- Axes: y up: ``(x, -y, -z)`` of our Panoptic world; where the bundle was imported from a lab's tool, the lab's
  own world turned to y up as Pose2Sim turns it (:func:`~dome_calib.skeletons.joints.y_up_axes`).
- Frames: every frame number from the person's first appearance to the last at ``Frame Time`` = 1 / the capture's
  rate. BVH has no missing value: a bone whose joints are not both there keeps its last direction (the first
  known one before that; the rest pose if never seen), the root its last position. Joints whose whole chain to the
  root is reconstructed land where ours are, up to the difference between the person's bone length in that frame
  and its median (:func:`constant_bone_body` is what a BVH reader must give back there).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dome_calib.arrays import fixed_text
from dome_calib.skeletons.joints import PARENT, bones, marker_names, y_up_axes
from dome_calib.skeletons.scenes import People, Track

#: Rest direction (y up, facing +z, the person's left at +x) of the bone from each joint's parent to it.
REST_DIRECTION = {"neck": (0, 1, 0), "nose": (0, 0.6, 0.8), "head_top": (0, 1, 0), "l_shoulder": (1, 0, 0),
                  "l_elbow": (1, 0, 0), "l_wrist": (1, 0, 0), "r_shoulder": (-1, 0, 0), "r_elbow": (-1, 0, 0),
                  "r_wrist": (-1, 0, 0), "l_hip": (1, 0, 0), "l_knee": (0, -1, 0), "l_ankle": (0, -1, 0),
                  "r_hip": (-1, 0, 0), "r_knee": (0, -1, 0), "r_ankle": (0, -1, 0), "l_eye": (0.6, 0.8, 0),
                  "l_ear": (0.8, 0, -0.6), "r_eye": (-0.6, 0.8, 0), "r_ear": (-0.8, 0, -0.6), "upper_neck": (0, 1, 0),
                  "l_big_toe": (0, -0.3, 0.95), "l_small_toe": (1, 0, 0), "l_heel": (0, -0.6, -0.8),
                  "r_big_toe": (0, -0.3, 0.95), "r_small_toe": (-1, 0, 0), "r_heel": (0, -0.6, -0.8)}
MIN_BONE_CM = 1.0  # a bone never seen gets its mirror's length, else this
#: BVH length units and their size per cm.
UNIT_PER_CM = {"m": 0.01, "cm": 1.0, "mm": 10.0}
END_SITE_CM = 5.0


@dataclass(frozen=True)
class BvhBody:
    """One person's dense frames (F = last - first frame number + 1) in the BVH frame (y up, cm): ``X`` (F, J, 3)
    our joints (NaN where missing), ``length_cm`` (J,) bone length to each joint's parent (0 at the root),
    ``direction`` (F, J, 3) unit bone directions (held where missing), ``root`` (F, 3) root positions (held)."""

    first_frame: int
    X: np.ndarray
    length_cm: np.ndarray
    direction: np.ndarray
    root: np.ndarray


def _hold(values: np.ndarray, ok: np.ndarray, default: np.ndarray) -> np.ndarray:
    """(F, ...) values with the rows where ``ok`` is False replaced by the last ok row (the first ok row before it;
    ``default`` if none)."""
    if not ok.any():
        return np.broadcast_to(default, values.shape).copy()
    idx = np.where(ok, np.arange(len(ok)), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = np.flatnonzero(ok)[0]
    return values[idx]


def bvh_body(people: People, track: Track, joint_ok: np.ndarray) -> BvhBody:
    """The person's frames in the BVH frame, bone lengths and (held) bone directions."""
    joints = people.joints
    frames = people.frames[track.rows]
    F = int(frames[-1] - frames[0]) + 1
    X = np.full((F, len(joints), 3), np.nan)
    X[frames - frames[0]] = np.where(joint_ok[..., None], track.X_cm @ y_up_axes(people).T, np.nan)
    ok = np.isfinite(X).all(-1)
    length = np.zeros(len(joints))
    direction = np.zeros((F, len(joints), 3))
    for p, c in bones(joints):
        both = ok[:, p] & ok[:, c]
        v = X[:, c] - X[:, p]
        n = np.linalg.norm(v, axis=-1)
        length[c] = float(np.median(n[both])) if both.any() else 0.0
        unit = np.where(both[:, None], v / np.where(n > 0, n, 1.0)[:, None], 0.0)
        rest = np.asarray(REST_DIRECTION[joints[c]], float)
        direction[:, c] = _hold(unit, both & (n > 0), rest / np.linalg.norm(rest))
    for c, name in enumerate(joints):  # never seen: the mirror's length (left/right), else MIN_BONE_CM
        if PARENT[name] is not None and length[c] == 0.0:
            mirror = name.replace("l_", "#").replace("r_", "l_").replace("#", "r_")
            length[c] = length[joints.index(mirror)] if mirror in joints else 0.0
            length[c] = length[c] or MIN_BONE_CM
    r = joints.index("body_center")
    root = X[:, r].copy()
    hips = [joints.index(n) for n in ("l_hip", "r_hip")]
    mid = np.nanmean(X[:, hips], axis=1) if ok[:, hips].all(1).any() else np.full((F, 3), np.nan)
    root = np.where(ok[:, r:r + 1], root, np.where(ok[:, hips].all(1)[:, None], mid, np.nan))
    root = _hold(root, np.isfinite(root).all(-1), np.zeros(3))
    return BvhBody(first_frame=int(frames[0]), X=X, length_cm=length, direction=direction, root=root)


def _swing(a: np.ndarray, b: np.ndarray) -> Rotation:
    """The smallest rotations taking unit vectors ``a`` (F, 3) to ``b`` (F, 3)."""
    cross = np.cross(a, b)
    sin = np.linalg.norm(cross, axis=-1)
    cos = np.einsum("fi,fi->f", a, b)
    axis = cross / np.where(sin > 1e-12, sin, 1.0)[:, None]
    flip = (sin <= 1e-12) & (cos < 0)  # opposite: any axis across a
    if flip.any():
        other = np.where(np.abs(a[flip, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        across = np.cross(a[flip], other)
        axis[flip] = across / np.linalg.norm(across, axis=-1, keepdims=True)
    return Rotation.from_rotvec(axis * np.arctan2(sin, cos)[:, None])


def _pelvis(body: BvhBody, joints: tuple[str, ...]) -> Rotation:
    """The root's rotation per frame: x across the hips (left minus right), y from the body centre to the neck
    (made orthogonal), z = x cross y; held where the hips or the neck are missing."""
    X = body.X
    across = X[:, joints.index("l_hip")] - X[:, joints.index("r_hip")]
    up = X[:, joints.index("neck")] - X[:, joints.index("body_center")]
    x = across / np.linalg.norm(across, axis=-1, keepdims=True)
    y = up - np.einsum("fi,fi->f", up, x)[:, None] * x
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    frame = np.stack([x, y, np.cross(x, y)], axis=-1)
    ok = np.isfinite(frame).all((-2, -1))
    return Rotation.from_matrix(_hold(np.where(ok[:, None, None], frame, 0.0), ok, np.eye(3)))


@dataclass(frozen=True)
class BvhJoint:
    name: str
    offset: np.ndarray
    children: list[BvhJoint]
    rotation: Rotation  # global, per frame


def skeleton(body: BvhBody, joints: tuple[str, ...], markers: list[str]) -> BvhJoint:
    """The BVH hierarchy of one person with every joint's global rotation per frame (``markers``: the joints'
    names, :func:`~dome_calib.skeletons.joints.marker_names`)."""
    index = {n: k for k, n in enumerate(joints)}
    marker = dict(zip(joints, markers))

    def bone_rotation(c: str, parent_rot: Rotation) -> Rotation:
        rest = np.asarray(REST_DIRECTION[c], float) / np.linalg.norm(REST_DIRECTION[c])
        carried = parent_rot.apply(np.tile(rest, (len(body.root), 1)))
        return _swing(carried, body.direction[:, index[c]]) * parent_rot

    def node(name: str, offset: np.ndarray, parent_rot: Rotation) -> BvhJoint:
        children = [c for c in joints if PARENT[c] == name]
        chain = len(children) == 1 and PARENT[name] is not None
        if PARENT[name] is None:
            rot = _pelvis(body, joints)
        else:
            rot = bone_rotation(children[0], parent_rot) if chain else parent_rot
        kids = []
        for c in children:
            rest = np.asarray(REST_DIRECTION[c], float) / np.linalg.norm(REST_DIRECTION[c])
            child_offset = body.length_cm[index[c]] * rest
            if chain:
                kids.append(node(c, child_offset, rot))
            else:  # a branch joint per child: its own rotation for the bone
                branch = bone_rotation(c, rot)
                kids.append(BvhJoint(name=f"{marker[name]}_{marker[c]}", offset=np.zeros(3),
                                     children=[node(c, child_offset, branch)], rotation=branch))
        return BvhJoint(name=marker[name], offset=offset, children=kids, rotation=rot)

    return node("body_center", np.zeros(3), Rotation.identity(len(body.root)))


def _hierarchy(joint: BvhJoint, depth: int, lines: list[str], order: list[tuple[BvhJoint, BvhJoint | None]],
               parent: BvhJoint | None, scale: float) -> None:
    pad = "  " * depth
    root = parent is None
    lines.append(f"{pad}{'ROOT' if root else 'JOINT'} {joint.name}")
    lines.append(f"{pad}{{")
    lines.append(f"{pad}  OFFSET {' '.join(f'{v * scale:.6f}' for v in joint.offset)}")
    lines.append(f"{pad}  CHANNELS " + ("6 Xposition Yposition Zposition " if root else "3 ")
                 + "Zrotation Xrotation Yrotation")
    order.append((joint, parent))
    for child in joint.children:
        _hierarchy(child, depth + 1, lines, order, joint, scale)
    if not joint.children:
        lines += [f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0.000000 {END_SITE_CM * scale:.6f} 0.000000",
                  f"{pad}  }}"]
    lines.append(f"{pad}}}")


def bvh_text(people: People, track: Track, joint_ok: np.ndarray, unit: str = "m") -> str:
    """The BVH file of one person, lengths in ``unit`` (see the module docstring)."""
    scale = UNIT_PER_CM[unit]
    body = bvh_body(people, track, joint_ok)
    top = skeleton(body, people.joints, marker_names(people))
    lines = ["HIERARCHY"]
    order: list[tuple[BvhJoint, BvhJoint | None]] = []
    _hierarchy(top, 0, lines, order, None, scale)
    columns = [body.root * scale]
    with warnings.catch_warnings():  # at +-90 deg about x the ZXY angles are not unique: scipy says so; any is right
        warnings.simplefilter("ignore", UserWarning)
        for joint, parent in order:
            local = joint.rotation if parent is None else parent.rotation.inv() * joint.rotation
            columns.append(local.as_euler("ZXY", degrees=True))
    motion = np.concatenate(columns, axis=1)
    lines += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1.0 / float(people.fps):.10f}"]
    lines += [" ".join(row) for row in fixed_text(motion, 6)]
    return "\n".join(lines) + "\n"


def constant_bone_body(people: People, track: Track, joint_ok: np.ndarray) -> tuple[int, np.ndarray]:
    """(first frame, (F, J, 3)): where a BVH reader must put each joint (y up, cm): the root's position plus the
    person's bone lengths along its bone directions, summed down the tree. Equal to our joints where the bones
    have their median lengths."""
    body = bvh_body(people, track, joint_ok)
    out = np.zeros_like(body.X)
    for p, c in [(None, people.joints.index("body_center"))] + bones(people.joints):
        out[:, c] = body.root if p is None else out[:, p] + body.length_cm[c] * body.direction[:, c]
    return body.first_frame, out


def write_bvh(folder: Path, people: People, track: Track, joint_ok: np.ndarray, *, unit: str = "m") -> Path:
    """Write ``person<id>.bvh`` into ``folder`` (a staging folder), lengths in ``unit``; returns its path."""
    path = folder / f"person{track.id}.bvh"
    path.write_text(bvh_text(people, track, joint_ok, unit), encoding="utf-8")
    return path
