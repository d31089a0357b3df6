"""Session layout loader (timecode.sync.session): a synthetic session reads back; bad files give one-line errors."""
from __future__ import annotations

import json

import numpy as np
import pytest

from timecode.labels import label_to_frames
from timecode.rates import RATE_25, RATE_29_97_DF
from timecode.sync.session import SessionError, load_session
from dome_calib.synth.sync_session import SynthSessionOptions, load_truth, make_session


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("session")
    make_session(folder, SynthSessionOptions(duration_s=2.0, n_kinects=2, kinect_missing_audio=("KINECTNODE2",),
                                             hd_timecode_every=3))
    return folder


def test_synthetic_session_reads_back(session_dir):
    s = load_session(session_dir)
    truth = load_truth(session_dir)
    assert s.seq == "synth_sync" and s.ltc.vga_rate is RATE_25 and s.ltc.hd_rate is RATE_29_97_DF
    np.testing.assert_array_equal(s.streams["vga"].index, truth.index["vga"])
    assert s.streams["vga"].ref_index.tolist() == [truth.index["vga"][0]]
    hd = s.streams["hd"]
    assert hd.ref_index.size == -(-hd.index.size // 3)  # every third HD frame carries its timecode
    assert hd.ref_count[0] == label_to_frames("10:00:00;03", RATE_29_97_DF)  # index[0] is tick 3
    assert s.kinects["KINECTNODE1"].audio_path.is_file() and s.kinects["KINECTNODE2"].audio_path is None
    np.testing.assert_array_equal(s.kinects["KINECTNODE1"].color.index, truth.index["KINECTNODE1/color"])


def _broken(session_dir, tmp_path, edit):
    doc = json.loads((session_dir / "session.json").read_text())
    edit(doc)
    (tmp_path / "session.json").write_text(json.dumps(doc))
    (tmp_path / "kinect").symlink_to(session_dir / "kinect")
    return tmp_path


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("ltc"), r"session.json: ltc: missing \(expected an object\)$"),
    (lambda d: d["ltc"].update(hd_rate="29.9"), r"session.json: ltc.hd_rate: frame rate '29.9' is not supported"),
    (lambda d: d["streams"]["vga"].update(index=[3, 2, 5]), r"session.json: streams.vga.index\[1\]: must increase \(2 after 3\)"),
    (lambda d: d["streams"]["vga"].update(ref_timecode="10:00:00:25"), r"session.json: streams.vga.ref_timecode: timecode 10:00:00:25: frame 25 outside 0-24"),
    (lambda d: d["streams"]["hd"].update(timecode=None), r"session.json: streams.hd: needs 'ref_index' \+ 'ref_timecode'"),
    (lambda d: d["streams"]["hd"].update(clock="kinect"), r"session.json: streams.hd.clock: expected \"vga\" or \"hd\", got \"kinect\""),
    (lambda d: d.update(version=7), r"session.json: version: expected 1 \(the version this toolkit reads\), got 7"),
    (lambda d: d["kinect"]["KINECTNODE1"].update(timestamps="nope.json"), r"nope.json: file not found"),
])
def test_malformed_session_is_a_one_line_error(session_dir, tmp_path, edit, message):
    folder = _broken(session_dir, tmp_path, edit)
    with pytest.raises(SessionError, match=message) as err:
        load_session(folder)
    assert "\n" not in str(err.value)


def test_missing_folder_and_bad_json(tmp_path):
    with pytest.raises(SessionError, match="not a session folder"):
        load_session(tmp_path / "absent")
    (tmp_path / "session.json").write_text("{not json")
    with pytest.raises(SessionError, match=r"session.json: not valid JSON"):
        load_session(tmp_path)


def test_the_same_session_is_the_same_bytes(session_dir, tmp_path):
    """Every file of a synthetic session, written again from the same options, is byte for byte the same (a float
    WAV's PEAK chunk stamped the time of writing: the recordings are 24-bit PCM)."""
    import time
    time.sleep(1.1)  # a stamped second would differ
    make_session(tmp_path, SynthSessionOptions(duration_s=2.0, n_kinects=2, kinect_missing_audio=("KINECTNODE2",),
                                               hd_timecode_every=3))
    files = sorted(p.relative_to(session_dir) for p in session_dir.rglob("*") if p.is_file())
    assert [str(p) for p in files if p.suffix == ".wav"]
    assert files == sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert [str(p) for p in files if (session_dir / p).read_bytes() != (tmp_path / p).read_bytes()] == []
