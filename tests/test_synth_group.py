"""Synthetic groups (dome_calib.synth.group): truth invariants of every scenario."""
import numpy as np
import pytest

from dome_calib.synth.body_volume import capsules_cm, segment_distance2
from dome_calib.synth.group import (ANKLE_HEIGHT_CM, CAPTURE_RADIUS_CM, MIN_CENTRE_DISTANCE_CM, NOMINAL_BONE_CM,
                                    PARENT19, SCENARIOS, GroupError, GroupOptions, make_group, max_people,
                                    min_centre_distance_cm, roles_of)

TIMES_MS = np.arange(0.0, 4000.0, 7.0)  # not the layout's 20 ms grid


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("n", [1, 2, 5, 8, 10])
def test_bone_lengths_constant_and_ids_unique(scenario, n):
    n = min(n, max_people(scenario))
    truth = make_group(GroupOptions(n_people=n, scenario=scenario, seed=n))
    assert truth.ids == list(range(n)) and len(set(truth.ids)) == n
    X, present = truth.joints_cm(TIMES_MS + truth.start_ms)
    assert X.shape == (len(TIMES_MS), n, 19, 3) and present.shape == (len(TIMES_MS), n)
    bones = np.linalg.norm(X - X[:, :, np.where(PARENT19 >= 0, PARENT19, 2)], axis=-1)  # (T, P, 19)
    scale = np.array([p.scale for p in truth.plans])
    np.testing.assert_allclose(bones, np.broadcast_to(scale[:, None] * NOMINAL_BONE_CM, bones.shape), atol=1e-9)
    assert np.all((scale >= 0.9) & (scale <= 1.1))
    # Feet on the floor (y down): the lowest ankle 8 cm (scaled) above it, the head well above.
    lowest = np.max(X[:, :, [8, 14], 1], axis=-1)
    np.testing.assert_allclose(lowest, np.broadcast_to(-ANKLE_HEIGHT_CM * scale, lowest.shape), atol=1e-9)
    assert np.all(X[..., 1] <= 0.0)


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_interpenetration(scenario, seed):
    n = min(8, max_people(scenario))
    truth = make_group(GroupOptions(n_people=n, scenario=scenario, seed=seed))
    assert min_centre_distance_cm(truth, TIMES_MS) >= MIN_CENTRE_DISTANCE_CM
    # Torsos (capsules of radius 13 cm) of two people never overlap.
    X, _ = truth.joints_cm(TIMES_MS[::5])
    A, B, r = capsules_cm(X.reshape(-1, 19, 3))
    A, B, r = (a.reshape(len(X), n, *a.shape[1:]) for a in (A, B, r))
    i, j = np.triu_indices(n, 1)
    d2 = segment_distance2(A[:, i, 0].reshape(-1, 3), B[:, i, 0].reshape(-1, 3), A[:, j, 0].reshape(-1, 3),
                           B[:, j, 0].reshape(-1, 3))
    assert np.sqrt(d2.min()) > 2 * r[0, 0, 0]


def test_leaving_and_entering():
    truth = make_group(GroupOptions(n_people=5, scenario="leave", seed=4))
    assert roles_of("leave", 5) == ["leave", "enter", "talk", "talk", "talk"]
    t = np.arange(0.0, 4000.0, 10.0)
    X, present = truth.joints_cm(t)
    r = np.hypot(X[:, :, 2, 0], X[:, :, 2, 2])
    leaver, enterer = present[:, 0], present[:, 1]
    # The leaver is in at first, out at the end, and never back once out; the enterer the other way round.
    assert leaver[0] and not leaver[-1]
    gone = np.argmax(~leaver)
    assert not leaver[gone:].any() and np.all(r[gone:, 0] > CAPTURE_RADIUS_CM)
    assert not enterer[0] and enterer[-1]
    came = np.argmax(enterer)
    assert enterer[came:].all() and np.all(r[:came, 1] > CAPTURE_RADIUS_CM)
    assert present[:, 2:].all()
    # The enterer takes the leaver's place in the conversation, after the leaver is gone.
    spot = X[0, 0, 2, [0, 2]]
    np.testing.assert_allclose(X[-1, 1, 2, [0, 2]], spot, atol=1e-6)
    arrived = np.argmax(np.linalg.norm(X[:, 1, 2][:, [0, 2]] - spot, axis=-1) < 1.0)
    assert np.linalg.norm(X[arrived, 0, 2, [0, 2]] - spot) > 100.0


