"""People-out bench: body3DScene folders exported by `dome-calib export-people` to TRC, C3D and BVH and read back by
each format's own tools, and the people page's load time in Chromium.

Run: .venv/bin/python bench/people_out.py [--page-people 10] [--page-frames 3000] [--loads 3]
Prints one JSON object per line:
- ``machine``: the load average when the run starts (the machine may be shared);
- one line per (dataset, format): export seconds (wall), the files' size, and per peer reader the largest distance
  (cm) between what it reads and our joints (in the format's axes and units, converted back to cm): TRC through
  OpenSim's ``TRCFileAdapter`` and Pose2Sim's ``read_trc``; C3D through ezc3d and the ``c3d`` package; BVH through
  bvhio's forward kinematics, against the person's constant-bone skeleton (``bvh_vs_constant_bones_cm``: what the
  file holds) and against our joints where the whole chain to the root is reconstructed (``bvh_vs_ours_cm``:
  median, 95th percentile, max: the frame's bone lengths against their medians); joints compared; missing joints
  read back as missing (``missing_kept``);
- ``pose2sim_agreement``: the real capture's TRC against Pose2Sim's own TRC of the same detections (its own
  triangulation, a peer's result, not a truth), both y up in metres and in the same axes (our TRC of a bundle
  imported from a z-up lab is in the lab's world as Pose2Sim turns it): the median height difference per marker and
  the median 3D distance;
- ``page``: 10 people x 3,000 frames (the issue's size; synthetic walkers, 25 fps): the page's size, the seconds to
  build it, and per fresh load in headless Chromium the time until the page is ready (``ready_ms``, the aim is
  under 2 s) and the load event, then the frames advanced while playing ~2 s at 4 x (beside the number the clock
  asks for: 100 per second) and console errors.
Datasets: the demo's group (7 people, "mixed", its truth written as body3DScene files: constant bones), the same
group reconstructed from its synthetic OpenPose detections on the tiny dome, the real Pose2Sim capture reconstructed.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dome_calib.skeletons.bvh import constant_bone_body  # noqa: E402
from dome_calib.skeletons.export import export_people  # noqa: E402
from dome_calib.skeletons.joints import marker_names, y_up_axes, z_up_axes  # noqa: E402
from dome_calib.skeletons.scenes import read_people  # noqa: E402
from tests.people_helpers import group_joints_cm  # noqa: E402
from tests.skeletons_helpers import (DATA, bvhio_positions, c3d_package_read, chain_present,  # noqa: E402
                                     demo_group_reconstructed, demo_group_scenes, ezc3d_read, opensim_trc,
                                     ours_dense, pose2sim_trc, real_capture_scenes, write_scenes)


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def worst(got: np.ndarray, ours: np.ndarray, to_cm: float) -> float:
    return round(float(np.nanmax(np.abs(got - ours))) * to_cm, 7)


def sizes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.iterdir())


def bench_formats(name: str, folder: Path, work: Path) -> None:
    people = read_people(folder)
    for fmt in ("trc", "c3d", "bvh"):
        out = work / f"{name}_{fmt}"
        t0 = time.perf_counter()
        export_people(folder, fmt, out)
        seconds = time.perf_counter() - t0
        fields = {"dataset": name, "format": fmt, "people": len(people.tracks), "frames": len(people.frames),
                  "export_s": round(seconds, 3), "kB": round(sizes(out) / 1e3)}
        if fmt == "trc":
            worst_osim = worst_p2s = 0.0
            kept = True
            for pid, track in people.tracks.items():
                span = people.frames[track.rows[0]:track.rows[-1] + 1]
                ours = ours_dense(people, pid, span, y_up_axes(people), 0.01)
                (path,) = out.glob(f"*_P{pid}_*.trc")
                osim, p2s = opensim_trc(path), pose2sim_trc(path)
                worst_osim = max(worst_osim, worst(osim["X"], ours, 100.0))
                worst_p2s = max(worst_p2s, worst(p2s["X"], ours, 100.0))
                kept &= bool(np.array_equal(np.isnan(osim["X"]), np.isnan(ours)))
            fields |= {"opensim_max_cm": worst_osim, "pose2sim_max_cm": worst_p2s, "missing_kept": kept}
        elif fmt == "c3d":
            frames = np.arange(people.frames[0], people.frames[-1] + 1)
            ours = np.concatenate([ours_dense(people, pid, frames, z_up_axes(people), 10.0) for pid in people.tracks],
                                  axis=1)
            ez, pkg = ezc3d_read(out / "people.c3d"), c3d_package_read(out / "people.c3d")
            missing = np.isnan(ours).any(-1)
            fields |= {"ezc3d_max_cm": worst(ez["X"], ours, 0.1),
                       "c3d_package_max_cm": worst(np.where(missing[..., None], np.nan, pkg["X"]), ours, 0.1),
                       "missing_kept": bool(np.array_equal(np.isnan(ez["X"]), np.isnan(ours))
                                            and np.all(pkg["residual"][missing] == -1))}
        else:
            vs_const, gaps, n = 0.0, [], 0
            for pid, track in people.tracks.items():
                _, got_m = bvhio_positions(out / f"person{pid}.bvh", marker_names(people))
                got = got_m * 100.0  # the BVH is in metres
                first, ref = constant_bone_body(people, track, track.confidence >= 0)
                vs_const = max(vs_const, float(np.max(np.abs(got - ref))))
                ours = ours_dense(people, pid, np.arange(first, first + len(got)), y_up_axes(people), 1.0)
                held = chain_present(people, ours)
                gaps.append(np.linalg.norm(got - ours, axis=-1)[held])
                n += int(np.isfinite(ours).all(-1).sum())
            g = np.concatenate(gaps)
            fields |= {"bvh_vs_constant_bones_cm": round(vs_const, 7),
                       "bvh_vs_ours_cm": {"median": round(float(np.median(g)), 5),
                                          "p95": round(float(np.percentile(g, 95)), 5),
                                          "max": round(float(np.max(g)), 5)},
                       "joints_compared": int(len(g)), "joints_reconstructed": n}
        emit(**fields)


def pose2sim_agreement(folder: Path, work: Path) -> None:
    """Our TRC of the real capture against Pose2Sim's own TRC of the same detections."""
    export_people(folder, "trc", work / "real_vs_p2s")
    ours = opensim_trc(next((work / "real_vs_p2s").glob("*_P0_*.trc")))
    theirs = pose2sim_trc(DATA / "pose2sim_result" / "S00_P00_T01_BalancingTrial_0-100.trc")
    out = {}
    for m in ours["markers"]:
        if m not in theirs["markers"]:
            continue
        a = ours["X"][:, ours["markers"].index(m)]
        b = theirs["X"][:, theirs["markers"].index(m)]  # the same axes: ours of an imported z-up lab are Pose2Sim's
        out[m] = {"height_cm": round(float(np.nanmedian(a[:, 1] - b[:, 1])) * 100, 2),
                  "distance_cm": round(float(np.nanmedian(np.linalg.norm(a - b, axis=-1))) * 100, 2)}
    emit(pose2sim_agreement=out, note="Pose2Sim's own TRC of the same detections (a peer's triangulation), in the "
         "same axes; Neck and Head are BODY_25B's upper neck and head top in both")


