"""Every export computes its numbers in IEEE basic operations only (dome_calib.exact), so every machine writes
the same bytes for the same bundle (README, "Same result on every machine").

What differs between CPUs is BLAS and LAPACK (``@``, ``np.linalg``, scipy's ``Rotation.from_matrix``: OpenBLAS's
kernels), numpy's transcendental ufuncs (SVML on AVX-512) and the C library's (glibc's FMA variants); what does not is
one +, -, *, /, sqrt at a time. The test runs every exporter on a bundle whose arrays admit only those: any matrix
product, reduction, linear-algebra call or transcendental on them raises. (Across OpenBLAS's Haswell and SkylakeX
kernels every exporter wrote other bytes before: ``bench/same_bytes.py``, docs/benchmarks.md.)
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib import exact
from dome_calib.interop import convert
from dome_calib.interop.convert import export_bundle
from dome_calib.interop.registry import EXPORT_FORMATS
from dome_calib.panoptic_io import read_calibration

from .conftest import REAL_CALIBRATION

#: One element at a time, correctly rounded (or exact): the same bits on every CPU.
BASIC = {"add", "subtract", "multiply", "divide", "true_divide", "negative", "positive", "sqrt", "absolute", "rint",
         "equal", "not_equal", "less", "less_equal", "greater", "greater_equal", "logical_and", "logical_or",
         "logical_not", "isfinite", "isnan", "maximum", "minimum", "sign"}
#: Reductions whose result does not depend on the order (no sums).
ORDERLESS = {"logical_and", "logical_or", "maximum", "minimum"}
FORBIDDEN_FUNCTIONS = {"dot", "vdot", "inner", "tensordot", "einsum", "trace", "cross"}


class BasicOnly(np.ndarray):
    """An array that refuses what another CPU computes otherwise: a ufunc not in BASIC, a reduction that sums, a
    function of numpy.linalg, a dot product."""

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if ufunc.__name__ not in BASIC or (method != "__call__" and ufunc.__name__ not in ORDERLESS):
            raise AssertionError(f"np.{ufunc.__name__}.{method} on a bundle's numbers: not the same bits on every CPU")
        plain = [np.asarray(x) if isinstance(x, BasicOnly) else x for x in inputs]
        out = getattr(ufunc, method)(*plain, **kwargs)
        return out.view(BasicOnly) if isinstance(out, np.ndarray) else out

    def __array_function__(self, func, types, args, kwargs):
        if func.__module__.startswith("numpy.linalg") or func.__name__ in FORBIDDEN_FUNCTIONS:
            raise AssertionError(f"np.{func.__name__} on a bundle's numbers: BLAS / LAPACK, not the same bits on "
                                 "every CPU")
        return super().__array_function__(func, types, args, kwargs)


def _trapped(bundle: Bundle) -> Bundle:
    cams = {n: replace(c, K=c.K.view(BasicOnly), dist=c.dist.view(BasicOnly), R=c.R.view(BasicOnly),
                       t_cm=c.t_cm.view(BasicOnly)) for n, c in bundle.cameras.items()}
    return replace(bundle, cameras=cams)


@pytest.fixture(scope="module")
def real_bundle(tmp_path_factory) -> Path:
    """Twelve cameras of the real Panoptic calibration (rotations orthonormal to ~1e-10: the export makes them
    exact)."""
    cameras, source = read_calibration(REAL_CALIBRATION)
    names = sorted(cameras)[::45]
    folder = tmp_path_factory.mktemp("real") / "bundle"
    write_bundle(Bundle(seq="real", cameras={n: cameras[n] for n in names}, calib_data_source=source), folder)
    return folder


def _refuse(*_args, **_kwargs):
    raise AssertionError("scipy's Rotation on a bundle's numbers: from_matrix orthonormalises by SVD (LAPACK)")


@pytest.mark.parametrize("fmt", EXPORT_FORMATS)
def test_every_exporter_computes_in_basic_operations_only(real_bundle, tmp_path, monkeypatch, fmt):
    for name in ("from_matrix", "from_quat", "from_rotvec"):
        monkeypatch.setattr(Rotation, name, _refuse)
    plain = tmp_path / "plain"
    export_bundle(real_bundle, fmt, plain)
    monkeypatch.setattr(convert, "load_bundle", lambda folder: _trapped(load_bundle(folder)))
    trapped = tmp_path / "trapped"
    export_bundle(real_bundle, fmt, trapped)
    files = sorted(p.relative_to(plain) for p in plain.rglob("*") if p.is_file()) if plain.is_dir() else [Path()]
    for rel in files:
        assert (plain / rel).read_bytes() == (trapped / rel).read_bytes(), rel


def test_the_trap_catches_what_differs_across_cpus():
    R = np.eye(3).view(BasicOnly)
    for bad in (lambda: R @ R, lambda: np.linalg.svd(R), lambda: np.dot(R, R), lambda: R.sum(),
                lambda: np.arctan2(R, R), lambda: np.linalg.norm(R)):
        with pytest.raises(AssertionError):
            bad()
    assert np.array_equal(exact.matmul3(R, R), np.eye(3))


def test_the_helpers_agree_with_numpy_and_scipy():
    rng = np.random.default_rng(0)
    R = np.concatenate([Rotation.random(2000, random_state=1).as_matrix(), np.eye(3)[None],
                        Rotation.from_rotvec([[np.pi, 0, 0], [0, np.pi - 1e-9, 0], [1e-12, 0, 0]]).as_matrix()])
    noisy = R + rng.normal(scale=1e-10, size=R.shape)  # as orthonormal as the Panoptic files' 10 digits
    U, _, Vt = np.linalg.svd(noisy)
    near = exact.nearest_rotation(noisy)
    assert np.abs(near - U @ Vt).max() < 1e-14
    assert np.abs(exact.matmul3(near, exact.transpose3(near)) - np.eye(3)).max() < 1e-15
    ours, theirs = exact.rotvec(R), Rotation.from_matrix(R).as_rotvec()
    assert np.minimum(np.abs(ours - theirs).max(-1), np.abs(ours + theirs).max(-1)).max() < 1e-14  # +-pi alike
    A, b = rng.normal(size=(50, 3, 3)), rng.normal(size=(50, 3)) * 300
    np.testing.assert_allclose(exact.matmul3(A, A), A @ A, rtol=0, atol=1e-14)
    np.testing.assert_allclose(exact.solve3(A, b), np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-9)
    t = rng.normal(size=(50, 3)) * 300
    R_exact, t_exact = exact.rotation_exact(noisy[:50], t)
    np.testing.assert_allclose(exact.centre(R_exact, t_exact), -np.linalg.solve(noisy[:50], t[..., None])[..., 0],
                               rtol=0, atol=1e-11)


def test_the_arctangent_is_within_two_units_in_the_last_place():
    rng = np.random.default_rng(2)
    s, c = rng.uniform(0, 1, 20000), rng.uniform(0, 1, 20000)
    s[:3], c[:3] = [0.0, 1.0, 1e-300], [1.0, 0.0, 1.0]
    ours = exact.atan_ratio(s, c)
    libm = np.array([math.atan2(y, x) for y, x in zip(s, c)])
    assert (np.abs(ours - libm) <= 2 * np.spacing(libm)).all()
    assert ours[0] == 0.0 and ours[1] == math.pi / 2


def test_every_exporter_is_compared_across_machines():
    from .hostile.same_bytes import writers
    assert {f"export-{fmt}" for fmt in EXPORT_FORMATS} <= {label for label, _ in writers()}
