"""The Panoptic joint layouts of body3DScene files, their kinematic trees, the marker names written for other tools,
and the axes of each output format.

Layouts (the Panoptic toolbox's README and its Matlab ``PoseLoaderJson.m``/``Visualize3DPose.m``):

- ``joints19`` (``hdPose3d_stage1_coco19``, what ``dome-calib reconstruct`` writes): neck, nose, body centre (the
  centre of the hips), left shoulder, elbow, wrist, hip, knee, ankle, the same on the right, left eye, left ear,
  right eye, right ear;
- ``joints15`` (the older "mpi15" files, ``vgaPose3d_stage1``): the first 15 of joints19 with the head top in place
  of the nose.

Marker names are Pose2Sim's (``Pose2Sim/skeletons.py``, its OpenSim marker sets ``Markers_Body25.xml``,
``Markers_Body25b.xml``, ``Markers_Halpe26.xml``, ``Markers_Coco17.xml``): ``Neck``, ``Nose``, ``CHip`` (the hip
centre, as in its BODY_25 tree; ``Hip`` for HALPE_26 and COCO_17), ``LShoulder`` ..., ``LEye``, ``LEar``, ``Head``
for the head top, ``LBigToe``, ``LSmallToe``, ``LHeel`` ... for the feet (:func:`marker_names`). OpenSim's inverse
kinematics uses the markers its marker set names and ignores the others.

Axes (ours: the Panoptic world, y down, cm):

- y up (OpenSim, Pose2Sim's TRC files, BVH): ``(x, -y, -z)``, a half turn about x;
- z up (C3D, as Vicon, Qualisys and Visual3D show it): ``(x, z, -y)``, a quarter turn about x.

Where the bundle was imported from a lab's tool (the files' ``labUp``), the lab's own world instead
(:func:`y_up_axes`, :func:`z_up_axes`): Pose2Sim's TRC axes for a z-up lab.
"""
from __future__ import annotations

import numpy as np

# the file's layouts and extra joints are declared with the file (dome_calib.body3d_scene) and named here too
from dome_calib.body3d_scene import EXTRA_NAMES, JOINTS15, JOINTS19, LAYOUTS  # noqa: F401
from dome_calib.lab_world import PANOPTIC_FROM_UP

#: Marker name of each joint (Pose2Sim's names).
MARKER = {"neck": "Neck", "nose": "Nose", "head_top": "Head", "body_center": "CHip", "l_shoulder": "LShoulder",
          "l_elbow": "LElbow", "l_wrist": "LWrist", "l_hip": "LHip", "l_knee": "LKnee", "l_ankle": "LAnkle",
          "r_shoulder": "RShoulder", "r_elbow": "RElbow", "r_wrist": "RWrist", "r_hip": "RHip", "r_knee": "RKnee",
          "r_ankle": "RAnkle", "l_eye": "LEye", "l_ear": "LEar", "r_eye": "REye", "r_ear": "REar",
          "upper_neck": "Neck", "l_big_toe": "LBigToe", "l_small_toe": "LSmallToe", "l_heel": "LHeel",
          "r_big_toe": "RBigToe", "r_small_toe": "RSmallToe", "r_heel": "RHeel"}
#: The hip centre's marker name per detector model where Pose2Sim's tree names it ``Hip`` (else ``CHip``).
HIP_CENTRE_MARKER = {"HALPE_26": "Hip", "COCO_17": "Hip"}
#: Marker name of joints19's neck where the detector's own neck joint (BODY_25B's UpperNeck) is ``Neck``: ours is
#: the shoulders' midpoint there.
MID_SHOULDER_MARKER = "MidShoulder"

