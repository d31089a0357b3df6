"""Issue 50: one module keeps file data out of every page (dome_calib.pages: the shared styles, the error handler and
the escaping helpers, and the inline data no string can end). The report page and the people page are rendered
through it (no copy of the handler, helpers or base styles left in them), and each, with hostile names (markup,
quotes, a script end) in every field a file gives, shows every row in Chromium and runs none of it."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.layout import nominal_dome
from dome_calib.pages import MARKS, inline_json, render

from .skeletons_helpers import write_scenes
from .test_report_page import _console_errors, browser  # noqa: F401 (the browser fixture)

ROOT = Path(__file__).resolve().parents[1]
TEMPLATES = sorted((ROOT / "dome_calib").rglob("*.html"))
#: Camera names a file may carry (plain names: no '/'), each markup, quotes or the like.
HOSTILE_NAMES = ['<img src=x onerror="window.__pwned=1">', "'><svg onload=window.__pwned=2>", '"q" & <b>b',
                 "${window.__pwned=3}", "<!--x"]
HOSTILE_TEXT = "</script><script>window.__pwned=4</script><b id=inj>"


def test_every_page_template_goes_through_the_one_module():
    """Each template holds the shared module's marks once and no copy of what it provides."""
    assert TEMPLATES, "no page template found"
    for path in TEMPLATES:
        text = path.read_text()
        assert all(text.count(m) == 1 for m in MARKS), path
        assert 'addEventListener("error"' not in text and "const esc =" not in text, path
        assert ":root {" not in text and "box-sizing" not in text, path  # the base styles are the module's


def test_render_refuses_a_template_without_the_marks(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="expected each of"):
        render("dome_calib", "page_assets/kit.js", {})  # not a page: no marks
    text = inline_json({"a": "</script><!--\u2028&"})
    assert "<" not in text and ">" not in text and "&" not in text and "\u2028" not in text


def _open(driver, page: Path) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(page.as_uri())
    WebDriverWait(driver, 30).until(lambda d: d.execute_script("return document.body.dataset.ready === '1'"))


def _nothing_ran(driver) -> None:
    assert driver.execute_script("return window.__pwned") is None
    assert driver.execute_script("return document.querySelectorAll('img, svg #inj, #inj, b#inj').length") == 0


def _hostile_dome() -> Bundle:
    dome = nominal_dome("tiny", seed=0)
    names = sorted(dome.cameras)
    renamed = {HOSTILE_NAMES[i] if i < len(HOSTILE_NAMES) else n: dataclasses.replace(dome.cameras[n],
               name=HOSTILE_NAMES[i] if i < len(HOSTILE_NAMES) else n) for i, n in enumerate(names)}
    return Bundle(seq="s", cameras=renamed, calib_data_source=HOSTILE_TEXT)


def test_the_report_page_with_hostile_names_shows_every_row(browser, tmp_path):  # noqa: F811
    from dome_calib.report import ReportOptions, write_report

    from .report_data import synthetic_residuals

    dome = _hostile_dome()
    names = sorted(dome.cameras)
    folder = write_bundle(dome, tmp_path / "b")
    write_report(folder, dome, synthetic_residuals(dome, loose_lens=names[0], skewed=names[1], few=names[2]),
                 ReportOptions(plots=False), missing={"01_24": HOSTILE_TEXT})
    _open(browser, folder / "report" / "index.html")
    _nothing_ran(browser)
    rows = browser.execute_script("return [...document.querySelectorAll('#rows tr')].map((r) => r.dataset.cam)")
    assert sorted(rows) == names  # every camera a row, named as the file names it
    assert HOSTILE_TEXT in browser.find_element("id", "subtitle").text
    assert _console_errors(browser) == []


def test_the_people_page_with_hostile_names_shows_every_row(browser, tmp_path, dome_calib_cli):  # noqa: F811
    dome = _hostile_dome()
    write_bundle(dome, tmp_path / "b")
    folder = tmp_path / "people <b id=inj>x"
    rng = np.random.default_rng(2)
    bodies = [{pid: np.c_[rng.uniform(-50, 50, (19, 3)) + [0, -100, 0], np.full(19, 0.5)] for pid in (0, 3, 7)}
              for _ in range(3)]
    write_scenes(folder, [0, 1, 2], [0.0, 40.0, 80.0], bodies, fps_type=HOSTILE_TEXT)
    run = dome_calib_cli("people-page", folder, "-o", tmp_path / "page.html", "--bundle", tmp_path / "b")
    assert run.returncode == 0, run.stderr
    _open(browser, tmp_path / "page.html")
    _nothing_ran(browser)
    rows = browser.execute_script("return document.querySelectorAll('#rows tr').length")
    assert rows == 3  # every person a row
    options = browser.execute_script("return [...document.querySelectorAll('#camera option')].map((o) => o.value)")
    assert set(HOSTILE_NAMES) <= set(options)  # every camera offered, by its name as text
    assert HOSTILE_TEXT in browser.find_element("id", "subtitle").text
    assert re.search("people <b id=inj>x", browser.find_element("id", "title").text)
    assert _console_errors(browser) == []
