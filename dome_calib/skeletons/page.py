"""The people page ``index.html``: one self-contained file (no network, no server) to watch a body3DScene folder: the
dome from the top and the side, every body over time (play, pause, step, a time slider, speed), each person's id
and trail, and for a chosen camera its detections against the bodies reprojected through the calibration.

The template :file:`page.html` (plain JavaScript and canvas) gets the data inline as JSON in a
``<script type="application/json">`` element, every ``<`` written ``\\u003c`` so that no string from a file can
close it; the page puts strings into the document as text, never as markup.

Sizes (10 people x 3,000 frames is a 6 MB page): joints as little-endian int16 millimetres (+-32.7 m; a joint
beyond is not drawn and counted in the page's notes), missing ``-32768``; detections as int16 quarter pixels
(images up to 8,191 px) and confidence x 10,000, embedded for the cameras given (default: cameras in name order
while the page holds at most :data:`MAX_DETECTED_PEOPLE` detected people; the page names the others).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dome_calib.bundle import Bundle
from dome_calib.ownership import write_text
from dome_calib.pages import pack_b64, render
from dome_calib.skeletons.joints import JOINTS19, bones, marker_names
from dome_calib.skeletons.scenes import People

logger = logging.getLogger(__name__)

PAGE_FILE = "index.html"
MISSING_I16 = -32768
MAX_DETECTED_PEOPLE = 60_000  # detected people (one camera, one frame, one person) embedded at most: ~7 MB
TRAIL_S = 2.0


@dataclass(frozen=True)
class CameraDetections:
    """One camera's detections on universal time: ``times_ms`` (F,) and per frame ``people[f]`` (N, 19, 3)
    joints19 ``[x_px, y_px, c]`` (c = 0: not detected)."""

    camera: str
    times_ms: np.ndarray
    people: list[np.ndarray]


def _mm_i16(X_cm: np.ndarray) -> tuple[np.ndarray, int]:
    """World cm -> int16 mm (missing and beyond +-32.767 m: MISSING_I16) and how many finite values were beyond."""
    mm = np.rint(X_cm * 10.0)
    finite = np.isfinite(mm)
    beyond = finite & (np.abs(mm) > 32767)
    out = np.where(finite & ~beyond, mm, MISSING_I16)
    return out.astype("<i2"), int(np.any(beyond.reshape(*beyond.shape[:-1], -1), axis=-1).sum())


def _cameras(bundle: Bundle) -> list[dict]:
    out = []
    for name, cam in bundle.cameras.items():
        out.append({"name": name, "type": str(cam.type), "res": [int(v) for v in cam.resolution],
                    "K": np.asarray(cam.K, float).ravel().tolist(), "dist": np.asarray(cam.dist, float).tolist(),
                    "R": np.asarray(cam.R, float).ravel().tolist(), "t": np.asarray(cam.t_cm, float).ravel().tolist(),
                    "c": np.round(cam.center_cm, 2).tolist()})
    return out


def _detections(det: CameraDetections) -> dict:
    counts = np.array([len(p) for p in det.people], dtype=np.int64)
    kp = np.concatenate([p.reshape(-1, 19, 3) for p in det.people]) if counts.sum() else np.zeros((0, 19, 3))
    packed = np.stack([np.clip(np.rint(kp[..., 0] * 4), -32767, 32767), np.clip(np.rint(kp[..., 1] * 4), -32767,
                                                                                  32767),
                       np.clip(np.rint(kp[..., 2] * 10000), 0, 32767)], axis=-1)
    return {"times_ms": np.round(det.times_ms, 3).tolist(), "counts": pack_b64(np.minimum(counts, 65535), "<u2"),
            "kp": pack_b64(packed, "<i2")}


def page_data(people: People, *, bundle: Bundle | None = None, detections: list[CameraDetections] | None = None,
              notes: list[str] | None = None, folder: Path | None = None, patches: dict | None = None,
              camera_flags: list[dict] | None = None) -> dict:
    """Everything the page shows, as plain data (the template's ``DATA``); ``folder``: the folder named on the page
    (default: the one read; reconstruct reads its staging folder and names its output); ``patches``: the patch
    layer (:func:`dome_calib.recon.patches.page_layer.patch_layer`), drawn under the bodies; ``camera_flags``: the
    run's camera agreement, one row per camera (:func:`dome_calib.pipeline.people_page.camera_flags`), shown as a
    table above the views (none: no table)."""
    notes = list(notes or [])
    folder = Path(folder) if folder is not None else people.folder
    tracks, beyond = [], 0
    for pid, track in people.tracks.items():
        xyz, far = _mm_i16(track.X_cm)
        beyond += far
        tracks.append({"id": int(pid), "n": int(len(track.rows)), "rows": pack_b64(track.rows, "<i4"),
                       "xyz": pack_b64(xyz, "<i2")})
    if beyond:
        notes.append(f"{beyond} joints beyond 32.7 m of the origin are not drawn")
    return {"title": folder.name, "source": str(folder), "layout": people.layout,
            "joints": list(people.joints), "markers": marker_names(people),
            "bones": bones(people.joints), "root": people.joints.index("body_center"),
            "fps": float(people.fps), "fps_type": people.fps_type, "frames": people.frames.tolist(),
            "times_ms": np.round(people.times_ms, 3).tolist(), "people": tracks, "trail_s": TRAIL_S,
            "cameras": _cameras(bundle) if bundle is not None else [],
            "detections": {d.camera: _detections(d) for d in detections or []},
            "detection_bones": bones(JOINTS19), "notes": notes + list((patches or {}).get("notes", [])),
            "patches": patches, "camera_flags": list(camera_flags or [])}


def render_page(data: dict) -> str:
    """The page's HTML: the template through the pages' one module (:func:`dome_calib.pages.render`: shared styles,
    error handler, escaping helpers, ``data`` inline)."""
    return render("dome_calib.skeletons", "page.html", data)


def write_people_page(path: str | Path, people: People, *, bundle: Bundle | None = None,
                      detections: list[CameraDetections] | None = None, notes: list[str] | None = None,
                      folder: Path | None = None, patches: dict | None = None,
                      camera_flags: list[dict] | None = None) -> Path:
    """Write the page of ``people`` to ``path`` (atomic, where :mod:`dome_calib.ownership` allows); returns the path
    (``folder``: see :func:`page_data`). A page staged with its folder is logged where it is written: the commands
    say it at its final place (:func:`dome_calib.final_place.said`)."""
    path = Path(path)
    write_text(path, render_page(page_data(people, bundle=bundle, detections=detections, notes=notes,
                                           folder=folder, patches=patches, camera_flags=camera_flags)))
    logger.info("people page written to %s (%.0f kB)", path, path.stat().st_size / 1e3)
    return path
