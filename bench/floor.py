"""The floor under the calibration's time: the CPU that SIFT and matching alone need, against an end-to-end time.

    .venv/bin/python bench/floor.py --capture WORK/capture --reference-tree /tmp/base --target 0.5
    .venv/bin/python bench/floor.py --capture WORK/capture --work-folder WORK/bundle.work --end-to-end-s 567.7

With ``--reference-tree`` (a checkout, e.g. ``git worktree add /tmp/base 2a6a476``) that checkout's ``calibrate``
runs on the capture before and after the sampling (child processes, ``bench/calibrate_in.py``, as
``bench/dome.py --compare`` runs them): the end-to-end time the floor is judged against comes from the same run on
the same machine (a shared machine's speed moved 25 % within a day), and its work folder is the one sampled.

Otherwise ``--capture`` and ``--work-folder`` are what ``bench/dome.py`` leaves behind (the synthetic capture and the
``calibrate`` work folder, whose ``sfm/<scene>/`` holds the database with every image's features and the pairs
matched). Per scene, a seeded sample of images is run through the SIFT task of ``calibrate``
(``projector.features.extract_image``) and a seeded sample of the matched pairs through its matching and
verification (``projector.matching.match_descriptors`` + pycolmap's two-view geometry), one after the other in
this process with one BLAS thread, as calibrate's worker processes run them; each call is timed in CPU seconds.
The means per kind (images by camera type; pairs by the types of their two cameras) times the counts in the work
folder give the CPU that the whole capture's SIFT and matching need. Divided by the cores (perfect parallelism, no
overhead), that is a floor no schedule can beat without doing less of that work.

Prints one JSON object per line: one per scene and kind, then the totals; with ``--end-to-end-s`` (a same-run
reference time) the floor as a fraction of it and the CPU left for everything else within a target fraction.
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # before numpy: one BLAS thread, as in calibrate's worker processes

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pycolmap  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(1, str(ROOT / "bench"))

from dome import calibrate_in  # noqa: E402  (bench/dome.py: imports the toolkit only when run itself)

from dome_calib.bundle import camera_type_from_name  # noqa: E402
from projector.database import image_name  # noqa: E402
from projector.features import FeatureOptions, extract_image  # noqa: E402
from projector.matching import MatchOptions, _reader, match_descriptors, verify_options  # noqa: E402


def emit(**obj) -> None:
    print(json.dumps(obj), flush=True)


def _kind(camera: str) -> str:
    return camera_type_from_name(camera).value


def _pair_kind(a: str, b: str) -> str:
    return "-".join(sorted((_kind(a), _kind(b))))


def _cpu(fn, *args, **kwargs) -> tuple[object, float]:
    t0 = time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - t0


def _pairs(path: Path) -> list[tuple[str, str]]:
    out = []
    for line in path.read_text().splitlines():
        if line.strip():
            a, b = line.split()
            out.append((Path(a).stem, Path(b).stem))
    return out


def sift_scene(images: list[Path], sample: int, rng: np.random.Generator, scene: str) -> dict[str, float]:
    """CPU seconds of the scene's SIFT, estimated per camera type from a sample; emits one line per type."""
    by_kind: dict[str, list[Path]] = defaultdict(list)
    for p in images:
        by_kind[_kind(p.stem)].append(p)
    options = FeatureOptions()
    extract_image((images[0].stem, str(images[0]), options))  # the extractor built once, outside the timing
    totals = {}
    for kind, paths in sorted(by_kind.items()):
        picked = [paths[i] for i in sorted(rng.choice(len(paths), min(sample, len(paths)), replace=False))]
        cpu, features = [], []
        for p in picked:
            res, s = _cpu(extract_image, (p.stem, str(p), options))
            cpu.append(s)
            features.append(0 if res.keypoints is None else len(res.keypoints))
        totals[kind] = float(np.mean(cpu)) * len(paths)
        emit(bench="floor", part="sift", scene=scene, kind=kind, images=len(paths), sampled=len(picked),
             cpu_ms_mean=round(1000 * float(np.mean(cpu)), 2), cpu_ms_median=round(1000 * float(np.median(cpu)), 2),
             features_mean=round(float(np.mean(features)), 1), cpu_s_estimated=round(totals[kind], 2))
    return totals


