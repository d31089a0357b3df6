"""Every pycolmap options object is made by dome_calib.colmap_options: one thread and a fixed seed throughout, so
COLMAP's solvers give the same bytes on every run (docs/conventions.md, "Same result on every machine")."""
from __future__ import annotations

import re
from pathlib import Path

import pycolmap
import pytest

from dome_calib.colmap_options import colmap_options, pin, unpinned
from projector.known_scene import KnownPoseOptions, triangulator_options
from projector.mapping import MappingOptions, _global_options, _incremental_options
from projector.matching import MatchOptions, verify_options

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dome_calib", "projector", "timecode")
MADE = re.compile(r"pycolmap\.\w+Options\s*\(")


def test_no_pycolmap_options_made_elsewhere():
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
             for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))
             if path != ROOT / "dome_calib" / "colmap_options.py"
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if MADE.search(line)]
    assert found == [], "make pycolmap options with dome_calib.colmap_options.colmap_options:\n" + "\n".join(found)


@pytest.mark.parametrize("kind", ["GlobalPipelineOptions", "IncrementalPipelineOptions", "RANSACOptions",
                                  "FeatureExtractionOptions", "FeatureMatchingOptions", "TwoViewGeometryOptions",
                                  "AbsolutePoseEstimationOptions"])
def test_colmap_options_pins_threads_and_seeds_throughout(kind):
    raw = getattr(pycolmap, kind)()
    assert unpinned(raw) != []  # pycolmap's defaults: all cores, or a seed from the clock (-1)
    made = colmap_options(getattr(pycolmap, kind), seed=7)
    assert unpinned(made, seed=7) == []
    assert unpinned(pin(raw)) == [] and unpinned(raw) == []  # in place, nested options included


def test_colmap_options_sets_fields():
    ransac = colmap_options(pycolmap.RANSACOptions, max_error=2.5)
    assert ransac.max_error == 2.5 and ransac.num_threads == 1 and ransac.random_seed == 0


def test_the_builders_hand_colmap_pinned_options():
    assert unpinned(_global_options(MappingOptions())) == []
    assert unpinned(_incremental_options(MappingOptions())) == []
    assert unpinned(triangulator_options(KnownPoseOptions())) == []
    assert unpinned(verify_options(MatchOptions())) == []
    assert unpinned(_global_options(MappingOptions(num_threads=2))) == ["num_threads", "mapper.num_threads"]