def test_conversation_faces_the_circle_and_crouch_goes_down():
    truth = make_group(GroupOptions(n_people=4, scenario="crouch", seed=7))
    t = np.array([0.0, 2000.0, 3990.0])
    X, present = truth.joints_cm(t)
    assert present.all()
    centre = X[0, :, 2, [0, 2]].T.mean(0)  # one circle of 4
    for p in range(4):
        xz, heading, walk = truth.plans[p].root_xz(t)
        to_centre = centre - xz[0]
        cos = (np.cos(heading[0]) * to_centre[0] + np.sin(heading[0]) * to_centre[1]) / np.linalg.norm(to_centre)
        assert cos > 0.9 and np.all(walk == 0)
        # the nose is in front of the neck, towards the circle's centre
        nose = X[0, p, 1, [0, 2]] - X[0, p, 0, [0, 2]]
        assert nose @ to_centre > 0
    head = X[:, 0, 1, 1]  # y down: the crouching person's nose goes down by > 30 cm and comes back up
    assert head[1] - head[0] > 30.0 and abs(head[2] - head[0]) < 1.0
    others = X[:, 1:, 1, 1]
    assert np.ptp(others, axis=0).max() < 2.0


def test_walkers_pass_each_other_close():
    truth = make_group(GroupOptions(n_people=2, scenario="walk_past", seed=5))
    t = np.arange(0.0, 4000.0, 5.0)
    xz = truth.centres_xz(t)
    d = np.linalg.norm(xz[:, 0] - xz[:, 1], axis=-1)
    assert MIN_CENTRE_DISTANCE_CM <= d.min() < 70.0
    assert d[0] > 150.0 and d[-1] > 150.0  # far apart before and after
    a = np.unwrap(np.arctan2(xz[:, :, 1], xz[:, :, 0]), axis=0)
    side = np.sign(a[:, 0] - a[:, 1])
    assert side[0] != side[-1]  # they went past each other
    speed = np.linalg.norm(np.diff(xz, axis=0), axis=-1) / 5.0 * 1000.0
    assert np.all((speed > 70.0) & (speed < 105.0))


def test_deterministic_and_seeded():
    a = make_group(GroupOptions(n_people=6, seed=11, start_ms=1234.5))
    b = make_group(GroupOptions(n_people=6, seed=11, start_ms=1234.5))
    c = make_group(GroupOptions(n_people=6, seed=12, start_ms=1234.5))
    t = np.array([1234.5, 2000.0, 5000.0])
    assert np.array_equal(a.joints_cm(t)[0], b.joints_cm(t)[0])
    assert not np.allclose(a.joints_cm(t)[0], c.joints_cm(t)[0])
    # start_ms shifts the motion in universal time (up to the gait, which runs on universal time)
    d = make_group(GroupOptions(n_people=6, seed=11, start_ms=0.0))
    np.testing.assert_allclose(a.centres_xz(t), d.centres_xz(t - 1234.5), atol=1e-9)


@pytest.mark.parametrize("kwargs, match", [({"scenario": "dance"}, "scenario 'dance' is unknown"),
                                           ({"n_people": 11}, "n_people=11"), ({"n_people": 0}, "n_people=0"),
                                           ({"n_people": 7, "scenario": "small_area"}, "expected 1..6"),
                                           ({"duration_ms": 0.0}, "duration_ms=0.0")])
def test_bad_options(kwargs, match):
    with pytest.raises(GroupError, match=match):
        GroupOptions(**kwargs)
