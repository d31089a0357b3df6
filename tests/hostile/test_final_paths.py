"""A path reaches the user only at its final place (:func:`dome_calib.final_place.said`): the commands the hostile
matrix never sees go through (``report``), the nested staging of ``calibrate`` (the report staged inside the staged
bundle), an error naming a staging folder; the judge of what is printed; and ``people-page`` rebuilds the camera
table ``reconstruct`` wrote."""
from __future__ import annotations

import io
import logging
import shutil
import subprocess

import pytest

from dome_calib.bundle_io import load_bundle, replace_folder, staging_folder
from dome_calib.errors import console_handler
from dome_calib.final_place import STAGING_MARK, said
from dome_calib.io_utils import atomic_folder
from dome_calib.report.build import ReportOptions, write_report

from ..skeletons_helpers import people_page_data
from .catalogue import ENTRIES
from .oracle import judge, judge_printed, snapshot
from .test_matrix import _run_in_process


def test_report_says_its_page_at_its_final_place(hostile_inputs, tmp_path, monkeypatch, capsys):
    """`dome-calib report` logged "report page written to BUNDLE/.report.new.<random>/index.html" (gone at exit);
    the matrix runs report only where it is refused, so its one run that goes through is judged here."""
    entry = ENTRIES["report"][0]
    sandbox = tmp_path / "sandbox"
    shutil.copytree(hostile_inputs.bundle, sandbox / "bundle")
    out = entry.out_at(sandbox)
    monkeypatch.chdir(sandbox)
    before = snapshot(sandbox)
    done = _run_in_process(entry, entry.argv(hostile_inputs, out), monkeypatch, capsys)
    assert done.returncode == 0, done.stderr
    assert f"report page written to {out / 'index.html'} (" in done.stderr
    judge(done, before, snapshot(sandbox), sandbox=sandbox, out=out, also=[], must_refuse=False)


def test_a_report_staged_in_a_staged_bundle_is_said_in_the_bundle(hostile_inputs, tmp_path):
    """calibrate's write: the report staged (``.report.new.*``) inside the bundle's staging folder
    (``.bundle.staging``): both are said at the bundle's place, which holds them after the swap."""
    out = tmp_path / "bundle"
    log, handler = io.StringIO(), console_handler("dome-calib")
    handler.setStream(log)
    logger = logging.getLogger("dome_calib")
    level, logger.level = logger.level, logging.INFO
    logger.addHandler(handler)
    try:
        staging = staging_folder(out)
        write_report(staging, load_bundle(hostile_inputs.bundle), options=ReportOptions(plots=False))
        replace_folder(staging, out)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    text = log.getvalue()
    assert f"report page written to {out / 'report' / 'index.html'} (" in text, text
    assert f"report written to {out / 'report'} (" in text, text
    assert not STAGING_MARK.search(text) and (out / "report" / "index.html").is_file()


def test_an_error_naming_a_staging_folder_names_the_output(tmp_path):
    out = tmp_path / "out"
    try:
        with atomic_folder(out) as staging:
            raise ValueError(f"{staging / 'cameras.json'}: cut short")
    except ValueError as exc:
        said_error = said(str(exc))
    assert said_error == f"{out / 'cameras.json'}: cut short" and not out.exists()


def test_people_page_rebuilds_the_camera_table_reconstruct_wrote(hostile_inputs, tmp_path, monkeypatch, capsys):
    """`dome-calib people-page` read no cameras.json: the rebuilt page had no camera table. It reads it through its
    schema (:class:`~dome_calib.recon.people.scene_io.CamerasFile`) and shows the table reconstruct's page shows."""
    i, people, page = hostile_inputs, tmp_path / "people", tmp_path / "page.html"
    for entry, args in ((ENTRIES["reconstruct"][0], ENTRIES["reconstruct"][0].argv(i, people)),
                        (ENTRIES["people-page"][0], ["people-page", people, "-o", page, "--bundle", i.bundle])):
        done = _run_in_process(entry, args, monkeypatch, capsys)
        assert done.returncode == 0, done.stderr
    written = people_page_data(people / "index.html")["camera_flags"]
    assert written and people_page_data(page)["camera_flags"] == written
    cameras = people / "cameras.json"  # a field out of place: one line naming the file and the field, no page
    cameras.write_text(cameras.read_text().replace('"detected": ', '"detected": -', 1))
    done = _run_in_process(ENTRIES["people-page"][0], ["people-page", people, "-o", tmp_path / "bad.html"],
                           monkeypatch, capsys)
    lines = [ln for ln in done.stderr.splitlines() if ln.startswith("dome-calib: error:")]
    assert done.returncode == 1 and len(lines) == 1 and f"{cameras}: cameras." in lines[0], done.stderr
    assert ".detected: expected an integer >= 0" in lines[0] and not (tmp_path / "bad.html").exists()


def test_the_judge_refuses_a_staging_name_and_a_printed_path_that_is_gone(tmp_path):
    """The oracle's check of what is printed (:func:`.oracle.judge_printed`), on the lines the old code printed."""
    sandbox = tmp_path / "sandbox"
    (sandbox / "out").mkdir(parents=True)
    (sandbox / "out" / "index.html").write_text("page")
    after = snapshot(sandbox)

    def printed(line: str, code: int = 0) -> subprocess.CompletedProcess:
        return subprocess.CompletedProcess(["dome-calib"], code, "", line + "\n")

    judge_printed(printed(f"dome-calib: people page written to {sandbox}/out/index.html (42 kB)"), sandbox, {}, after)
    judge_printed(printed("dome-calib: people page written to out/index.html (42 kB)"), sandbox, {}, after)
    for line, code in ((f"dome-calib: report page written to {sandbox}/.out.new.82yjm5p2/index.html (42 kB)", 0),
                       ("dome-calib: report written to bundle.work/.calibration.staging/report", 0),
                       (f"dome-calib: error: {sandbox}/.out.a1b2c3d4.tmp: No space left on device", 1),
                       (f"wrote {sandbox}/out/cameras.json", 0), ("wrote out/cameras.json, out/index.html", 0)):
        with pytest.raises(AssertionError):
            judge_printed(printed(line, code), sandbox, {}, after)


def test_the_record_of_staging_places_is_bounded(tmp_path):
    """A library user writing for ever does not grow the record without end; the latest places are still said."""
    from dome_calib import final_place
    for k in range(final_place._FINAL_KEPT + 10):
        final_place.stage(tmp_path / f".o{k}.new.x", tmp_path / f"o{k}")
    assert len(final_place._FINAL) <= final_place._FINAL_KEPT
    last = final_place._FINAL_KEPT + 9
    assert final_place.said(str(tmp_path / f".o{last}.new.x" / "a")) == str(tmp_path / f"o{last}" / "a")
