"""Issue 50: every kept array checked like every kept JSON. A bundle's ``report/residuals.npz`` is read through one
declared spec (dome_calib.residuals.RESIDUAL_ARRAYS, read by dome_calib.arrays.read_arrays): each array's kind,
shape, finite values, indices in range, camera names by the camera-name rule. Every mutation below ends in one line
naming the file and the array, from `dome-calib report` and in the page.

Before (main at aaf6910): NaN or infinite residuals and negative indices were tracebacks (`report`), other kinds
(a float index, a pickled object array, a name that is a path) passed unchecked."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from dome_calib.arrays import ArraySpec, read_arrays
from dome_calib.bundle_io import write_bundle
from dome_calib.errors import ReportError
from dome_calib.layout import nominal_dome
from dome_calib.report import ReportOptions, write_report
from dome_calib.report.page import read_report_folder
from dome_calib.residuals import RESIDUAL_ARRAYS

from .report_data import synthetic_residuals


@pytest.fixture(scope="module")
def kept(tmp_path_factory):
    tiny = nominal_dome("tiny", seed=0)
    folder = write_bundle(tiny, tmp_path_factory.mktemp("kept") / "b")
    write_report(folder, tiny, synthetic_residuals(tiny, loose_lens="01_01", skewed="01_02", few="01_03"),
                 ReportOptions(plots=False))
    return folder


def _arrays(folder) -> dict:
    with np.load(folder / "report" / "residuals.npz") as z:
        return {k: z[k] for k in z.files}


def _set(a: dict, key: str, i, value) -> dict:
    b = {k: v.copy() for k, v in a.items()}
    b[key][i] = value
    return b


#: mutation -> (what is written, what the line must name)
MUTATIONS = {
    "NaN residual": (lambda a: _set(a, "residual_px", (3, 0), np.nan), "residual_px[3, 0]: nan"),
    "infinite residual": (lambda a: _set(a, "residual_px", (0, 1), np.inf), "residual_px[0, 1]: inf"),
    "NaN pixel": (lambda a: _set(a, "uv_px", (5, 1), np.nan), "uv_px[5, 1]: nan"),
    "negative index": (lambda a: _set(a, "camera_index", 2, -1), "camera_index[2]: -1, expected an index"),
    "index past the cameras": (lambda a: _set(a, "camera_index", 0, len(a["camera_names"])),
                               "expected an index into camera_names"),
    "float index": (lambda a: {**a, "camera_index": a["camera_index"].astype(float)}, "camera_index: dtype float64"),
    "numbers as names": (lambda a: {**a, "camera_names": np.arange(len(a["camera_names"]))}, "camera_names: dtype"),
    "a name that is a path": (lambda a: {**a, "camera_names": np.array(["../../x", *a["camera_names"][1:]])},
                              "camera_names[0]"),
    "a name twice": (lambda a: {**a, "camera_names": np.array([a["camera_names"][1], *a["camera_names"][1:]])},
                     "listed twice"),
    "rows that do not match": (lambda a: {**a, "uv_px": a["uv_px"][:-1]}, "uv_px: shape"),
    "a residual of 3 numbers": (lambda a: {**a, "residual_px": np.zeros((len(a["camera_index"]), 3))},
                                "residual_px: shape"),
    "missing array": (lambda a: {k: v for k, v in a.items() if k != "camera_index"}, "camera_index: missing"),
    "unknown array": (lambda a: {**a, "extra": np.zeros(2)}, "extra: unknown array"),
    "not an archive": (lambda a: None, "not a residual file (not a zip archive"),
    "pickled objects": (lambda a: {**a, "camera_names": np.array([object()] * len(a["camera_names"]))},
                        "not a residual file (Object arrays cannot be loaded"),
}


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_a_mutated_residual_file_is_one_line(kept, mutation, dome_calib_cli, tmp_path):
    folder = shutil.copytree(kept, tmp_path / "b")
    change, named = MUTATIONS[mutation]
    path = folder / "report" / "residuals.npz"
    arrays = change(_arrays(folder))
    with open(path, "wb") as f:
        if arrays is None:
            f.write(b"PK\x03\x04 cut")
        else:
            np.savez(f, **arrays, allow_pickle=True) if mutation == "pickled objects" else np.savez(f, **arrays)
    out = dome_calib_cli("report", str(folder))
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1 and len(lines) == 1, out.stderr[-3000:]
    assert "residuals.npz" in lines[0] and named in lines[0], lines[0]
    # the page of the same folder says it instead of drawing (no traceback either)
    data = read_report_folder(folder / "report")
    assert any(named in m for m in data["missing"]), data["missing"]


def test_as_written_it_is_read(kept):
    read_report_folder(kept / "report")
    arrays = read_arrays(kept / "report" / "residuals.npz", RESIDUAL_ARRAYS, ReportError)
    assert set(arrays) == set(RESIDUAL_ARRAYS)


def test_a_file_without_the_optional_array_is_read(kept, tmp_path):
    """Older residual files have no uv_px."""
    a = _arrays(kept)
    del a["uv_px"]
    np.savez(tmp_path / "r.npz", **a)
    assert "uv_px" not in read_arrays(tmp_path / "r.npz", RESIDUAL_ARRAYS, ReportError)


def test_every_spec_rule_on_an_empty_file(tmp_path):
    """No observations (a quick recalibration that changed no camera): every rule holds on empty arrays."""
    specs = {"names": ArraySpec("str", ("C",)), "index": ArraySpec("int", ("M",), index_of="names"),
             "values": ArraySpec("float", ("M", 2))}
    np.savez(tmp_path / "e.npz", names=np.array([], dtype=str), index=np.zeros(0, int), values=np.zeros((0, 2)))
    assert read_arrays(tmp_path / "e.npz", specs, ReportError)["values"].shape == (0, 2)
    np.savez(tmp_path / "e.npz", names=np.array([], dtype=str), index=np.zeros(1, int), values=np.zeros((1, 2)))
    with pytest.raises(ReportError, match=r"index\[0\]: 0, expected an index into names \(which is empty\)"):
        read_arrays(tmp_path / "e.npz", specs, ReportError)
