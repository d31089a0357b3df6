"""The same bytes run to run, and what differs under another CPU's kernels: every command that writes, twice.

    .venv/bin/python bench/same_bytes.py [--work /tmp/same_bytes] [--kernels Haswell,SkylakeX]
                                         [--pairs run,kernels,older,switches] [--writers synth,triangulate]

Runs ``tests/hostile/same_bytes.py``'s two processes (every command of the hostile catalogue that writes, on
the matrix's small inputs, ``export`` to every format; calibrate on five VGA cameras of ``data/synthetic/tiny``)
as pairs (``--pairs``, default ``run,kernels``):

- ``run``: both on this machine as it is (run to run: every file must be the same);
- ``kernels``: one with ``OPENBLAS_CORETYPE`` set to each of ``--kernels`` (OpenBLAS's kernels of two CPUs);
- ``older``: this machine against an older x86-64 CPU as far as the libraries choose by CPU: OpenBLAS's Nehalem
  kernels (SSE only), numpy without its AVX-512 paths (``NPY_DISABLE_CPU_FEATURES``: on AVX-512 numpy takes
  Intel's SVML for ``arctan2``, ``arccos``, ``exp``, ``log``, ...) and glibc's maths without its AVX2 / FMA
  variants (``GLIBC_TUNABLES=glibc.cpu.hwcaps``: ``math.atan2``, ``np.sin``). OpenBLAS's kernels alone do not show
  the other two;
- ``switches``: this machine against each of ``older``'s three variables alone (which library's CPU-chosen path
  makes a file differ).

``--writers`` runs only those (labels as in ``tests/hostile/same_bytes.writers``: ``synth``, ``export-colmap``).

The variables are set only for those children: a diagnostic of other CPUs, never in tests or CI. One JSON object
per line: per pair of runs, the commands' exit codes and seconds, the files that differ (after the test's
normalisation: timings, the run's folder, ownership hashes), and for a JSON file that differs the largest
difference of any number in it.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.hostile.inputs import build_inputs  # noqa: E402
from tests.hostile.same_bytes import Runs, run_twice  # noqa: E402
from kernels import _untimed, json_numbers  # noqa: E402  (numbers in a fixed order, less timings: as bench/kernels.py)


def emit(**obj) -> None:
    print(json.dumps(obj), flush=True)


def _largest(runs: Runs, rel: str) -> float | None:
    """The largest difference of any number (timings left out) in a JSON file both runs wrote with the same shape
    (else None)."""
    paths = [files.get(rel) for files in runs.files]
    if rel[-5:] != ".json" or None in paths:
        return None
    a, b = (json_numbers(_untimed(json.loads(p.read_text(encoding="utf-8")))) for p in paths)
    if len(a) != len(b) or not a:
        return None
    return max(abs(x - y) for x, y in zip(a, b))


def _report(what: str, runs: Runs) -> None:
    differ = runs.differing()
    emit(what=what, codes=dict(zip(runs.labels, zip(*runs.codes))),
         seconds=dict(zip(runs.labels, zip(*runs.seconds))), files=sum(len(f) for f in runs.files) // 2,
         differ=differ, largest={rel: _largest(runs, rel) for rel in differ})


#: An older x86-64 CPU, as far as OpenBLAS, numpy and glibc choose their code by CPU (see the docstring).
OLDER_CPU = {"OPENBLAS_CORETYPE": "Nehalem",
             "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR AVX512F AVX512_SKX",  # numpy 2.4 and 1.x names
             "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX512F,-AVX2,-FMA,-AVX"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=None, help="folder for the runs (default: a temporary one)")
    parser.add_argument("--kernels", default="Haswell,SkylakeX", help="two OPENBLAS_CORETYPE values")
    parser.add_argument("--pairs", default="run,kernels", help="comma-separated: run, kernels, older, switches")
    parser.add_argument("--writers", default=None, help="comma-separated labels: only these writers (default all)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="same_bytes_"))
    shutil.rmtree(work, ignore_errors=True)
    inputs = build_inputs(work / "inputs")
    pairs = args.pairs.split(",")
    only = frozenset(args.writers.split(",")) if args.writers else None
    if "run" in pairs:
        _report("run to run", run_twice(inputs, work / "same", only=only))
    if "kernels" in pairs:
        kernels = args.kernels.split(",")
        _report(f"kernels {kernels[0]} / {kernels[1]}",
                run_twice(inputs, work / "kernels", envs=tuple({"OPENBLAS_CORETYPE": k} for k in kernels), only=only))
    if "older" in pairs:
        _report("this CPU / an older one (OpenBLAS Nehalem, numpy without AVX-512, glibc without AVX2/FMA)",
                run_twice(inputs, work / "older", envs=({}, OLDER_CPU), only=only))
    if "switches" in pairs:
        for key, value in OLDER_CPU.items():
            _report(f"this CPU / {key}={value} alone",
                    run_twice(inputs, work / key, envs=({}, {key: value}), only=only))


if __name__ == "__main__":
    main()
