"""The same bytes run to run (docs/conventions.md, "Same result on every machine"): every command of the catalogue
that writes (``export`` to every format), run on its small input twice, in two processes at once, every file either
run wrote compared byte for byte (the tests are in :mod:`.test_matrix`, which builds the same inputs;
``bench/same_bytes.py`` runs it across OpenBLAS kernel sets and against an older CPU's library paths).

The inputs are the hostile matrix's (:mod:`.inputs`), each process with its own copy, and for ``calibrate`` a capture
with images (five VGA cameras of ``data/synthetic/tiny``: the matrix's capture has none, so calibrate stops before
its solvers). Each process runs every command in turn in one interpreter (as the console scripts do), so the cost is
two start-ups, not two per command. Before the comparison:

- **timings**: a JSON field named ``seconds`` or ``*_seconds`` (in the file, or in the JSON a page embeds) holds
  measured durations (``report.json``'s ``stage_seconds``, the work folder's stage records): its value is not
  compared;
- **the place of the run**: the path of each process's own folder, where a file names an input or an output by
  its path, is read as the same;
- **ownership records** (``.dome-calib-written.json``): the same paths listed; their hashes are of files compared
  here themselves;
- **SQLite's write-ahead log** (``*.db-wal``, ``*.db-shm`` in calibrate's work folder): its header holds a random
  salt per connection; the database it belongs to (``database.db``) is compared;
- **pickled stage results** (``*.pkl`` in calibrate's work folder): they hold the stage's timings; the bundle made
  from them is compared.

Not run: ``demo`` (minutes: it synthesises a session and runs ``session`` and ``reconstruct`` on it; across kernels
``bench/kernels.py --stages demo`` compares it) and the commands that write nothing (``info``, ``compare``).
``kinect``, ``pointcloud`` and ``session`` refuse the matrix's small inputs (no Kinect images: :data:`REFUSED`) and
so write nothing, the same twice; the test fails if any other command does not go through.
"""
from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path


from dome_calib.interop.registry import FORMATS

from .catalogue import ENTRIES, Entry
from .inputs import Inputs, rooted

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "data" / "synthetic" / "tiny"
CALIBRATE_CAMERAS = ("01_01", "01_02", "01_03", "13_01", "13_02")  # VGA (640 x 480): the cheapest images to match
NOT_RUN = {"demo": "minutes; its stages are session and reconstruct (bench/kernels.py --stages demo)"}
#: The writers that take more than a few seconds on their small input (on 2 cores): their pair runs in the slow tests.
HEAVY = {"calibrate": "SIFT, matching, mapping, bundle adjustment and the report of 5 images: ~20 s",
         "synth": "renders an HD image: ~10 s", "kinect-synth": "renders the Kinect frames: ~15 s"}
#: What refuses the matrix's small inputs, so writes nothing (the same nothing twice), and why.
REFUSED = {"kinect": "the matrix's Kinect folder is empty", "pointcloud": "no depth frames (the same empty folder)",
           "session": "no Kinect images in the matrix's session"}
RECORD = ".dome-calib-written.json"
EXEMPT = re.compile(r"\.(db-wal|db-shm|pkl)$")  # calibrate's work folder: SQLite's log (a random salt), timings

_SECONDS = re.compile(r'("(?:\w+_)?seconds"\s*:\s*)(\{[^{}]*\}|-?[0-9][0-9.eE+-]*)')

_DRIVER = """
import json, sys, time
from dome_calib.cli import main as dome_calib
from timecode.cli import main as timecode
codes, seconds = [], []
for prog, args in json.loads(sys.argv[1]):
    sys.argv = [prog, *args]
    t0 = time.perf_counter()
    try:
        (dome_calib if prog == "dome-calib" else timecode)()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    codes.append(code)
    seconds.append(round(time.perf_counter() - t0, 2))
open("codes.json", "w").write(json.dumps({"codes": codes, "seconds": seconds}))
"""


def _every_export() -> list[Entry]:
    """``export`` to every format that writes (the catalogue has two: the matrix crosses those with every situation;
    here each format's own numbers are compared), the catalogue's own entries first."""
    have = {e.variant: e for e in ENTRIES["export"]}
    out = []
    for info in FORMATS:
        if not info.writes or info.name in have:
            continue
        name = info.default_file or {"pose2sim": "Calib.toml", "blender": "cameras.py"}.get(info.name, "out")
        out.append(Entry("dome-calib", "folder" if info.folder else "file",
                         lambda i, o, fmt=info.name: ["export", i.bundle, "--to", fmt, "-o", o],
                         out_name=name, variant=info.name))
    return list(have.values()) + out


def writers(heavy: bool | None = None) -> list[tuple[str, Entry]]:
    """(label, entry) of every command that writes (``heavy``: only those of :data:`HEAVY`, or only the others);
    ``export`` to every format (:func:`_every_export`)."""
    entries = {**ENTRIES, "export": _every_export()}
    return [(f"{name}{'-' + e.variant if e.variant else ''}", e) for name, entries in sorted(entries.items())
            for e in entries if e.output != "none" and name not in NOT_RUN
            and (heavy is None or (name in HEAVY) == heavy)]


