"""Every interop format judged by its peer's own code on the real 520-camera Panoptic calibration.

Run: .venv/bin/python bench/interop.py [--blender-cameras 520]

For each format and direction, the peer's code reads our file (export) or writes the file we read (import), and
the worst pixel difference between the peer's camera and ours is taken over a 9 x 9 grid of pixels reaching the
image corners, at 0.3, 3 and 30 m along each pixel's ray (``tests/interop_helpers.py``). Where a peer cannot be
installed here (nerfstudio and EasyMocap need torch, Kalibr needs ROS), its code is followed as read (the test
helpers name the file and commit). Also: what each format loses, in pixels at the image corners, and the two
figures of issue 41's defects (nerfstudio's centring offset divided by applied_scale; Pose2Sim's k3).

Prints one JSON object per line: a setup line (machine load, commit, peer versions), then one line per format and
direction.
"""
from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle import Bundle, Camera  # noqa: E402
from dome_calib.bundle_io import load_bundle, write_bundle  # noqa: E402
from dome_calib.interop.common import (CM_PER_UNIT, PANOPTIC_FROM_UP, ExportOptions, ForeignCamera,  # noqa: E402
                                       ImportOptions, corner_shift_px)
from dome_calib.interop.convert import export_bundle, import_calibration, read_foreign  # noqa: E402
from dome_calib.panoptic_io import read_calibration  # noqa: E402
from tests.interop_helpers import (calib_intri_extri, gaps_px, in_cam0_frame, kalibr_camchain,  # noqa: E402
                                   nerfstudio_round_trip, pixels, projection_gap_worst_px, world_points_cm)

REAL = ROOT / "tests" / "data" / "panoptic" / "calibration_160906_band1.json"
QCA = ROOT / "tests" / "data" / "pose2sim_qualisys" / "Calib.qca.txt"
ZUP_M = PANOPTIC_FROM_UP["+z"] / 100.0  # our point (cm, row) @ ZUP_M: the same point in a z-up world, metres


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def worst_opencv(cams: list[Camera], rvecs, tvecs, Ks, dists, cm_to_file=ZUP_M) -> float:
    """Worst px between ours and OpenCV's projectPoints on the peer's reading of each camera."""
    worst = 0.0
    for cam, r, t, K, d in zip(cams, rvecs, tvecs, Ks, dists):
        X = world_points_cm(cam)
        uv, _ = cv2.projectPoints(X @ cm_to_file, np.asarray(r, float), np.asarray(t, float), np.asarray(K, float),
                                  np.asarray(d, float))
        worst = max(worst, float(np.abs(uv.reshape(-1, 2) - pixels(cam, X)).max()))
    return worst


def without(cam: Camera, k3: bool = False, all_terms: bool = False) -> Camera:
    dist = np.zeros(5) if all_terms else np.array([*cam.dist[:4], 0.0]) if k3 else cam.dist
    return Camera(**{**cam.__dict__, "dist": dist})


def corner_range(cams: list[Camera], kept) -> list[float]:
    shifts = [corner_shift_px(ForeignCamera(name=c.name, size=c.resolution, K=c.K, dist=c.dist, R=c.R, t=c.t_cm),
                              kept(c)) for c in cams]
    return [round(min(shifts), 3), round(max(shifts), 3)]


