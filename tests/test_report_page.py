"""The report page (report/index.html) in a real browser: Debian's chromium, headless, driven by the system's
chromedriver through selenium (installed by `make system-deps`; selenium is in the test extra).

Selenium Manager stays offline (SE_OFFLINE, SE_AVOID_STATS): the driver and the browser are named explicitly,
nothing is downloaded and no statistics are sent. Without chromium the tests skip with the reason, except under
CI, where they fail.

On a 60-camera report (the panel preset) and a 521-camera report (the real Panoptic calibration plus the one
camera it lacks, 14_18, from the design, with synthetic residuals): one row per camera, sorting by RMS puts the
largest first, filtering by type leaves only that type, clicking a camera in the dome selects its row and draws
its residuals, and the console has no error. The 521-camera page's size and the time until it is interactive
are printed (measured, not asserted: the machine is shared).
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from dome_calib.bundle import Bundle
from dome_calib.layout import nominal_dome

from .conftest import REAL_CALIBRATION
from .report_data import old_report_json, write_synthetic_report

os.environ["SE_OFFLINE"] = "true"  # Selenium Manager: no download, no statistics
os.environ["SE_AVOID_STATS"] = "true"

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


def _unavailable(reason: str):
    if os.environ.get("CI"):
        pytest.fail(f"browser tests cannot run in CI: {reason} (run `make system-deps`)")
    pytest.skip(f"{reason}: run `make system-deps` (apt chromium chromium-driver) and install '.[test]'")


@pytest.fixture(scope="module")
def browser():
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        _unavailable("selenium is not installed")
    for path in (CHROMIUM, CHROMEDRIVER):
        if not path.exists():
            _unavailable(f"{path} not found")
    profile = tempfile.mkdtemp(prefix="report-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--no-first-run", "--disable-extensions", "--disable-sync",
                f"--user-data-dir={profile}", "--window-size=1400,1000"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


@pytest.fixture(scope="module")
def panel_report(tmp_path_factory):
    bundle = dataclasses.replace(nominal_dome("panel", seed=0), seq="panel")
    folder = tmp_path_factory.mktemp("panel") / "bundle"
    planted = write_synthetic_report(bundle, folder, missing={"01_24": "saw no tent in any scene"})
    return folder / "report", planted


@pytest.fixture(scope="module")
def full_report(tmp_path_factory):
    from dome_calib.panoptic_io import read_calibration

    cameras, _ = read_calibration(REAL_CALIBRATION)
    cameras = dict(cameras) | {"14_18": nominal_dome("full", seed=0).cameras["14_18"]}  # the one it lacks
    bundle = Bundle(seq="160906_band1", cameras=dict(sorted(cameras.items())),
                    calib_data_source="real Panoptic calibration, synthetic residuals")
    folder = tmp_path_factory.mktemp("full") / "bundle"
    planted = write_synthetic_report(bundle, folder)
    return folder / "report", planted


def _console_errors(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]


def _open(driver, page: Path) -> dict:
    """Open the page; return its timings (ms since navigation start) once the page says it is ready."""
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(page.as_uri())
    WebDriverWait(driver, 30).until(lambda d: d.execute_script("return document.body.dataset.ready === '1'"))
    return driver.execute_script("""
        const n = performance.getEntriesByType('navigation')[0];
        return {dom_interactive_ms: n.domInteractive, load_end_ms: n.loadEventEnd,
                ready_ms: window.__reportReady};""")


def _rows(driver, visible_only: bool = False) -> list[list[str]]:
    """[name, type] of the table's rows in their order (one script call: 521 element round trips take seconds)."""
    return driver.execute_script("""
        return [...document.querySelectorAll('#rows tr')]
            .filter(r => !arguments[0] || r.getClientRects().length > 0)
            .map(r => [r.dataset.cam, r.dataset.type]);""", visible_only)


