"""What the capture folder says: its scenes and cameras (``capture.json``, or the folders under ``scenes/``) and
which capture node holds which cameras' images (``capture.json``'s ``"nodes"``)."""
from __future__ import annotations

import json
from pathlib import Path

from dome_calib.capture_checks import check_capture
from dome_calib.errors import CaptureError


def capture_contents(capture: Path) -> tuple[list[str], list[str]]:
    """Scenes and cameras named by ``capture.json`` (or found under scenes/)."""
    if not capture.is_dir():
        raise CaptureError(f"{capture}: not a folder")
    meta_path = capture / "capture.json"
    if meta_path.exists():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            scenes, cams = list(meta["scenes"]), list(meta["cameras"])
        except (ValueError, KeyError, TypeError) as exc:
            raise CaptureError(f"{meta_path}: malformed ({exc})") from exc
        check_capture(capture, scenes, cams, listed=True, local=not meta.get("nodes"))
        return scenes, cams
    scenes = sorted(p.name for p in (capture / "scenes").glob("*") if p.is_dir())
    if not scenes:
        raise CaptureError(f"{capture}: no capture.json and no scenes/<scene>/ folders")
    cams = sorted({p.stem for s in scenes for p in (capture / "scenes" / s).glob("*.png")})
    check_capture(capture, scenes, cams, listed=False)
    return scenes, cams


def capture_nodes(capture: Path) -> dict[str, list[str]]:
    """``capture.json``'s ``"nodes"`` (node -> cameras), {} if absent; one line if malformed or a camera is on
    two nodes."""
    meta_path = capture / "capture.json"
    if not meta_path.exists():
        return {}
    try:
        nodes = json.loads(meta_path.read_text(encoding="utf-8")).get("nodes", {})
    except (ValueError, AttributeError) as exc:
        raise CaptureError(f"{meta_path}: malformed ({exc})") from exc
    if not isinstance(nodes, dict) or not all(isinstance(v, list) and all(isinstance(c, str) for c in v)
                                              for v in nodes.values()):
        raise CaptureError(f"{meta_path}: field 'nodes' must map a worker name to a list of camera names")
    seen: dict[str, str] = {}
    for node, cams in sorted(nodes.items()):
        for cam in cams:
            if cam in seen:
                raise CaptureError(f"{meta_path}: camera {cam} is listed under nodes {seen[cam]} and {node}")
            seen[cam] = node
    return {str(n): sorted(c) for n, c in sorted(nodes.items())}
