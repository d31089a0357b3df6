"""Reading audio for the decoder: any file libsndfile reads (WAV, FLAC, AIFF, ...) or headerless raw PCM,
in overlapping blocks so an hour of audio never sits in memory as floats.

Samples come out as float32 with full scale 1.0 (integers are divided by 2^(bits-1); unsigned centred).
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import numpy.typing as npt
import soundfile as sf

from timecode.errors import TimecodeError


class AudioError(TimecodeError, OSError):
    """An audio file that cannot be read."""


class RawSampleFormat(StrEnum):
    """Sample encodings of headerless raw files (little endian unless stated)."""

    U8 = "u8"
    S8 = "s8"
    S16 = "s16"
    S16BE = "s16be"
    S32 = "s32"
    F32 = "f32"
    F64 = "f64"


_RAW_DTYPES = {
    RawSampleFormat.U8: np.dtype("u1"), RawSampleFormat.S8: np.dtype("i1"), RawSampleFormat.S16: np.dtype("<i2"),
    RawSampleFormat.S16BE: np.dtype(">i2"), RawSampleFormat.S32: np.dtype("<i4"), RawSampleFormat.F32: np.dtype("<f4"),
    RawSampleFormat.F64: np.dtype("<f8"),
}


@dataclass(frozen=True, kw_only=True)
class RawFormat:
    """How to read a headerless file: sample encoding, rate and interleaved channel count."""

    sample_format: RawSampleFormat
    sample_rate: int
    channels: int = 1


@dataclass(frozen=True, kw_only=True)
class AudioInfo:
    path: Path
    sample_rate: int
    channels: int
    frames: int  # samples per channel


def to_float32(x: npt.NDArray) -> npt.NDArray[np.float32]:
    """Integer or float samples -> float32, full scale 1.0 (unsigned integers are centred)."""
    if x.dtype.kind == "f":
        return x.astype(np.float32, copy=False)
    info = np.iinfo(x.dtype)
    scale = np.float32(2.0 ** (info.bits - 1))
    centre = np.float32(0.0 if info.min < 0 else 2.0 ** (info.bits - 1))
    return (x.astype(np.float32) - centre) / scale


class AudioReader:
    """Block reader over one audio file (context manager)."""

    def __init__(self, path: str | os.PathLike[str], raw: RawFormat | None = None) -> None:
        self.path = Path(path)
        self._raw = raw
        self._sf: sf.SoundFile | None = None
        self._mm: npt.NDArray | None = None
        if not self.path.is_file():
            raise AudioError(f"{self.path}: no such file")
        try:
            if raw is None:
                self._sf = sf.SoundFile(str(self.path))
                self.info = AudioInfo(path=self.path, sample_rate=int(self._sf.samplerate),
                                      channels=int(self._sf.channels), frames=int(self._sf.frames))
            else:
                dt = _RAW_DTYPES[RawSampleFormat(raw.sample_format)]
                size = self.path.stat().st_size
                n = size // (dt.itemsize * raw.channels)
                if n == 0:
                    raise AudioError(f"{self.path}: empty raw audio file")
                self._mm = np.memmap(self.path, dtype=dt, mode="r", shape=(n, raw.channels))
                self.info = AudioInfo(path=self.path, sample_rate=raw.sample_rate, channels=raw.channels, frames=n)
        except (sf.LibsndfileError, TypeError, RuntimeError) as exc:
            why = exc.error_string if isinstance(exc, sf.LibsndfileError) else str(exc)
            raise AudioError(f"{self.path}: not a readable audio file ({why}); "
                             "for headerless files give --raw-format and --raw-rate") from None
        if self.info.frames == 0:
            raise AudioError(f"{self.path}: the file holds no audio samples")
        if self._sf is not None:
            self._check_end()

    def _check_end(self) -> None:
        """AudioError when the last sample the header promises cannot be read: a half-copied file (cut short, or a
        header claiming more samples than the file holds). Seeking there is cheap; decoding would fail only at
        the end, after the rest of the file (and, in a batch, of the other files) was decoded."""
        n = self.info.frames
        try:
            self._sf.seek(n - 1)
            got = len(self._sf.read(1, dtype="float32", always_2d=True))
        except (sf.LibsndfileError, RuntimeError) as exc:
            why = exc.error_string if isinstance(exc, sf.LibsndfileError) else str(exc)
            got, detail = 0, f": {why.strip()}"
        else:
            detail = ""
        if got < 1:
            raise AudioError(f"{self.path}: cut short or damaged: its header promises {n} samples but sample {n - 1} "
                             f"cannot be read{detail} (a half-copied file? copy it again)")
        self._sf.seek(0)

    def read(self, start: int, stop: int) -> npt.NDArray[np.float32]:
        """Samples [start, stop) as float32, shape (n, channels)."""
        start, stop = max(0, start), min(self.info.frames, stop)
        if self._sf is not None:
            try:
                self._sf.seek(start)
                data = self._sf.read(stop - start, dtype="float32", always_2d=True)
            except (sf.LibsndfileError, RuntimeError) as exc:
                why = exc.error_string if isinstance(exc, sf.LibsndfileError) else str(exc)
                raise AudioError(f"{self.path}: damaged: samples {start}..{stop} cannot be read ({why.strip()})") from None
            if len(data) < stop - start:
                raise AudioError(f"{self.path}: cut short: its header promises {self.info.frames} samples, reading "
                                 f"stopped at sample {start + len(data)} (a half-copied file? copy it again)")
            return data
        return to_float32(np.asarray(self._mm[start:stop]))

    def blocks(self, block: int, margin: int) -> Iterator[tuple[int, int, int, npt.NDArray[np.float32]]]:
        """Yield (data_start, core_start, core_stop, data) covering the file; data reaches ``margin`` past the core."""
        n = self.info.frames
        for core0 in range(0, n, block):
            core1 = min(n, core0 + block)
            d0, d1 = max(0, core0 - margin), min(n, core1 + margin)
            yield d0, core0, core1, self.read(d0, d1)

    def close(self) -> None:
        if self._sf is not None:
            self._sf.close()
        self._mm = None

    def __enter__(self) -> AudioReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
