"""Kill `dome-calib calibrate` with SIGKILL at random moments (seeded) and check what a stop leaves behind.

    .venv/bin/python bench/kill.py                 # 20 kills on the tiny synthetic dome, 2 tent positions
    .venv/bin/python bench/kill.py --kills 3 --late-kills 2   # what tests/test_calibrate_kill.py runs (slow)

The output folder starts as an "old" bundle (the design layout, seq "old"). Each round starts calibrate on the
tiny capture into it and SIGKILLs the whole process group (workers included) after a random delay in
[0, 1.1 x the uninterrupted wall time); when a run was allowed to finish, the work folder is emptied so the next
round's kill lands in a stage again. Then ``--late-kills`` rounds aim at the end of the run: with the SfM
finished and only the bundle adjustment's result removed from the work folder, each run does the bundle
adjustment, the world frame and the write (bundle and report staged beside OUT, then swapped in), and is killed
at a random moment of that (0 to 1.1 x its uninterrupted time). After every kill the output folder must load
and hold either the old bundle or the new one. Finally a rerun completes, and its cameras are compared with an
uninterrupted run's.
Prints one JSON object per line.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dome_calib.bundle_io import load_bundle, write_bundle  # noqa: E402
from dome_calib.compare import camera_error  # noqa: E402
from dome_calib.layout import nominal_dome  # noqa: E402

SEQ = "tiny"


def calibrate_cmd(capture: Path, out: Path) -> list[str]:
    return [sys.executable, "-c", "from dome_calib.cli import main; main()", "calibrate", str(capture), "-o",
            str(out), "--seq", SEQ]


def run(cmd: list[str], kill_after_s: float | None = None) -> tuple[int, float, str]:
    """Run ``cmd`` in its own process group; SIGKILL the group after ``kill_after_s``. (rc, seconds, stderr)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=ROOT)
    try:
        _, err = proc.communicate(timeout=kill_after_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
    return proc.returncode, time.perf_counter() - t0, err


def output_state(out: Path) -> str:
    try:
        seq = load_bundle(out).seq
    except Exception as exc:  # noqa: BLE001 - counted and reported
        return f"unloadable: {exc}"
    return "old" if seq == "old" else "new" if seq == SEQ else f"other seq {seq}"


def stage_of(work: Path) -> str:
    """The last stage finished in the work folder ("" for none)."""
    try:
        return ",".join(json.loads((work / "state.json").read_text())["stages"])
    except (OSError, ValueError, KeyError):
        return ""


def compare(a: dict, b: dict) -> dict:
    errs = [camera_error(a[n], b[n]) for n in sorted(a)]
    return {"cameras": len(a), "same_names": sorted(a) == sorted(b),
            "center_mm_max": max(e.center_cm for e in errs) * 10,
            "rotation_deg_max": max(e.rotation_deg for e in errs), "focal_pct_max": max(e.focal_pct for e in errs)}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20, help="kills at random moments of the whole run")
    ap.add_argument("--late-kills", type=int, default=10, help="kills during BA, world frame and the write of OUT")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--work", type=Path, help="keep the capture and runs here (default: a temp folder)")
    args = ap.parse_args(argv)
    base = args.work or Path(tempfile.mkdtemp(prefix="dome_kill_"))
    base.mkdir(parents=True, exist_ok=True)
    capture, ref, out = base / "capture", base / "reference", base / "out"
    work = out.with_name(out.name + ".work")
    if not (capture / "capture.json").exists():
        subprocess.run([sys.executable, "-c", "from dome_calib.cli import main; main()", "synth", str(capture),
                        "--preset", "tiny", "--scenes", str(args.scenes), "--overwrite"], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL)
    for p in (ref, ref.with_name(ref.name + ".work"), out, work):
        shutil.rmtree(p, ignore_errors=True)
    rc, full_s, err = run(calibrate_cmd(capture, ref))
    if rc != 0:
        raise SystemExit(f"uninterrupted run failed: {err}")
    reference = load_bundle(ref)
    print(json.dumps({"bench": "kill", "what": "uninterrupted", "seconds": round(full_s, 1),
                      "cameras": len(reference.cameras)}), flush=True)
    write_bundle(nominal_dome("tiny", 0).__class__(seq="old", cameras=nominal_dome("tiny", 0).cameras), out)
    rng = np.random.default_rng(args.seed)
    outcomes = {"old": 0, "new": 0, "unloadable": 0, "finished": 0}
    for k in range(args.kills):
        delay = float(rng.uniform(0.0, 1.1 * full_s))
        before = stage_of(work)
        rc, seconds, err = run(calibrate_cmd(capture, out), kill_after_s=delay)
        finished = rc == 0
        state = output_state(out)
        outcomes["finished" if finished else ("old" if state == "old" else "new" if state == "new" else "unloadable")] += 1
        print(json.dumps({"bench": "kill", "round": k + 1, "kill_after_s": round(delay, 2), "rc": rc,
                          "stages_done_before": before, "stages_done_after": stage_of(work), "output": state,
                          "stderr_lines": len([line for line in err.splitlines() if line.strip()])}), flush=True)
        if finished:
            shutil.rmtree(work, ignore_errors=True)  # the next kill lands in a stage again
    late_outcomes = {"old": 0, "new": 0, "unloadable": 0, "finished": 0}
    late_s = 0.0
    if args.late_kills:
        run(calibrate_cmd(capture, out))  # every stage finished once
        (work / "ba.pkl").unlink()
        _, late_s, _ = run(calibrate_cmd(capture, out))  # BA, world frame and write only
        shutil.rmtree(out)
        write_bundle(nominal_dome("tiny", 0).__class__(seq="old", cameras=nominal_dome("tiny", 0).cameras), out)
    for k in range(args.late_kills):
        (work / "ba.pkl").unlink(missing_ok=True)
        delay = float(rng.uniform(0.0, 1.1 * late_s))
        rc, seconds, err = run(calibrate_cmd(capture, out), kill_after_s=delay)
        state = output_state(out)
        late_outcomes["finished" if rc == 0 else state if state in ("old", "new") else "unloadable"] += 1
        print(json.dumps({"bench": "kill", "late_round": k + 1, "kill_after_s": round(delay, 2),
                          "late_run_s": round(late_s, 2), "rc": rc, "output": state}), flush=True)
        if rc == 0 or state == "new":  # the old bundle back, so that old and new stay distinguishable
            shutil.rmtree(out)
            write_bundle(nominal_dome("tiny", 0).__class__(seq="old", cameras=nominal_dome("tiny", 0).cameras), out)
    rc, seconds, err = run(calibrate_cmd(capture, out))
    final = load_bundle(out)
    summary = {"bench": "kill", "what": "summary", "kills": args.kills, "seed": args.seed, **outcomes,
               "late_kills": args.late_kills, "late_phase": late_outcomes,
               "rerun_rc": rc, "rerun_seconds": round(seconds, 1),
               "vs_uninterrupted": compare(final.cameras, reference.cameras)}
    print(json.dumps(summary), flush=True)
    if args.work is None:
        shutil.rmtree(base, ignore_errors=True)
    return summary


if __name__ == "__main__":
    main()
