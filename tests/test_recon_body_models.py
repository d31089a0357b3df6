"""Body models: joint orders, maps to and from Panoptic joints19, derived joints."""
import numpy as np
import pytest

from dome_calib.recon.body_models import (JOINT_NAMES, JOINTS19, MIRROR19, BodyModel, from_joints19, joint_map,
                                          models_with_joints, parse_body_model, to_joints19)
from dome_calib.recon.errors import ReconError
from dome_calib.synth.skeleton import JOINTS19 as SYNTH_JOINTS19


def test_joints19_is_the_synth_order():
    assert JOINTS19 == SYNTH_JOINTS19
    assert [JOINTS19[MIRROR19[k]] for k in range(19)][3] == "r_shoulder"
    assert all(MIRROR19[MIRROR19[k]] == k for k in range(19))


def test_lengths_and_known_indices():
    assert {m: len(n) for m, n in JOINT_NAMES.items()} == {"BODY_25": 25, "BODY_25B": 25, "COCO_18": 18,
                                                          "COCO_17": 17, "HALPE_26": 26, "PANOPTIC19": 19}
    b25, b25b, coco = (JOINT_NAMES[m] for m in ("BODY_25", "BODY_25B", "COCO_18"))
    # OpenPose BODY_25: Neck 1, MidHip 8, LHip 12, REye 15, LBigToe 19; BODY_25B: COCO-17 order, LHip 11,
    # RHip 12, UpperNeck 17, HeadTop 18, RHeel 24; COCO-18: RHip 8, LHip 11, LEar 17.
    assert (b25[1], b25[8], b25[12], b25[15], b25[19]) == ("neck", "body_center", "l_hip", "r_eye", "l_big_toe")
    assert (b25b[0], b25b[5], b25b[11], b25b[12], b25b[17], b25b[18], b25b[24]) == (
        "nose", "l_shoulder", "l_hip", "r_hip", "upper_neck", "head_top", "r_heel")
    assert (coco[8], coco[11], coco[17]) == ("r_hip", "l_hip", "l_ear")
    assert models_with_joints(25) == [BodyModel.BODY_25, BodyModel.BODY_25B]
    assert models_with_joints(21) == []
    assert parse_body_model("body-25b") == BodyModel.BODY_25B and parse_body_model("coco") == BodyModel.COCO_18
    assert parse_body_model("halpe26") == BodyModel.HALPE_26 and parse_body_model("COCO-17") == BodyModel.COCO_17
    assert models_with_joints(26) == [BodyModel.HALPE_26] and models_with_joints(17) == [BodyModel.COCO_17]
    with pytest.raises(ReconError, match="unknown"):
        parse_body_model("MPI_15")


@pytest.mark.parametrize("model", list(BodyModel))
def test_round_trip_through_each_model(model):
    rng = np.random.default_rng(3)
    j19 = np.concatenate([rng.uniform(0, 1000, (4, 19, 2)), rng.uniform(0.2, 1, (4, 19, 1))], axis=-1)
    names = JOINT_NAMES[model]
    # make the truth consistent with the derivation: derived joints are midpoints of their sources
    jm = joint_map(model)
    for k in np.flatnonzero(jm.direct < 0):
        a, b = JOINTS19.index(names[jm.derived_a[k]]), JOINTS19.index(names[jm.derived_b[k]])
        j19[:, k, :2] = 0.5 * (j19[:, a, :2] + j19[:, b, :2])
        j19[:, k, 2] = np.minimum(j19[:, a, 2], j19[:, b, 2])
    kp = from_joints19(j19, model)
    assert kp.shape == (4, len(names), 3)
    for i, n in enumerate(names):
        if n in JOINTS19 and jm.to_model[i] >= 0:
            np.testing.assert_array_equal(kp[:, i], j19[:, JOINTS19.index(n)])
        else:
            assert np.all(kp[:, i] == 0)
    np.testing.assert_allclose(to_joints19(kp, model), j19, atol=1e-12)


def test_derived_joint_missing_when_a_source_is_missing():
    kp = np.zeros((25, 3))
    names = JOINT_NAMES["BODY_25B"]
    kp[names.index("l_hip")] = [100, 200, 0.9]
    kp[names.index("l_shoulder")] = [100, 50, 0.8]
    kp[names.index("r_shoulder")] = [140, 50, 0.6]
    j19 = to_joints19(kp, "BODY_25B")
    assert np.all(j19[JOINTS19.index("body_center")] == 0)  # r_hip missing
    np.testing.assert_allclose(j19[JOINTS19.index("neck")], [120, 50, 0.6])
    with pytest.raises(ReconError, match="expects"):
        to_joints19(np.zeros((18, 3)), "BODY_25")


@pytest.mark.parametrize("model", ["BODY_25", "BODY_25B", "HALPE_26", "COCO_17"])
def test_every_joint_of_pose2sims_tree_is_read_and_named_as_pose2sim_names_it(model):
    """Pose2Sim 0.10.49's own skeletons (``Pose2Sim/skeletons.py``): each node with a detector index is, in our
    joint order, the joint (joints19's or an extra one) whose marker name is the node's name; so every joint
    Pose2Sim's tree reads comes out of ``reconstruct`` and into the TRC under Pose2Sim's name."""
    from types import SimpleNamespace

    import Pose2Sim.skeletons as p2s
    from anytree import PreOrderIter

    from dome_calib.recon.body_models import EXTRA_JOINTS
    from dome_calib.skeletons.joints import marker_names

    names = JOINT_NAMES[model]
    carried = tuple(JOINTS19) + tuple(EXTRA_JOINTS[model])  # what reconstruct writes: joints19, then the extras
    markers = dict(zip(carried, marker_names(SimpleNamespace(joints=carried, body_model=model))))
    nodes = [(n.name, n.id) for n in PreOrderIter(getattr(p2s, model)) if n.id is not None]
    assert nodes
    for name, index in nodes:
        assert markers[names[index]] == name, (model, name, index, names[index])
    assert len(set(markers.values())) == len(markers)  # one name per joint
