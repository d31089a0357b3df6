"""Stage 3: descriptor matching and geometric verification of the selected pairs of a scene.

One task per batch of pairs (:func:`match_batch`): the worker reads features and cameras from the scene's
database (read-only), matches descriptors and verifies the matches with pycolmap's two-view geometry
(``estimate_two_view_geometry``: E / F / H RANSAC with the known intrinsics); the main process writes raw
matches and the two-view geometries into the database in pair order (not completion order), where the mapper
reads them. A rerun skips pairs that already have matches.

Descriptor matching is mutual nearest neighbour with Lowe's ratio test and a maximum angular distance,
COLMAP's SIFT rule (``SiftMatchingOptions``: max_ratio 0.8, max_distance 0.7, cross_check), computed with one
BLAS matrix product of the uint8 descriptors, which is exact (:func:`match_descriptors`): the matches do not
depend on the machine. pycolmap 4.2's CPU brute-force ``FeatureMatcher`` gives the same matches but took
1.3 s per VGA pair here against 0.04 s for the BLAS product, so it is an option (``backend="pycolmap"``),
not the default.
"""
from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import numpy as np
import pycolmap

from dome_calib.colmap_options import colmap_options
from dome_calib.executor import Executor, SerialExecutor, in_order
from dome_calib.progress import Progress, counting
from projector.database import FeatureReader, image_name
from projector.pairs import Pair
from dome_calib.options import AtLeast, Field, Lax, options
from dome_calib.schema import PosFinite

logger = logging.getLogger(__name__)


class MatchBackend(StrEnum):
    BLAS = "blas"
    PYCOLMAP = "pycolmap"


@options
class MatchOptions:
    """Matching and verification options (pixel errors in COLMAP/OpenCV px, identical scale)."""

    max_ratio: Annotated[float, Field(gt=0, le=1)] = 0.8
    max_distance: PosFinite = 0.7  # angle between unit descriptors, rad
    cross_check: bool = True
    min_num_matches: AtLeast(0) = 15  # fewer raw matches: not verified
    min_num_inliers: AtLeast(0) = 15
    ransac_max_error_px: PosFinite = 4.0
    # RANSAC's floor on hypotheses per model (COLMAP: 100). The trial count still grows with the outlier ratio
    # (confidence 0.999), so only clean pairs stop earlier: projector-pattern pairs are ~100 % inliers and need a
    # few hypotheses, and 100 of each of E, F and H were two thirds of the verification time (full dome, 150
    # pairs: 9.9 ms per pair with 100, 4.9 with 20, 4.2 with 10; inlier sets identical to 100's but for one match
    # in one pair, no configuration changed)
    ransac_min_num_trials: AtLeast(1) = 10
    # COLMAP's two extras after RANSAC: a search for a watermark (matches moving together near the border, a
    # burnt-in logo or timestamp; the dome's frames carry none) and a Sampson-error refinement of the model (the
    # inlier sets are the same without it: 160,193 against 160,191 inlier matches on 314 pairs of the full
    # dome's quick scene; verification 5.8 -> 4.3 ms per pair)
    detect_watermark: bool = False
    sampson_refinement: bool = False
    # the most distinctive matches of a pair; verification time grows with the count, and a few hundred
    # well-spread matches per pair are plenty for mapping and the bundle adjustment (None: keep all)
    max_matches_per_pair: AtLeast(1) | None = 512
    backend: Annotated[MatchBackend, Lax] = MatchBackend.BLAS
    pairs_per_task: AtLeast(1) = 40


@dataclass(kw_only=True)
class PairResult:
    pair: Pair
    matches: np.ndarray  # (M, 2) uint32 keypoint indices (a, b)
    geometry: object | None = None  # pycolmap.TwoViewGeometry of the verified matches
    num_inliers: int = 0


@dataclass(kw_only=True)
class MatchReport:
    scene: str
    num_pairs: int = 0
    reused: int = 0
    num_matches: int = 0  # raw matches over all pairs
    num_verified_pairs: int = 0
    num_inlier_matches: int = 0
    inliers: dict[Pair, int] = field(default_factory=dict)  # verified pairs only
    skipped: list[Pair] = field(default_factory=list)  # pairs with an image without features
    seconds: float = 0.0