def page_bench(n_people: int, n_frames: int, loads: int, work: Path) -> None:
    os.environ["SE_OFFLINE"] = "true"
    os.environ["SE_AVOID_STATS"] = "true"
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    from dome_calib.pipeline.people_page import build_people_page

    frames = np.arange(n_frames)
    X = group_joints_cm(frames * 40.0, n_people, seed=1)
    folder = write_scenes(work / "page_people", frames, frames * 40.0,
                          [{p: np.c_[X[k, p], np.full(19, 0.8)] for p in range(n_people)} for k in range(n_frames)])
    t0 = time.perf_counter()
    summary = build_people_page(folder)
    build_s = time.perf_counter() - t0
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1400,1000",
                f"--user-data-dir={work / 'chromium'}"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    try:
        runs = []
        for _ in range(loads):
            driver.get("about:blank")
            driver.get(summary.page.as_uri())
            WebDriverWait(driver, 60).until(lambda d: d.execute_script("return document.body.dataset.ready === '1'"))
            t = driver.execute_script("const n = performance.getEntriesByType('navigation')[0];"
                                      "return [window.__pageReady, n.loadEventEnd];")
            runs.append({"ready_ms": round(t[0]), "load_event_ms": round(t[1])})
        driver.execute_script("document.getElementById('speed').value = '4';"
                              "document.getElementById('speed').dispatchEvent(new Event('change'));")
        start = driver.execute_script("window.__t0 = performance.now(); document.getElementById('play').click();"
                                      "return window.peoplePage.frame()")
        time.sleep(2.0)
        end, elapsed_ms = driver.execute_script("const t = performance.now() - window.__t0;"
                                                "document.getElementById('play').click();"
                                                "return [window.peoplePage.frame(), t]")
        errors = [e["message"] for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    finally:
        driver.quit()
    emit(page={"people": n_people, "frames": n_frames, "page_MB": round(summary.page.stat().st_size / 1e6, 2),
               "build_s": round(build_s, 2), "loads": runs,
               "ready_ms_median": float(np.median([r["ready_ms"] for r in runs])),
               "playing_at_4x": {"seconds": round(elapsed_ms / 1000, 3), "frames_advanced": int(end - start),
                                 "expected": int(elapsed_ms / 1000 * 4 * 25)}, "console_errors": len(errors)})


class _Temp:
    """What demo_group_reconstructed asks of pytest's tmp_path_factory."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def getbasetemp(self) -> Path:
        return self.root


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--page-people", type=int, default=10)
    parser.add_argument("--page-frames", type=int, default=3000)
    parser.add_argument("--loads", type=int, default=3)
    args = parser.parse_args()
    emit(machine={"load_average_1min": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()})
    with tempfile.TemporaryDirectory(prefix="people_out_") as tmp:
        work = Path(tmp)
        group = demo_group_scenes(work / "group")
        reconstructed = demo_group_reconstructed(_Temp(work)) / "people"
        (work / "real").mkdir()
        real = real_capture_scenes(work / "real")
        for name, folder in (("demo group (truth)", group), ("demo group (reconstructed)", reconstructed),
                             ("real Pose2Sim capture", real)):
            bench_formats(name, folder, work)
        pose2sim_agreement(real, work)
        page_bench(args.page_people, args.page_frames, args.loads, work)


if __name__ == "__main__":
    main()
