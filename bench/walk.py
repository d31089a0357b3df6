"""A walk of the calibration (capture -> SfM -> BA -> world frame -> write), or of `reconstruct`: which modules it
passes through.

    .venv/bin/python bench/walk.py CAPTURE [--work /tmp/dome_walk] [--tree CHECKOUT]
    .venv/bin/python bench/walk.py --reconstruct DETECTIONS --bundle BUNDLE [--options='--body-model BODY_25'] [--work
        /tmp/dome_walk] [--tree CHECKOUT]

Runs `calibrate` on CAPTURE (from the design layout, no prior, no progress display) in this process with a
profile hook on every thread (the worker processes are not followed: they run one task function each) and
records every call that crosses from one of our modules (``dome_calib``, ``projector``, ``timecode``) into
another (a generator resumed by its consumer is not a crossing). At each crossing the stack of our modules is
read (consecutive frames of one module count once). One JSON object per line:

- ``modules``: how many of our modules the walk enters, and how many it enters per package;
- ``way_down``: the modules on the stack when ``run_sfm`` is called (its callers, from ``run_calibration``);
- ``reentries``: crossings into a module that is already on the stack below another module (A -> B -> A: the
  data goes out of A and comes back into it): how many distinct (stack) patterns and the first few;
- ``run_sfm``: the crossings out of ``run_sfm``'s own frame into other modules' functions (each a hand-over of the
  calibration's data and its return), and how many distinct functions they are;
- ``work_folder``: the way of the SfM's work folder: every call (from ``run_sfm_stage`` down) that is handed the
  work folder or a path inside it, by module in the order of the calls (a module's consecutive calls once): the
  rooms it passes through, and the returns (a room entered again after the way had left it for another); and the
  same per thread (``per_thread``: the mappers run in threads while the pool works on, so the way above is two
  ways interleaved as the threads happen to run: the per-thread returns are the structure's alone);
- ``work_folder_held``: the same way, counting also a call handed an object that holds the work folder (an
  attribute that is the folder or a path inside it, one level deep: an object of the places, ``self`` of its
  methods), so that a folder kept in an object is followed too.

``--reconstruct``: `dome-calib reconstruct DETECTIONS --bundle BUNDLE -o WORK/people` (this checkout's own command
line, in this process, on one core: no ``--workers``) under the same hook, followed as data (``reconstruct_way``):
every call handed one of the run's places (the detections folder, the bundle folder, the output folder and its
staging folder beside it: the folder or a path inside it, or an object or container holding one, two levels deep:
the plan, the source's camera -> frame -> file index) by module in call order (a module's consecutive calls once;
a call from a module into itself below a frame of that module that holds a place is no new stay: one file after
another read by one reader is one stay, and so is a loop of one frame into the same room again: a stream after
another, a camera after another): stays, rooms, returns, as the work folder's way above; and what the run opened (``reconstruct_reads``, from the
interpreter's ``open`` audit events): per place the files read, how often each was read (a detection file read by
three passes counts 3), and the calls of ``load_bundle`` and ``camera_report``.

Works on any checkout (module names are read from the frames), so the same capture walks the old and the new
house: ``--tree`` imports the toolkit of another checkout (``git worktree add``). Timings are meaningless under the hook and not printed.
"""
from __future__ import annotations

import argparse
import inspect
import json
import shlex
import shutil
import sys
import threading
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OURS = ("dome_calib", "projector", "timecode")
_GENERATOR = inspect.CO_GENERATOR | inspect.CO_COROUTINE | inspect.CO_ASYNC_GENERATOR


def emit(**obj) -> None:
    print(json.dumps(obj), flush=True)


def _module(frame) -> str:
    return frame.f_globals.get("__name__", "") or ""


def _ours(name: str) -> bool:
    return name.split(".")[0] in OURS


def _stack(frame) -> list[str]:
    """Our modules from the bottom of the stack to ``frame`` (consecutive frames of one module once)."""
    mods = []
    while frame is not None:
        m = _module(frame)
        if _ours(m) and (not mods or mods[-1] != m):
            mods.append(m)
        frame = frame.f_back
    return mods[::-1]