# --------------------------------------------------------------------------------------------- export: peers read
def export_rows(folder: Path, bundle: Bundle, work: Path, blender_cameras: int) -> None:
    cams = list(bundle.cameras.values())
    n = len(cams)

    import pycolmap
    export_bundle(folder, "colmap", work / "model")
    rec = pycolmap.Reconstruction(str(work / "model"))
    worst = 0.0
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        cam = bundle.cameras[image.name.removesuffix(".png")]
        X = world_points_cm(cam)
        uv = rec.cameras[image.camera_id].img_from_cam(image.cam_from_world() * (X / 100.0)) - 0.5
        worst = max(worst, float(np.abs(uv - pixels(cam, X)).max()))
    emit(format="colmap", direction="export", peer=f"pycolmap {version('pycolmap')} Reconstruction + img_from_cam",
         cameras=n, worst_px=worst, lost="points3D (the bundle keeps residuals, not points)", said="printed")

    from aniposelib.cameras import CameraGroup
    export_bundle(folder, "aniposelib", work / "calibration.toml")
    group = CameraGroup.load(str(work / "calibration.toml"))
    worst = max(float(np.abs(p.project(world_points_cm(c) * 10.0).reshape(-1, 2)
                             - pixels(c, world_points_cm(c))).max()) for p, c in zip(group.cameras, cams))
    emit(format="aniposelib", direction="export", peer=f"aniposelib {version('aniposelib')} CameraGroup.load + "
         "Camera.project", cameras=len(group.cameras), worst_px=worst, lost="nothing", said="")

    from Pose2Sim.common import retrieve_calib_params
    export_bundle(folder, "pose2sim", work / "Calib.toml")
    p = retrieve_calib_params(work / "Calib.toml")
    emit(format="pose2sim", direction="export", peer=f"pose2sim {version('pose2sim')} retrieve_calib_params + "
         "OpenCV", cameras=len(p["K"]), worst_px=worst_opencv(cams, p["R"], p["T"], p["K"], p["dist"]),
         lost="nothing (k3 kept: 5 terms)", said="",
         k3_dropped_before_corner_px_hd=corner_range([c for c in cams if c.name.startswith("00_")],
                                                      lambda c: [*c.dist[:4], 0.0]))

    export_bundle(folder, "easymocap", work / "emc")
    intri = cv2.FileStorage(str(work / "emc" / "intri.yml"), cv2.FILE_STORAGE_READ)
    extri = cv2.FileStorage(str(work / "emc" / "extri.yml"), cv2.FILE_STORAGE_READ)
    names = [c.name for c in cams]
    worst = worst_opencv(cams, [extri.getNode(f"R_{k}").mat() for k in names],
                         [extri.getNode(f"T_{k}").mat() for k in names], [intri.getNode(f"K_{k}").mat() for k in names],
                         [intri.getNode(f"dist_{k}").mat() for k in names])
    emit(format="easymocap", direction="export", peer="EasyMocap read_camera as read (zju3dv/EasyMocap "
         "mytools/camera_utils.py @ 0ebb1d25) with cv2.FileStorage + OpenCV", cameras=n, worst_px=worst,
         lost="nothing", said="", world="z up (EasyMocap's)")

    for unit in ("mm", "cm", "m"):
        export_bundle(folder, "nerfstudio", work / f"transforms_{unit}.json", ExportOptions(unit=unit))
        frame_names, back = nerfstudio_round_trip(work / f"transforms_{unit}.json")
        doc = {f["camera_name"]: f for f in json.loads((work / f"transforms_{unit}.json").read_text())["frames"]}
        worst, worst_cm = 0.0, 0.0
        for name, pose in zip(frame_names, back):
            cam, f = bundle.cameras[name], doc[name]
            R, centre_cm = pose[:3, :3].T, pose[:3, 3] * CM_PER_UNIT[unit]
            worst_cm = max(worst_cm, float(np.linalg.norm(centre_cm - cam.center_cm)))
            X = world_points_cm(cam)
            K = np.array([[f["fl_x"], 0, f["cx"] - 0.5], [0, f["fl_y"], f["cy"] - 0.5], [0, 0, 1]])
            uv, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], -R @ centre_cm, K,
                                      np.array([f["k1"], f["k2"], f["p1"], f["p2"], f["k3"]]))
            worst = max(worst, float(np.abs(uv.reshape(-1, 2) - pixels(cam, X)).max()))
        old = {}
        if unit == "m":
            body = json.loads((work / "transforms_m.json").read_text())
            (work / "old.json").write_text(json.dumps(body | {"applied_scale": 0.01}))
            old_names, old_back = nerfstudio_round_trip(work / "old.json")
            off = np.linalg.norm(old_back[:, :3, 3] - np.array([bundle.cameras[k].center_cm for k in old_names]),
                                 axis=1)
            old = {"before_applied_scale_0p01_median_cm_off": round(float(np.median(off)), 1)}
        emit(format="nerfstudio", direction="export", unit=unit, peer="nerfstudio dataparser + "
             "transform_poses_to_original_space as read (nerfstudio_dataparser.py @ 01595f7f, camera_utils.py @ "
             "0079b674, base_dataparser.py @ c0464f8a), float64", cameras=n, worst_px=worst,
             worst_camera_centre_cm=worst_cm, lost="nothing", said="", **old)

    result = export_bundle(folder, "blender", work / "dome.py")
    subset = cams[:blender_cameras]
    points = {c.name: (world_points_cm(c) @ ZUP_M).tolist() for c in subset}
    (work / "points.json").write_text(json.dumps(points))
    probe = (ROOT / "tests" / "test_interop_peers.py").read_text().split('_BPY_PROBE = """')[1].split('"""')[0]
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", probe, str(work / "dome.py"), str(work / "points.json")],
                         capture_output=True, text=True, timeout=3600)
    if run.returncode != 0:
        emit(format="blender", direction="export", error=run.stderr[-500:])
        return
    uv = json.loads(run.stdout.split("RESULT", 1)[1])
    worst = max(float(np.abs(np.array(uv[c.name]) - pixels(without(c, all_terms=True), world_points_cm(c))).max())
                for c in subset)
    shifts = list(result.corner_shift_px.values())
    emit(format="blender", direction="export", peer=f"Blender (bpy {version('bpy')}) runs the script; "
         "world_to_camera_view", cameras=len(subset), worst_px_vs_our_pinhole=worst,
         seconds_in_blender=round(time.perf_counter() - start, 1),
         lost="lens distortion (Blender's camera is a pinhole)",
         said=f"per camera, the corner point's shift: {min(shifts):.1f} to {max(shifts):.1f} px")


