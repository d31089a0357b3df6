"""Body of ``timecode sync`` (kept out of timecode/cli/__init__.py so --help stays fast and the shell stays thin)."""
from __future__ import annotations

import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from timecode.sync.pipeline import output_seq, sync_session, write_sync
from timecode.sync.report import summary_lines
from timecode.sync.session import load_session
from timecode.sync.tables import SyncOptions


def run_sync(session: Path, output: Path, *, seq: str | None, strict_kinect: bool, max_extrapolation_s: float) -> None:
    """Decode, fit, write; print the per-stream summary. Errors propagate as one-line user errors."""
    opts = SyncOptions(strict_kinect=strict_kinect, max_extrapolation_s=max_extrapolation_s)
    loaded = load_session(session)
    output_seq(output, seq, loaded.seq)  # a contradicting --seq fails before the decoding work
    n_steps = 2 + len(loaded.kinects)
    with Progress(TextColumn("{task.description:<40}"), BarColumn(), MofNCompleteColumn(),
                  console=Console(stderr=True), transient=True, disable=not sys.stderr.isatty()) as bar:
        task = bar.add_task("decoding", total=n_steps)
        done = [0]

        def step(what: str) -> None:  # called before each decoding step
            bar.update(task, description=what, completed=done[0])
            done[0] += 1

        result = sync_session(loaded, opts, progress=step)
        bar.update(task, completed=n_steps)
    written = write_sync(result, output, seq=seq)
    for line in summary_lines(result):
        typer.echo(line)
    typer.echo(f"wrote {', '.join(str(p) for p in written)}")
