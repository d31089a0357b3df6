"""Issue 42: the report's own files are typed (report.json: dome_calib.report.schema; session.json and sync.json:
dome_calib.report.kept). A value of the wrong type in any of them (a script where a number belongs, a string where
a list of reasons belongs, NaN) is one line naming the file and the field, before anything is written; an older
report.json is read through its migration; a rebuild keeps the calibration's reasons by their codes."""
from __future__ import annotations

import json
import shutil

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dome_calib.bundle_io import write_bundle
from dome_calib.errors import ReportError
from dome_calib.layout import nominal_dome
from dome_calib.reasons import ReasonCode
from dome_calib.report import write_report

from .report_data import REPORT_FILES, copy_kept_files, synthetic_residuals

SCRIPT = '<img src=x onerror="window.__pwned=1">'


@pytest.fixture(scope="module")
def tiny_bundle(tmp_path_factory):
    """The tiny dome with a full report (residuals, a moved camera found by the calibration, one not calibrated)
    and the real session.json and sync.json in report/."""
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path_factory.mktemp("tiny") / "b")
    res = synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03")
    from dome_calib.reasons import reason

    copy_kept_files(folder / "report")
    write_report(folder, tiny, res, changes={"01_04": [reason(ReasonCode.MOVED, "moved 3.1 cm")]},
                 missing={"01_24": "saw no tent in any scene"},
                 extra={"center_sigma_cm": {n: 0.05 for n in tiny.cameras}, "stage_seconds": {"sfm": 12.5}})
    return folder


@pytest.fixture
def bundle(tiny_bundle, tmp_path):
    return shutil.copytree(tiny_bundle, tmp_path / "b")


def _edit(path, change) -> None:
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def _refused(dome_calib_cli, bundle, start: str, end: str = "") -> None:
    """`dome-calib report BUNDLE` exits 1 with one line beginning with ``start`` (and ending with ``end``), and
    leaves report/ as it was."""
    before = {p.name: p.read_bytes() for p in (bundle / "report").iterdir()}
    proc = dome_calib_cli("report", bundle)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"dome-calib: error: {start}") and proc.stderr.endswith(f"{end}\n"), proc.stderr
    assert {p.name: p.read_bytes() for p in (bundle / "report").iterdir()} == before


@pytest.mark.parametrize("name, field, set_it", [
    ("sync.json", "streams.vga.n_frames", lambda d: d["streams"]["vga"].update(n_frames=SCRIPT)),
    ("sync.json", "streams.hd.n_outliers", lambda d: d["streams"]["hd"].update(n_outliers=SCRIPT)),
    ("session.json", "pillars.kinect.sensors[0].frames_used",
     lambda d: d["pillars"]["kinect"]["sensors"][0].update(frames_used=SCRIPT)),
    ("session.json", "pillars.kinect.sensors[0].frames_rejected",
     lambda d: d["pillars"]["kinect"]["sensors"][0].update(frames_rejected=SCRIPT)),
    ("report.json", "rules.min_observations", lambda d: d["rules"].update(min_observations=SCRIPT)),
    ("report.json", "per_camera.01_02.panel", lambda d: d["per_camera"]["01_02"].update(panel=SCRIPT)),
])
def test_a_script_where_a_number_belongs_is_refused_before_the_page(bundle, dome_calib_cli, name, field, set_it):
    """The issue's case: a bundle from someone else with "n_frames": "<img src=x onerror=...>" gave a page that
    ran the script. The number is typed: one line naming the file and the field, nothing written."""
    path = bundle / "report" / name
    _edit(path, set_it)
    _refused(dome_calib_cli, bundle, f"{path}: {field}: expected an integer >= 0", ' got "<img src=x '
                                                                                 'onerror=\\"window.__pwned=...')


