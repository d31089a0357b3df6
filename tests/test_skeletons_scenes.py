"""body3DScene folders read through their schema: the Panoptic dataset's own example and the older joints15 layout
read as they are; every bad file is one line naming the file and the field, and export-people then writes nothing."""
from __future__ import annotations

import json
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dome_calib.skeletons.errors import PeopleFileError
from dome_calib.skeletons.scenes import read_people

#: The example body of the Panoptic toolbox's README ("Skeleton Output Format"; CMU-Perceptual-Computing-Lab/
#: panoptic-toolbox, README.md at commit 0281dcf2): one person of hdPose3d_stage1_coco19, HD 29.97 fps.
PANOPTIC_EXAMPLE = {"version": 0.7, "univTime": 53541.542, "fpsType": "hd_29_97", "bodies": [{"id": 0, "joints19": [
    -19.4528, -146.612, 1.46159, 0.724274, -40.4564, -163.091, -0.521563, 0.575897, -14.9749, -91.0176, 4.24329,
    0.361725, -19.2473, -146.679, -16.1136, 0.643555, -14.7958, -118.804, -20.6738, 0.619599, -22.611, -93.8793,
    -17.7834, 0.557953, -12.3267, -91.5465, -6.55368, 0.353241, -12.6556, -47.0963, -4.83599, 0.455566, -10.8069,
    -8.31645, -4.20936, 0.501312, -20.2358, -147.348, 19.1843, 0.628022, -13.1145, -120.269, 28.0371, 0.63559,
    -20.1037, -94.3607, 30.0809, 0.625916, -17.623, -90.4888, 15.0403, 0.327759, -17.3973, -46.9311, 15.9659,
    0.419586, -13.1719, -7.60601, 13.4749, 0.519653, -38.7164, -166.851, -3.25917, 0.46228, -28.7043, -167.333,
    -7.15903, 0.523224, -39.0433, -166.677, 2.55916, 0.395965, -30.0718, -167.264, 8.18371, 0.510041]}]}


def _folder(tmp_path, docs: dict[int, object]):
    folder = tmp_path / "people"
    folder.mkdir(parents=True, exist_ok=True)
    for frame, doc in docs.items():
        text = doc if isinstance(doc, str) else json.dumps(doc)
        (folder / f"body3DScene_{frame:08d}.json").write_text(text, encoding="utf-8")
    return folder


def _second(doc: dict, dt_ms: float = 33.3667) -> dict:
    return {**doc, "univTime": doc["univTime"] + dt_ms}


def test_the_panoptic_datasets_own_example_reads(tmp_path):
    folder = _folder(tmp_path, {400: PANOPTIC_EXAMPLE, 401: _second(PANOPTIC_EXAMPLE)})
    people = read_people(folder)
    assert people.layout == "joints19" and people.fps == Fraction(30000, 1001) and people.fps_type == "hd_29_97"
    assert people.frames.tolist() == [400, 401] and list(people.tracks) == [0]
    j = np.array(PANOPTIC_EXAMPLE["bodies"][0]["joints19"]).reshape(19, 4)
    np.testing.assert_array_equal(people.tracks[0].X_cm[0], j[:, :3])
    np.testing.assert_array_equal(people.tracks[0].confidence[0], j[:, 3])


def test_a_custom_rate_is_measured_from_the_times(tmp_path):
    doc = {**PANOPTIC_EXAMPLE, "fpsType": "custom", "univTime": 1000.0}
    folder = _folder(tmp_path, {0: doc, 1: {**doc, "univTime": 1000.0 + 1000 / 60}, 3: {**doc, "univTime": 1050.0}})
    assert read_people(folder).fps == 60


BAD = [
    ("joints19 of 75 numbers", lambda d: d["bodies"][0].update(joints19=d["bodies"][0]["joints19"][:75]),
     "bodies[0].joints19: expected a list of 76 finite numbers >= -1e+06 and <= 1e+06 or null, got"),
    ("a 20-digit joint", lambda d: d["bodies"][0]["joints19"].__setitem__(11, 12345678901234567890),
     "bodies[0].joints19[11]: expected a finite number >= -1e+06 and <= 1e+06, got 12345678901234567890"),
    ("no univTime", lambda d: d.pop("univTime"), "univTime: missing"),
    ("a string id", lambda d: d["bodies"][0].update(id="0"), "bodies[0].id: expected an integer"),
    ("a negative id", lambda d: d["bodies"][0].update(id=-2), "bodies[0].id: expected an integer >= 0"),
    ("both layouts", lambda d: d["bodies"][0].update(joints15=[0.0] * 60), "bodies[0]: expected joints19 or joints15"),
    ("neither layout", lambda d: d["bodies"][0].pop("joints19"), "bodies[0]: expected joints19 or joints15"),
    ("two bodies with one id", lambda d: d["bodies"].append(dict(d["bodies"][0])),
     "bodies[1].id: 0 is given to two bodies"),
    ("bodies not a list", lambda d: d.update(bodies={"id": 0}), "bodies: expected a list"),
]