def _check_page(driver, report_dir: Path, planted) -> None:
    """The page's table, sorting, filtering, dome selection and residual plot against report.json."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    rep = json.loads((report_dir / "report.json").read_text())
    per_cam = rep["per_camera"]
    assert sorted(n for n, _ in _rows(driver)) == sorted(per_cam)  # one row per camera
    # sort by RMS: the largest first
    header = next(th for th in driver.find_elements(By.CSS_SELECTOR, "#head th") if th.text.startswith("RMS"))
    header.click()
    order = [n for n, _ in _rows(driver)]
    rms = [per_cam[n]["rms_px"] for n in order]
    assert rms[0] == max(rms) and order[0] == planted.loose_lens
    assert all(a >= b for a, b in zip(rms, rms[1:]))
    # filter by type: only that type is left
    Select(driver.find_element(By.ID, "ftype")).select_by_value("hd")
    shown = _rows(driver, visible_only=True)
    assert {t for _, t in shown} == {"hd"}
    assert len(shown) == sum(c["type"] == "hd" for c in per_cam.values())
    Select(driver.find_element(By.ID, "ftype")).select_by_value("")
    assert len(_rows(driver, visible_only=True)) == len(per_cam)
    # a camera clicked in the dome's top view: its row is selected and its residuals drawn
    from selenium.webdriver.common.action_chains import ActionChains

    name = planted.skewed
    circle = driver.find_element(By.CSS_SELECTOR, f'#top circle[data-cam="{name}"]')
    ActionChains(driver).move_to_element(circle).perform()  # hovering names the camera and gives its figures
    tip = driver.find_element(By.ID, "tip")
    assert tip.is_displayed() and name in tip.text and "observations" in tip.text and "RMS" in tip.text
    circle.click()
    selected = driver.find_elements(By.CSS_SELECTOR, "#rows tr.sel")
    assert [r.get_attribute("data-cam") for r in selected] == [name]
    quiver = driver.find_element(By.ID, "quiver")
    assert quiver.is_displayed() and int(quiver.get_attribute("data-arrows")) > 50
    assert "drawn" in driver.find_element(By.ID, "qlegend").text  # the arrow scale is stated
    assert driver.find_element(By.ID, "cover").is_displayed()
    # the list of cameras to check names the planted problems, and the tail of the distributions is stated
    to_check = driver.find_element(By.ID, "tocheck").text
    for n in (planted.loose_lens, planted.few, *planted.moved):
        assert n in to_check, n
    assert "largest" in driver.find_element(By.ID, "hists").text
    assert _console_errors(driver) == []


def test_panel_report_in_the_browser(browser, panel_report):
    report_dir, planted = panel_report
    _open(browser, report_dir / "index.html")
    _check_page(browser, report_dir, planted)
    assert "01_24: not calibrated" in browser.find_element("id", "tocheck").text
    assert "47 / 48" in browser.find_element("id", "cards").text  # vga calibrated / expected (01_24 not)


def test_full_dome_report_in_the_browser_is_interactive_quickly(browser, full_report):
    report_dir, planted = full_report
    page = report_dir / "index.html"
    timing = _open(browser, page)
    interactive_ms = max(timing.values())  # handlers attached (ready) and the document loaded (load end)
    clicks = browser.execute_script("""
        const t0 = performance.now();
        document.querySelector('#head th:nth-child(5)').dispatchEvent(new MouseEvent('click', {bubbles: true}));
        const t1 = performance.now();
        document.querySelector('#top circle.cam').dispatchEvent(new MouseEvent('click', {bubbles: true}));
        const t2 = performance.now();
        document.querySelector('#head th:nth-child(1)').dispatchEvent(new MouseEvent('click', {bubbles: true}));
        return {sort_ms: t1 - t0, select_ms: t2 - t1};""")
    print(json.dumps({"page": "full dome report", "cameras": len(json.loads((report_dir / "report.json").read_text())
                                                                 ["per_camera"]),
                      "page_kB": round(page.stat().st_size / 1e3),
                      "residuals_npz_kB": round((report_dir / "residuals.npz").stat().st_size / 1e3),
                      "interactive_ms": round(interactive_ms), **{k: round(v) for k, v in timing.items()},
                      **{k: round(v, 1) for k, v in clicks.items()}}))
    assert interactive_ms < 30_000  # a generous bound only (shared machine); the aim, 2 s, is printed above
    browser.refresh()
    _open(browser, page)
    _check_page(browser, report_dir, planted)


def test_hostile_report_folder_page_is_not_blank(browser, tmp_path):
    """No residuals.npz and a report.json from an older version: the page lists what is missing, shows the
    cameras it has, and raises no error."""
    from dome_calib.report.page import write_page

    tiny = nominal_dome("tiny", seed=0)
    folder = tmp_path / "report"
    folder.mkdir()
    old = old_report_json(tiny, "old", [{"name": "01_03", "type": "vga", "reasons": ["moved 3.1 cm"]}])
    (folder / "report.json").write_text(json.dumps(old))
    _open(browser, write_page(folder))
    missing = browser.find_element("id", "missing")
    assert missing.is_displayed() and "residuals.npz" in missing.text and "older version" in missing.text
    assert len(browser.find_elements("css selector", "#rows tr")) == 16
    browser.find_element("css selector", '#rows tr[data-cam="01_03"]').click()
    assert "no residuals saved for this camera" in browser.find_element("id", "selpanel").text
    assert _console_errors(browser) == []
    (folder / "report.json").unlink()
    _open(browser, write_page(folder))
    assert "report.json: not found" in browser.find_element("id", "missing").text
    assert _console_errors(browser) == []


def test_session_report_page_has_the_sync_and_kinect_sections(browser, small_product_session, monkeypatch,
                                                             tmp_path, dome_calib_cli):
    """`dome-calib session` (calibration stand-ins as in test_session): the page shows per stream the clock-fit
    error and the dropped frames (the synthetic session drops 2 of each stream: the truth), and the Kinect's
    depth-to-colour figures."""
    import numpy as np

    from dome_calib.synth.sync_session import load_truth

    root, truth = small_product_session
    import dome_calib.pipeline.full as pipeline
    from dome_calib.pipeline.stages import residuals_of
    from dome_calib.pipeline.types import BAOutcome, SfmOutcome

    from .test_calibrate import _problem

    monkeypatch.setattr(pipeline, "run_sfm_stage", lambda *a, **k: SfmOutcome(problem=_problem(truth)))
    monkeypatch.setattr(pipeline, "run_ba_stage", lambda problem, *, progress=True: BAOutcome(
        problem=problem, cameras={n: problem.camera(n) for n in problem.camera_names},
        residuals=residuals_of(problem), inlier=np.ones(problem.n_observations, bool)))
    out = tmp_path / "bundle"
    proc = dome_calib_cli("session", root, "-o", out)
    assert proc.returncode == 0, proc.stderr
    t = load_truth(root / "sync")
    dropped = {k: int(v.max() - v.min() + 1 - len(v)) for k, v in t.index.items()}
    assert set(dropped.values()) == {2}
    _open(browser, out / "report" / "index.html")
    from selenium.webdriver.common.by import By

    sync_rows = browser.find_elements(By.CSS_SELECTOR, "#sync tbody tr")
    shown = {r.find_elements(By.TAG_NAME, "td")[0].text: int(r.find_elements(By.TAG_NAME, "td")[2].text)
             for r in sync_rows}
    assert shown == dropped
    kinect = browser.find_element(By.ID, "kinect").text
    assert "KINECTNODE4" in kinect and "50_04" in kinect
    assert "50_05: Kinect colour camera without checkerboard pairs" in kinect
    assert len(browser.find_elements(By.CSS_SELECTOR, "#rows tr")) == len(truth.cameras)
    assert _console_errors(browser) == []


def test_scrambled_report_json_page_shows_what_it_can_without_an_error(browser, tmp_path):
    """A report.json whose sections have the wrong types (damaged by hand or by another tool): the page lists
    them as not shown, draws the cameras it can, and the console stays clean."""
    from dome_calib.report.page import write_page

    tiny = nominal_dome("tiny", seed=0)
    folder = tmp_path / "report"
    folder.mkdir()
    per_camera = {n: {"type": str(c.type), "center_cm": c.center_cm.tolist(), "observations": 300, "rms_px": 0.5,
                      "resolution": list(c.resolution), "panel": c.panel} for n, c in tiny.cameras.items()}
    per_camera["01_01"] |= {"rms_px": "high", "center_cm": [1, 2], "observations": None, "resolution": "640x480"}
    scrambled = {"report_version": 2, "seq": 7, "per_type": {"vga": None, "hd": 3}, "expected_per_type": {"vga": 3},
                 "rms_px": float("inf"), "stage_seconds": {"sfm": "long"},
                 "cluster": {"executor": "dask", "stages": {"features": None}, "on_this_machine": "head"},
                 "to_check": [{"name": "01_02", "reasons": "moved"}, "01_03", {"reasons": ["x"]}],
                 "previous": {"added": "01_01", "cameras": 5, "seq": ["x"]}, "per_camera": per_camera,
                 "world_frame": "prior", "lens_model": {"cameras": {"01_02": {"free": "fx", "decisions": [None]}}}}
    (folder / "report.json").write_text(json.dumps(scrambled))
    (folder / "sync.json").write_text(json.dumps({"streams": {"vga": None}}))
    (folder / "session.json").write_text(json.dumps({"pillars": {"kinect": {"sensors": [None, {"sensor": 4}]}}}))
    _open(browser, write_page(folder))
    missing = browser.find_element("id", "missing").text
    assert "seq, world_frame of an unexpected type" in missing and "sync.json: unexpected layout" in missing
    assert len(browser.find_elements("css selector", "#rows tr")) == 16
    assert len(browser.find_elements("css selector", "#top circle.cam")) == 15  # 01_01 has no usable centre
    browser.find_element("css selector", '#rows tr[data-cam="01_02"]').click()
    assert "no residuals saved for this camera" in browser.find_element("id", "selpanel").text
    assert _console_errors(browser) == []
