"""A whole synthetic session with one ground truth: what a technician brings back from the dome, for
`dome-calib session`, the demo and bench/product.py. It composes the pillar generators, it does not redo them:

    SESSION/dome_session.json  what was made (preset, seed, options) and where; reruns reuse a matching session
    SESSION/capture/           projector-pattern tent captures of the dome as built   (synth.capture; calibrate)
    SESSION/kinect/            Kinect IR/colour/depth checkerboard pairs              (synth.kinect_boards; kinect)
    SESSION/sync/              ltc.wav (VGA + HD LTC), Kinect microphones, frame stamps (synth.sync_session; sync)
    SESSION/detections.json    2D joints of a walking person in every VGA, HD and Kinect colour camera, at each
                               stream's own frames (synth.skeleton; triangulate)
    SESSION/group/             optional (group_people > 0): a group of people as OpenPose folders per camera and
                               its truth (synth.group_session; reconstruct)
    SESSION/ground_truth/      the truth as one bundle: cameras as built, Kinect depth-colour calibration, the
                               true frame times (synctables/ksynctables) of every stream

One truth: the capture is rendered from the as-built cameras, the Kinect boards use the same ``50_<nn>`` colour
cameras, the sync session's Kinect nodes are the dome's, and the person is projected through the as-built
cameras at the TRUE frame times of each stream (which the sync must recover from the audio alone).
"""
from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Literal

import numpy as np

from dome_calib.bundle import Bundle, SyncTable, SyncTables
from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.errors import DomeCalibError
from dome_calib.schema import FileSchema, NonNegFinite, PosFinite, read_json
from dome_calib.io_utils import atomic_write_text
from dome_calib.ownership import claim_folder, seal
from dome_calib.synth.capture import SynthOptions, synthesize as write_capture
from dome_calib.synth.detector import DetectorModel
from dome_calib.synth.dome import as_built_dome
from dome_calib.synth.group import GroupOptions
from dome_calib.synth.group_session import GroupSessionOptions, make_group_session, session_span_ms
from dome_calib.synth.kinect_boards import KinectBoardsOptions, generate_kinect_boards, truth_kcalibration
from dome_calib.synth.skeleton import DetectionNoise, synthetic_tracks
from dome_calib.synth.sync_session import SynthSessionOptions, SynthTruth, make_session
from dome_calib.options import AtLeast, Field, UnitInterval, options

MANIFEST = "dome_session.json"
VERSION = 1


@options
class SessionOptions:
    """What to simulate. Sync and detections: see SynthSessionOptions and DetectionNoise for the models."""

    preset: str = "tiny"
    scenes: AtLeast(1) = 3
    seed: AtLeast(0) = 0
    seq: str = "session"
    duration_s: PosFinite = 4.0  # audio and streams; the person is detected over all of it
    kinect_good_frames: AtLeast(0) = 14  # board poses per Kinect (+ blurred, + cut off)
    kinect_blurred_frames: AtLeast(0) = 2
    kinect_cut_off_frames: AtLeast(0) = 2
    kinect_sensors: tuple[str, ...] | None = None  # default: every Kinect colour camera of the dome
    noise_px: NonNegFinite = 2.0  # 2D detection noise (std per coordinate)
    wrong_fraction: UnitInterval = 0.05  # detections on the mirror joint or anywhere in the image
    miss_fraction: UnitInterval = 0.10  # detections missing (occlusion, detector misses)
    group_people: Annotated[int, Field(ge=0, le=10)] = 0  # > 0: also a group of this many people, OpenPose folders in group/ (synth.group_session)
    group_scenario: str = "mixed"


class SessionManifest(FileSchema):
    """``SESSION/dome_session.json``: what :func:`make_product_session` made (its options) and where (its parts)."""

    version: Literal[1]
    options: SessionOptions
    parts: dict[str, Annotated[str, Field(min_length=1)]]


def _made_here(folder: Path) -> SessionOptions | None:
    """The options the session in ``folder`` was made with (its manifest, read through its schema); None without
    one. Whether a folder that is not reused may be replaced is :func:`make_product_session`'s claim."""
    manifest = folder / MANIFEST
    if not manifest.is_file():
        return None
    try:
        return read_json(manifest, SessionManifest, error=DomeCalibError).options
    except DomeCalibError as exc:
        raise DomeCalibError(f"{exc} (not a session this toolkit made: choose a new or empty folder)") from None


def truth_sync(truth: SynthTruth) -> SyncTables:
    """The true universal times of every frame of the sync session as sync tables."""
    def table(key: str) -> SyncTable:
        return SyncTable(index=truth.index[key].astype(np.int64), univ_time_ms=truth.univ_ms[key].astype(float))

    nodes = sorted({k.split("/")[0] for k in truth.index if "/" in k})
    return SyncTables(streams={"vga": table("vga"), "hd": table("hd")},
                      kinect_color={n: table(f"{n}/color") for n in nodes},
                      kinect_depth={n: table(f"{n}/depth") for n in nodes})


