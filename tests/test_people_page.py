"""The people page (`dome-calib people-page`) opened in Debian's chromium through selenium, as the report page is
(tests/test_report_page.py: its browser, offline, no download): the demo's group reconstructed with its bundle and
detections plays, pauses, steps, follows the slider, chooses a person, and for a chosen camera draws its detections
beside the bodies reprojected by the page's own projection, which agrees with dome_calib.camera to 1e-6 px; every
string from a file lands as text; the console stays clean. Load time on 10 people x 3,000 frames: bench/people_out.py.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from dome_calib.bundle_io import load_bundle
from dome_calib.interop.common import ImportOptions
from dome_calib.interop.convert import import_calibration
from dome_calib.recon.project import project_points, view_set
from dome_calib.skeletons.scenes import read_people
from dome_calib.ownership import RECORD

from .skeletons_helpers import CAMERA_MAP, DATA, demo_group_reconstructed, write_scenes
from .test_report_page import _console_errors, browser  # noqa: F401 (the report page's browser fixture)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return demo_group_reconstructed(tmp_path_factory)


def _open(driver, page) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(page.as_uri())
    WebDriverWait(driver, 30).until(lambda d: d.execute_script("return document.body.dataset.ready === '1'"))


def _frame(driver) -> int:
    return int(driver.execute_script("return window.peoplePage.frame()"))


def test_the_demo_groups_page_plays_steps_and_shows_a_camera(browser, demo, dome_calib_cli, tmp_path):  # noqa: F811
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait
    from selenium.webdriver.support.ui import Select

    page = tmp_path / "index.html"
    run = dome_calib_cli("people-page", demo / "people", "-o", page, "--bundle", demo / "bundle", "--detections",
                         demo / "session" / "detections", "--body-model", "BODY_25")
    assert run.returncode == 0, run.stderr
    people = read_people(demo / "people")
    _open(browser, page)
    assert len(browser.find_elements(By.CSS_SELECTOR, "#rows tr")) == len(people.tracks) == 7
    first = sum(0 in t.rows for t in people.tracks.values())
    assert int(browser.find_element(By.ID, "top").get_attribute("data-bodies")) == first
    # step on and back, the slider, play and pause
    browser.find_element(By.ID, "fwd").click()
    browser.find_element(By.ID, "fwd").click()
    assert _frame(browser) == 2
    browser.find_element(By.ID, "back").click()
    assert _frame(browser) == 1 and str(people.frames[1]) in browser.find_element(By.ID, "clock").text
    browser.execute_script("const s = document.getElementById('slider'); s.value = 20;"
                           "s.dispatchEvent(new Event('input'));")
    assert _frame(browser) == 20
    browser.find_element(By.ID, "play").click()
    # playing moves the frame on (waited for, not timed: a loaded machine draws fewer frames per second)
    WebDriverWait(browser, 30, poll_frequency=0.05).until(lambda d: _frame(d) > 21)
    # pause: checked and clicked in one turn of the page's script (a stalled browser may have played to the last
    # frame and stopped by itself meanwhile; a click then would play again from the first)
    browser.execute_script("const p = document.getElementById('play'); if (p.dataset.playing === '1') p.click();")
    assert browser.find_element(By.ID, "play").get_attribute("data-playing") == "0"
    stopped = _frame(browser)
    assert stopped > 21
    time.sleep(0.3)
    assert _frame(browser) == stopped  # paused
    # choose a person: the row is marked and the views know it
    pid = list(people.tracks)[3]
    browser.find_element(By.CSS_SELECTOR, f'#rows tr[data-id="{pid}"]').click()
    assert browser.find_element(By.ID, "top").get_attribute("data-selected") == str(pid)
    assert browser.find_element(By.CSS_SELECTOR, "#rows tr.sel").get_attribute("data-id") == str(pid)
    # a camera: its detections against the reprojected bodies
    bundle = load_bundle(demo / "bundle")
    cam = sorted(bundle.cameras)[0]
    Select(browser.find_element(By.ID, "camera")).select_by_value(cam)
    canvas = browser.find_element(By.ID, "cam")
    assert int(canvas.get_attribute("data-reprojected")) > 0 and int(canvas.get_attribute("data-detected")) > 0
    # the page's projection is dome_calib.camera's
    X = np.random.default_rng(0).uniform([-100, -180, -100], [100, -10, 100], size=(20, 3))
    for name in sorted(bundle.cameras)[::3]:
        ours = project_points(view_set(bundle, [name]), X).uv_px[0]
        page_uv = np.array([browser.execute_script("return window.peoplePage.project(arguments[0], arguments[1])",
                                                   name, x.tolist()) for x in X], dtype=float)
        assert np.max(np.abs(page_uv - ours)) < 1e-6, name
    assert _console_errors(browser) == []


def test_strings_from_files_are_text_on_the_page(browser, tmp_path, dome_calib_cli):  # noqa: F811
    """A folder name and an fpsType holding markup are shown as text: no element is made from them."""
    hostile = '<img src=x onerror="window.__pwned=1"></script><b id="inj">'
    folder = tmp_path / "people <b id=inj2>x"
    X = np.random.default_rng(2).uniform(-50, 50, (2, 19, 3)) + [0, -100, 0]
    write_scenes(folder, [0, 1], [0.0, 40.0], [{1: np.c_[X[0], np.full(19, 0.5)]}, {1: np.c_[X[1], np.full(19, 0.5)]}],
                 fps_type=hostile)
    run = dome_calib_cli("people-page", folder, "-o", tmp_path / "page.html")
    assert run.returncode == 0, run.stderr
    _open(browser, tmp_path / "page.html")
    assert browser.execute_script("return document.querySelectorAll('#inj, #inj2, img').length") == 0
    assert not browser.execute_script("return window.__pwned === 1")
    assert hostile in browser.find_element("id", "subtitle").text
    assert "<b id=inj2>" in browser.find_element("id", "title").text
    assert _console_errors(browser) == []


def test_many_people_load_and_play_without_error(browser, tmp_path, dome_calib_cli):  # noqa: F811
    """10 people x 600 frames (the bench measures 3,000): the page is ready, plays to the end, the console is clean;
    the time until ready is printed (measured in bench/people_out.py, not asserted here: the machine is shared)."""
    from .people_helpers import group_joints_cm

    frames = np.arange(600)
    X = group_joints_cm(frames * 40.0, 10, seed=1)
    write_scenes(tmp_path / "many", frames, frames * 40.0,
                 [{p: np.c_[X[k, p], np.full(19, 0.8)] for p in range(10)} for k in range(len(frames))])
    assert dome_calib_cli("people-page", tmp_path / "many").returncode == 0
    _open(browser, tmp_path / "many" / "index.html")
    print(json.dumps({"people_page_ready_ms": round(browser.execute_script("return window.__pageReady"))}))
    assert browser.find_element("id", "top").get_attribute("data-bodies") == "10"
    browser.execute_script("document.getElementById('speed').value = '4';"
                           "document.getElementById('speed').dispatchEvent(new Event('change'));"
                           "const s = document.getElementById('slider'); s.value = 560;"
                           "s.dispatchEvent(new Event('input'));")
    browser.find_element("id", "play").click()
    time.sleep(1.2)  # 40 frames at 4 x 25 fps: the end
    assert _frame(browser) == 599 and browser.find_element("id", "play").get_attribute("data-playing") == "0"
    assert _console_errors(browser) == []


def test_reconstruct_writes_the_page_into_its_output(browser, tmp_path, dome_calib_cli):  # noqa: F811
    """`dome-calib reconstruct` on the real Pose2Sim capture stages index.html with its body3DScene files: the page
    names the output folder, has the four cameras and their detections; a rerun replaces the folder, page and all."""
    import_calibration(DATA / "calibration" / "Calib_qualisys.toml", "pose2sim", tmp_path / "bundle",
                       ImportOptions(names={f"cam_{k:02d}": f"00_{k:02d}" for k in range(1, 5)}))
    args = ("reconstruct", DATA / "pose", "--bundle", tmp_path / "bundle", "--body-model", "BODY_25B",
            "--camera-map", CAMERA_MAP, "--fps", "60", "-o", tmp_path / "out")
    for _ in range(2):  # the second run replaces an earlier run's folder, index.html included
        run = dome_calib_cli(*args)
        assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if not p.name.startswith("body3DScene_")) == [
        RECORD, "cameras.json", "index.html"]
    _open(browser, tmp_path / "out" / "index.html")
    assert browser.find_element("id", "title").text == "People: out"
    options = [o.get_attribute("value") for o in browser.find_elements("css selector", "#camera option")]
    assert options == ["00_01", "00_02", "00_03", "00_04"]
    assert int(browser.find_element("id", "cam").get_attribute("data-detected")) >= 1
    assert _console_errors(browser) == []
