"""2D body models of pose detectors and their maps to and from the Panoptic 19-joint layout (``joints19``).

Models (joint order = the detector's output order):

- ``BODY_25``: OpenPose's default model (``pose_keypoints_2d`` of 25 joints; MidHip at 8).
- ``BODY_25B``: OpenPose's experimental model (openpose_train ``experimental_models``): the 17 COCO joints in COCO
  order, then UpperNeck, HeadTop and the six foot joints. Same length as BODY_25 with another order, so a
  detections folder cannot tell them apart by length: the caller names the model.
- ``COCO_18``: OpenPose's COCO output (18 joints, Neck at 1, no MidHip).
- ``COCO_17``: the 17 COCO joints (RTMPose, MMPose, what Pose2Sim 0.9 and later write with ``pose_model =
  'COCO_17'``): no neck, no hip centre.
- ``HALPE_26``: Halpe's 26 joints (RTMPose / AlphaPose, Pose2Sim's default model since 0.9): the 17 COCO joints,
  then Head (the head top), Neck, Hip (the hip centre) and the six foot joints (big toe, small toe, heel; left
  before right, as Pose2Sim's ``skeletons.py`` numbers them: LBigToe 20, RBigToe 21, LSmallToe 22, RSmallToe 23,
  LHeel 24, RHeel 25).
- ``PANOPTIC19``: the Panoptic Studio's ``joints19`` itself (order of :data:`dome_calib.synth.skeleton.JOINTS19`).

Derived joints (joints19 needs them, the model lacks them):

- ``body_center`` (Panoptic's hip centre) = midpoint of the two hips for BODY_25B, COCO_18 and COCO_17 (BODY_25 has
  MidHip, HALPE_26 Hip);
- ``neck`` = midpoint of the two shoulders for BODY_25B and COCO_17 (BODY_25B's UpperNeck sits at the top of the
  neck, about 10 cm above Panoptic's neck, so it is not used for it).

Extra joints (:data:`EXTRA_JOINTS`): the model's joints that joints19 lacks (the feet, BODY_25B's UpperNeck, the
head top), carried beside joints19 by :func:`with_extras` (``reconstruct`` triangulates them for the people it
found: :mod:`dome_calib.recon.people.extras`).

A derived joint's confidence is the smaller of its sources' (0 if either is missing). Going the other way
(:func:`from_joints19`), joints the model has and joints19 lacks (feet, HeadTop, UpperNeck, BODY_25's MidHip is
not among them: it is body_center) get confidence 0 and pixel 0.
"""
from __future__ import annotations

import functools

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from dome_calib.recon.errors import ReconError

#: Panoptic joints19 order (the same list as dome_calib.synth.skeleton.JOINTS19; a test keeps them equal).
JOINTS19 = ["neck", "nose", "body_center", "l_shoulder", "l_elbow", "l_wrist", "l_hip", "l_knee", "l_ankle",
            "r_shoulder", "r_elbow", "r_wrist", "r_hip", "r_knee", "r_ankle", "l_eye", "l_ear", "r_eye", "r_ear"]

