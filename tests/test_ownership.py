"""dome_calib.ownership: what a command may replace is decided by a record of what dome-calib wrote (sha256 per
file), never by names. Each rule of the module docstring, on small folders."""
from __future__ import annotations

import json
import os

import pytest

from dome_calib import io_utils, ownership
from dome_calib.ownership import (RECORD, NotOursError, claim_file, claim_folder, claim_scratch, mark_scratch,
                                  replace_file, replace_folder, write_text)


def _write_folder(path, files: dict[str, str]):
    with replace_folder(path) as staging:
        for rel, text in files.items():
            (staging / rel).parent.mkdir(parents=True, exist_ok=True)
            (staging / rel).write_text(text)


def test_a_folder_we_wrote_is_replaced_and_its_record_lists_every_file(tmp_path):
    out = tmp_path / "out"
    _write_folder(out, {"a.json": "1", "sub/b.json": "2"})
    entries = json.loads((out / RECORD).read_text())["entries"]
    assert sorted(entries) == ["a.json", "sub", "sub/b.json"] and entries["sub"] == "folder"
    assert entries["a.json"].startswith("sha256:")
    _write_folder(out, {"c.json": "3"})  # a rerun over our own output
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "c.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing hidden left beside it


@pytest.mark.parametrize("how", ["added", "changed", "no record", "bad record", "a FIFO"])
def test_anything_not_provably_ours_is_refused_in_one_line_and_kept(tmp_path, how):
    out = tmp_path / "out"
    _write_folder(out, {"body3DScene_00000001.json": "ours"})
    if how == "added":
        (out / "body3DScene_00000002.json").write_text("theirs, same kind of name")
    elif how == "changed":
        (out / "body3DScene_00000001.json").write_text("edited")
    elif how == "no record":
        (out / RECORD).unlink()  # as an output of dome-calib before records, or someone else's folder
    elif how == "bad record":
        (out / RECORD).write_text("{not json")
    else:
        os.mkfifo(out / "pipe")
    before = {p.name: (p.read_bytes() if p.is_file() else None) for p in out.iterdir()}
    with pytest.raises(NotOursError) as err:
        claim_folder(out)
    message = str(err.value)
    assert "\n" not in message and str(out) in message and "choose another path" in message
    with pytest.raises(NotOursError):
        with replace_folder(out) as staging:
            pytest.fail(f"staged {staging} though the folder is not ours")
    assert {p.name: (p.read_bytes() if p.is_file() else None) for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_links_and_wrong_kinds_are_refused_before_any_work(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (tmp_path / "link").symlink_to(theirs, target_is_directory=True)
    (tmp_path / "file").write_text("x")
    (tmp_path / "flink").symlink_to(tmp_path / "file")
    with pytest.raises(NotOursError, match="link: is a symbolic link"):
        claim_folder(tmp_path / "link")
    with pytest.raises(NotOursError, match="file: is a file, not a folder"):
        claim_folder(tmp_path / "file")
    with pytest.raises(NotOursError, match="flink: is a symbolic link"):
        claim_file(tmp_path / "flink")
    with pytest.raises(NotOursError, match="theirs: is a folder, not a file"):
        claim_file(theirs)
    with pytest.raises(io_utils.OutputPathError, match="is the input"):
        claim_file(tmp_path / "file", inputs=[tmp_path / "flink"])


def test_a_single_file_is_recorded_in_its_folder_and_replaced_only_while_unchanged(tmp_path):
    page = tmp_path / "page.html"
    write_text(page, "v1")
    write_text(page, "v2")  # ours, unchanged since: replaced
    assert page.read_text() == "v2"
    assert list(json.loads((tmp_path / RECORD).read_text())["entries"]) == ["page.html"]
    page.write_text("edited by the user")
    with pytest.raises(NotOursError, match="changed since dome-calib wrote it"):
        write_text(page, "v3")
    assert page.read_text() == "edited by the user"
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(NotOursError, match="notes.txt: a file dome-calib did not write"):
        claim_file(tmp_path / "notes.txt")
    with pytest.raises(RuntimeError):
        with replace_file(tmp_path / "new.txt") as tmp:
            tmp.write_text("half")
            raise RuntimeError("stop")
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD, "notes.txt", "page.html"]


def test_a_file_written_into_our_folder_updates_its_record_and_nested_records_judge_their_own(tmp_path):
    bundle = tmp_path / "bundle"
    _write_folder(bundle, {"calibration_x.json": "{}"})
    with replace_folder(bundle / "report") as staging:
        (staging / "report.json").write_text("{}")
    write_text(bundle / "synctables_x.json", "{}")  # as `timecode sync` adds its tables
    write_text(bundle / "report" / "sync.json", "{}")  # into report/, which has its own record
    assert "sync.json" in json.loads((bundle / "report" / RECORD).read_text())["entries"]
    claim_folder(bundle)  # all of it provably ours
    (bundle / "report" / "notes.txt").write_text("mine")
    with pytest.raises(NotOursError, match="holds report/notes.txt"):
        claim_folder(bundle)
    claim_folder(bundle / "report", keep=("notes.txt",))  # a file the writer carries over is not lost


def test_seal_rewrites_the_records_of_a_staged_tree(tmp_path):
    staging = tmp_path / "s"
    (staging / "gt").mkdir(parents=True)
    write_text(staging / "gt" / "calibration_x.json", "{}")  # a record made in gt/ while staging
    (staging / "gt" / "tent.npz").write_bytes(b"written without the module")
    ownership.seal(staging)
    assert "tent.npz" in json.loads((staging / "gt" / RECORD).read_text())["entries"]
    claim_folder(staging)


def test_a_work_folder_is_a_scratch_folder_of_ours_or_refused(tmp_path):
    work = tmp_path / "work"
    claim_scratch(work)  # absent
    work.mkdir()
    (work / "state.json").write_text("{}")  # a name ours use, in a folder we did not make
    with pytest.raises(NotOursError, match="state.json"):
        claim_scratch(work)
    mark_scratch(work)
    claim_scratch(work)


def test_no_rule_by_name_is_left():
    assert not hasattr(io_utils, "foreign_names")


def test_a_new_file_beside_a_record_that_is_not_ours_is_refused_before_it_is_written(tmp_path):
    (tmp_path / RECORD).write_text('{"written_by": "someone else"}')
    with pytest.raises(NotOursError, match="not a record of dome-calib"):
        write_text(tmp_path / "page.html", "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == [RECORD]