#: Parent of each joint in the kinematic tree rooted at the body centre (None: the root).
PARENT = {"body_center": None, "neck": "body_center", "nose": "neck", "head_top": "neck", "l_shoulder": "neck",
          "l_elbow": "l_shoulder", "l_wrist": "l_elbow", "r_shoulder": "neck", "r_elbow": "r_shoulder",
          "r_wrist": "r_elbow", "l_hip": "body_center", "l_knee": "l_hip", "l_ankle": "l_knee",
          "r_hip": "body_center", "r_knee": "r_hip", "r_ankle": "r_knee", "l_eye": "nose", "l_ear": "l_eye",
          "r_eye": "nose", "r_ear": "r_eye", "upper_neck": "neck", "l_big_toe": "l_ankle", "l_small_toe": "l_big_toe",
          "l_heel": "l_ankle", "r_big_toe": "r_ankle", "r_small_toe": "r_big_toe", "r_heel": "r_ankle"}

#: Panoptic world (y down) -> y up (OpenSim, BVH): a half turn about x.
Y_UP_FROM_PANOPTIC = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
#: Panoptic world (y down) -> z up (C3D): a quarter turn about x.
Z_UP_FROM_PANOPTIC = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def marker_names(people) -> list[str]:
    """The marker name of each joint of ``people`` (a :class:`~dome_calib.skeletons.scenes.People`), in its order:
    the names Pose2Sim's tree of the detector (``Pose2Sim/skeletons.py``) and its OpenSim marker set
    (``Markers_<model>.xml``) give them. ``Neck`` is the detector's own neck joint (BODY_25B's UpperNeck, as
    Pose2Sim's BODY_25B tree has it; joints19's neck, the shoulders' midpoint there, is ``MidShoulder``); the hip
    centre is ``Hip`` for HALPE_26 and COCO_17 (Pose2Sim's names), ``CHip`` otherwise."""
    names = {j: MARKER[j] for j in people.joints}
    if "upper_neck" in names:
        names["neck"] = MID_SHOULDER_MARKER
    names["body_center"] = HIP_CENTRE_MARKER.get(people.body_model or "", "CHip")
    return [names[j] for j in people.joints]


#: Pose2Sim's turn of a z-up lab world to OpenSim's y up (``Pose2Sim/common.py``, ``zup2yup``: the TRC's x, y, z
#: are the lab's y, z, x).
Y_UP_FROM_Z_UP_LAB = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def lab_from_world(people) -> np.ndarray | None:
    """(3, 3): our world -> the lab world the bundle was imported from (``labUp`` of the body3DScene files: the
    import turned that world's up axis to our -y with :data:`~dome_calib.lab_world.PANOPTIC_FROM_UP`), or
    None when the bundle was not imported."""
    if people.lab_up is None:
        return None
    return PANOPTIC_FROM_UP[people.lab_up].T


def y_up_axes(people) -> np.ndarray:
    """(3, 3): our world -> the y-up axes of the TRC and BVH files (OpenSim's). A bundle imported from a z-up lab
    (Pose2Sim, Qualisys, ...): the lab's world turned as Pose2Sim turns it (:data:`Y_UP_FROM_Z_UP_LAB`), so the
    files, and the joint angles OpenSim finds in them, are Pose2Sim's; from a y-up lab: the lab's world itself;
    otherwise (our own calibration, other labs): :data:`Y_UP_FROM_PANOPTIC`."""
    lab = lab_from_world(people)
    if people.lab_up == "+z":
        return Y_UP_FROM_Z_UP_LAB @ lab
    if people.lab_up == "+y":
        return lab
    return Y_UP_FROM_PANOPTIC


def z_up_axes(people) -> np.ndarray:
    """(3, 3): our world -> the z-up axes of the C3D file: a z-up lab's own world where the bundle was imported
    from one, else :data:`Z_UP_FROM_PANOPTIC`."""
    return lab_from_world(people) if people.lab_up == "+z" else Z_UP_FROM_PANOPTIC


def bones(joints: tuple[str, ...]) -> list[tuple[int, int]]:
    """(parent index, child index) of every bone of a layout, parents before children (the drawing and the BVH
    tree)."""
    index = {name: k for k, name in enumerate(joints)}
    out: list[tuple[int, int]] = []
    pending = [n for n in joints if PARENT[n] is None]
    while pending:
        parent = pending.pop(0)
        children = [n for n in joints if PARENT[n] == parent]
        out += [(index[parent], index[c]) for c in children]
        pending += children
    return out