@pytest.mark.parametrize("what, change, message", BAD, ids=[b[0] for b in BAD])
def test_a_bad_file_is_one_line_naming_it_and_the_field(tmp_path, what, change, message):
    bad = json.loads(json.dumps(_second(PANOPTIC_EXAMPLE)))
    change(bad)
    folder = _folder(tmp_path, {1: PANOPTIC_EXAMPLE, 2: bad})
    with pytest.raises(PeopleFileError) as err:
        read_people(folder)
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(folder / "body3DScene_00000002.json") + ": "), text
    assert message in text, text


def test_nan_text_layouts_rates_and_times_are_refused(tmp_path):
    cases = {
        "NaN": ({1: json.dumps(PANOPTIC_EXAMPLE).replace("-19.4528", "NaN")}, "body3DScene_00000001.json: "),
        "not JSON": ({1: "{\"version\": 0.7,"}, "body3DScene_00000001.json: not valid JSON"),
        "two rates": ({1: PANOPTIC_EXAMPLE, 2: _second({**PANOPTIC_EXAMPLE, "fpsType": "vga_25"})},
                      'body3DScene_00000002.json: fpsType: "vga_25", but earlier files have "hd_29_97"'),
        "time back": ({1: PANOPTIC_EXAMPLE, 2: _second(PANOPTIC_EXAMPLE, -5.0)},
                      "body3DScene_00000002.json: univTime: 53536.5 ms is not after"),
        "two layouts": ({1: PANOPTIC_EXAMPLE, 2: _second({**PANOPTIC_EXAMPLE, "bodies": [
            {"id": 0, "joints15": [1.0] * 60}]})}, "body3DScene_00000002.json: bodies[0].joints15: earlier files have "
                                                   "joints19"),
    }
    for k, (name, (docs, message)) in enumerate(cases.items()):
        folder = _folder(tmp_path / str(k), docs)
        with pytest.raises(PeopleFileError) as err:
            read_people(folder)
        assert message in str(err.value) and "\n" not in str(err.value), (name, str(err.value))
    (tmp_path / "empty").mkdir()
    with pytest.raises(PeopleFileError, match="no body3DScene_<frame>.json file"):
        read_people(tmp_path / "empty")


def test_export_people_of_a_bad_folder_is_one_line_and_writes_nothing(tmp_path, dome_calib_cli):
    bad = json.loads(json.dumps(PANOPTIC_EXAMPLE))
    bad["bodies"][0]["joints19"][7] = "0.5"
    folder = _folder(tmp_path, {1: PANOPTIC_EXAMPLE, 2: _second(bad)})
    for fmt in ("trc", "c3d", "bvh"):
        run = dome_calib_cli("export-people", folder, "--to", fmt, "-o", tmp_path / "out")
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 1 and len(lines) == 1, run.stderr
        assert "body3DScene_00000002.json: bodies[0].joints19[7]: expected a finite number" in lines[0]
        assert not (tmp_path / "out").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["people"]
    run = dome_calib_cli("people-page", folder)
    assert run.returncode == 1 and not (folder / "index.html").exists()


JSON_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10, 10), st.floats(allow_nan=False, width=32),
                        st.text(max_size=5), st.lists(st.integers(0, 3), max_size=3), st.just({}))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(path=st.sampled_from([("version",), ("univTime",), ("fpsType",), ("bodies",), ("bodies", 0),
                             ("bodies", 0, "id"), ("bodies", 0, "joints19"), ("bodies", 0, "joints19", 5),
                             ("bodies", 0, "inlierViews19")]), value=JSON_VALUES)
def test_any_mutated_field_is_read_or_refused_in_one_line(tmp_path, path, value):
    """A field replaced by any JSON value: either a valid file (read) or PeopleFileError naming the file; nothing
    else escapes (no KeyError, TypeError, numpy error)."""
    doc = json.loads(json.dumps(PANOPTIC_EXAMPLE))
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    folder = _folder(tmp_path / "h", {1: doc})
    try:
        people = read_people(folder)
    except PeopleFileError as exc:
        assert str(exc).startswith(str(folder / "body3DScene_00000001.json")) and "\n" not in str(exc)
    else:
        assert all(t.X_cm.shape[1:] == (19, 3) for t in people.tracks.values())


def test_the_joint_layout_is_the_reconstructions_and_the_generators():
    """joints19 is written down in three rooms (reconstruction, the synthetic generators, people out): one list."""
    from dome_calib.recon.body_models import JOINTS19 as RECON
    from dome_calib.skeletons.joints import JOINTS19, MARKER, PARENT
    from dome_calib.synth.skeleton import JOINTS19 as SYNTH

    assert list(JOINTS19) == RECON == SYNTH
    assert set(MARKER) == set(PARENT)  # names unique per detector: marker_names (tests/test_recon_body_models.py)
    assert len(set(MARKER.values())) == len(MARKER) - 1  # BODY_25B's upper_neck is Neck, joints19's neck renamed


def test_export_refuses_a_nan_confidence_bound(tmp_path, dome_calib_cli):
    folder = _folder(tmp_path, {1: PANOPTIC_EXAMPLE})
    run = dome_calib_cli("export-people", folder, "--to", "trc", "-o", tmp_path / "out", "--min-confidence", "nan")
    assert run.returncode == 1 and "--min-confidence NaN: expected a finite number >= 0" in run.stderr
    assert not (tmp_path / "out").exists()
