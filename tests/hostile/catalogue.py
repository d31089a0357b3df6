"""The catalogue of the hostile matrix: one entry per command of the `dome-calib` and `timecode` applications (the
matrix fails for a command without one), saying where the command writes and how to run it; and the situation
kinds it is crossed with.

An entry's ``output``: ``folder`` (replaced whole), ``file`` (one file), ``into`` (a folder the command writes some
files into, each claimed by itself) or ``none`` (reads only). ``ours``: paths (relative to the output) the command
writes, which the "foreign" situation fills with someone else's files of the same names.
"""
from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from .contents import CONTENT_KINDS
from .inputs import Inputs

Argv = Callable[[Inputs, Path], list]


@dataclass(frozen=True)
class Entry:
    prog: str  # "dome-calib" or "timecode"
    output: str  # "folder" | "file" | "into" | "none"
    argv: Argv  # (inputs, output path) -> the command line after the program name
    ours: tuple[str, ...] = ()
    inputs: Callable[[Inputs], list[Path]] | None = None  # input places: an output equal to one is refused
    names: Callable[[Inputs, Path, str], list] | None = None  # argv with a hostile name where a name is taken
    long: Argv | None = None  # argv of a run long enough to be stopped midway
    started: Callable[[Path], bool] | None = None  # (sandbox) -> whether the long run is midway
    out_name: str = "out"  # the output's name in the case's sandbox
    out_at: Callable[[Path], Path] | None = None  # (sandbox) -> the output, when the command does not take it
    setup: Callable[[Inputs, Path], None] | None = None  # prepares the sandbox (before the situation)
    also: Callable[[Path], list[Path]] = lambda out: []  # other places it may write (a work folder)
    variant: str = ""
    reads: Callable[[Inputs], list[Path]] | None = None  # the files (folders: all in them) it reads; else inputs
    contents: tuple[str, ...] = ("number", "empty", "truncated")  # the input-content kinds its reads admit
    stops: str = ""  # the refusal its small inputs end in (no images): a valid changed file may reach it


def _work(out: Path) -> list[Path]:
    return [out.with_name(out.name + ".work")]


def _copy_bundle(i: Inputs, sandbox: Path) -> None:
    shutil.copytree(i.bundle, sandbox / "bundle", symlinks=True)


def _staging_in(sandbox: Path) -> bool:
    return any(p.name.startswith(".out.") for p in sandbox.iterdir())


def _first_file(folder: Path) -> Path:
    return sorted(p for p in folder.rglob("*") if p.is_file() and not p.name.startswith("."))[0]


def _scenes(i: Inputs) -> list[Path]:  # what is read of a reconstruction (not its cameras.json, nor its page)
    return sorted(i.people.glob("body3DScene_*.json"))


def _sync_reads(i: Inputs) -> list[Path]:  # a sync session but its synthetic ground truth (truth.json)
    return [i.sync / "session.json", i.sync / "ltc.wav", i.sync / "kinect"]


CAL = "calibration_test.json"
ALL = ("number", "empty", "truncated", "one frame")  # the reads hold sequences of frames

