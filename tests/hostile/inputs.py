"""Small valid inputs for every command of the hostile matrix, built once per test session (a few seconds): a
trimmed real dome with sync tables and the real Kinect calibration, a group's OpenPose detections and their
reconstruction, a triangulate detections file, a capture skeleton, a sync session, an aniposelib file and LTC."""
from __future__ import annotations

import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.interop.convert import export_bundle
from dome_calib.layout import nominal_dome
from dome_calib.recon.people.commands import reconstruct_folder
from dome_calib.synth.openpose_write import write_openpose_folder
from dome_calib.synth.sync_session import SynthSessionOptions, make_session

from ..people_helpers import group_detections
from ..recon_helpers import real_bundle

LTC = Path(__file__).parent.parent / "data" / "ltc" / "ltcsync_ltc.wav"


@dataclass(frozen=True)
class Inputs:
    root: Path  # everything below is inside it (the oracle hashes it before and after each case)
    bundle: Path  # calibration, kcalibration, synctables, ksynctables of seq "test"
    det: Path  # OpenPose folder: one sub-folder per camera (BODY_25)
    people: Path  # reconstruct's output of det: body3DScene files, cameras.json, index.html
    det_json: Path  # triangulate's detections file (one person)
    capture: Path  # a capture skeleton (capture.json, ground_truth/): the calibration's checks pass
    session: Path  # capture/, kinect/, sync/ (session.json, ltc.wav, Kinect audio)
    sync: Path  # session/sync
    kinect: Path  # an empty Kinect capture folder (refusals come before it is read)
    toml: Path  # an aniposelib calibration of the bundle
    ltc: Path  # an LTC recording


def _small(bundle: Bundle) -> Bundle:
    vga = sorted(bundle.of_type("vga"))[::4][:10]
    hd = sorted(bundle.of_type("hd"))[::6][:4]
    kin = sorted(bundle.of_type("kinect-color"))
    return Bundle(seq=bundle.seq, cameras={n: bundle.cameras[n] for n in vga + hd + kin},
                  calib_data_source=bundle.calib_data_source, kinect=bundle.kinect, sync=bundle.sync)


def _triangulate_doc(people: dict[str, dict[int, np.ndarray]]) -> dict:
    cameras = {}
    for cam, frames in sorted(people.items()):
        order = sorted(frames)
        joints = []
        for f in order:
            rows = frames[f]
            row = rows[0] if len(rows) else np.zeros((19, 3))
            joints.append([[round(float(u), 3), round(float(v), 3), round(float(c), 3)] if c > 0
                           else [None, None, None] for u, v, c in row[:19]])
        cameras[cam] = {"frames": order, "joints": joints}
    return {"joints": 19, "reference": "vga", "cameras": cameras}


def rooted(inputs: Inputs, root: Path) -> Inputs:
    """``inputs`` as they are once ``inputs.root`` is copied to ``root``."""
    return dataclasses.replace(inputs, **{f.name: root / getattr(inputs, f.name).relative_to(inputs.root)
                                          for f in dataclasses.fields(inputs) if f.name != "root"}, root=root)


def build_inputs(root: Path) -> Inputs:
    root.mkdir(parents=True, exist_ok=True)
    full = real_bundle(kinect=True, n_vga=40, start_ms=1000.0, duration_ms=400.0, seed=3)
    bundle = _small(full)
    write_bundle(bundle, root / "bundle")
    seen = sorted(n for n, c in bundle.cameras.items() if c.type in ("vga", "hd"))
    people, _ = group_detections(bundle, seen, 2, seed=4)
    write_openpose_folder(root / "det", people, body_model="BODY_25")
    reconstruct_folder(root / "det", root / "bundle", root / "people", body_model="BODY_25")
    one, _ = group_detections(bundle, seen, 1, seed=5, false_people=0.0)
    (root / "det.json").write_text(json.dumps(_triangulate_doc(one)))
    session = root / "session"
    capture = session / "capture"
    truth = nominal_dome("tiny", seed=0)
    (capture / "scenes" / "scene_01").mkdir(parents=True)
    (capture / "capture.json").write_text(json.dumps({"preset": "tiny", "seed": 0, "scenes": ["scene_01"],
                                                      "cameras": sorted(truth.cameras)}))
    write_bundle(truth, capture / "ground_truth")
    (session / "kinect").mkdir()
    make_session(session / "sync", SynthSessionOptions(duration_s=2.0, n_kinects=1, seed=1, seq="test"))
    (root / "kinect").mkdir()
    export_bundle(root / "bundle", "aniposelib", root / "calib.toml")
    shutil.copy(LTC, root / "ltc.wav")
    return Inputs(root=root, bundle=root / "bundle", det=root / "det", people=root / "people",
                  det_json=root / "det.json", capture=capture, session=session, sync=session / "sync",
                  kinect=root / "kinect", toml=root / "calib.toml", ltc=root / "ltc.wav")
