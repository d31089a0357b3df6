"""The people page's camera table (issue 51): the run's cameras.json report, handed over by ``reconstruct``
(:class:`~dome_calib.recon.people.scene_io.StagedPeople`), shown per camera with its offset note; camera names, which
come from files, reach the page only through the pages' one escaping module (:func:`dome_calib.pages.render`).
No browser (tests/test_people_page.py opens the page in chromium)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dome_calib.pages import inline_json
from dome_calib.pipeline.people_page import build_people_page, camera_flags
from dome_calib.recon.people.scene_io import CAMERAS_FILE, StagedPeople, camera_report, camera_report_text

from .skeletons_helpers import people_page_data, write_scenes
from .test_camera_flags import HD, tallies

HOSTILE = "<script>window.__pwned=1</script>"


def _report() -> dict:
    """Five cameras, the first (named with markup) 16 px off to the left: flagged for its offset."""
    names = [HOSTILE, "00_01", "00_02", "00_03", "00_04"]
    return camera_report(tallies([(-16.0, 0.0), (0.0, 1.0), (1.0, 0.5), (-2.0, 1.0), (0.5, -1.5)], sigma_px=6.0,
                                 names=names), HD)


def _staged(folder: Path, report: dict) -> StagedPeople:
    X = np.random.default_rng(2).uniform(-50, 50, (2, 19, 3)) + [0, -100, 0]
    write_scenes(folder, [0, 1], [0.0, 40.0], [{1: np.c_[X[k], np.full(19, 0.5)]} for k in range(2)])
    files = [(k, folder / f"body3DScene_{k:08d}.json") for k in (0, 1)]
    return StagedPeople(files=files, scenes=lambda: (json.loads(p.read_text()) for _, p in files), report=report)


def test_the_rows_say_each_cameras_figures_offset_and_verdict():
    listed = camera_flags(_report())
    assert [r["camera"] for r in listed] == [HOSTILE, "00_01", "00_02", "00_03", "00_04"]  # flagged first
    rows = {r["camera"]: r for r in listed}
    bad = rows[HOSTILE]
    assert bad["flagged"] and bad["verdict"].startswith("flagged: its joints lie 16 px to the left of where the others")
    assert bad["offset"].startswith("16 px to the left (-16.") and bad["outvoted_share"] == 0.0
    assert bad["reprojection_px"] > 10
    assert rows["00_01"] == rows["00_01"] | {"flagged": False, "verdict": "agrees"}
    assert camera_flags(None) == []


def test_a_camera_shifted_by_correct_offsets_says_so_on_the_page():
    """--correct-offsets: the camera it shifted agrees afterwards; its row says the shift."""
    a = tallies([(0.5, 0.0), (0.0, 1.0), (1.0, 0.5), (-2.0, 1.0), (0.5, -1.5)], sigma_px=6.0)
    rows = {r["camera"]: r for r in camera_flags(camera_report(a, HD, corrected_px={"00_00": np.array([-16.0, 0.4])}))}
    assert rows["00_00"]["verdict"].startswith("agrees; its image shifted 16 px to the left (--correct-offsets")
    assert rows["00_01"]["verdict"] == "agrees"


def test_the_page_of_a_run_shows_the_flagged_camera_and_escapes_its_name(tmp_path):
    report = _report()
    summary = build_people_page(tmp_path / "people", out=tmp_path / "index.html",
                                staged=_staged(tmp_path / "people", report))
    html = summary.page.read_text(encoding="utf-8")
    assert HOSTILE not in html and "__pwned" in html  # there, but never as markup
    rows = camera_flags(report)
    assert inline_json(rows)[1:-1] in html  # the rows as the template's data, through the one module
    assert inline_json(rows[0]["verdict"]) in html and "16 px to the left" in html
    assert 'id="flagrows"' in html  # the table the template fills (text only: PageKit.el)


def test_the_demos_printout_says_why_a_camera_is_flagged():
    """`make demo`'s group lines: under the flagged cameras, cameras.json's notes (figures here are placeholders)."""
    from collections import defaultdict

    from dome_calib.pipeline.demo import format_group

    report = _report()
    g = defaultdict(lambda: 1) | {"reference": "hd", "scenario": "mixed", "body_model": "BODY_25",
                                  "flagged_cameras": report["flagged"], "camera_notes": report["notes"],
                                  "median_reprojection_px": 7.1}
    lines = "\n".join(format_group(defaultdict(lambda: 1, g)))
    assert f"cameras that disagree: {HOSTILE} (median reprojection 7.1 px)" in lines
    assert f"\n    camera {HOSTILE}: its joints lie 16 px to the left of where the others put them" in lines


def test_a_rebuilt_page_shows_the_runs_table_from_cameras_json_as_text(tmp_path):
    """`dome-calib people-page` reads cameras.json back (its schema, CamerasFile): the same rows as the page of the
    run, a camera name holding markup (a camera name has no '/') still only text."""
    markup = "<img src=x onerror=window.__pwned=1>"
    report = camera_report(tallies([(-16.0, 0.0), (0.0, 1.0), (1.0, 0.5), (-2.0, 1.0), (0.5, -1.5)], sigma_px=6.0,
                                   names=[markup, "00_01", "00_02", "00_03", "00_04"]), HD)
    folder = tmp_path / "people"
    staged = _staged(folder, report)
    (folder / CAMERAS_FILE).write_text(camera_report_text(report), encoding="utf-8")  # as reconstruct writes it
    run = build_people_page(folder, out=tmp_path / "run.html", staged=staged).page
    rebuilt = build_people_page(folder, out=tmp_path / "rebuilt.html").page
    assert people_page_data(rebuilt)["camera_flags"] == people_page_data(run)["camera_flags"] == camera_flags(report)
    html = rebuilt.read_text(encoding="utf-8")
    assert markup not in html and "__pwned" in html and camera_flags(report)[0]["camera"] == markup
