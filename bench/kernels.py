"""Same result on every machine: the tiny dome synthesised and calibrated under two OpenBLAS kernel sets.

    .venv/bin/python bench/kernels.py [--preset tiny] [--work /tmp/dome_kernels] [--stages calibrate,demo,patches]

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

``--stages`` adds the stages after calibration (default: all three):

- ``demo``: ``dome-calib demo`` (synthesis, calibration, the group of people reconstructed and judged) under each
  kernel set: every file it writes (its work folders left out) compared, JSON by its numbers (less timings), the
  others by their bytes, each run's own folder written alike in both;
- ``patches``: the patch trajectory stream (``bench/patches.py --save``: 8 VGA cameras, one person, 3 frames each
  way, seeded from images) under each: every saved array identical or not, and the largest difference.
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


def json_numbers(obj) -> list[float]:
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return []
    if isinstance(obj, (int, float)):
        return [float(obj)]
    if isinstance(obj, dict):
        return [x for k in sorted(obj) for x in json_numbers(obj[k])]
    return [x for v in obj for x in json_numbers(v)]


def _json_diff(a: Path, b: Path, drop: tuple[str, ...] = ()) -> dict:
    ja, jb = (json.loads(p.read_text(encoding="utf-8")) for p in (a, b))
    for key in drop:
        ja.pop(key, None), jb.pop(key, None)
    return _compare(ja, jb)


def _compare(ja, jb) -> dict:
    """Two JSON values: identical or not, the same structure (strings and shape) or not, the largest difference of
    any number in them (None where the structure differs)."""
    na, nb = json_numbers(ja), json_numbers(jb)
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
    parser.add_argument("--stages", default="calibrate,demo,patches",
                        help="comma-separated: calibrate (bench/dome.py), demo (dome-calib demo), patches")
    args = parser.parse_args()
    work = Path(args.work)
    stages = set(args.stages.split(","))
    if "calibrate" in stages:
        calibrate_stage(args.preset, work)
    if "demo" in stages:
        demo_stage(work)
    if "patches" in stages:
        patches_stage(work)


def calibrate_stage(preset: str, work: Path) -> None:
    """The preset synthesised and calibrated under each kernel set (bench/dome.py), compared."""
    presets = {}
    for k in KERNELS:
        presets[k] = json.loads(_child(k, "import json; from dome_calib.layout import all_nominal_cameras, "
                                          f"select_preset; print(json.dumps(select_preset(all_nominal_cameras(0), "
                                          f"'{preset}')))"))
    emit(bench="kernels", stage="preset", preset=preset, cameras={k: len(v) for k, v in presets.items()},
         identical=presets[KERNELS[0]] == presets[KERNELS[1]])
    for k in KERNELS:
        env = dict(os.environ, OPENBLAS_CORETYPE=k)
        out = subprocess.run([sys.executable, str(ROOT / "bench" / "dome.py"), "--preset", preset,
                              "--work", str(work / k)], env=env, check=True, capture_output=True, text=True)
        lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
        figures = {d["stage"]: {key: v for key, v in d.items() if key not in ("bench", "stage", "preset", "sfm", "ba")}
                   for d in lines if d.get("stage") in ("accuracy", "oracle", "ratios")}
        emit(bench="kernels", stage="run", kernel=k, **figures)
    a, b = (work / k / preset for k in KERNELS)
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


def _run(kernel: str, argv: list[str]) -> str:
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel)
    return subprocess.run(argv, env=env, check=True, capture_output=True, text=True, cwd=ROOT).stdout


def _untimed(obj):
    """A JSON value less what records how long things took (any key naming seconds)."""
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if "second" not in k}
    if isinstance(obj, list):
        return [_untimed(v) for v in obj]
    return obj


def demo_stage(work: Path) -> None:
    """``dome-calib demo`` under each kernel set; every file it wrote compared (each run's own folder written as
    ``<out>`` in both: pages and records name where they were written)."""
    for k in KERNELS:
        _run(k, [sys.executable, "-c", "from dome_calib.cli import main; main()", "demo", "--out",
                 str(work / k / "demo")])
    a, b = (work / k / "demo" for k in KERNELS)
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and ".work" not in str(p.relative_to(a)))
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file() and ".work" not in str(p.relative_to(b)))
    differ, worst = [], 0.0
    for rel in sorted(set(files_a) & set(files_b)):
        da, db = ((root / rel).read_bytes().replace(str(root).encode(), b"<out>") for root in (a, b))
        if da == db:
            continue
        if rel.suffix == ".json":
            d = _compare(*(_untimed(json.loads(x)) for x in (da, db)))
            differ.append({"file": str(rel), "same_structure": d["same_structure"],
                           "max_abs_difference": d["max_abs_difference"]})
            worst = max(worst, d["max_abs_difference"] or 0.0)
        else:
            differ.append({"file": str(rel), "bytes_differ": True})
    emit(bench="kernels", stage="demo", files=len(files_a), same_files=files_a == files_b,
         identical=len(files_a) - len(differ), differing=differ, max_abs_difference=worst)


def patches_stage(work: Path) -> None:
    """The patch stream of a small rendered capture under each kernel set; the saved arrays compared."""
    for k in KERNELS:
        (work / k).mkdir(parents=True, exist_ok=True)
        _run(k, [sys.executable, str(ROOT / "bench" / "patches.py"), "--vga", "8", "--hd", "0", "--kinect", "0",
                 "--people", "1", "--frames", "3", "--seeding", "images", "--save", str(work / k / "patches.npz")])
    za, zb = (np.load(work / k / "patches.npz") for k in KERNELS)
    rows = {}
    for key in sorted(set(za.files) | set(zb.files)):
        if key not in za.files or key not in zb.files or za[key].shape != zb[key].shape:
            rows[key] = {"identical": False, "same_shape": False}
            continue
        x, y = za[key], zb[key]
        same = bool(np.array_equal(x, y, equal_nan=x.dtype.kind == "f"))
        diff = (float(np.nanmax(np.abs(x.astype(float) - y.astype(float)))) if not same and x.dtype.kind in "fiub"
                and x.size else None)
        rows[key] = {"identical": same, "max_abs_difference": diff}
    emit(bench="kernels", stage="patches", arrays=rows, identical=all(r["identical"] for r in rows.values()))


if __name__ == "__main__":
    main()
