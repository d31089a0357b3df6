"""Issue 50: the package installed as users have it (its folders read-only, no writable home, NUMBA_CACHE_DIR unset)
imports and runs, numba compiling without its cache and saying so once. Before (main at aaf6910): importing any
module with a compiled kernel raised `RuntimeError: cannot cache function ...: no locator available`.

The package is copied to a folder that cannot be written: read-only permissions for a user, and for root (who
writes through permissions) a read-only bind mount in a mount namespace of the test's own (`unshare -m`)."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dome_calib", "projector", "timecode")

RUN = """
import numpy as np
import dome_calib.ba.blocks, dome_calib.ba.yyt, dome_calib.recon.people.compiled, dome_calib.recon.kernel
import projector.refine_images
from dome_calib.ba.submatrix import submatrix
S = np.arange(16.0).reshape(4, 4)
assert (submatrix(S, np.array([0, 2]), n_threads=1) == S[np.ix_([0, 2], [0, 2])]).all()
print("ran")
"""


def _copy(tmp_path: Path) -> Path:
    site = tmp_path / "site"
    for name in PACKAGES:
        shutil.copytree(ROOT / name, site / name, ignore=shutil.ignore_patterns("__pycache__"))
    (site / "home").mkdir()
    return site


def _run_readonly(site: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "PYTHONPATH")}
    env.update(PYTHONPATH=str(site), HOME=str(site / "home"), PYTHONDONTWRITEBYTECODE="1")
    python = [sys.executable, "-c", RUN]
    if os.geteuid() != 0:
        for p in [site, *site.rglob("*")]:
            p.chmod(p.stat().st_mode & ~0o222)
        return subprocess.run(python, capture_output=True, text=True, env={**env, "HOME": "/nonexistent"},
                              cwd=site.parent, timeout=600)
    if shutil.which("unshare") is None:
        pytest.skip("root without unshare: no way to make a folder read-only for root")
    mount = f"mount --bind {site} {site} && mount -o remount,bind,ro {site} && exec \"$@\""
    out = subprocess.run(["unshare", "-m", "sh", "-c", mount, "sh", *python], capture_output=True, text=True,
                         env=env, cwd=site.parent, timeout=600)  # not this checkout's folder: `-c` puts it first
    if "mount:" in out.stderr or "unshare:" in out.stderr:
        pytest.skip(f"no mount namespace here: {out.stderr.strip()[:200]}")
    return out


def test_the_package_imports_and_runs_read_only_without_a_home(tmp_path):
    out = _run_readonly(_copy(tmp_path))
    assert out.returncode == 0 and out.stdout.strip() == "ran", out.stderr[-3000:]
    said = [line for line in out.stderr.splitlines() if "numba's cache" in line]
    assert len(said) == 1 and "NUMBA_CACHE_DIR" in said[0], out.stderr
    assert not list((tmp_path / "site").rglob("*.nbi"))  # nothing was written


def test_every_kernel_goes_through_the_one_decorator():
    """The rule held for the whole code: numba.njit(cache=True) anywhere else fails a read-only install."""
    found = [f"{p.relative_to(ROOT)}:{i}" for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))
             if p.name != "jit.py"
             for i, line in enumerate(p.read_text().splitlines(), 1) if re.search(r"numba\.(n?jit|vectorize)", line)]
    assert found == [], f"use dome_calib.jit.njit: {found}"
