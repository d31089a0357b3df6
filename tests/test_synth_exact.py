"""The synthetic generators write the same bytes on every CPU: their truth and their pixels are computed in IEEE
basic operations (:mod:`dome_calib.exact`), never in what another CPU computes otherwise.

``bench/same_bytes.py --pairs older`` (this machine against an older x86-64 CPU as far as OpenBLAS, numpy and glibc
choose their code by CPU) found ``synth``'s ``projectors.json`` (5.7e-14 cm), its tent (1.4e-14 cm) and an image
(16 of 307,200 pixels one grey level apart), and ``kinect-synth``'s ``ground_truth.json`` (2.8e-14), differing:
``-R @ c`` and ``X @ R.T`` are BLAS products (OpenBLAS's Nehalem kernels sum without FMA), ``np.linalg.inv`` is
LAPACK, and the tone curve's ``x ** 0.625`` is Intel's SVML on an AVX-512 CPU (the image's 8-bit rounding then
flips a pixel whose value lies within its last bits of a half grey level). The rule, read from the source (AST):
in the modules that make ``synth``'s and ``kinect-synth``'s files no matrix product (``@``, ``np.dot``,
``np.einsum``, ...), no ``np.linalg`` and no SVML ufunc (``np.exp``, ``np.arctan2``, ``np.power``, a ``**`` by a
variable), but for the uses listed below, each with why.

The keypoint refinement of calibrate is held to it too (``projector/refine_images.py``: its window's ``np.exp``
made every refined keypoint, hence the bundle, differ with and without numpy's AVX-512 paths).

The sines and cosines are :func:`~dome_calib.exact.sincos`'s and the rotation vectors'
:func:`~dome_calib.exact.rotvec_matrix` (glibc's ``sin`` / ``cos``, and scipy's ``from_rotvec`` through
them, have variants with and without FMA that differ on some inputs). Not covered: what those modules call elsewhere
(``camera.project``, ``kinect.board``: their files were alike with and without each variable).
"""
from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import dome_calib
from dome_calib import exact
from dome_calib.synth.render import tone_curve

PACKAGE = Path(dome_calib.__file__).parent
#: The modules whose numbers reach ``synth``'s and ``kinect-synth``'s files (the truth, the rendered images).
MODULES = ("layout.py", "synth/dome.py", "synth/tent.py", "synth/rays.py", "synth/render.py",
           "synth/kinect_boards.py", "../projector/refine_images.py")  # and calibrate's keypoint refinement
#: numpy functions another CPU computes otherwise: BLAS / LAPACK products, Intel's SVML on AVX-512 CPUs.
CPU_CHOSEN = {"dot", "vdot", "inner", "tensordot", "einsum", "matmul", "arctan2", "arccos", "arcsin", "arctan",
              "exp", "expm1", "exp2", "log", "log1p", "log2", "log10", "power", "float_power", "tan", "sinh", "cosh",
              "tanh", "cbrt", "sin", "cos"}
#: Other calls whose last bits are the CPU's: scipy's rotations (the C library's sine and cosine, LAPACK's SVD).
OTHER_CPU_CHOSEN = ("rotvec_to_matrix", "matrix_to_rotvec", "Rotation.")

#: (module, function) -> how many such uses, and why they stay.
ALLOWED = {
    # the design's cameras on the arc between two panels (the tiny preset's HD and Kinect cameras): the arc's angle,
    # the point's latitude and azimuth; next to write out (exact has an arctangent, not yet arccos and arcsin)
    ("layout.py", "_arc_point_cm"): (3, "np.arccos, np.arcsin, np.arctan2 of the arc between two panels"),
    ("layout.py", "_nearest"): (1, "a distance for ties.order_by (quantised to 1 um before it chooses)"),
    ("layout.py", "check_dome_scale"): (1, "a median distance in a plausibility message"),
    ("synth/render.py", "trace"): (1, "markers' Gaussian spots (np.exp): the marker check's images, never synth's"),
    ("synth/render.py", "tone_curve"): (1, "a gamma that is not k / 2^m: np.power (the default 5 / 8 is exact)"),
}


def _name(node: ast.AST) -> str:
    return f"{_name(node.value)}.{node.attr}" if isinstance(node, ast.Attribute) else getattr(node, "id", "?")