#: joints19 bones (pairs of joints19 names) used for bone-length plausibility and drawing.
BONES19 = [("neck", "nose"), ("neck", "body_center"), ("neck", "l_shoulder"), ("l_shoulder", "l_elbow"),
           ("l_elbow", "l_wrist"), ("body_center", "l_hip"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
           ("neck", "r_shoulder"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"), ("body_center", "r_hip"),
           ("r_hip", "r_knee"), ("r_knee", "r_ankle"), ("nose", "l_eye"), ("l_eye", "l_ear"), ("nose", "r_eye"),
           ("r_eye", "r_ear")]

#: Nominal adult length (cm) of each bone of :data:`BONES19` and of the two cross bones (shoulders, hips): the one
#: table of bone lengths (the association's ghost test and the per-joint skeleton check both read it).
BONE_LENGTH_CM: dict[tuple[str, str], float] = {
    ("neck", "nose"): 20.0, ("neck", "body_center"): 52.0, ("neck", "l_shoulder"): 18.0,
    ("neck", "r_shoulder"): 18.0, ("l_shoulder", "l_elbow"): 28.0, ("r_shoulder", "r_elbow"): 28.0,
    ("l_elbow", "l_wrist"): 25.0, ("r_elbow", "r_wrist"): 25.0, ("body_center", "l_hip"): 11.0,
    ("body_center", "r_hip"): 11.0, ("l_hip", "l_knee"): 44.0, ("r_hip", "r_knee"): 44.0, ("l_knee", "l_ankle"): 42.0,
    ("r_knee", "r_ankle"): 42.0, ("nose", "l_eye"): 5.0, ("nose", "r_eye"): 5.0, ("l_eye", "l_ear"): 9.0,
    ("r_eye", "r_ear"): 9.0, ("l_shoulder", "r_shoulder"): 36.0, ("l_hip", "r_hip"): 22.0}

#: Left/right partner of each joints19 joint (itself for the midline joints): a left/right swap exchanges these.
MIRROR19 = [JOINTS19.index(n.replace("l_", "#").replace("r_", "l_").replace("#", "r_")) for n in JOINTS19]

_COCO17 = ["nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_shoulder", "r_shoulder", "l_elbow", "r_elbow",
           "l_wrist", "r_wrist", "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle"]
_FEET = ["l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel"]


class BodyModel(StrEnum):
    BODY_25 = "BODY_25"
    BODY_25B = "BODY_25B"
    COCO_18 = "COCO_18"
    COCO_17 = "COCO_17"
    HALPE_26 = "HALPE_26"
    PANOPTIC19 = "PANOPTIC19"


#: Joint names of each model in the detector's order (joints19 names where the joint is the same).
JOINT_NAMES: dict[BodyModel, list[str]] = {
    BodyModel.BODY_25: ["nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist",
                        "body_center", "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye",
                        "r_ear", "l_ear"] + _FEET,
    BodyModel.BODY_25B: _COCO17 + ["upper_neck", "head_top"] + _FEET,
    BodyModel.COCO_18: ["nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist",
                        "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye", "r_ear",
                        "l_ear"],
    BodyModel.COCO_17: list(_COCO17),
    BodyModel.HALPE_26: _COCO17 + ["head_top", "neck", "body_center", "l_big_toe", "r_big_toe", "l_small_toe",
                                   "r_small_toe", "l_heel", "r_heel"],
    BodyModel.PANOPTIC19: list(JOINTS19),
}

#: joints19 joints a model lacks and how they are derived: the midpoint of these two joints of the model.
DERIVED: dict[BodyModel, dict[str, tuple[str, str]]] = {
    BodyModel.BODY_25: {},
    BodyModel.BODY_25B: {"body_center": ("l_hip", "r_hip"), "neck": ("l_shoulder", "r_shoulder")},
    BodyModel.COCO_18: {"body_center": ("l_hip", "r_hip")},
    BodyModel.COCO_17: {"body_center": ("l_hip", "r_hip"), "neck": ("l_shoulder", "r_shoulder")},
    BodyModel.HALPE_26: {},
    BodyModel.PANOPTIC19: {},
}

#: Each extra joint's joints19 neighbour and their nominal adult distance (cm): the feet from their ankle (big toe
#: 16, small toe 16, heel 8), BODY_25B's UpperNeck from joints19's neck (the shoulders' midpoint, ~10 cm below it),
#: the head top from the nose (18); the bone an extra joint hangs from, as BONE_LENGTH_CM's bones for joints19.
EXTRA_BONE_CM: dict[str, tuple[str, float]] = {
    "l_big_toe": ("l_ankle", 16.0), "l_small_toe": ("l_ankle", 16.0), "l_heel": ("l_ankle", 8.0),
    "r_big_toe": ("r_ankle", 16.0), "r_small_toe": ("r_ankle", 16.0), "r_heel": ("r_ankle", 8.0),
    "upper_neck": ("neck", 10.0), "head_top": ("nose", 18.0)}

#: The joints of each model that joints19 lacks, in the model's order: carried beside joints19 (:func:`with_extras`).
EXTRA_JOINTS: dict[BodyModel, list[str]] = {m: [n for n in names if n not in JOINTS19]
                                            for m, names in JOINT_NAMES.items()}


@dataclass(frozen=True)
class JointMap:
    """How one model's joints become joints19 and back.

    direct (19,) int: the model's index of each joints19 joint, -1 where derived; derived_a, derived_b (19,) int:
    the two model joints whose midpoint is the joints19 joint (-1 where direct); to_model (J,) int: the joints19
    index of each model joint, -1 where joints19 lacks it.
    """

    model: BodyModel
    n_joints: int
    direct: np.ndarray
    derived_a: np.ndarray
    derived_b: np.ndarray
    to_model: np.ndarray


def parse_body_model(name: str) -> BodyModel:
    """``"body_25b"`` / ``"BODY-25B"`` / ``"coco"`` -> :class:`BodyModel`; ReconError naming the known ones."""
    key = name.strip().upper().replace("-", "_")
    key = {"COCO": "COCO_18", "COCO18": "COCO_18", "COCO17": "COCO_17", "HALPE26": "HALPE_26", "HALPE": "HALPE_26",
           "BODY25": "BODY_25", "BODY25B": "BODY_25B", "PANOPTIC": "PANOPTIC19", "JOINTS19": "PANOPTIC19"}.get(key, key)
    try:
        return BodyModel(key)
    except ValueError:
        raise ReconError(f"body model {name!r} is unknown (known: {', '.join(m.value for m in BodyModel)})") from None


def joint_map(model: BodyModel | str) -> JointMap:
    """The :class:`JointMap` of a model (made once per model: it is asked for every file read)."""
    return _joint_map(parse_body_model(model) if not isinstance(model, BodyModel) else model)


@functools.cache
def _joint_map(model: BodyModel) -> JointMap:
    names = JOINT_NAMES[model]
    derived = DERIVED[model]
    direct = np.full(19, -1)
    da, db = np.full(19, -1), np.full(19, -1)
    for k, joint in enumerate(JOINTS19):
        if joint in derived:
            a, b = derived[joint]
            da[k], db[k] = names.index(a), names.index(b)
        else:
            direct[k] = names.index(joint)
    to_model = np.array([JOINTS19.index(n) if n in JOINTS19 and n not in derived else -1 for n in names])
    for a in (direct, da, db, to_model):
        a.flags.writeable = False  # shared by every caller
    return JointMap(model=model, n_joints=len(names), direct=direct, derived_a=da, derived_b=db, to_model=to_model)


def models_with_joints(n_joints: int) -> list[BodyModel]:
    """The models whose detector writes ``n_joints`` joints per person (BODY_25 and BODY_25B share 25)."""
    return [m for m in BodyModel if len(JOINT_NAMES[m]) == n_joints]


def to_joints19(keypoints: np.ndarray, model: BodyModel | str) -> np.ndarray:
    """(..., J, 3) ``[x_px, y_px, c]`` in the model's order -> (..., 19, 3) in joints19 order.

    Derived joints: midpoint of the two sources, confidence the smaller one (0 if either source has c <= 0).
    Joints with c <= 0 come out as [0, 0, 0].
    """
    jm = joint_map(model)
    kp = np.asarray(keypoints, dtype=float)
    if kp.shape[-2:] != (jm.n_joints, 3):
        raise ReconError(f"keypoints have shape {kp.shape} but {jm.model} expects (..., {jm.n_joints}, 3)")
    out = np.zeros(kp.shape[:-2] + (19, 3))
    d = jm.direct >= 0
    out[..., d, :] = kp[..., jm.direct[d], :]
    dv = ~d
    if dv.any():
        a, b = kp[..., jm.derived_a[dv], :], kp[..., jm.derived_b[dv], :]
        c = np.minimum(a[..., 2], b[..., 2])
        out[..., dv, :2] = 0.5 * (a[..., :2] + b[..., :2])
        out[..., dv, 2] = np.where((a[..., 2] > 0) & (b[..., 2] > 0), c, 0.0)
    return np.where((out[..., 2:3] > 0), out, 0.0)


def from_joints19(joints19: np.ndarray, model: BodyModel | str) -> np.ndarray:
    """(..., 19, 3) joints19 ``[x_px, y_px, c]`` -> (..., J, 3) in the model's order (joints19 lacks -> 0).

    A model joint that joints19 derives (BODY_25B's hips, shoulders) is taken directly; the derived joints19 ones
    (body_center, neck of BODY_25B) are dropped, so ``to_joints19(from_joints19(x))`` rebuilds them as midpoints.
    """
    jm = joint_map(model)
    j19 = np.asarray(joints19, dtype=float)
    if j19.shape[-2:] != (19, 3):
        raise ReconError(f"joints19 have shape {j19.shape} but expected (..., 19, 3)")
    out = np.zeros(j19.shape[:-2] + (jm.n_joints, 3))
    have = jm.to_model >= 0
    out[..., have, :] = j19[..., jm.to_model[have], :]
    return out


def with_extras(keypoints: np.ndarray, model: BodyModel | str) -> np.ndarray:
    """(..., J, 3) in the model's order -> (..., 19 + E, 3): joints19 (:func:`to_joints19`), then the model's
    :data:`EXTRA_JOINTS` as detected (c <= 0 -> [0, 0, 0])."""
    model = parse_body_model(model) if not isinstance(model, BodyModel) else model
    kp = np.asarray(keypoints, dtype=float)
    j19 = to_joints19(kp, model)
    names = JOINT_NAMES[model]
    extra = kp[..., [names.index(n) for n in EXTRA_JOINTS[model]], :]
    extra = np.where(extra[..., 2:3] > 0, extra, 0.0)
    return np.concatenate([j19, extra], axis=-2)
