"""Peak memory of `timecode decode` on noise (an unplugged LTC input) against the recording's length.

Each length's noise is written in blocks to a temporary WAV (16-bit, 48 kHz, mono: the size the capture nodes
record), then decoded in a fresh Python process (``timecode.decode.decoder.decode_file``, as the command runs it); its peak
resident memory is that child's own ``ru_maxrss`` (``os.wait4``). Flat memory across lengths means the decoder
keeps a block, not the file. The truth: noise holds no LTC, so 0 frames must be found.

    python bench/ltc_memory.py                 # 1 min, 30 min, 2 h
    python bench/ltc_memory.py --minutes 1 5   # other lengths

One JSON object per line: {"duration_s", "file_mb", "peak_rss_mb", "frames", "seconds"}.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import soundfile as sf

SAMPLE_RATE = 48000
BLOCK_S = 60

_CHILD = """
import sys
from timecode.decode.decoder import decode_file
result = decode_file(sys.argv[1])
print(sum(len(ch) for ch in result))
"""


def write_noise(path: Path, seconds: int, seed: int = 0) -> None:
    """``seconds`` of Gaussian noise at -20 dBFS RMS, written BLOCK_S seconds at a time (memory: one block)."""
    rng = np.random.default_rng(seed)
    with sf.SoundFile(path, "w", samplerate=SAMPLE_RATE, channels=1, subtype="PCM_16") as f:
        for start in range(0, seconds, BLOCK_S):
            n = min(BLOCK_S, seconds - start) * SAMPLE_RATE
            f.write(np.clip(rng.normal(0.0, 0.1, n), -1, 1).astype(np.float32))


def measure(seconds: int, folder: Path) -> dict:
    path = folder / f"noise_{seconds}s.wav"
    write_noise(path, seconds)
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(path)], stdout=subprocess.PIPE, text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage: its peak resident memory (kB on Linux)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"decoding {path} failed (exit {proc.returncode})")
    row = {"duration_s": seconds, "file_mb": round(path.stat().st_size / 2**20, 1),
           "peak_rss_mb": round(usage.ru_maxrss / 1024, 1), "frames": int(out.split()[-1]),
           "seconds": round(time.perf_counter() - t0, 1)}
    path.unlink()
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1, 30, 120])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="ltc_memory.") as tmp:
        for minutes in args.minutes:
            print(json.dumps(measure(int(round(minutes * 60)), Path(tmp))), flush=True)


if __name__ == "__main__":
    main()