def _uses(tree: ast.AST) -> dict[str, list[str]]:
    """Function (Class.method) -> the CPU-chosen operations in it."""
    out: dict[str, list[str]] = {}

    def visit(node: ast.AST, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.ClassDef)):
                visit(child, f"{where}.{child.name}" if where else child.name)
                continue
            what = None
            if isinstance(child, ast.BinOp) and isinstance(child.op, ast.MatMult):
                what = "@"
            elif isinstance(child, ast.BinOp) and isinstance(child.op, ast.Pow) and not isinstance(
                    child.right.operand if isinstance(child.right, ast.UnaryOp) else child.right, ast.Constant):
                what = "** a variable"
            elif isinstance(child, ast.Call):
                name = _name(child.func)
                if name.startswith(("np.linalg.", "numpy.linalg.", *OTHER_CPU_CHOSEN)) or (
                        name.startswith("np.") and name[3:] in CPU_CHOSEN):
                    what = name
            if what is not None:
                out.setdefault(where or "<module>", []).append(what)
            visit(child, where)

    visit(tree, "")
    return out


def _found() -> dict[tuple[str, str], list[str]]:
    found = {}
    for module in MODULES:
        for func, uses in _uses(ast.parse((PACKAGE / module).read_text(encoding="utf-8"))).items():
            found[(module, func)] = uses
    return found


def test_the_synthetic_truth_and_pixels_are_computed_in_basic_operations():
    found = _found()
    bad = {k: v for k, v in found.items() if k not in ALLOWED or len(v) != ALLOWED[k][0]}
    assert not bad, ("a product, np.linalg or an SVML ufunc where a synthetic file's numbers are made: write it with "
                     f"dome_calib.exact (or list it in ALLOWED, with why): {bad}")
    assert not set(ALLOWED) - set(found), f"ALLOWED lists uses that are gone: {sorted(set(ALLOWED) - set(found))}"


def test_the_rule_sees_what_it_refuses():
    code = ("def f(R, c, x, g):\n    a = -R @ c\n    b = np.linalg.inv(R)\n    d = np.einsum('ij,ij->i', x, x)\n"
            "    e = x ** g\n    return np.arctan2(a, b), x ** 2, np.sqrt(x), np.cross(x, x)\n")
    assert _uses(ast.parse(code)) == {"f": ["@", "np.linalg.inv", "np.einsum", "** a variable", "np.arctan2"]}


def test_the_power_the_exponential_and_the_sine_are_within_a_few_units_in_the_last_place():
    x = np.concatenate([np.random.default_rng(0).uniform(0.0, 1.0, 20000), [0.0, 1.0, 1e-300, 0.5]])
    for p in (0.625, 0.5, 1.0, 2.0, 3.25, 0.015625):
        ours = exact.power_dyadic(x, p)
        libm = np.array([math.pow(v, p) for v in x])
        assert (np.abs(ours - libm) <= 4 * np.spacing(np.maximum(libm, 1e-300))).all(), p
    with pytest.raises(ValueError):
        exact.power_dyadic(x, 1 / 2.2)
    e = np.concatenate([np.random.default_rng(1).uniform(-700.0, 700.0, 20000), [0.0, -0.5, 1.0]])
    libm = np.array([math.exp(v) for v in e])
    assert (np.abs(exact.exp(e) - libm) <= 2 * np.spacing(libm)).all()
    a = np.concatenate([np.random.default_rng(2).uniform(-1e5, 1e5, 20000), np.linspace(-7.0, 7.0, 2001)])
    for ours, f in zip(exact.sincos(a), (math.sin, math.cos)):
        libm = np.array([f(v) for v in a])
        assert (np.abs(ours - libm) <= np.maximum(2 * np.spacing(np.abs(libm)), 1.2e-16)).all()
    np.testing.assert_allclose(tone_curve(x, 1 / 2.2), x ** (1 / 2.2), rtol=0, atol=0)  # any other gamma: np.power


def test_the_helpers_are_the_products_they_replace():
    rng = np.random.default_rng(1)
    R, X = rng.normal(size=(3, 3)), rng.normal(size=(500, 3)) * 300
    np.testing.assert_allclose(exact.matvec3(R, X), X @ R.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(exact.dot3(X, X[::-1]), np.einsum("ij,ij->i", X, X[::-1]), rtol=1e-15, atol=1e-9)
    np.testing.assert_allclose(exact.norm3(X), np.linalg.norm(X, axis=1), rtol=1e-15)
    r = np.concatenate([Rotation.random(500, random_state=3).as_rotvec(), [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0]]])
    np.testing.assert_allclose(exact.rotvec_matrix(r), Rotation.from_rotvec(r).as_matrix(), rtol=0, atol=2e-15)
    f32 = X.astype(np.float32)
    assert exact.matvec3(R.astype(np.float32), f32).dtype == np.float32 and exact.dot3(f32, f32).dtype == np.float32