# -------------------------------------------------------------------------------------------- import: peers write
def import_rows(bundle: Bundle, work: Path) -> None:
    cams = list(bundle.cameras.values())
    n = len(cams)

    def compare(src, fmt, truth: list[Camera], **options) -> float:
        """By name where the file keeps ours (aniposelib's load sorts its tables as strings: cam_0, cam_1, cam_10,
        ..., and so does our import), else in order (caliscope names cam_<id>)."""
        got, _ = read_foreign(src, fmt, ImportOptions(**options))
        found = ([got.cameras[c.name] for c in truth] if all(c.name in got.cameras for c in truth)
                 else list(got.cameras.values()))
        return projection_gap_worst_px(truth, found)

    from aniposelib.cameras import Camera as AniCamera
    from aniposelib.cameras import CameraGroup
    group = CameraGroup([AniCamera(matrix=c.K, dist=c.dist, size=c.resolution, rvec=cv2.Rodrigues(c.R)[0].ravel(),
                                   tvec=c.t_cm * 10.0, name=c.name) for c in cams])
    group.dump(str(work / "anipose.toml"))
    emit(format="aniposelib", direction="import", peer=f"aniposelib {version('aniposelib')} CameraGroup.dump",
         cameras=n, worst_px=compare(work / "anipose.toml", "aniposelib", cams, unit="mm"),
         lost="nothing (its unit is not recorded: --unit)", said="")

    from Pose2Sim.calibration import toml_write
    zup = [c.R @ PANOPTIC_FROM_UP["+z"] for c in cams]
    toml_write(str(work / "p2s.toml"), [c.name for c in cams], [list(map(float, c.resolution)) for c in cams],
               [c.dist for c in cams], [c.K for c in cams], [cv2.Rodrigues(R)[0].ravel() for R in zup],
               [c.t_cm / 100.0 for c in cams])
    emit(format="pose2sim", direction="import", peer=f"pose2sim {version('pose2sim')} toml_write", cameras=n,
         worst_px=compare(work / "p2s.toml", "pose2sim", [without(c, k3=True) for c in cams]),
         worst_px_vs_the_cameras_with_k3=compare(work / "p2s.toml", "pose2sim", cams),
         lost="k3: Pose2Sim's own writer prints 4 terms", said="by Pose2Sim's writer, not by us")

    names = [c.name for c in cams]
    calib_intri_extri(work / "emc_peer", bundle, names)
    for c in cams:
        (work / "emc_peer" / "images" / c.name).mkdir(parents=True)
        cv2.imwrite(str(work / "emc_peer" / "images" / c.name / "000000.png"),
                    np.zeros((c.resolution[1], c.resolution[0]), np.uint8))
    emit(format="easymocap", direction="import", peer="EasyMocap calib_intri / calib_extri output as read "
         "(write_intri / write_extri: 6 decimals, no H_/W_)", cameras=n,
         worst_px=compare(work / "emc_peer", "easymocap", cams), lost="digits past the 6th decimal (EasyMocap's "
         "writer)", said="image size taken from images/<camera>/")

    from Pose2Sim.calibration import calib_qca_fun
    _, C, S, D, K, R, T = calib_qca_fun(str(QCA))
    got, _ = read_foreign(QCA, "qualisys", ImportOptions())
    emit(format="qualisys", direction="import", peer=f"pose2sim {version('pose2sim')} calib_qca_fun (the "
         "demo's real .qca.txt)", cameras=len(C), worst_px=worst_opencv(list(got.cameras.values()), R, T, K, D),
         lost="radialDistortion3 and skew (not read by Pose2Sim either; zero in this file)", said="warned if not 0")

    from caliscope.cameras.camera_array import CameraArray, CameraData
    CameraArray({i: CameraData(cam_id=i, size=c.resolution, matrix=c.K.copy(), distortions=c.dist.copy(),
                               rotation=c.R @ PANOPTIC_FROM_UP["+z"], translation=c.t_cm / 100.0)
                 for i, c in enumerate(cams)}).to_toml(work / "camera_array.toml")
    emit(format="caliscope", direction="import", peer=f"caliscope {version('caliscope')} CameraArray.to_toml",
         cameras=n, worst_px=compare(work / "camera_array.toml", "caliscope", cams), lost="nothing", said="")

    import yaml
    (work / "camchain.yaml").write_text(yaml.dump(kalibr_camchain(cams)))
    got, _ = read_foreign(work / "camchain.yaml", "kalibr", ImportOptions())
    emit(format="kalibr", direction="import", peer="Kalibr CameraChainParameters as read (kalibr_common/"
         "ConfigReader.py @ ea2791f0): yaml.dump of cam0.. with T_cn_cnm1", cameras=n,
         worst_px=projection_gap_worst_px(in_cam0_frame(cams), list(got.cameras.values())),
         lost="k3 (radtan has 4 terms); the world is cam0's frame", said="by Kalibr's model, not by us")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blender-cameras", type=int, default=520, help="cameras Blender projects (all: 520)")
    args = parser.parse_args()
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    emit(bench="interop", commit=commit, load_average_1min=round(os.getloadavg()[0], 1), cpus=os.cpu_count(),
         data=str(REAL.relative_to(ROOT)), grid="9 x 9 pixels to the corners, at 0.3, 3 and 30 m")
    cameras, source = read_calibration(REAL)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        write_bundle(Bundle(seq="band1", cameras=cameras, calib_data_source=source), work / "real")
        bundle = load_bundle(work / "real")
        start = time.perf_counter()
        export_rows(work / "real", bundle, work, args.blender_cameras)
        import_rows(bundle, work)
        for fmt in ("colmap", "aniposelib", "pose2sim", "easymocap", "nerfstudio"):
            out = work / f"rt_{fmt}"
            result = export_bundle(work / "real", fmt, out)
            import_calibration(out, fmt, work / f"back_{fmt}", ImportOptions(unit="m" if fmt == "colmap" else None,
                                                                            seq="rt"))
            again = list(load_bundle(work / f"back_{fmt}").cameras.values())
            proj, rays = gaps_px(list(bundle.cameras.values()), again)
            emit(format=fmt, direction="round trip (ours both ways)", cameras=len(bundle.cameras),
                 worst_px=float(proj.max()), worst_ray_px=float(rays.max()), unit=result.unit)
        emit(bench="interop", seconds=round(time.perf_counter() - start, 1))


if __name__ == "__main__":
    main()