class Walk:
    def __init__(self) -> None:
        self.entered: Counter[str] = Counter()
        self.reentries: Counter[tuple[str, ...]] = Counter()
        self.way_down: list[str] | None = None
        self.sfm_crossings: Counter[str] = Counter()
        self.lock = threading.Lock()
        self.work: str | None = None  # the SfM's work folder, once run_sfm_stage is called
        self.work_way: list[str] = []  # modules handed the work folder, in call order (consecutive ones once)
        self.thread_ways: dict[int, list[str]] = {}  # the same, per thread (a thread's ident may be reused: own keys)
        self._thread = threading.local()
        self.held_way: list[str] = []  # modules handed the work folder or an object holding it

    def _is_work(self, value) -> bool:
        return isinstance(value, (str, Path)) and (str(value) + "/").startswith(self.work + "/")

    def _hands_work(self, frame, held: bool = False) -> bool:
        """Whether a call's arguments are the work folder or a path inside it (``held``: or an object with such an
        attribute)."""
        code = frame.f_code
        for name in code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]:
            value = frame.f_locals.get(name)
            if self._is_work(value):
                return True
            if held and any(self._is_work(v) for v in getattr(value, "__dict__", {}).values()):
                return True
        return False

    @staticmethod
    def _append(way: list[str], module: str) -> None:
        if not way or way[-1] != module:
            way.append(module)

    def hook(self, frame, event, arg) -> None:
        if event != "call":
            return
        callee = _module(frame)
        if not _ours(callee):
            return
        if frame.f_code.co_flags & _GENERATOR:
            return  # a generator is resumed by whoever iterates it: not a call into its module
        caller = frame.f_back
        name = frame.f_code.co_name
        if caller is not None and caller.f_code.co_name == "run_sfm" and _module(caller).endswith("sfm") \
                and callee != _module(caller):
            with self.lock:
                self.sfm_crossings[f"{callee}.{name}"] += 1
        if name == "run_sfm" and self.way_down is None:
            self.way_down = _stack(frame)
        if name == "run_sfm_stage" and self.work is None:
            self.work = str(frame.f_locals.get("work_dir"))
        if self.work is not None and self._hands_work(frame):
            with self.lock:
                self._append(self.work_way, callee)
                if not hasattr(self._thread, "key"):
                    self._thread.key = len(self.thread_ways)
                self._append(self.thread_ways.setdefault(self._thread.key, []), callee)
        if self.work is not None and self._hands_work(frame, held=True):
            with self.lock:
                self._append(self.held_way, callee)
        # find the nearest caller of ours (stdlib frames, functools.partial, threads in between are skipped)
        f = caller
        while f is not None and not _ours(_module(f)):
            f = f.f_back
        if f is not None and _module(f) == callee:
            return
        stack = _stack(frame)
        with self.lock:
            self.entered[callee] += 1
            if callee in stack[:-1]:
                first = stack.index(callee)
                self.reentries[tuple(stack[first:])] += 1


class ReconstructWalk:
    """The way of `reconstruct`'s places (see the module docstring) and the files it opens."""

    COUNTED = ("load_bundle", "camera_report")

    def __init__(self, places: dict[str, Path]) -> None:
        self.places = {k: str(v.resolve()) for k, v in places.items()}
        out = Path(self.places["out"])
        self.staging = f"{out.parent}/.{out.name}."  # io_utils.atomic_folder's staging and set-aside folders
        self.way: list[str] = []
        self.reads: dict[str, Counter[str]] = {k: Counter() for k in self.places}
        self.calls: Counter[str] = Counter()
        self.on = False
        self.by_holder: dict[int, tuple[object, set[str]]] = {}  # frame id -> (the frame, kept alive; rooms entered)

    def place_of(self, value, depth: int = 2) -> str | None:
        if isinstance(value, (str, Path)):
            text = str(value)
            for name, root in self.places.items():
                if text == root or text.startswith(root + "/") or (name == "out" and text.startswith(self.staging)):
                    return name  # the output folder's staging sibling (.OUT.new.<tag>...) counts as the output
            return None
        if depth == 0 or isinstance(value, (int, float, bytes, bool)) or value is None:
            return None
        if isinstance(value, dict):  # its first key and first non-empty value (a camera may hold no file)
            items = list(value.keys())[:1] + [next((v for v in value.values() if not (isinstance(v, (dict, list, tuple)) and not v)), None)]
        elif isinstance(value, (list, tuple)):
            items = list(value[:1])
        else:
            items = list(getattr(value, "__dict__", {}).values()) if not inspect.isroutine(value) else []
        for v in items:
            found = self.place_of(v, depth - 1)
            if found:
                return found
        return None

    def hook(self, frame, event, arg) -> None:
        if event != "call" or not self.on:
            return
        callee = _module(frame)
        if not _ours(callee) or frame.f_code.co_flags & _GENERATOR:
            return
        name = frame.f_code.co_name
        if name in self.COUNTED:
            self.calls[name] += 1
        if not self._handed(frame):
            return
        holder = frame.f_back  # the nearest frame of ours below that holds a place: a call inside its room is a stay
        while holder is not None and not (_ours(_module(holder)) and self._handed(holder)):
            holder = holder.f_back
        if holder is not None and _module(holder) == callee:
            return
        # a loop of one holder (a stream after another, a camera after another) into the same room is one stay
        seen = self.by_holder.setdefault(id(holder), (holder, set()))[1]
        if callee not in seen:
            seen.add(callee)
            Walk._append(self.way, callee)

    def _handed(self, frame) -> bool:
        code = frame.f_code
        return any(self.place_of(frame.f_locals.get(n))
                   for n in code.co_varnames[:code.co_argcount + code.co_kwonlyargcount])

    def audit(self, event: str, args) -> None:
        if event != "open" or not self.on or not isinstance(args[0], (str, Path)):
            return
        mode = args[1] if len(args) > 1 and isinstance(args[1], str) else "r"
        if any(c in mode for c in "wax+"):
            return
        path = str(args[0])
        if not path.endswith((".json", ".png", ".npz")):
            return  # the files a run reads (not the modules Python imports)
        place = self.place_of(path, 0)
        if place:
            self.reads[place][path] += 1