def _capture(folder: Path) -> Path:
    """Five VGA cameras of the committed tiny capture, with its ground truth; every file with the time stamp of its
    original (the work folder's record of the inputs holds their sizes and times)."""
    shutil.copytree(TINY / "ground_truth", folder / "ground_truth")
    (folder / "scenes" / "scene_01").mkdir(parents=True)
    for name in CALIBRATE_CAMERAS:
        shutil.copy2(TINY / "scenes" / "scene_01" / f"{name}.png", folder / "scenes" / "scene_01")
    doc = json.loads((TINY / "capture.json").read_text())
    doc["cameras"] = list(CALIBRATE_CAMERAS)
    (folder / "capture.json").write_text(json.dumps(doc))
    os.utime(folder / "capture.json", ns=(0, (TINY / "capture.json").stat().st_mtime_ns))
    return folder


def _prepare(inputs: Inputs, side: Path, chosen: list[tuple[str, Entry]]) -> list[list]:
    """A copy of the inputs in ``side`` and the command lines of the ``chosen`` writers, each into its own folder."""
    i = rooted(inputs, side / "in")
    shutil.copytree(inputs.root, i.root, symlinks=True)
    i = dataclasses.replace(i, capture=_capture(side / "in" / "capture_images"))
    lines = []
    for label, entry in chosen:
        here = side / label
        here.mkdir()
        if entry.setup is not None:
            entry.setup(i, here)
        out = entry.out_at(here) if entry.out_at is not None else here / entry.out_name
        lines.append([entry.prog, [str(a) for a in entry.argv(i, out)]])
    return lines


def normal(path: Path, side: Path) -> bytes:
    data = path.read_bytes()
    if path.name == RECORD:
        return json.dumps(sorted(json.loads(data)["entries"])).encode()
    if path.suffix not in (".json", ".html", ".txt", ".toml", ".trc", ".csv", ".yaml", ".yml", ".py"):
        return data
    text = data.decode("utf-8", errors="surrogateescape").replace(str(side), "SIDE")
    return seconds_hidden(text).encode("utf-8", errors="surrogateescape")


def seconds_hidden(text: str) -> str:
    """``text`` with the value of every JSON field named ``seconds`` or ``*_seconds`` replaced by ``T``."""
    return _SECONDS.sub(r"\1T", text)


def files_of_side(side: Path) -> dict[str, Path]:
    return {str(p.relative_to(side)): p for p in sorted(side.rglob("*"))
            if p.is_file() and not p.is_symlink() and p.name != "codes.json" and not EXEMPT.search(p.name)}


@dataclasses.dataclass(frozen=True)
class Runs:
    """Two runs of every writer: ``sides`` (the folders), ``codes`` and ``seconds`` per side (in ``labels``' order),
    the files each side wrote (relative path -> path, exempt kinds left out)."""

    labels: list[str]
    sides: list[Path]
    codes: list[list[int]]
    seconds: list[list[float]]
    files: list[dict[str, Path]]

    def differing(self) -> list[str]:
        """Files of both sides whose normalised bytes differ, and files only one side wrote."""
        a, b = self.files
        only = sorted(set(a) ^ set(b))
        return only + [rel for rel in sorted(set(a) & set(b))
                       if normal(a[rel], self.sides[0]) != normal(b[rel], self.sides[1])]


def run_twice(inputs: Inputs, root: Path, envs: tuple[dict, dict] = ({}, {}), heavy: bool | None = None,
              only: frozenset[str] | None = None) -> Runs:
    """The writers (``heavy``: as :func:`writers`; ``only``: those labels) run on ``inputs`` by two processes at
    once, in ``root/a`` and ``root/b``, each with its own copy of the inputs and the variables of ``envs`` added to
    its environment (``bench/same_bytes.py``: OpenBLAS's kernel sets, an older CPU's library paths)."""
    sides, runs = [root / "a", root / "b"], []
    chosen = [(label, e) for label, e in writers(heavy) if only is None or label in only]
    for side, extra in zip(sides, envs):
        side.mkdir(parents=True)
        lines = _prepare(inputs, side, chosen)
        env = {**os.environ, "PYTHONPATH": str(ROOT), **extra}
        runs.append(subprocess.Popen([sys.executable, "-c", _DRIVER, json.dumps(lines)], cwd=side, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    for run in runs:
        _, err = run.communicate(timeout=900)
        if run.returncode != 0:
            raise RuntimeError(err[-2000:])
    done = [json.loads((side / "codes.json").read_text()) for side in sides]
    return Runs(labels=[label for label, _ in chosen], sides=sides, codes=[d["codes"] for d in done],
                seconds=[d["seconds"] for d in done], files=[files_of_side(side) for side in sides])