ENTRIES: dict[str, list[Entry]] = {
    "info": [Entry("dome-calib", "none", lambda i, o: ["info", i.bundle], reads=lambda i: [i.bundle])],
    "compare": [Entry("dome-calib", "none", lambda i, o: ["compare", i.bundle, i.bundle], reads=lambda i: [i.bundle])],
    "calibrate": [Entry(
        "dome-calib", "folder", lambda i, o: ["calibrate", i.capture, "-o", o], ours=(CAL, "report/report.json"),
        inputs=lambda i: [i.capture], also=_work, reads=lambda i: [i.capture / "capture.json"],
        stops="no scene folder with PNG images",
        names=lambda i, o, n: ["calibrate", i.capture, "-o", o, "--seq", n])],
    "session": [Entry(
        "dome-calib", "folder", lambda i, o: ["session", i.session, "-o", o], ours=(CAL, "synctables_test.json"),
        inputs=lambda i: [i.session], also=_work, reads=_sync_reads, stops="no KINECTNODE<n> folders",
        names=lambda i, o, n: ["session", i.session, "-o", o, "--seq", n])],
    "demo": [Entry(
        "dome-calib", "into", lambda i, o: ["demo", "-o", o, "--people", "0"],
        ours=("bundle/calibration_demo.json", "people/cameras.json"),
        long=lambda i, o: ["demo", "-o", o, "--people", "0"],
        started=lambda sandbox: (sandbox / "out" / "session").exists())],
    "export": [
        Entry("dome-calib", "folder", lambda i, o: ["export", i.bundle, "--to", "colmap", "-o", o],
              ours=("cameras.bin", "images.bin", "points3D.bin"), inputs=lambda i: [i.bundle], variant="colmap",
              names=lambda i, o, n: ["export", i.bundle, "--to", "colmap", "-o", o, "--names", f"00_00={n}"]),
        Entry("dome-calib", "file", lambda i, o: ["export", i.bundle, "--to", "aniposelib", "-o", o],
              inputs=lambda i: [i.bundle / CAL], out_name="out.toml", variant="aniposelib",
              names=lambda i, o, n: ["export", i.bundle, "--to", "aniposelib", "-o", o, "--names", f"00_00={n}"]),
    ],
    "import": [Entry(
        "dome-calib", "folder", lambda i, o: ["import", i.toml, "--from", "aniposelib", "--unit", "mm", "-o", o],
        ours=("calibration_out.json",), inputs=lambda i: [i.toml],
        names=lambda i, o, n: ["import", i.toml, "--from", "aniposelib", "--unit", "mm", "-o", o, "--seq", n])],
    "export-people": [Entry(
        "dome-calib", "folder", lambda i, o: ["export-people", i.people, "--to", "trc", "-o", o],
        ours=("person0.trc", "people.c3d"), inputs=lambda i: [i.people], reads=_scenes, contents=ALL)],
    "people-page": [Entry(
        "dome-calib", "file", lambda i, o: ["people-page", i.people, "-o", o, "--bundle", i.bundle, "--detections",
                                            i.det, "--body-model", "BODY_25"], out_name="page.html",
        inputs=lambda i: [_first_file(i.people), i.bundle / CAL, _first_file(i.det)],
        names=lambda i, o, n: ["people-page", i.people, "-o", o, "--bundle", i.bundle, "--detections", i.det,
                               "--body-model", "BODY_25", "--cameras", n],
        reads=lambda i: [*_scenes(i), i.people / "cameras.json", i.bundle, i.det], contents=ALL)],
    "reconstruct": [Entry(
        "dome-calib", "folder",
        lambda i, o: ["reconstruct", i.det, "--bundle", i.bundle, "--body-model", "BODY_25", "-o", o],
        ours=("body3DScene_00000001.json", "cameras.json"), inputs=lambda i: [i.det, i.bundle],
        names=lambda i, o, n: ["reconstruct", i.det, "--bundle", i.bundle, "--body-model", "BODY_25", "-o", o,
                               "--reference", n], contents=ALL)],
    "triangulate": [Entry(
        "dome-calib", "folder", lambda i, o: ["triangulate", i.det_json, "--bundle", i.bundle, "-o", o],
        ours=("body3DScene_00000000.json",), inputs=lambda i: [i.bundle, i.det_json], contents=ALL)],
    "pointcloud": [Entry(
        "dome-calib", "file",
        lambda i, o: ["pointcloud", "--bundle", i.bundle, "--time-ms", "1100", "--depth", i.kinect, "-o", o],
        out_name="c.ply", inputs=lambda i: [i.bundle / CAL], reads=lambda i: [i.bundle])],
    "synth": [Entry(
        "dome-calib", "folder",
        lambda i, o: ["synth", o, "--overwrite", "--scenes", "1", "--cameras", "01_01", "--workers", "1"],
        ours=("capture.json", "scenes/scene_01/01_01.png"),
        names=lambda i, o, n: ["synth", o, "--scenes", "1", "--cameras", f"01_01,{n}", "--workers", "1"],
        long=lambda i, o: ["synth", o, "--scenes", "1", "--cameras", "00_00,00_01,00_12", "--workers", "1"],
        started=_staging_in)],
    "kinect-synth": [Entry(
        "dome-calib", "folder",
        lambda i, o: ["kinect-synth", o, "--bundle", i.bundle, "--sensors", "1", "--frames", "1"],
        ours=("ground_truth.json",), inputs=lambda i: [i.bundle])],
    "patterns": [Entry(
        "dome-calib", "into", lambda i, o: ["patterns", o, "--width", "64", "--height", "64"],
        ours=("pattern_P1.png",))],
    "kinect": [Entry(
        "dome-calib", "into", lambda i, o: ["kinect", i.kinect, "--bundle", i.bundle, "-o", o],
        ours=("kcalibration_test.json",), inputs=lambda i: [i.kinect], reads=lambda i: [i.bundle])],
    "report": [Entry(
        "dome-calib", "folder", lambda i, o: ["report", o.parent], ours=("index.html", "dome.png"),
        out_at=lambda sandbox: sandbox / "bundle" / "report", setup=_copy_bundle,
        reads=lambda i: [i.root.parent / "bundle"])],
    "decode": [Entry(
        "timecode", "file", lambda i, o: ["decode", i.ltc, "-o", o], out_name="table.txt", inputs=lambda i: [i.ltc],
        contents=("empty", "truncated"))],
    "sync": [Entry(
        "timecode", "into", lambda i, o: ["sync", i.sync, "-o", o], ours=("synctables_test.json",),
        inputs=lambda i: [i.sync], reads=_sync_reads, names=lambda i, o, n: ["sync", i.sync, "-o", o, "--seq", n])],
}

#: The situation kinds. A "refuse" kind must end in a refusal; the others in a success or a clean refusal.
KINDS = {
    "foreign": "the output holds someone else's files (named as ours write them), or is someone else's file",
    "symlink": "the output is a symbolic link (to someone else's folder or file)",
    "wrong type": "a file where the output folder belongs, a folder where the output file belongs",
    "read-only": "the output cannot be written (a read-only place)",
    "equals input": "the output is one of the command's inputs",
    "inside input": "the output is a new folder or file inside an input folder",
    "names": "a name the command takes is a path or hostile text: ../x, absolute, empty, 300 characters, newline, HTML",
    "sigterm": "SIGTERM arrives midway through a long run",
    "reads only": "a command that writes nothing: it writes nothing",
    **CONTENT_KINDS,
}
REFUSE = {"foreign", "symlink", "wrong type", "read-only", "equals input"}

NAME_VALUES = ("../x", "{sandbox}/abs/x", "", "a" * 300, "a\nb", "<script>alert(1)</script>")
