"""The Panoptic joint layouts of body3DScene files, their kinematic trees, the marker names written for other tools,
and the axes of each output format.

Layouts (the Panoptic toolbox's README and its Matlab ``PoseLoaderJson.m``/``Visualize3DPose.m``):

- ``joints19`` (``hdPose3d_stage1_coco19``, what ``dome-calib reconstruct`` writes): neck, nose, body centre (the
  centre of the hips), left shoulder, elbow, wrist, hip, knee, ankle, the same on the right, left eye, left ear,
  right eye, right ear;
- ``joints15`` (the older "mpi15" files, ``vgaPose3d_stage1``): the first 15 of joints19 with the head top in place
  of the nose.

Marker names are Pose2Sim's (``Pose2Sim/skeletons.py``, its OpenSim marker sets ``Markers_Body25.xml``,
``Markers_Coco17.xml``): ``Neck``, ``Nose``, ``CHip`` (the hip centre, as in its BODY_25 tree), ``LShoulder`` ...,
``LEye``, ``LEar``, and ``Head`` for the head top (BODY_25B's). OpenSim's inverse kinematics uses the markers its
marker set names and ignores the others.

Axes (ours: the Panoptic world, y down, cm):

- y up (OpenSim, Pose2Sim's TRC files, BVH): ``(x, -y, -z)``, a half turn about x;
- z up (C3D, as Vicon, Qualisys and Visual3D show it): ``(x, z, -y)``, a quarter turn about x.
"""
from __future__ import annotations

import numpy as np

#: joints19 names, in file order.
JOINTS19 = ("neck", "nose", "body_center", "l_shoulder", "l_elbow", "l_wrist", "l_hip", "l_knee", "l_ankle",
            "r_shoulder", "r_elbow", "r_wrist", "r_hip", "r_knee", "r_ankle", "l_eye", "l_ear", "r_eye", "r_ear")
#: joints15 ("mpi15") names, in file order.
JOINTS15 = ("neck", "head_top") + JOINTS19[2:15]
LAYOUTS = {"joints19": JOINTS19, "joints15": JOINTS15}

#: Marker name of each joint (Pose2Sim's names).
MARKER = {"neck": "Neck", "nose": "Nose", "head_top": "Head", "body_center": "CHip", "l_shoulder": "LShoulder",
          "l_elbow": "LElbow", "l_wrist": "LWrist", "l_hip": "LHip", "l_knee": "LKnee", "l_ankle": "LAnkle",
          "r_shoulder": "RShoulder", "r_elbow": "RElbow", "r_wrist": "RWrist", "r_hip": "RHip", "r_knee": "RKnee",
          "r_ankle": "RAnkle", "l_eye": "LEye", "l_ear": "LEar", "r_eye": "REye", "r_ear": "REar"}

#: Parent of each joint in the kinematic tree rooted at the body centre (None: the root).
PARENT = {"body_center": None, "neck": "body_center", "nose": "neck", "head_top": "neck", "l_shoulder": "neck",
          "l_elbow": "l_shoulder", "l_wrist": "l_elbow", "r_shoulder": "neck", "r_elbow": "r_shoulder",
          "r_wrist": "r_elbow", "l_hip": "body_center", "l_knee": "l_hip", "l_ankle": "l_knee",
          "r_hip": "body_center", "r_knee": "r_hip", "r_ankle": "r_knee", "l_eye": "nose", "l_ear": "l_eye",
          "r_eye": "nose", "r_ear": "r_eye"}

#: Panoptic world (y down) -> y up (OpenSim, BVH): a half turn about x.
Y_UP_FROM_PANOPTIC = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
#: Panoptic world (y down) -> z up (C3D): a quarter turn about x.
Z_UP_FROM_PANOPTIC = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def marker_names(people) -> list[str]:
    """The marker name of each joint of ``people`` (a :class:`~dome_calib.skeletons.scenes.People`), in its order."""
    return [MARKER[j] for j in people.joints]


def y_up_axes(people) -> np.ndarray:
    """(3, 3): our world -> the y-up axes of the TRC and BVH files (OpenSim's)."""
    return Y_UP_FROM_PANOPTIC


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