def _matchable(d: np.ndarray) -> np.ndarray:
    """float32 descriptors for the product: integer ones as they are (exact), float ones scaled to unit length."""
    d = np.asarray(d)
    if np.issubdtype(d.dtype, np.integer):
        return d.astype(np.float32)
    d = d.astype(np.float32)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def match_descriptors(d1: np.ndarray, d2: np.ndarray, *, max_ratio: float = 0.8, max_distance: float = 0.7,
                      cross_check: bool = True, max_matches: int | None = None) -> np.ndarray:
    """(M, 2) uint32 indices of mutual nearest neighbours passing the ratio and distance tests.

    d1 (N1, 128), d2 (N2, 128): SIFT descriptors, COLMAP's uint8 storage (each about 512 long) or float. The
    neighbours are ranked by the dot product of the stored descriptors, as COLMAP's matcher does (float ones are
    first scaled to unit length). For uint8 descriptors every product and partial sum of the BLAS product is an
    integer below 2**24 (128 x 255**2), exact in float32 in any order of summation: the same neighbours, the same
    test results and the same order on every machine and BLAS kernel (with unit vectors, two kernels' last bits
    reordered the matches of 108 of 1,295 panel pairs). The tests take the angle between the descriptors as unit
    vectors, from their exact norms (float64). With ``cross_check`` each keypoint of either image is in at most one
    match (rows tied as a column's nearest: the first). Matches come most distinctive first (by the ratio of the
    two angles, ties by row); ``max_matches`` keeps only that many.
    """
    if len(d1) < 2 or len(d2) < 2:
        return np.zeros((0, 2), np.uint32)
    a, b = _matchable(d1), _matchable(d2)
    norm_a = np.sqrt(np.einsum("ij,ij->i", a, a, dtype=np.float64))
    norm_b = np.sqrt(np.einsum("ij,ij->i", b, b, dtype=np.float64))
    sim = a @ b.T
    rows = np.arange(len(a))
    col_best = sim.max(axis=0) if cross_check else None  # before the best entries are masked below
    best = np.argmax(sim, axis=1)
    s1 = sim[rows, best].copy()
    sim[rows, best] = -np.inf
    second = np.argmax(sim, axis=1)
    s2 = sim[rows, second]
    cos1 = s1 / np.maximum(norm_a * norm_b[best], 1e-300)
    cos2 = s2 / np.maximum(norm_a * norm_b[second], 1e-300)
    dist1 = np.arccos(np.clip(cos1, -1.0, 1.0))
    dist2 = np.arccos(np.clip(cos2, -1.0, 1.0))
    keep = (dist1 <= max_distance) & (dist1 < max_ratio * dist2)
    if cross_check:
        keep &= s1 >= col_best[best]  # row i is also column best's nearest neighbour
        # integer products tie more often than float ones: of several rows equally nearest to one column, the first
        kept = np.flatnonzero(keep)
        keep[kept] = False
        keep[kept[np.unique(best[kept], return_index=True)[1]]] = True
    order = np.argsort(dist1[keep] / np.maximum(dist2[keep], 1e-12), kind="stable")[:max_matches]
    return np.stack([rows[keep][order], best[keep][order]], axis=1).astype(np.uint32)


_READERS: dict[str, tuple[str, FeatureReader]] = {}  # per worker process: path -> (call, reader)
_MATCHERS: dict[tuple, object] = {}


def _reader(database_path: str, call: str) -> FeatureReader:
    """The worker's reader of a database for one :func:`match_pairs` call. Its cache lives no longer than the call:
    features can change between calls (the quick path extracts suspects again), and a worker outlives calls."""
    held = _READERS.get(database_path)
    if held is None or held[0] != call:
        if held is not None:
            held[1].close()
        _READERS[database_path] = held = (call, FeatureReader(database_path))
    return held[1]


def _pycolmap_match(d1: np.ndarray, d2: np.ndarray, options: MatchOptions) -> np.ndarray:
    key = (options.max_ratio, options.max_distance, options.cross_check)
    if key not in _MATCHERS:
        mo = colmap_options(pycolmap.FeatureMatchingOptions)
        mo.sift.max_ratio, mo.sift.max_distance, mo.sift.cross_check = key
        _MATCHERS[key] = pycolmap.FeatureMatcher.create(mo, pycolmap.Device.cpu)
    t = pycolmap.FeatureExtractorType.SIFT
    return np.asarray(_MATCHERS[key].match(None, pycolmap.FeatureDescriptors(t, d1), None,
                                           pycolmap.FeatureDescriptors(t, d2)), np.uint32)


def verify_options(options: MatchOptions):
    vo = colmap_options(pycolmap.TwoViewGeometryOptions)
    vo.min_num_inliers = options.min_num_inliers
    vo.ransac.max_error = options.ransac_max_error_px
    vo.ransac.min_num_trials = options.ransac_min_num_trials
    vo.detect_watermark = options.detect_watermark
    vo.use_sampson_refinement = options.sampson_refinement
    return vo