def test_a_string_where_a_list_of_reasons_belongs_is_refused_not_split_into_letters(bundle, dome_calib_cli):
    """The issue's case, in the layout the issue saw (2): found.reasons "moved" was stored as m; o; v; e; d."""
    path = bundle / "report" / "report.json"
    path.write_bytes((REPORT_FILES / "report_v2.json").read_bytes())
    _edit(path, lambda d: d["found"]["reasons"].update({"01_03": "moved"}))
    _refused(dome_calib_cli, bundle, f'{path}: found.reasons.01_03: expected a list of non-empty strings, got '
                                     '"moved"')
    path.write_bytes((REPORT_FILES / "report_v2.json").read_bytes())  # and in today's layout
    proc = dome_calib_cli("report", bundle)
    assert proc.returncode == 0, proc.stderr
    _edit(path, lambda d: d["found"]["reasons"].update({"01_03": "moved"}))
    _refused(dome_calib_cli, bundle, f'{path}: found.reasons.01_03: expected a non-empty list of objects with '
                                     'code, text, got "moved"')


@pytest.mark.parametrize("field, set_it, expected", [
    ("center_sigma_cm.01_01", lambda d: d["center_sigma_cm"].update({"01_01": float("nan")}),
     "expected a finite number >= 0, got NaN"),
    ("stage_seconds.sfm", lambda d: d["stage_seconds"].update(sfm="long"), 'expected a finite number >= 0, got "long"'),
    ("to_check", lambda d: d.update(to_check="01_03"), 'expected a list of objects with name, type, reasons, got '
                                                       '"01_03"'),
    ("report_version", lambda d: d.update(report_version="3"), 'expected 2 or 3 (or absent: the first layout), got "3"'),
])
def test_an_edited_report_json_is_one_line_naming_the_field(bundle, dome_calib_cli, field, set_it, expected):
    path = bundle / "report" / "report.json"
    _edit(path, set_it)
    _refused(dome_calib_cli, bundle, f"{path}: {field}: {expected}")


def test_a_report_json_of_layout_2_is_read_through_its_migration(bundle, dome_calib_cli):
    """The file the code before the typed report wrote (tests/data/report_files/report_v2.json): its findings are
    kept with their codes, its sections kept, and it is rewritten in layout 3."""
    path = bundle / "report" / "report.json"
    path.write_bytes((REPORT_FILES / "report_v2.json").read_bytes())
    (bundle / "report" / "residuals.npz").unlink()  # the fixture has none: geometry only
    proc = dome_calib_cli("report", bundle)
    assert proc.returncode == 0, proc.stderr
    assert "was of layout 2: read through its migration, rewritten as layout 3" in proc.stdout
    after = json.loads(path.read_text())
    assert after["report_version"] == 3
    assert after["found"] == {"reasons": {"01_03": [{"code": "moved", "text": "moved 3.1 cm"},
                                                    {"code": "rotated", "text": "rotated 0.52 deg"}]},
                              "missing": {"01_24": "saw no tent in any scene"},
                              "held": {"00_00": "held from the prior (agrees with it)"}}
    assert {r["name"]: [x["code"] for x in r["reasons"]] for r in after["to_check"]} == {
        "01_03": ["moved", "rotated"], "01_24": ["not_calibrated"]}
    assert after["stage_seconds"] == {"sfm": 12.5, "ba": 3.25} and after["center_sigma_cm"]["01_01"] == 0.05


def test_the_rebuild_keeps_the_calibrations_reasons_by_code_whatever_their_text(bundle, dome_calib_cli):
    """A reason the calibration found, reworded to begin like a rule's ("too few observations"), is kept by its
    code; a rule's reason is recomputed whatever its text says."""
    path = bundle / "report" / "report.json"

    def reword(d):
        d["found"]["reasons"]["01_04"] = [{"code": "moved", "text": "too few observations, and moved 3.1 cm"}]
        for row in d["to_check"]:
            for r in row["reasons"]:
                if r["code"] == "too_few_observations":
                    r["text"] = "moved (a rule's reason, reworded)"

    _edit(path, reword)
    proc = dome_calib_cli("report", bundle)
    assert proc.returncode == 0, proc.stderr
    after = {r["name"]: r["reasons"] for r in json.loads(path.read_text())["to_check"]}
    assert after["01_04"] == [{"code": "moved", "text": "too few observations, and moved 3.1 cm"}]
    assert after["01_03"] == [{"code": "too_few_observations", "text": "too few observations (40 < 100)"}]