def _detections_doc(tracks, rng: np.random.Generator, miss_fraction: float) -> dict:
    """StreamTracks -> the detections JSON of `dome-calib triangulate` (null = not detected), with misses."""
    cameras = {}
    for tr in tracks:
        for c, name in enumerate(tr.cameras):
            uv, conf = tr.uv_px[:, c], tr.conf[:, c]
            missed = rng.random(conf.shape) < miss_fraction
            ok = (conf > 0) & ~missed & np.all(np.isfinite(uv), axis=-1)
            joints = [[[round(float(u), 3), round(float(v), 3), round(float(k), 3)] if good else [None, None, None]
                       for (u, v), k, good in zip(uv[f], conf[f], ok[f])] for f in range(len(tr.frame_index))]
            cameras[name] = {"frames": tr.frame_index.astype(int).tolist(), "joints": joints}
    return {"joints": 19, "reference": "vga", "cameras": dict(sorted(cameras.items()))}


def make_product_session(folder: str | Path, options: SessionOptions | None = None,
                         progress=None) -> Path:
    """Write the whole session into ``folder`` (reused as it is when its manifest matches ``options``).

    ``progress(description)`` is called before each part. Returns ``folder``.
    """
    o = options or SessionOptions()
    folder = Path(folder)
    manifest = folder / MANIFEST
    wanted = {"version": VERSION, "options": json.loads(json.dumps(asdict(o)))}
    if _made_here(folder) == o:
        return folder
    claim_folder(folder)  # replaced whole: only what dome-calib wrote (dome_calib.ownership)
    step = progress or (lambda what: None)
    shutil.rmtree(folder, ignore_errors=True)  # ours, or nothing
    folder.mkdir(parents=True)
    try:
        _write_session(folder, o, step)
        atomic_write_text(manifest, json.dumps(wanted | {"parts": _parts(o)}, indent=1) + "\n")
        seal(folder)  # what dome-calib wrote: a later run may replace it
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)  # nothing half-written
        raise
    return folder


def _parts(o: SessionOptions) -> dict[str, str]:
    parts = {"capture": "capture", "kinect": "kinect", "sync": "sync", "detections": "detections.json",
             "ground_truth": "ground_truth"}
    return parts | ({"group": "group"} if o.group_people else {})


def _write_session(folder: Path, o: SessionOptions, step) -> None:
    """Every part of the session, into the new folder ``folder``."""
    dome = as_built_dome(o.preset, o.seed)
    layout = folder / "as_built"
    write_bundle(dome, layout)
    step("tent captures")
    write_capture(folder / "capture", SynthOptions(preset=o.preset, n_scenes=o.scenes, seed=o.seed,
                                                   layout=layout / f"calibration_{dome.seq}.json", overwrite=True))
    step("Kinect checkerboard pairs")
    boards = generate_kinect_boards(dome, folder / "kinect", KinectBoardsOptions(
        sensors=list(o.kinect_sensors) if o.kinect_sensors else None, good_frames=o.kinect_good_frames,
        blurred_frames=o.kinect_blurred_frames, cut_off_frames=o.kinect_cut_off_frames, seed=o.seed))
    step("LTC audio and Kinect microphones")
    nodes = tuple(sorted(boards["sensors"], key=lambda n: int(n.removeprefix("KINECTNODE"))))
    sync_truth = make_session(folder / "sync", SynthSessionOptions(seed=o.seed, seq=o.seq, duration_s=o.duration_s,
                                                                   kinect_nodes=nodes))
    truth = Bundle(seq=o.seq, cameras=dome.cameras, calib_data_source=f"synth session {o.preset} seed {o.seed}",
                   kinect=truth_kcalibration(boards), sync=truth_sync(sync_truth))
    write_bundle(truth, folder / "ground_truth")
    step("person and 2D detections")
    seen_by = [n for n, c in sorted(truth.cameras.items())  # Kinect colour cameras only with a synced node
               if c.type != "kinect-color" or f"KINECTNODE{int(n[3:])}" in nodes]
    tracks = synthetic_tracks(truth, seen_by, seed=o.seed,
                              noise=DetectionNoise(noise_px=o.noise_px, wrong_fraction=o.wrong_fraction))
    doc = _detections_doc(tracks, np.random.default_rng(o.seed + 7), o.miss_fraction)
    atomic_write_text(folder / "detections.json", json.dumps(doc, separators=(",", ":")) + "\n")
    if o.group_people:
        step("a group of people and its OpenPose detections")
        start_ms, duration_ms = session_span_ms(truth)
        make_group_session(folder / "group", truth, GroupSessionOptions(
            group=GroupOptions(n_people=o.group_people, scenario=o.group_scenario, start_ms=start_ms,
                               duration_ms=duration_ms, seed=o.seed), detector=DetectorModel(seed=o.seed),
            cameras=seen_by))


def load_truth_bundle(folder: str | Path) -> Bundle:
    return load_bundle(Path(folder) / "ground_truth")
