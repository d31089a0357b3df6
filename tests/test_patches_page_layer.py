"""The people page's patch layer (dome_calib.recon.patches.page_layer): the live patches per reference time, packed
as the page reads them, coloured by part; thinned with a note past its size; inlined through the pages' one
module; drawn by the people page (chromium, as tests/test_people_page.py)."""
from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from dome_calib.pages import inline_json
from dome_calib.recon.patches.model import PatchTrajectories
from dome_calib.recon.patches.page_layer import PART_COLOURS, patch_layer
from dome_calib.recon.patches.parts import BONES, PartLabels
from dome_calib.skeletons.page import write_people_page
from dome_calib.skeletons.scenes import read_people

from .skeletons_helpers import write_scenes
from .test_report_page import _console_errors, browser  # noqa: F401 (the report page's browser fixture)


def _trajectories() -> PatchTrajectories:
    """3 patches (ids out of order) over 3 times; patch 7 alive at times 0-1, patch 3 at 1-2, patch 100005 at 0-2."""
    ids = np.array([7, 3, 100005])
    alive = np.array([[1, 1, 0], [0, 1, 1], [1, 1, 1]], bool)
    X = np.full((3, 3, 3, 3), np.nan)
    rng = np.random.default_rng(0)
    X[alive] = rng.uniform(-100, 100, (alive.sum(), 3, 3))
    return PatchTrajectories(ids=ids, seed_time_ms=np.zeros(3), times_ms=np.array([0.0, 40.0, 80.0]),
                             cameras=["00_00"], X_cm=X, normal=np.zeros((3, 3, 3)), visible=np.zeros((3, 3, 1), bool),
                             photometric=np.zeros((3, 3, 1), bool), alive=alive)


def _decode(text: str, dtype: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype=dtype)


def test_the_layer_holds_each_times_live_patches_by_id_with_their_part():
    traj = _trajectories()
    labels = PartLabels(person=np.array([0, 1, -1]), bone=np.array([4, 11, -1]), cost=np.zeros(3))
    layer = json.loads(inline_json(patch_layer(traj, labels)))  # through the pages' one module: plain JSON
    assert layer["parts"] == [b[0] for b in BONES] and len(layer["colours"]) == len(BONES) == len(PART_COLOURS)
    assert _decode(layer["counts"], "<u4").tolist() == [2, 3, 2]
    part = _decode(layer["part"], "<i1").tolist()
    assert part == [4, -1, 11, 4, -1, 11, -1]  # per time, patches by id: 3 (bone 11), 7 (bone 4), 100005 (none)
    xyz = _decode(layer["xyz"], "<i2").reshape(-1, 3)
    assert np.array_equal(xyz[0], np.rint(traj.X_cm[0, 0, 0] * 10))  # patch 7's centre at time 0, mm
    assert np.array_equal(xyz[2], np.rint(traj.X_cm[1, 1, 0] * 10))  # patch 3 at time 1
    assert layer["notes"] == []


def test_a_big_stream_is_thinned_and_says_so():
    traj = _trajectories()
    layer = patch_layer(traj, None, max_points=4)  # 7 patch-times: every 2nd patch by id (3 and 100005)
    assert layer["patches"] == 2 and layer["of_patches"] == 3 and layer["notes"][0].startswith("one patch in 2 shown")
    assert _decode(layer["counts"], "<u4").tolist() == [1, 2, 2] and set(_decode(layer["part"], "<i1")) == {-1}
    with pytest.raises(ValueError, match="2 labels for 3 patches"):
        patch_layer(traj, PartLabels(person=np.zeros(2), bone=np.zeros(2), cost=np.zeros(2)))


def test_the_people_page_draws_the_layer(browser, tmp_path):  # noqa: F811
    from selenium.webdriver.support.ui import WebDriverWait

    X = np.random.default_rng(2).uniform(-50, 50, (3, 19, 3)) + [0, -100, 0]
    folder = write_scenes(tmp_path / "people", [0, 1, 2], [0.0, 40.0, 80.0],
                          [{1: np.c_[X[k], np.full(19, 0.5)]} for k in range(3)])
    page = write_people_page(tmp_path / "page.html", read_people(folder), patches=patch_layer(_trajectories()))
    browser.get(page.as_uri())
    WebDriverWait(browser, 30).until(lambda d: d.execute_script("return document.body.dataset.ready === '1'"))
    assert browser.find_element("id", "top").get_attribute("data-patches") == "2"  # frame 0: two live patches
    assert _console_errors(browser) == []