def test_calibrate_refuses_a_damaged_carried_sync_json_before_any_work(tmp_path, bundle, dome_calib_cli):
    """A recalibration of the same seq carries OUT's sync.json into the new report: it is checked first, not
    after the calibration."""
    path = bundle / "report" / "sync.json"
    _edit(path, lambda d: d["streams"]["vga"].update(n_frames=-1))
    capture = tmp_path / "capture"
    (capture / "scenes" / "s1").mkdir(parents=True)
    proc = dome_calib_cli("calibrate", capture, "-o", bundle)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1
    assert f"{path}: streams.vga.n_frames: expected an integer >= 0" in proc.stderr and proc.stderr.endswith("-1\n")


JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers(-5, 10**6) | st.floats(allow_nan=True)
                           | st.text(max_size=4) | st.just(SCRIPT),
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner,
                                                                                        max_size=3), max_leaves=6)


def _paths(doc, prefix=()):
    """Every place in a JSON document (dict value or list item), as key paths."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


@settings(max_examples=80, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_value_of_any_report_file_replaced_is_refused_in_one_line_or_shown_as_typed(tiny_bundle, tmp_path_factory,
                                                                                      data):
    """Any place of report.json, session.json or sync.json replaced by any JSON value (NaN, a script, a list, an
    object...): the page data is built and is plain JSON, or one ReportError line names that file."""
    from dome_calib.report.page import read_report_folder, render_page

    folder = shutil.copytree(tiny_bundle / "report", tmp_path_factory.mktemp("mut") / "report")
    name = data.draw(st.sampled_from(["report.json", "session.json", "sync.json"]))
    doc = json.loads((folder / name).read_text())
    where = data.draw(st.sampled_from(sorted(_paths(doc), key=str)))
    node = doc
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = data.draw(JSON_VALUES)
    (folder / name).write_text(json.dumps(doc))
    try:
        built = read_report_folder(folder)
    except ReportError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(f"{folder / name}: "), str(exc)
    else:
        json.dumps(built, allow_nan=False)
        assert "report-data" in render_page(built)


def test_every_reason_of_an_older_layout_gets_the_code_its_text_meant():
    """Layout 2's texts (the frozen table of the migration) -> codes, in to_check, found and changes_vs_prior; a
    text that no code names is kept as a note."""
    from dome_calib.report.schema import parse_report

    doc = json.loads((REPORT_FILES / "report_v2.json").read_text())
    doc["changes_vs_prior"] = {"01_03": {"name": "01_03", "moved_cm": 3.1, "rotated_deg": 0.52, "focal_pct": 0.1,
                                         "distortion_px": None, "reasons": ["moved 3.1 cm", "rotated 0.52 deg"]}}
    doc["found"]["reasons"]["01_04"] = ["new intrinsics (focal 4.1 %, distortion 0.3 px): replaced?",
                                        "a technician's own note"]
    report, version = parse_report("report.json", json.dumps(doc).encode())
    assert version == 2 and report.report_version == 3
    assert [(r.code, r.text) for r in report.changes_vs_prior["01_03"].reasons] == [
        (ReasonCode.MOVED, "moved 3.1 cm"), (ReasonCode.ROTATED, "rotated 0.52 deg")]
    assert [r.code for r in report.found.reasons["01_04"]] == [ReasonCode.INTRINSICS_CHANGED, ReasonCode.NOTE]
    assert {r.name: [x.code for x in r.reasons] for r in report.to_check} == {
        "00_12": [ReasonCode.TOO_FEW_OBSERVATIONS], "01_03": [ReasonCode.MOVED, ReasonCode.ROTATED],
        "01_24": [ReasonCode.NOT_CALIBRATED]}
