"""`dome-calib demo` (the README's first command, `make demo`): synthesise a small dome capture, calibrate it
with the real pipeline, compare the result with the ground truth, and print what a technician would look at.

Everything lands in one folder (default ``demo_out/``): ``as_built/`` (the synthetic dome's cameras),
``capture/`` (images + ground truth), ``bundle/``
(the calibration and its ``report/``), ``bundle.work/`` (resumable intermediate results). A rerun reuses the
capture if it was made with the same preset, scenes and seed.
"""
from __future__ import annotations

import contextlib
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from dome_calib.bundle_io import load_bundle, write_bundle
from dome_calib.compare import Comparison, compare_cameras
from dome_calib.errors import DomeCalibError
from dome_calib.pipeline import CalibrateOptions, CalibrationResult, format_result, run_calibration
from dome_calib.synth.capture import SynthOptions
from dome_calib.synth.capture import synthesize as write_capture
from dome_calib.synth.dome import as_built_dome

logger = logging.getLogger(__name__)

#: Tent positions per preset when not given: enough views for a good calibration in the time budget.
DEFAULT_SCENES = {"tiny": 3, "panel": 3, "full": 3}


@dataclass(kw_only=True)
class DemoOptions:
    preset: str = "tiny"  # panel's SfM alone needs ~6.5 CPU-minutes: over the 5-minute budget on 2 cores
    scenes: int | None = None
    seed: int = 0
    progress: bool = True


@dataclass(kw_only=True)
class DemoResult:
    out: Path
    preset: str
    scenes: int
    seed: int
    synth_seconds: float  # 0 when the capture was reused
    calibration: CalibrationResult
    comparison: Comparison


def synthesize(capture: Path, preset: str, scenes: int, seed: int, progress: bool = True) -> float:
    """Write the synthetic capture of the dome AS BUILT (:func:`dome_calib.synth.dome.as_built_dome`: not the
    design that calibrate starts from) unless the same one is already there; returns the seconds spent."""
    layout = capture.parent / "as_built" / "calibration_as_built.json"
    meta = capture / "capture.json"
    if meta.exists() and layout.exists():
        old = json.loads(meta.read_text(encoding="utf-8"))
        if (old.get("preset") == preset and old.get("seed") == seed and len(old.get("scenes", [])) == scenes
                and old.get("layout") == str(layout)):
            logger.info("reusing the synthetic capture in %s", capture)
            return 0.0

    t0 = time.perf_counter()
    write_bundle(as_built_dome(preset, seed), layout.parent)
    with _progress_bar(f"synthesising {preset} capture", progress) as update:
        write_capture(capture, SynthOptions(preset=preset, n_scenes=scenes, seed=seed, layout=layout, overwrite=True),
                      progress=update)
    return time.perf_counter() - t0


@contextlib.contextmanager
def _progress_bar(description: str, enabled: bool):
    """A rich progress bar fed by ``update(done, total)`` callbacks (a no-op when disabled)."""
    if not enabled:
        yield lambda done, total: None
        return

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  transient=False) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


def run_demo(out: Path, options: DemoOptions | None = None) -> DemoResult:
    """Synthesise, calibrate, compare. Raises DomeCalibError for an unknown preset."""
    options = options or DemoOptions()
    if options.preset not in DEFAULT_SCENES:
        raise DomeCalibError(f"unknown preset {options.preset!r}; choose one of {', '.join(DEFAULT_SCENES)}")
    scenes = options.scenes or DEFAULT_SCENES[options.preset]
    if scenes < 1:
        raise DomeCalibError(f"--scenes {scenes}: need at least one tent position")
    out = Path(out)
    capture = out / "capture"
    synth_s = synthesize(capture, options.preset, scenes, options.seed, options.progress)
    calibration = run_calibration(capture, out / "bundle", CalibrateOptions(seq="demo", progress=options.progress))
    truth = load_bundle(capture / "ground_truth")
    comparison = compare_cameras(calibration.bundle.cameras, truth.cameras)
    return DemoResult(out=out, preset=options.preset, scenes=scenes, seed=options.seed, synth_seconds=synth_s,
                      calibration=calibration, comparison=comparison)


def format_demo(result: DemoResult) -> str:
    """What the demo prints: per-type counts, RMS, errors against ground truth, worst cameras, where things are."""
    cal, cmp = result.calibration, result.comparison
    summary = cmp.summary()
    lines = [f"dome-calib demo: synthetic '{result.preset}' dome, {len(cal.expected)} cameras, "
             f"{result.scenes} tent positions, seed {result.seed}"]
    lines.append(f"  capture: {result.out / 'capture'}" + (f" (synthesised in {result.synth_seconds:.0f} s)"
                                                          if result.synth_seconds else " (reused)"))
    lines.append("  ground truth: the dome as built (cameras off the design by ~1.5 cm and ~3 deg, other lenses);\n"
                 "  the calibration starts from the design layout (no --prior)")
    lines.append("")
    lines.append("calibration (dome-calib calibrate):")
    lines += ["  " + line for line in _format_calibration_lines(cal)]
    lines.append("")
    lines.append("against the ground truth (after a similarity alignment):")
    for key in ["vga", "hd", "kinect-color", "all"]:
        if key in summary:
            s = summary[key]
            lines.append(f"  {key:<13}{s['count']:>4} cams  centre error {s['center_cm_median'] * 10:6.2f} mm median, "
                         f"{s['center_cm_max'] * 10:6.2f} mm max;  rotation {s['rotation_deg_median']:.3f} deg;  "
                         f"focal {s['focal_pct_median']:.3f} %;  lens {s['distortion_px_median']:.1f} px")
    lines.append("  worst cameras: " + ", ".join(f"{e.name} {e.center_cm * 10:.1f} mm" for e in cmp.worst(5)))
    lines.append("  (lens: median over cameras of the largest distortion difference over the whole image, corners\n"
                 "   included where the tent never appears)")
    lines.append("")
    lines.append(f"bundle: {cal.bundle_dir}/calibration_{cal.bundle.seq}.json")
    lines.append(f"report: {cal.report_dir}/dome.png (open it), report.json")
    return "\n".join(lines)


def _format_calibration_lines(cal: CalibrationResult) -> list[str]:

    return [line for line in format_result(cal).splitlines() if not line.startswith(("bundle:", "report:"))]
