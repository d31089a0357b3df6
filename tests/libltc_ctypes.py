"""Minimal ctypes binding to libltc (Debian ``libltc11``), the reference LTC codec, for tests and bench only.

libltc works on unsigned 8-bit audio internally (float input is converted with ``128 + x * 127``).
Its reported frame position ``off_start`` is the index of the first sample at which its hysteresis
detector (thresholds at half the tracked envelope around the fixed 8-bit centre 128) noticed the
transition that opens bit 0; it is a whole sample, later than the true edge by a level-dependent amount.
For the first frame after a gap it is only an estimate (posinfo minus one bit period).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

_LIB: ctypes.CDLL | None = None
_LOAD_ERROR = ""

TV_525_60, TV_625_50, TV_1125_60, TV_FILM_24 = 0, 1, 2, 3


class SMPTETimecode(ctypes.Structure):
    _fields_ = [("timezone", ctypes.c_char * 6), ("years", ctypes.c_ubyte), ("months", ctypes.c_ubyte),
                ("days", ctypes.c_ubyte), ("hours", ctypes.c_ubyte), ("mins", ctypes.c_ubyte),
                ("secs", ctypes.c_ubyte), ("frame", ctypes.c_ubyte)]


class LTCFrameExt(ctypes.Structure):
    # LTCFrame is 80 bits of unsigned-int bitfields: 12 bytes on x86-64/arm64 (3 x 32-bit units)
    _fields_ = [("ltc", ctypes.c_ubyte * 12), ("off_start", ctypes.c_longlong), ("off_end", ctypes.c_longlong),
                ("reverse", ctypes.c_int), ("biphase_tics", ctypes.c_float * 80), ("sample_min", ctypes.c_ubyte),
                ("sample_max", ctypes.c_ubyte), ("volume", ctypes.c_double), ("_spare", ctypes.c_ubyte * 64)]


def load() -> ctypes.CDLL | None:
    """The library, or None (see ``load_error()``)."""
    global _LIB, _LOAD_ERROR
    if _LIB is not None:
        return _LIB
    names = [os.environ.get("LIBLTC_PATH", ""), "libltc.so.11", ctypes.util.find_library("ltc") or ""]
    for name in filter(None, names):
        try:
            lib = ctypes.CDLL(name)
            break
        except OSError as exc:
            _LOAD_ERROR = str(exc)
    else:
        _LOAD_ERROR = _LOAD_ERROR or "libltc not found"
        return None
    lib.ltc_decoder_create.restype = ctypes.c_void_p
    lib.ltc_decoder_create.argtypes = [ctypes.c_int, ctypes.c_int]
    lib.ltc_decoder_free.argtypes = [ctypes.c_void_p]
    lib.ltc_decoder_write_float.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_float), ctypes.c_size_t,
                                            ctypes.c_longlong]
    lib.ltc_decoder_write.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_ubyte), ctypes.c_size_t,
                                      ctypes.c_longlong]
    lib.ltc_decoder_read.argtypes = [ctypes.c_void_p, ctypes.POINTER(LTCFrameExt)]
    lib.ltc_decoder_read.restype = ctypes.c_int
    lib.ltc_frame_to_time.argtypes = [ctypes.POINTER(SMPTETimecode), ctypes.c_void_p, ctypes.c_int]
    lib.ltc_time_to_frame.argtypes = [ctypes.c_void_p, ctypes.POINTER(SMPTETimecode), ctypes.c_int, ctypes.c_int]
    lib.ltc_frame_reset.argtypes = [ctypes.c_void_p]
    lib.ltc_encoder_create.restype = ctypes.c_void_p
    lib.ltc_encoder_create.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.c_int, ctypes.c_int]
    lib.ltc_encoder_free.argtypes = [ctypes.c_void_p]
    lib.ltc_encoder_set_timecode.argtypes = [ctypes.c_void_p, ctypes.POINTER(SMPTETimecode)]
    lib.ltc_encoder_set_user_bits.argtypes = [ctypes.c_void_p, ctypes.c_ulong]
    lib.ltc_encoder_set_volume.argtypes = [ctypes.c_void_p, ctypes.c_double]
    lib.ltc_encoder_encode_frame.argtypes = [ctypes.c_void_p]
    lib.ltc_encoder_inc_timecode.argtypes = [ctypes.c_void_p]
    lib.ltc_encoder_get_frame.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.ltc_encoder_set_frame.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.ltc_frame_set_parity.argtypes = [ctypes.c_void_p, ctypes.c_int]
    lib.ltc_encoder_get_bufferptr.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.POINTER(ctypes.c_ubyte)),
                                              ctypes.c_int]
    lib.ltc_encoder_get_bufferptr.restype = ctypes.c_int
    lib.ltc_encoder_get_buffersize.argtypes = [ctypes.c_void_p]
    lib.ltc_encoder_get_buffersize.restype = ctypes.c_size_t
    _LIB = lib
    return lib


def load_error() -> str:
    load()
    return _LOAD_ERROR


def require() -> ctypes.CDLL:
    """The library for a test: fails when the environment variable CI is set, else skips, if missing."""
    import pytest

    lib = load()
    if lib is None:
        msg = f"libltc11 not installed ({_LOAD_ERROR}); run `make system-deps` or `apt-get install libltc11`"
        if os.environ.get("CI"):
            pytest.fail(msg)
        pytest.skip(msg)
    return lib


def pack(label: tuple[int, int, int, int], *, standard: int, drop_frame: bool = False,
         user_bits: int = 0) -> npt.NDArray[np.uint8]:
    """libltc's 80 bits (wire order) for a label: ltc_frame_reset, user bits, DF flag, ltc_time_to_frame
    (which computes the polarity bit for ``standard``)."""
    lib = load()
    if lib is None:
        raise RuntimeError(f"libltc unavailable: {_LOAD_ERROR}")
    raw = (ctypes.c_ubyte * 12)()
    lib.ltc_frame_reset(raw)
    for g in range(8):  # user group g+1 sits in the high nibble of byte g
        raw[g] = (raw[g] & 0x0F) | (((user_bits >> (4 * g)) & 0xF) << 4)
    if drop_frame:
        raw[1] |= 0x04
    tc = SMPTETimecode(b"+0000", 0, 0, 0, *label)
    lib.ltc_time_to_frame(raw, ctypes.byref(tc), standard, 0)
    return np.unpackbits(np.frombuffer(bytes(raw)[:10], np.uint8), bitorder="little")


@dataclass(kw_only=True)
class LibltcFrames:
    labels: npt.NDArray[np.int64]  # (N, 4) hours, minutes, seconds, frames
    user_bits: npt.NDArray[np.uint32]
    dfbit: npt.NDArray[np.bool_]
    off_start: npt.NDArray[np.int64]  # libltc's frame start sample (see module docstring)
    off_end: npt.NDArray[np.int64]
    reverse: npt.NDArray[np.bool_]


def _frame_fields(raw: bytes) -> tuple[int, int, int, int, int, bool]:
    bits = np.unpackbits(np.frombuffer(raw[:10], np.uint8), bitorder="little")

    def val(start: int, width: int) -> int:
        return int((bits[start:start + width].astype(np.int64) << np.arange(width)).sum())

    f = val(0, 4) + 10 * val(8, 2)
    s = val(16, 4) + 10 * val(24, 3)
    m = val(32, 4) + 10 * val(40, 3)
    h = val(48, 4) + 10 * val(56, 2)
    ub = 0
    for g, start in enumerate((4, 12, 20, 28, 36, 44, 52, 60)):
        ub |= val(start, 4) << (4 * g)
    return h, m, s, f, ub, bool(bits[10])


class Decoder:
    """Streaming libltc decoder: ``write`` blocks of mono audio in order, then ``frames()``."""

    def __init__(self, sample_rate: float, fps: float = 25.0, chunk: int = 4096) -> None:
        lib = load()
        if lib is None:
            raise RuntimeError(f"libltc unavailable: {_LOAD_ERROR}")
        self._lib, self._chunk, self._pos = lib, chunk, 0
        self._dec = lib.ltc_decoder_create(int(round(sample_rate / fps)), 64)
        self._rows: list[tuple] = []
        self._frame = LTCFrameExt()

    def write(self, samples: npt.ArrayLike) -> None:
        """Floats (full scale 1.0; libltc converts to 8 bits as 128 + 127 x) or uint8 samples as they are."""
        lib, x = self._lib, np.asarray(samples)
        if x.dtype == np.uint8:
            buf, ptr_t, write = np.ascontiguousarray(x), ctypes.POINTER(ctypes.c_ubyte), lib.ltc_decoder_write
        else:
            buf = np.ascontiguousarray(x, dtype=np.float32)
            ptr_t, write = ctypes.POINTER(ctypes.c_float), lib.ltc_decoder_write_float
        for start in range(0, len(buf), self._chunk):
            part = buf[start:start + self._chunk]
            write(self._dec, part.ctypes.data_as(ptr_t), len(part), self._pos + start)
            while lib.ltc_decoder_read(self._dec, ctypes.byref(self._frame)):
                f = self._frame
                self._rows.append((*_frame_fields(bytes(f.ltc)), f.off_start, f.off_end, bool(f.reverse)))
        self._pos += len(buf)

    def frames(self) -> LibltcFrames:
        rows = self._rows
        if not rows:
            z = np.zeros(0, np.int64)
            return LibltcFrames(labels=np.zeros((0, 4), np.int64), user_bits=z.astype(np.uint32),
                                dfbit=z.astype(bool), off_start=z, off_end=z, reverse=z.astype(bool))
        a = list(zip(*rows))
        return LibltcFrames(labels=np.stack([a[0], a[1], a[2], a[3]], axis=1).astype(np.int64),
                            user_bits=np.array(a[4], np.uint32), dfbit=np.array(a[5], bool),
                            off_start=np.array(a[6], np.int64), off_end=np.array(a[7], np.int64),
                            reverse=np.array(a[8], bool))

    def close(self) -> None:
        if self._dec:
            self._lib.ltc_decoder_free(self._dec)
            self._dec = None

    def __del__(self) -> None:
        self.close()


def decode(samples: npt.ArrayLike, sample_rate: float, fps: float = 25.0, chunk: int = 4096) -> LibltcFrames:
    """Decode mono audio with libltc (floats, full scale 1.0, or uint8 samples written as they are)."""
    dec = Decoder(sample_rate, fps, chunk)
    try:
        dec.write(samples)
        return dec.frames()
    finally:
        dec.close()


def encode(start: tuple[int, int, int, int], n_frames: int, *, sample_rate: float, fps: float, standard: int,
           drop_frame: bool = False, user_bits: int = 0, volume_dbfs: float = -3.0) -> npt.NDArray[np.uint8]:
    """Encode ``n_frames`` consecutive frames with libltc; returns its unsigned 8-bit samples.

    libltc sets the drop-frame bit itself whenever ``round(fps * 100) == 2997``; for 29.97 non-drop we
    clear it in the encoder's frame (its increment then counts without drops) and redo the parity.
    """
    lib = load()
    if lib is None:
        raise RuntimeError(f"libltc unavailable: {_LOAD_ERROR}")
    enc = lib.ltc_encoder_create(float(sample_rate), float(fps), standard, 0)
    out: list[np.ndarray] = []
    try:
        lib.ltc_encoder_set_volume(enc, volume_dbfs)
        tc = SMPTETimecode(b"+0000", 0, 0, 0, *start)
        lib.ltc_encoder_set_timecode(enc, ctypes.byref(tc))
        lib.ltc_encoder_set_user_bits(enc, user_bits)
        raw = (ctypes.c_ubyte * 12)()
        lib.ltc_encoder_get_frame(enc, raw)
        if bool(raw[1] & 0x04) != drop_frame:
            raw[1] = (raw[1] | 0x04) if drop_frame else (raw[1] & ~0x04 & 0xFF)
            lib.ltc_frame_set_parity(raw, standard)
            lib.ltc_encoder_set_frame(enc, raw)
        ptr = ctypes.POINTER(ctypes.c_ubyte)()
        for _ in range(n_frames):
            lib.ltc_encoder_encode_frame(enc)
            n = lib.ltc_encoder_get_bufferptr(enc, ctypes.byref(ptr), 1)
            out.append(np.ctypeslib.as_array(ptr, shape=(n,)).copy())
            lib.ltc_encoder_inc_timecode(enc)
    finally:
        lib.ltc_encoder_free(enc)
    return np.concatenate(out)
