"""Issue 50: `reconstruct --scheduler` workers read the detection files themselves; a worker whose copy differs
(another version of the folder at the same path) turned 9 people into none, exit 0. The head now records the digest
of every file as it reads it and each worker checks what it reads: a different file is one line naming it.

The cluster is played by an executor marked remote whose "worker" reads the folder after it was changed (the head
indexed it before): what a machine with another copy reads."""
from __future__ import annotations

import dataclasses
from fractions import Fraction
import json
import shutil

import pytest

from dome_calib.executor import SerialExecutor
from dome_calib.recon.errors import ReconError
from dome_calib.recon.people.commands import reconstruct_folder
from dome_calib.recon.people.run import PeopleOptions

from .test_reconstruct_situations import shared  # noqa: F401  (a fixture)


#: Chunks of 4 of the 12 times: three tasks, run on the executor.
CHUNKED = dataclasses.replace(PeopleOptions(), chunk_times=4, shared_fps=Fraction(30))  # the bundle has no sync tables


class OtherCopyWorkers(SerialExecutor):
    """Tasks run here, but as on workers (``remote``) that see ``change`` done to the files first."""

    remote = True

    def __init__(self, change) -> None:
        self.change, self.changed = change, False

    def map(self, fn, items):
        if not self.changed:
            self.change()
            self.changed = True
        return super().map(fn, items)


def _nobody_in(det):
    def change():
        for f in sorted(det.rglob("*.json")):
            f.write_text('{"version": 1.3, "people": []}')
    return change


def test_a_worker_reading_another_copy_is_one_line_naming_the_file(shared, tmp_path):  # noqa: F811
    det = shutil.copytree(shared / "det", tmp_path / "det")
    with pytest.raises(ReconError, match=r"_keypoints\.json: camera \S+: frame \d+: its bytes on .* differ from the "
                                         r"file the run indexed on its head"):
        reconstruct_folder(det, shared / "bundle", tmp_path / "out", options=CHUNKED,
                           executor=OtherCopyWorkers(_nobody_in(det)))
    assert not (tmp_path / "out").exists()


def test_workers_reading_the_same_files_run_as_here(shared, tmp_path):  # noqa: F811
    det = shutil.copytree(shared / "det", tmp_path / "det")
    here = reconstruct_folder(det, shared / "bundle", tmp_path / "here", options=CHUNKED)
    there = reconstruct_folder(det, shared / "bundle", tmp_path / "there", options=CHUNKED,
                               executor=OtherCopyWorkers(lambda: None))
    assert here.people == there.people == 2 and here.body_frames == there.body_frames
    a = [json.loads(f.read_text()) for f in sorted((tmp_path / "here").glob("body3DScene_*.json"))]
    b = [json.loads(f.read_text()) for f in sorted((tmp_path / "there").glob("body3DScene_*.json"))]
    assert a == b and len(a) == 12
