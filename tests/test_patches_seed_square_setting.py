"""``reconstruct --patch-setting``: "body" (the default) tracks with PatchOptions' defaults, "visibility" with the
setting that meets issue 49's visibility aims (model.PATCH_SETTINGS, one place); a name it does not know is one line
naming the option and what it takes, before the images are opened."""
from __future__ import annotations

import inspect
from pathlib import Path
from types import SimpleNamespace

import pytest

from dome_calib.cli.people import reconstruct
from dome_calib.recon.errors import ReconError
from dome_calib.recon.patches.model import PATCH_SETTINGS, PatchOptions, refine_square_cm, seed_square_cm
from dome_calib.recon.patches.stage import plan_patches


def test_the_default_setting_is_the_defaults():
    assert inspect.signature(reconstruct).parameters["patch_setting"].default.default == "body"
    assert PatchOptions(**PATCH_SETTINGS["body"]) == PatchOptions()


def test_the_visibility_setting_compares_4_cm_squares_and_refines_the_seeds_on_6_cm():
    o = PatchOptions(**PATCH_SETTINGS["visibility"])  # every field valid
    assert o.ncc_size_cm == 4.0 and refine_square_cm(o) == 6.0 and seed_square_cm(o) == 4.0
    assert o.anchor_flow and o.neighbour_ncc and o.body_occlusion and o.seed_appearance_end


def test_an_unknown_setting_is_refused_before_the_images_are_opened():
    with pytest.raises(ReconError, match=r"--patch-setting 'visible': expected one of body, visibility"):
        plan_patches(SimpleNamespace(images=Path("nowhere")), setting="visible")