def walk_reconstruct(args) -> None:
    from dome_calib.cli import main as cli_main

    out = args.work / "people"
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    walk = ReconstructWalk({"detections": args.reconstruct, "bundle": args.bundle, "out": out})
    sys.addaudithook(walk.audit)
    argv = ["dome-calib", "reconstruct", str(args.reconstruct), "--bundle", str(args.bundle), "-o", str(out),
            *shlex.split(args.options)]
    sys.argv = argv
    threading.setprofile(walk.hook)
    sys.setprofile(walk.hook)
    walk.on = True
    try:
        cli_main()
    except SystemExit as exc:
        if exc.code not in (0, None):
            raise
    finally:
        walk.on = False
        sys.setprofile(None)
        threading.setprofile(None)
    rooms = Counter(walk.way)
    emit(bench="walk", stage="reconstruct_way", argv=argv[1:], stays=len(walk.way), rooms=len(rooms),
         returns=sum(v - 1 for v in rooms.values()),
         visits={m: v for m, v in sorted(rooms.items(), key=lambda kv: (-kv[1], kv[0]))}, way=walk.way)
    emit(bench="walk", stage="reconstruct_reads", calls=dict(sorted(walk.calls.items())),
         **{place: {"files": len(c), "reads": sum(c.values()),
                    "reads_per_file": {str(n): k for n, k in sorted(Counter(c.values()).items())}}
            for place, c in walk.reads.items()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path, nargs="?")
    parser.add_argument("--work", type=Path, default=Path("/tmp/dome_walk"))
    parser.add_argument("--tree", type=Path, help="walk the toolkit of this checkout instead of this one's")
    parser.add_argument("--reconstruct", type=Path, metavar="DETECTIONS", help="walk `reconstruct` of this "
                        "detections folder instead of the calibration (with --bundle)")
    parser.add_argument("--bundle", type=Path, help="the bundle of --reconstruct")
    parser.add_argument("--options", default="", help="more options of reconstruct, one string: "
                        "--options='--body-model BODY_25'")
    args = parser.parse_args()
    if args.tree is not None:
        sys.path.insert(0, str(args.tree.resolve()))
    if args.reconstruct is not None:
        if args.bundle is None:
            parser.error("--reconstruct needs --bundle")
        args.reconstruct, args.bundle = args.reconstruct.resolve(), args.bundle.resolve()
        args.work = args.work.resolve()
        return walk_reconstruct(args)
    if args.capture is None:
        parser.error("give CAPTURE, or --reconstruct DETECTIONS --bundle BUNDLE")
    try:  # the new house
        from dome_calib.pipeline.full import run_calibration
        from dome_calib.pipeline.types import CalibrateOptions
    except ImportError:  # the flat house (before issue 35)
        from dome_calib.pipeline import CalibrateOptions, run_calibration
    shutil.rmtree(args.work, ignore_errors=True)
    walk = Walk()
    threading.setprofile(walk.hook)
    sys.setprofile(walk.hook)
    try:
        options = CalibrateOptions(seq="walk")
        if options.progress is True:  # the flat house: a bool (spinners); now None, no bars
            options.progress = False
        result = run_calibration(args.capture, args.work / "bundle", options)
    finally:
        sys.setprofile(None)
        threading.setprofile(None)
    per_package = Counter(m.split(".")[0] for m in walk.entered)
    emit(bench="walk", stage="modules", cameras=len(result.bundle.cameras), entered=len(walk.entered),
         per_package=dict(sorted(per_package.items())))
    emit(bench="walk", stage="way_down", run_sfm_callers=walk.way_down, modules=len(walk.way_down or []))
    patterns = sorted(walk.reentries, key=lambda p: (-walk.reentries[p], p))
    emit(bench="walk", stage="reentries", patterns=len(patterns),
         first=[" -> ".join(p) for p in patterns[:8]])
    emit(bench="walk", stage="run_sfm", crossings=sum(walk.sfm_crossings.values()),
         distinct=len(walk.sfm_crossings), functions=sorted(walk.sfm_crossings))
    for stage, way in (("work_folder", walk.work_way), ("work_folder_held", walk.held_way)):
        rooms = Counter(way)
        per_thread = [sum(v - 1 for v in Counter(w).values()) for w in walk.thread_ways.values()]
        emit(bench="walk", stage=stage, stays=len(way), rooms=len(rooms),
             rooms_projector=sum(1 for m in rooms if m.startswith("projector.")),
             returns=sum(v - 1 for v in rooms.values()),
             returns_without_io=sum(v - 1 for m, v in rooms.items() if m != "dome_calib.io_utils"),
             **({"per_thread": {"threads": len(per_thread), "returns": per_thread}} if stage == "work_folder" else {}),
             visits={m: v for m, v in sorted(rooms.items(), key=lambda kv: (-kv[1], kv[0]))}, way=way)


if __name__ == "__main__":
    main()
