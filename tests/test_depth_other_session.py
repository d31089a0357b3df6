"""Issue 50: depth frames of another session remove everybody (the sensors see through where this session's people
stand), and the run blamed the bundle ("is the bundle the calibration of these cameras?"). The removal is now told
as what it is: the joints the Kinects saw through, of how many, and the question to ask (are these depth frames of
this session?), as the reason nobody is left or, when people are left, as one warning."""
from __future__ import annotations

import logging

import pytest

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.synth.depth_people import write_group_depth
from dome_calib.synth.detector import DetectorModel, synth_detections, write_openpose_folder
from dome_calib.synth.group import GroupOptions, make_group

from .test_depth_witness import dome  # noqa: F401  (a fixture)


@pytest.fixture(scope="module")
def sessions(dome, tmp_path_factory):  # noqa: F811
    """This session's detections and bundle, and the depth frames of another session (other people elsewhere)."""
    root = tmp_path_factory.mktemp("sessions")
    truth = make_group(GroupOptions(n_people=4, scenario="mixed", start_ms=1200.0, duration_ms=1000.0, seed=2))
    other = make_group(GroupOptions(n_people=2, scenario="mixed", start_ms=1200.0, duration_ms=1000.0, seed=11))
    nodes = [f"KINECTNODE{k}" for k in (1, 3, 5, 7, 9)]
    write_group_depth(root / "other_depth", dome, other, (1290.0, 1460.0), nodes=nodes, seed=1)
    cams = sorted(dome.of_type("vga"))[::2] + sorted(dome.of_type("hd"))[::4]
    bundle = Bundle(seq=dome.seq, cameras={n: dome.cameras[n] for n in cams + ["50_01", "50_05"]},
                    calib_data_source=dome.calib_data_source, kinect=dome.kinect, sync=dome.sync)
    write_bundle(bundle, root / "bundle")
    det = synth_detections(bundle, truth, cameras=cams, univ_time_ms=(1300.0, 1450.0), model=DetectorModel(seed=1))
    write_openpose_folder(root / "det", det)
    return root


def test_depth_of_another_session_is_named_not_the_bundle(sessions, dome_calib_cli, tmp_path, caplog):
    args = ["reconstruct", str(sessions / "det"), "--bundle", str(sessions / "bundle"), "--body-model", "BODY_25"]
    plain = dome_calib_cli(*args, "-o", str(tmp_path / "plain"))
    assert plain.returncode == 0 and "people" in plain.stdout and "no person" not in plain.stdout, plain.stdout
    with caplog.at_level(logging.WARNING):
        out = dome_calib_cli(*args, "-o", str(tmp_path / "o"), "--depth", str(sessions / "other_depth"))
    assert out.returncode == 0, out.stderr[-2000:]
    said = out.stdout + " ".join(r.getMessage() for r in caplog.records)
    assert "the Kinect depth frames (--depth) saw through" in said and "depth frames of this session" in said, said
    assert "is the bundle the calibration" not in said


def test_nobody_left_by_the_depth_is_told_as_that():
    """When the depth removed the people, the reason is the depth, not the bundle (before: "none was seen alike by
    --min-views 3 cameras: is the bundle the calibration of these cameras ...?")."""
    import numpy as np

    from dome_calib.recon.people.agreement import CameraAgreement
    from dome_calib.recon.people.commands import why_nobody
    from dome_calib.recon.people.run import PeopleOptions

    tallies = CameraAgreement.empty(["01_01", "01_02", "01_03"])
    tallies.detected += np.array([12, 12, 12])
    tallies.depth_joints, tallies.depth_rejected = 228, 228
    line = why_nobody(tallies, PeopleOptions(), 3)
    assert line.startswith("the Kinect depth frames (--depth) saw through 228 of the 228 joints"), line
    tallies.depth_rejected = 1  # this session's depth: a ghost joint; the reason is elsewhere
    assert "is the bundle the calibration" in why_nobody(tallies, PeopleOptions(), 3)
