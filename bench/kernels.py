"""Same result on every machine: the tiny dome synthesised and calibrated under two OpenBLAS kernel sets.

    .venv/bin/python bench/kernels.py [--preset tiny] [--work /tmp/dome_kernels]

Another CPU makes OpenBLAS pick other kernels (and numpy other SIMD paths), so floats differ in their last
bits. This diagnostic runs ``bench/dome.py`` (synthesis of the dome as built, `calibrate` from the design, the
oracle) once with ``OPENBLAS_CORETYPE=Haswell`` and once with ``SkylakeX`` in separate processes (the variable
is set only for those children: never in tests or CI), then compares what they made. One JSON object per line:

- ``run``: per kernel set, the accuracy against the truth and the oracle's, as bench/dome.py prints them;
- ``preset``: the preset's camera set under each kernel set (must be identical);
- ``capture``: capture.json (timings and the layout path left out) and the ground-truth files: identical bytes or not, and the
  largest difference of any number in them; the rendered images: how many are byte-identical and the largest
  grey-level difference of the others;
- ``bundle``: camera names identical or not; largest centre (mm), rotation (deg) and focal (%) difference
  between the two calibrations (aim: centres within 0.1 mm).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle_io import load_bundle  # noqa: E402
from dome_calib.compare import camera_error  # noqa: E402

KERNELS = ("Haswell", "SkylakeX")


def emit(**obj) -> None:
    print(json.dumps(obj), flush=True)


def _child(kernel: str, code: str) -> str:
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel)
    return subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True,
                          cwd=ROOT).stdout


def _numbers(obj) -> list[float]:
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return []
    if isinstance(obj, (int, float)):
        return [float(obj)]
    if isinstance(obj, dict):
        return [x for k in sorted(obj) for x in _numbers(obj[k])]
    return [x for v in obj for x in _numbers(v)]


def _json_diff(a: Path, b: Path, drop: tuple[str, ...] = ()) -> dict:
    ja, jb = (json.loads(p.read_text(encoding="utf-8")) for p in (a, b))
    for key in drop:
        ja.pop(key, None), jb.pop(key, None)
    na, nb = _numbers(ja), _numbers(jb)
    same_shape = len(na) == len(nb) and json.dumps(_strings(ja)) == json.dumps(_strings(jb))
    return {"identical": ja == jb, "same_structure": same_shape,
            "max_abs_difference": float(np.max(np.abs(np.subtract(na, nb)))) if same_shape and na else None}


def _strings(obj):
    if isinstance(obj, dict):
        return {k: _strings(v) for k, v in sorted(obj.items())}
    if isinstance(obj, list):
        return [_strings(v) for v in obj]
    return obj if isinstance(obj, str) else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="tiny", choices=["tiny", "panel"])
    parser.add_argument("--work", default="/tmp/dome_kernels")
    args = parser.parse_args()
    work = Path(args.work)
    presets = {}
    for k in KERNELS:
        presets[k] = json.loads(_child(k, "import json; from dome_calib.layout import all_nominal_cameras, "
                                          f"select_preset; print(json.dumps(select_preset(all_nominal_cameras(0), "
                                          f"'{args.preset}')))"))
    emit(bench="kernels", stage="preset", preset=args.preset, cameras={k: len(v) for k, v in presets.items()},
         identical=presets[KERNELS[0]] == presets[KERNELS[1]])
    for k in KERNELS:
        env = dict(os.environ, OPENBLAS_CORETYPE=k)
        out = subprocess.run([sys.executable, str(ROOT / "bench" / "dome.py"), "--preset", args.preset,
                              "--work", str(work / k)], env=env, check=True, capture_output=True, text=True)
        lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
        figures = {d["stage"]: {key: v for key, v in d.items() if key not in ("bench", "stage", "preset", "sfm", "ba")}
                   for d in lines if d.get("stage") in ("accuracy", "oracle", "ratios")}
        emit(bench="kernels", stage="run", kernel=k, **figures)
    a, b = (work / k / args.preset for k in KERNELS)
    cap = {"capture_json": _json_diff(a / "capture/capture.json", b / "capture/capture.json",
                                      drop=("seconds", "layout")),  # timings and the work path differ
           "ground_truth": _json_diff(next((a / "capture/ground_truth").glob("calibration_*.json")),
                                      next((b / "capture/ground_truth").glob("calibration_*.json"))),
           "projectors": _json_diff(a / "capture/ground_truth/projectors.json",
                                    b / "capture/ground_truth/projectors.json")}
    images = sorted((a / "capture/scenes").glob("*/*.png"))
    same, worst = 0, 0
    for p in images:
        q = b / "capture/scenes" / p.parent.name / p.name
        if p.read_bytes() == q.read_bytes():
            same += 1
        else:
            ia, ib = (cv2.imread(str(x), cv2.IMREAD_UNCHANGED).astype(int) for x in (p, q))
            worst = max(worst, int(np.abs(ia - ib).max()))
    emit(bench="kernels", stage="capture", **cap, images=len(images), images_identical=same,
         images_max_grey_difference=worst)
    ba, bb = (load_bundle(x / "bundle") for x in (a, b))
    names_same = sorted(ba.cameras) == sorted(bb.cameras)
    errs = [camera_error(ba.cameras[n], bb.cameras[n]) for n in sorted(set(ba.cameras) & set(bb.cameras))]
    emit(bench="kernels", stage="bundle", cameras_identical=names_same, cameras=len(errs),
         center_mm_max=max(e.center_cm for e in errs) * 10, rotation_deg_max=max(e.rotation_deg for e in errs),
         focal_pct_max=max(e.focal_pct for e in errs),
         aim_met=names_same and max(e.center_cm for e in errs) * 10 < 0.1)


if __name__ == "__main__":
    main()
