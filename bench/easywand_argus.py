"""easyWand's DLT import judged by argus' own DLT projection (argus_gui's ``tools.py``: ``dlt_inverse``).

argus_gui cannot be installed here without its GUI stack (pyglet, moviepy, sba, Pmw); its ``tools.py`` needs numpy,
cv2, scipy, tqdm and six only, so it is loaded from the wheel itself (``pip download argus_gui --no-deps``; six's
``moves.range`` is given as the built-in ``range``, which is what it is on Python 3). The DLT files are made from
real calibrations (the Panoptic dome's 480 VGA and 31 HD cameras, one file per image size; the real Pose2Sim trial's
4 cameras), their lens distortion left out (a DLT is linear), in mm; our import reads each, and per camera the worst
pixel difference between our camera and argus' ``dlt_inverse`` (its origin at the bottom left, turned to OpenCV's
rows: height - v) is taken over the grid of ``tests/interop_helpers.py`` (9 x 9 pixels to the corners, at 0.3, 3
and 30 m).

Run: .venv/bin/python bench/easywand_argus.py --argus-wheel argus_gui-2.1.dev3-py3-none-any.whl
Prints one JSON object per line: the setup (wheel, load), then per file the cameras and the worst px.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import tempfile
import types
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle import Camera  # noqa: E402
from dome_calib.interop.common import ImportOptions  # noqa: E402
from dome_calib.interop.convert import read_foreign  # noqa: E402
from dome_calib.panoptic_io import read_calibration  # noqa: E402
from tests.interop_helpers import dlt_columns, pixels, world_points_cm  # noqa: E402

REAL = ROOT / "tests" / "data" / "panoptic" / "calibration_160906_band1.json"
TRIAL = ROOT / "tests" / "data" / "pose2sim_balancing" / "calibration" / "Calib_qualisys.toml"


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def argus_tools(wheel: Path, work: Path):
    """argus_gui/tools.py of the wheel, loaded as a module (six.moves.range = range)."""
    with zipfile.ZipFile(wheel) as z:
        z.extract("argus_gui/tools.py", work)
    if "six" not in sys.modules:
        six = types.ModuleType("six")
        six.moves = types.SimpleNamespace(range=range)
        sys.modules["six"], sys.modules["six.moves"] = six, six.moves
    spec = importlib.util.spec_from_file_location("argus_tools", work / "argus_gui" / "tools.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def judge(label: str, cams: list[Camera], tools, work: Path) -> None:
    W, H = cams[0].resolution
    flat = [Camera(**{**c.__dict__, "dist": np.zeros(5)}) for c in cams]  # a DLT is linear
    L = dlt_columns(flat, H)
    path = work / f"{label}_dltCoefs.csv"
    np.savetxt(path, L, delimiter=",", fmt="%.17g")
    got, unit = read_foreign(path, "easywand", ImportOptions(image_size=(W, H), unit="mm", world_up="-y"))
    worst = 0.0
    for k, cam in enumerate(got.cameras.values()):
        X_cm = world_points_cm(cam)
        uv = tools.dlt_inverse(L[:, k], X_cm * 10.0)
        uv[:, 1] = H - uv[:, 1]
        worst = max(worst, float(np.abs(uv - pixels(cam, X_cm)).max()))
    emit(file=label, size=[int(W), int(H)], cameras=len(cams), unit=unit, worst_px=worst)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--argus-wheel", type=Path, required=True)
    args = ap.parse_args()
    emit(bench="easywand_argus", wheel=args.argus_wheel.name, load_average_1min=round(os.getloadavg()[0], 1))
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        tools = argus_tools(args.argus_wheel, work)
        cameras, _ = read_calibration(REAL)
        for kind in ("vga", "hd"):
            judge(f"panoptic_{kind}", [c for _, c in sorted(cameras.items()) if c.type.value == kind], tools, work)
        trial, _ = read_foreign(TRIAL, "pose2sim", ImportOptions(world_up="-y"))
        judge("pose2sim_balancing", list(trial.cameras.values()), tools, work)


if __name__ == "__main__":
    main()