def matching_scene(database: Path, pairs: list[tuple[str, str]], sample: int, rng: np.random.Generator,
                   scene: str) -> dict[str, float]:
    """CPU seconds of the scene's matching and verification, estimated per pair kind from a sample."""
    options = MatchOptions()
    vo = verify_options(options)
    reader = _reader(str(database), f"floor-{scene}")
    by_kind: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for a, b in pairs:
        by_kind[_pair_kind(a, b)].append((a, b))
    totals = {}
    for kind, kind_pairs in sorted(by_kind.items()):
        picked = [kind_pairs[i] for i in sorted(rng.choice(len(kind_pairs), min(sample, len(kind_pairs)),
                                                            replace=False))]
        read_s, match_s, verify_s = [], [], []
        for a, b in picked:
            t0 = time.process_time()
            kp1, d1 = reader.features(image_name(a))
            kp2, d2 = reader.features(image_name(b))
            t1 = time.process_time()
            m = match_descriptors(d1, d2, max_ratio=options.max_ratio, max_distance=options.max_distance,
                                  cross_check=options.cross_check, max_matches=options.max_matches_per_pair)
            t2 = time.process_time()
            if len(m) >= options.min_num_matches:
                pycolmap.estimate_two_view_geometry(reader.camera(image_name(a)), kp1, reader.camera(image_name(b)),
                                                    kp2, m, vo)
            t3 = time.process_time()
            read_s.append(t1 - t0)
            match_s.append(t2 - t1)
            verify_s.append(t3 - t2)
        per_pair = float(np.mean(read_s) + np.mean(match_s) + np.mean(verify_s))
        totals[kind] = per_pair * len(kind_pairs)
        emit(bench="floor", part="matching", scene=scene, kind=kind, pairs=len(kind_pairs), sampled=len(picked),
             read_ms=round(1000 * float(np.mean(read_s)), 2), match_ms=round(1000 * float(np.mean(match_s)), 2),
             verify_ms=round(1000 * float(np.mean(verify_s)), 2), cpu_s_estimated=round(totals[kind], 2))
    return totals


def _reference_figures(fig: dict) -> dict:
    return dict(seconds_total=fig["seconds_total"], seconds=fig.get("seconds"), sfm_seconds=fig.get("sfm_seconds"),
                load_average_1min=fig.get("load_average_1min"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", required=True, type=Path, help="the synthetic capture (scenes/<scene>/*.png)")
    parser.add_argument("--work-folder", type=Path, help="calibrate's work folder of that capture (not with "
                        "--reference-tree)")
    parser.add_argument("--reference-tree", type=Path, help="a checkout whose calibrate runs on the capture before "
                        "and after the sampling: the end-to-end time (their mean) and the work folder sampled")
    parser.add_argument("--reference-out", type=Path, default=Path("/tmp/floor_reference"), help="--reference-tree: "
                        "where its bundle goes (its work folder: this path + .work)")
    parser.add_argument("--sample", type=int, default=150, help="images per camera type and pairs per pair kind, "
                        "per scene")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cores", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--end-to-end-s", type=float, help="a reference end-to-end time of the same capture (s)")
    parser.add_argument("--target", type=float, default=0.5, help="the aimed fraction of --end-to-end-s")
    parser.add_argument("--bundle-adjustment-s", type=float, help="the bundle adjustment's wall time on this capture "
                        "(s; it runs after the SfM, so it adds to the floor)")
    args = parser.parse_args()
    if (args.work_folder is None) == (args.reference_tree is None):
        parser.error("give exactly one of --work-folder and --reference-tree")
    references = []

    def reference_run() -> None:  # the reference checkout's calibrate on the capture, timed (its work folder sampled)
        references.append(calibrate_in(args.reference_tree, args.capture, args.reference_out))
        emit(bench="floor", part="reference", run=len(references) - 1, tree=str(args.reference_tree),
             **_reference_figures(references[-1]))

    if args.reference_tree is not None:
        reference_run()
        args.work_folder = Path(f"{args.reference_out}.work")
    rng = np.random.default_rng(args.seed)
    sift, matching = {}, {}
    scenes = sorted(p.name for p in (args.work_folder / "sfm").iterdir() if (p / "database.db").exists())
    if not scenes:
        sys.exit(f"{args.work_folder / 'sfm'}: no scene folder with a database.db")
    t0 = time.perf_counter()
    for scene in scenes:
        images = sorted((args.capture / "scenes" / scene).glob("*.png"))
        pairs = _pairs(args.work_folder / "sfm" / scene / "pairs.txt")
        sift[scene] = sift_scene(images, args.sample, rng, scene)
        matching[scene] = matching_scene(args.work_folder / "sfm" / scene / "database.db", pairs, args.sample, rng,
                                         scene)
    if args.reference_tree is not None:
        reference_run()
        args.end_to_end_s = round(float(np.mean([r["seconds_total"] for r in references])), 2)
    sift_cpu = sum(sum(v.values()) for v in sift.values())
    matching_cpu = sum(sum(v.values()) for v in matching.values())
    floor_s = (sift_cpu + matching_cpu) / args.cores
    summary = dict(bench="floor", part="total", scenes=scenes, cores=args.cores, sift_cpu_s=round(sift_cpu, 1),
                   matching_cpu_s=round(matching_cpu, 1), floor_wall_s=round(floor_s, 1),
                   bench_seconds=round(time.perf_counter() - t0, 1))
    if args.bundle_adjustment_s is not None:
        summary["floor_with_bundle_adjustment_s"] = round(floor_s + args.bundle_adjustment_s, 1)
    if args.end_to_end_s:
        target_s = args.target * args.end_to_end_s
        summary.update(end_to_end_s=args.end_to_end_s, target_s=round(target_s, 1),
                       floor_over_end_to_end=round(floor_s / args.end_to_end_s, 3),
                       cpu_left_for_the_rest_s=round(args.cores * target_s - sift_cpu - matching_cpu, 1))
        if args.bundle_adjustment_s is not None:
            summary["floor_with_bundle_adjustment_over_end_to_end"] = round(
                (floor_s + args.bundle_adjustment_s) / args.end_to_end_s, 3)
    emit(**summary)


if __name__ == "__main__":
    main()
