"""Property-based tests of the four bundle readers (issue 15): random mutations of the real calibration (a subset
of its cameras), the real kcalibration and sync files written by our writer either load or raise the one-line
BundleFormatError that names the file; never another exception. Derandomized: the same examples on every run."""
from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dome_calib.bundle import SyncTable
from dome_calib.errors import BundleFormatError
from dome_calib.panoptic_io import (format_ksynctables, format_synctables, read_calibration, read_kcalibration,
                                    read_ksynctables, read_synctables)

from .conftest import REAL_CALIBRATION, REAL_KCALIBRATION

SETTINGS = settings(derandomize=True, database=None, max_examples=120, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

_CAL = json.loads(REAL_CALIBRATION.read_text())
CALIBRATION = {**_CAL, "cameras": [c for c in _CAL["cameras"] if c["name"] in ("01_01", "07_13", "00_04", "50_02")]}
KCALIBRATION = {**json.loads(REAL_KCALIBRATION.read_text())}
KCALIBRATION["sensors"] = KCALIBRATION["sensors"][:3]
_TABLE = SyncTable(index=np.array([100, 101, 103, 104]), univ_time_ms=np.array([1000.0, 1040.0, 1120.0, 1160.0125]))
SYNCTABLES = json.loads(format_synctables({"vga": _TABLE, "hd": SyncTable(index=np.array([5, 6]),
                                                                            univ_time_ms=np.array([1001.5, 1034.9]))}))
KSYNCTABLES = json.loads(format_ksynctables({"KINECTNODE1": _TABLE, "KINECTNODE2": _TABLE}, {"KINECTNODE1": _TABLE}))

READERS = {"calibration": (read_calibration, CALIBRATION), "kcalibration": (read_kcalibration, KCALIBRATION),
           "synctables": (read_synctables, SYNCTABLES), "ksynctables": (read_ksynctables, KSYNCTABLES)}

RETYPES = ["x", "", "1.5", None, True, False, [], [1], [[1, 2], [3]], {}, {"a": 1}, 0, -1, 1.5, 10**400]
NUMBERS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e-320, 0.0, -0.0, 3.5, 2**63]


def _paths(obj, prefix=()):
    """Every place in a JSON object: a tuple of keys and indices."""
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


def _parent(obj, path):
    for key in path[:-1]:
        obj = obj[key]
    return obj


@st.composite
def mutated(draw, base):
    """The base object with 1-3 random mutations: delete, retype, NaN/inf/huge, reshape, duplicate."""
    obj = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(obj)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent, key = _parent(obj, path), path[-1]
        value = parent[key]
        kind = draw(st.sampled_from(["delete", "retype", "number", "reshape", "duplicate"]))
        if kind == "delete":
            del parent[key]
        elif kind == "retype":
            parent[key] = copy.deepcopy(draw(st.sampled_from(RETYPES)))
        elif kind == "number":
            parent[key] = draw(st.sampled_from(NUMBERS))
        elif kind == "reshape" and isinstance(value, list):
            how = draw(st.sampled_from(["drop", "extend", "flatten", "wrap", "transpose"]))
            if how == "drop" and value:
                value.pop()
            elif how == "extend":
                value.append(copy.deepcopy(value[-1]) if value else 0)
            elif how == "flatten":
                parent[key] = [x for v in value for x in (v if isinstance(v, list) else [v])]
            elif how == "wrap":
                parent[key] = [value]
            elif how == "transpose" and value and all(isinstance(v, list) for v in value):
                try:
                    parent[key] = np.array(value, dtype=object).T.tolist()
                except ValueError:
                    pass
        elif kind == "duplicate" and isinstance(parent, list):
            parent.insert(key, copy.deepcopy(value))  # a camera, a sensor or a number twice
        elif kind == "duplicate" and isinstance(parent, dict):
            parent[f"{key}_copy"] = copy.deepcopy(value)  # an extra key
    return obj


def _check(tmp_path: Path, kind: str, obj) -> object | None:
    """Write ``obj`` as ``<kind>_m.json`` and read it: the result, or None after a proper one-line error."""
    reader, _ = READERS[kind]
    path = tmp_path / f"{kind}_m.json"
    path.write_text(json.dumps(obj))
    try:
        return reader(path)
    except BundleFormatError as exc:
        message = str(exc)
        assert "\n" not in message and "\r" not in message, message
        assert message.startswith(f"{path}: ") and len(message) < 600, message
        return None


def _sane_cameras(cameras) -> None:
    for cam in cameras.values():
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(cam.R) > 0
        for arr in (cam.K, cam.dist, cam.t_cm, cam.center_cm):
            assert np.all(np.isfinite(arr))
        assert cam.K[0, 0] > 0 and cam.K[1, 1] > 0 and min(cam.resolution) > 0


@SETTINGS
@given(obj=mutated(CALIBRATION))
def test_mutated_calibration_loads_or_fails_in_one_line(tmp_path, obj):
    got = _check(tmp_path, "calibration", obj)
    if got is not None:
        cameras, source = got
        assert cameras and isinstance(source, str)
        _sane_cameras(cameras)


@SETTINGS
@given(obj=mutated(KCALIBRATION))
def test_mutated_kcalibration_loads_or_fails_in_one_line(tmp_path, obj):
    kinect = _check(tmp_path, "kcalibration", obj)
    if kinect is not None:
        assert kinect.sensors and all(n.startswith("KINECTNODE") for n in kinect.sensors)
        for s in kinect.sensors.values():
            for M in (s.M_depth, s.M_color, s.M_world2sensor):
                np.testing.assert_allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-9)
            assert np.all(np.isfinite(s.color_from_depth)) and np.all(np.isfinite(s.dist_depth))
        assert np.isfinite(np.linalg.inv(kinect.M_world2vga)).all()


def _sane_tables(tables) -> None:
    for table in tables.values():
        assert len(table.index) >= 1 and table.index.dtype == np.int64
        assert np.all(np.diff(table.index) > 0) and np.all(np.diff(table.univ_time_ms) > 0)
        assert np.all(np.isfinite(table.univ_time_ms))
        table.nearest(table.univ_time_ms[0])  # usable


@SETTINGS
@given(obj=mutated(SYNCTABLES))
def test_mutated_synctables_load_or_fail_in_one_line(tmp_path, obj):
    tables = _check(tmp_path, "synctables", obj)
    if tables is not None:
        _sane_tables(tables)


@SETTINGS
@given(obj=mutated(KSYNCTABLES))
def test_mutated_ksynctables_load_or_fail_in_one_line(tmp_path, obj):
    got = _check(tmp_path, "ksynctables", obj)
    if got is not None:
        for tables in got:
            _sane_tables(tables)


@pytest.mark.parametrize("kind", sorted(READERS))
def test_unmutated_bases_load(tmp_path, kind):
    """The mutations start from files that load, so each refusal above comes from a mutation."""
    assert _check(tmp_path, kind, READERS[kind][1]) is not None
