"""Dense Cholesky factorisations past OpenBLAS's threaded bound run on one thread (issue 52's bundle adjustment).

OpenBLAS's threaded potrf (0.3.30, SkylakeX kernels, as bundled by scipy 1.17) packs a panel as wide as a thread's
share of the columns into the thread's fixed work buffer: on 2 threads a float64 system of 15,593 unknowns (the
two-dome bench's uncertainties, ``bench/ba.py --solve-phases --pair``) wrote past it and crashed the process
(SIGSEGV in potrf in isolation, twice; SIGBUS in ``free`` and ``munmap_chunk(): invalid pointer`` after it in the
bench). Every dense Cholesky of the bundle adjustment takes its thread count from
:func:`dome_calib.ba.blas.cholesky_threads`.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from dome_calib.ba import BAOptions, bundle_adjust, solution_uncertainty
from dome_calib.ba import blas
from dome_calib.ba.blas import cholesky_threads, get_blas_threads
from dome_calib.panoptic_io import read_calibration
from dome_calib.synth.ba_problem import SyntheticOptions, make_problem

CALIBRATION = Path(__file__).parent / "data" / "panoptic" / "calibration_160906_band1.json"


def test_the_bound_keeps_the_dome_threaded_and_the_two_domes_double_factor_on_one_thread():
    assert cholesky_threads(7_815, np.float64, 2) == 2  # the full dome's uncertainties
    assert cholesky_threads(15_600, np.float32, 2) == 2  # the two domes' single-precision solve factor
    assert cholesky_threads(15_593, np.float64, 2) == 1  # the two domes' uncertainties: crashed on 2 threads
    assert cholesky_threads(15_593, np.float64, 1) == 1


def test_the_uncertainties_factorise_with_the_bounded_thread_count(monkeypatch):
    if not get_blas_threads():
        pytest.skip("no OpenBLAS with thread control in this process")
    cams, _ = read_calibration(CALIBRATION)
    names = sorted(n for n in cams if not n.startswith("50_"))[:12]
    problem = make_problem([cams[n] for n in names], SyntheticOptions(
        n_points=300, target_observations=3000, noise_px=0.3, outlier_fraction=0.0, seed=5)).start
    result = bundle_adjust(problem, BAOptions(n_threads=2, compute_uncertainty=False, outlier_rounds=0))
    seen = []
    factor = scipy.linalg.cho_factor

    def recording(*a, **k):
        seen.append(get_blas_threads())
        return factor(*a, **k)

    monkeypatch.setattr(scipy.linalg, "cho_factor", recording)
    monkeypatch.setattr(blas, "CHOLESKY_PARALLEL_MAX_COLUMN_BYTES", 0)  # this small system as if past the bound
    solution_uncertainty(result, n_threads=2)
    monkeypatch.setattr(blas, "CHOLESKY_PARALLEL_MAX_COLUMN_BYTES", 10 ** 9)
    solution_uncertainty(result, n_threads=2)
    with blas.blas_threads(2):  # what each OpenBLAS gives when asked for 2 (one loaded under a 1-thread cap stays 1)
        reachable = get_blas_threads()
    assert 2 in reachable, reachable
    assert seen and all(n == 1 for n in seen[0]) and seen[-1] == reachable, (seen, reachable)


@pytest.mark.slow
def test_a_float64_system_of_the_two_domes_size_factorises_and_inverts(tmp_path):
    """~4 GB peak and ~1.5 min: the uncertainties' factorisation and inverse at 15,593 unknowns, in a child process (on
    2 threads without the bound it died in potrf)."""
    script = textwrap.dedent("""
        import numpy as np, scipy.linalg
        from scipy.linalg import lapack
        from dome_calib.ba.blas import blas_threads, cholesky_threads
        n = 15_593
        rng = np.random.default_rng(0)
        S = np.empty((n, n))
        for i in range(0, n, 2000):
            S[i:i + 2000] = rng.uniform(-1e-3, 1e-3, (min(2000, n - i), n))
        S = np.triu(S)
        S += np.triu(S, 1).T
        S[np.diag_indices(n)] += 10.0
        rows = S[[0, 7]].copy()  # rows 0 and 7 of S (symmetric): S x = e_7 for the inverse's column x
        with blas_threads(cholesky_threads(n, np.float64, 2)):
            c, _ = scipy.linalg.cho_factor(S.T, lower=False, overwrite_a=True, check_finite=False)
            inv, info = lapack.dpotri(c, lower=0, overwrite_c=1)
        assert info == 0
        x = np.concatenate([inv[:8, 7], inv[7, 8:]])  # the inverse's upper triangle holds it
        r = rows @ x
        assert abs(r[0]) < 1e-10 and abs(r[1] - 1.0) < 1e-10, r
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, (out.returncode, out.stderr[-2000:])
    assert out.stdout.startswith("ok")
