"""Body of ``timecode sync`` (kept out of timecode/cli/__init__.py so --help stays fast and the shell stays thin)."""
from __future__ import annotations

from pathlib import Path

import typer

from dome_calib.cli.progress import ProgressBars
from dome_calib.errors import flags
from dome_calib.ownership import claim_into
from timecode.sync.pipeline import (check_nodes_in_bundle, check_session_audio, check_sync_output, output_seq,
                                     sync_session, write_sync)
from timecode.sync.report import summary_lines
from timecode.sync.session import load_session
from timecode.sync.tables import SyncOptions


def run_sync(session: Path, output: Path, *, seq: str | None, strict_kinect: bool, max_extrapolation_s: float) -> None:
    """Decode, fit, write; print the per-stream summary. Errors propagate as one-line user errors."""
    with flags({"SyncOptions.max_extrapolation_s": "--max-extrapolation"}):
        opts = SyncOptions(strict_kinect=strict_kinect, max_extrapolation_s=max_extrapolation_s)
    claim_into(output, inputs=[session])  # a real folder, not an input nor holding one, writable: before reading
    loaded = load_session(session)
    # a contradicting --seq, and every file it writes (new, or ours and unchanged), before the decoding work
    check_sync_output(output, output_seq(output, seq, loaded.seq), [session])
    check_nodes_in_bundle(output, loaded)  # so does a Kinect the calibrated bundle does not have
    check_session_audio(loaded, kinect_required=strict_kinect)  # and an audio file that cannot give its channel
    n_steps = 2 + len(loaded.kinects)
    with ProgressBars(transient=True) as bars:
        result = sync_session(loaded, opts, progress=bars.steps(n_steps, "decoding"))
    written = write_sync(result, output, seq=seq)
    for line in summary_lines(result):
        typer.echo(line)
    typer.echo(f"wrote {', '.join(str(p) for p in written)}")
