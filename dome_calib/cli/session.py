"""`dome-calib session`: a thin shell over dome_calib.pipeline.session (imported inside the command: --help
stays fast)."""
from __future__ import annotations

import logging
from pathlib import Path

import typer

from dome_calib.errors import interrupt_as_one_line


def format_session(result) -> str:
    """What `dome-calib session` prints: per pillar what was achieved and what to check."""
    from dome_calib.cli.kinect import format_sensor_line
    from dome_calib.pipeline.full import format_result
    from timecode.sync.report import summary_lines

    lines = ["calibration (cameras):"]
    lines += ["  " + ln for ln in format_result(result.calibration).splitlines()
              if not ln.startswith(("bundle:", "report:"))]
    lines.append("kinect (depth to colour):")
    for r in result.kinect:
        lines += ["  " + ln for ln in format_sensor_line(r.summary())]
    lines.append("sync (universal time):")
    lines += ["  " + ln for ln in summary_lines(result.sync)]
    lines.append("to check:")
    checks = [(p, c) for p, v in result.report["pillars"].items() for c in v["to_check"]]
    lines += [f"  {p}: {c}" for p, c in checks] or ["  nothing: every pillar within its limits"]
    lines.append("stage times: " + ", ".join(f"{k} {v:.1f} s" for k, v in result.stage_seconds.items()))
    lines.append(f"bundle: {result.bundle_dir}/calibration_{result.bundle.seq}.json (+ kcalibration, synctables, "
                 "ksynctables)")
    lines.append(f"report: {result.bundle_dir}/report/index.html (open it in a browser; also session.json, sync.json)")
    return "\n".join(lines)


def session(
    folder: Path = typer.Argument(..., metavar="SESSION", help="Session folder: capture/ (tent images), kinect/ (checkerboard pairs), "
                                  "sync/ (session.json, ltc.wav, Kinect audio); see docs/session.md 'Session layout'.",
                                  show_default=False),
    out: Path = typer.Option(..., "-o", "--out", help="Bundle folder to write (created, or a bundle replaced "
                             "whole).", show_default=False),
    seq: str = typer.Option(None, "--seq", help="Sequence name (default: the session folder's name)."),
) -> None:
    """The technician's whole job in one run: calibrate the cameras, calibrate the Kinects against them, sync
    every stream from the LTC audio; write one bundle (calibration, kcalibration, synctables, ksynctables) and
    one report saying per pillar what was achieved and what to check. Rerun to resume the calibration."""
    with interrupt_as_one_line("dome-calib"):
        from dome_calib.cli.progress import ProgressBars
        from dome_calib.pipeline.session import SessionOptions, run_session

        logging.getLogger("dome_calib.ba").setLevel(logging.WARNING)

        def stage(name: str) -> None:
            typer.echo(f"dome-calib session: {name}", err=True)

        with ProgressBars() as bars:  # none in a log file
            result = run_session(folder, out, SessionOptions(seq=seq, progress=bars.tasks), on_stage=stage)
        typer.echo(format_session(result))


def register(app: typer.Typer) -> None:
    app.command()(session)