def match_batch(task: tuple[str, list[Pair], MatchOptions, str]) -> list[PairResult]:
    """Task: match and verify a batch of pairs of one database. ``task = (database_path, pairs, options, call)``
    (``call``: unique per :func:`match_pairs` call)."""

    database_path, pairs, options, call = task
    reader = _reader(database_path, call)
    vo = verify_options(options)
    out = []
    for a, b in pairs:
        kp1, d1 = reader.features(image_name(a))
        kp2, d2 = reader.features(image_name(b))
        if options.backend == MatchBackend.PYCOLMAP:
            m = _pycolmap_match(d1, d2, options)
        else:
            m = match_descriptors(d1, d2, max_ratio=options.max_ratio, max_distance=options.max_distance,
                                  cross_check=options.cross_check, max_matches=options.max_matches_per_pair)
        res = PairResult(pair=(a, b), matches=m)
        if len(m) >= options.min_num_matches:
            tvg = pycolmap.estimate_two_view_geometry(reader.camera(image_name(a)), kp1, reader.camera(image_name(b)),
                                                      kp2, m, vo)
            n = len(tvg.inlier_matches)
            if n >= options.min_num_inliers:
                res.geometry, res.num_inliers = tvg, n
        out.append(res)
    return out


def _batches(pairs: list[Pair], size: int) -> Iterable[list[Pair]]:
    for i in range(0, len(pairs), size):
        yield pairs[i:i + size]


def match_pairs(
    database_path: str | Path, pairs: Iterable[Pair], *, options: MatchOptions | None = None,
    executor: Executor | None = None, scene: str = "", progress: Progress | None = None,
) -> MatchReport:
    """Match and verify ``pairs`` (camera names) of a scene database; write matches and geometries into it.

    Pairs with an image that has no features in the database are skipped (listed in the report).
    ``progress`` is called with (pairs done, pairs) as batches arrive (those reused first).
    Returns a :class:`MatchReport` (inlier counts of the verified pairs, totals, time).
    """

    options = options or MatchOptions()
    executor = executor or SerialExecutor()
    t0 = time.perf_counter()
    report = MatchReport(scene=scene or Path(database_path).parent.name)
    with pycolmap.Database.open(str(database_path)) as db:
        ids = {im.name: im.image_id for im in db.read_all_images() if db.exists_keypoints(im.image_id)}
        todo: list[Pair] = []
        for a, b in sorted(set(pairs)):
            ia, ib = ids.get(image_name(a)), ids.get(image_name(b))
            if ia is None or ib is None:
                report.skipped.append((a, b))
            elif db.exists_matches(ia, ib):
                report.reused += 1
                if db.exists_two_view_geometry(ia, ib):
                    n = len(db.read_two_view_geometry(ia, ib).inlier_matches)
                    if n:
                        report.inliers[(a, b)] = n
            else:
                todo.append((a, b))
        report.num_pairs = report.reused + len(todo)
        call = uuid.uuid4().hex  # names this call's feature readers in the workers (never part of a result)
        tasks = [(str(database_path), batch, options, call) for batch in _batches(todo, options.pairs_per_task)]
        with counting(progress, report.num_pairs) as advance:
            advance(report.reused)
            # written in pair order whatever the completion order (the database's rows do not depend on the workers)
            arrived = executor.map(match_batch, tasks)
            for results in in_order(arrived, [tuple(t[1][0]) for t in tasks], lambda rs: tuple(rs[0].pair)):
                with pycolmap.DatabaseTransaction(db):
                    for r in results:
                        ia, ib = ids[image_name(r.pair[0])], ids[image_name(r.pair[1])]
                        db.write_matches(ia, ib, r.matches)
                        db.write_two_view_geometry(ia, ib, r.geometry if r.geometry is not None
                                                   else pycolmap.TwoViewGeometry())
                        report.num_matches += len(r.matches)
                        if r.geometry is not None:
                            report.inliers[r.pair] = r.num_inliers
                advance(len(results))
    report.num_verified_pairs = len(report.inliers)
    report.num_inlier_matches = int(sum(report.inliers.values()))
    report.seconds = time.perf_counter() - t0
    logger.info("%s: %d pairs (%d reused), %d verified, %d inlier matches, %.1f s", report.scene, report.num_pairs,
                report.reused, report.num_verified_pairs, report.num_inlier_matches, report.seconds)
    return report
