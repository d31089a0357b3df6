"""One LTC frame <-> its 80 bits (SMPTE 12M), scalar and vectorised.

Bit ``i`` is the i-th bit on the wire (bit 0 first in forward play). BCD digits and user-bit groups are
sent least-significant bit first. Layout (24, 30 fps and their 1000/1001 variants | 25 fps where it differs):

    0-3 frame units   4-7 user 1    8-9 frame tens   10 drop frame   11 colour frame   12-15 user 2
    16-19 sec units   20-23 user 3  24-26 sec tens   27 polarity | BGF0              28-31 user 4
    32-35 min units   36-39 user 5  40-42 min tens   43 BGF0 | BGF2                  44-47 user 6
    48-51 hour units  52-55 user 7  56-57 hour tens  58 BGF1         59 BGF2 | polarity  60-63 user 8
    64-79 sync word 0011 1111 1111 1101 (0x3FFD read MSB first on the wire)

The polarity-correction bit is set so that every 80-bit word holds an even number of zeros (and so of
ones), which makes every frame start with the same signal polarity. ``user_bits`` packs the eight 4-bit
groups into one 32-bit integer, user 1 in the lowest nibble (libltc's ``ltc_frame_get_user_bits``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from timecode.errors import TimecodeError
from timecode.labels import Timecode
from timecode.rates import FrameRate

N_BITS = 80
SYNC_WORD = 0x3FFD
#: Sync word bits 64..79 in wire order (forward play).
SYNC_BITS = np.array([(SYNC_WORD >> (15 - i)) & 1 for i in range(16)], dtype=np.uint8)
#: What a decoder sees first when the tape plays backwards: the sync word reversed (0xBFFC).
REVERSE_SYNC_BITS = SYNC_BITS[::-1].copy()

_USER_START = (4, 12, 20, 28, 36, 44, 52, 60)
# (first bit, width) of the BCD fields: frame units/tens, second units/tens, minute units/tens, hour units/tens
_BCD = ((0, 4), (8, 2), (16, 4), (24, 3), (32, 4), (40, 3), (48, 4), (56, 2))
_DF_BIT, _CF_BIT, _BGF1_BIT = 10, 11, 58


class FrameBitsError(TimecodeError, ValueError):
    """80 bits that are not a valid LTC frame (wrong sync word, BCD digit out of range)."""


def polarity_bit(is_25_layout: bool) -> int:
    """Index of the biphase-mark polarity-correction bit: 59 at 25 fps, 27 at 24/30 fps."""
    return 59 if is_25_layout else 27


def bgf_bits(is_25_layout: bool) -> tuple[int, int, int]:
    """Indices of binary group flags (BGF0, BGF1, BGF2): (27, 58, 43) at 25 fps, (43, 58, 59) otherwise."""
    return (27, 58, 43) if is_25_layout else (43, 58, 59)


@dataclass(frozen=True, kw_only=True)
class LTCFrame:
    """The content of one LTC frame. The polarity bit is not stored: it is computed when packing."""

    label: Timecode
    user_bits: int = 0
    drop_frame: bool = False
    color_frame: bool = False
    bgf0: bool = False
    bgf1: bool = False
    bgf2: bool = False


@dataclass(frozen=True, kw_only=True)
class FrameFields:
    """Fields of N frames unpacked from (N, 80) bits, layout-independent (flags read per rate later)."""

    hmsf: npt.NDArray[np.int64]  # (N, 4) hours, minutes, seconds, frames
    user_bits: npt.NDArray[np.uint32]  # (N,)
    bits: npt.NDArray[np.uint8]  # (N, 80) the raw bits
    bcd_ok: npt.NDArray[np.bool_]  # every BCD digit <= 9 and tens digits in range
    parity_ok: npt.NDArray[np.bool_]  # even number of zeros in the 80 bits
    sync_ok: npt.NDArray[np.bool_]  # bits 64..79 are the sync word

    def flag(self, index: int) -> npt.NDArray[np.bool_]:
        """Bit ``index`` of every frame as booleans."""
        return self.bits[:, index].astype(bool)


def _lsb_first(values: npt.NDArray[np.int64], width: int) -> npt.NDArray[np.uint8]:
    return ((values[:, None] >> np.arange(width)) & 1).astype(np.uint8)


def pack_bits(
    hmsf: npt.ArrayLike,
    *,
    is_25_layout: bool,
    user_bits: npt.ArrayLike = 0,
    drop_frame: npt.ArrayLike = False,
    color_frame: npt.ArrayLike = False,
    bgf: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike] = (False, False, False),
) -> npt.NDArray[np.uint8]:
    """Vectorised frames -> (N, 80) bits with the sync word and the polarity bit set.

    Labels are not validated here (see ``labels.label_problem``); only their digits are packed.
    """
    a = np.asarray(hmsf, dtype=np.int64).reshape(-1, 4)
    n = len(a)
    bits = np.zeros((n, N_BITS), dtype=np.uint8)
    digits = [a[:, 3] % 10, a[:, 3] // 10, a[:, 2] % 10, a[:, 2] // 10,
              a[:, 1] % 10, a[:, 1] // 10, a[:, 0] % 10, a[:, 0] // 10]
    for (start, width), d in zip(_BCD, digits):
        bits[:, start:start + width] = _lsb_first(d, width)
    ub = np.broadcast_to(np.asarray(user_bits, dtype=np.int64), (n,))
    for g, start in enumerate(_USER_START):
        bits[:, start:start + 4] = _lsb_first((ub >> (4 * g)) & 0xF, 4)
    bits[:, _DF_BIT] = np.broadcast_to(np.asarray(drop_frame, dtype=np.uint8), (n,))
    bits[:, _CF_BIT] = np.broadcast_to(np.asarray(color_frame, dtype=np.uint8), (n,))
    for idx, value in zip(bgf_bits(is_25_layout), bgf):
        bits[:, idx] = np.broadcast_to(np.asarray(value, dtype=np.uint8), (n,))
    bits[:, 64:] = SYNC_BITS
    p = polarity_bit(is_25_layout)
    bits[:, p] = 0
    bits[:, p] = bits.sum(axis=1) % 2  # make the number of ones (and so of zeros) even
    return bits


def unpack_bits(bits: npt.ArrayLike) -> FrameFields:
    """Vectorised (N, 80) bits -> fields, with BCD-range, parity and sync-word checks (no exceptions)."""
    b = np.asarray(bits, dtype=np.uint8).reshape(-1, N_BITS)
    vals = []
    for start, width in _BCD:
        vals.append((b[:, start:start + width].astype(np.int64) << np.arange(width)).sum(axis=1))
    fu, ft, su, st, mu, mt, hu, ht = vals
    bcd_ok = (fu <= 9) & (su <= 9) & (st <= 5) & (mu <= 9) & (mt <= 5) & (hu <= 9)
    hmsf = np.stack([ht * 10 + hu, mt * 10 + mu, st * 10 + su, ft * 10 + fu], axis=1)
    ub = np.zeros(len(b), dtype=np.int64)
    for g, start in enumerate(_USER_START):
        ub |= (b[:, start:start + 4].astype(np.int64) << np.arange(4)).sum(axis=1) << (4 * g)
    parity_ok = (b.sum(axis=1) % 2) == 0
    sync_ok = np.all(b[:, 64:] == SYNC_BITS, axis=1)
    return FrameFields(hmsf=hmsf, user_bits=ub.astype(np.uint32), bits=b, bcd_ok=bcd_ok,
                       parity_ok=parity_ok, sync_ok=sync_ok)


def frame_to_bits(frame: LTCFrame, rate: FrameRate) -> npt.NDArray[np.uint8]:
    """One frame -> its 80 bits (uint8 0/1) in wire order, for ``rate``'s bit layout."""
    return pack_bits(
        [frame.label.as_tuple()], is_25_layout=rate.is_25_layout, user_bits=frame.user_bits,
        drop_frame=frame.drop_frame, color_frame=frame.color_frame, bgf=(frame.bgf0, frame.bgf1, frame.bgf2),
    )[0]


def bits_to_frame(bits: npt.ArrayLike, rate: FrameRate) -> tuple[LTCFrame, bool]:
    """80 bits -> (frame, parity_ok). Raises FrameBitsError for a wrong sync word or a BCD digit out of range."""
    b = np.asarray(bits, dtype=np.uint8).ravel()
    if b.shape != (N_BITS,) or np.any(b > 1):
        raise FrameBitsError(f"an LTC frame is 80 bits of 0/1, got shape {b.shape}")
    f = unpack_bits(b)
    if not f.sync_ok[0]:
        raise FrameBitsError(f"bits 64-79 are {''.join(map(str, b[64:]))}, not the sync word 0011111111111101")
    if not f.bcd_ok[0]:
        raise FrameBitsError(f"BCD digit out of range in label fields {f.hmsf[0].tolist()}")
    h, m, s, fr = (int(v) for v in f.hmsf[0])
    i0, i1, i2 = bgf_bits(rate.is_25_layout)
    df = bool(b[_DF_BIT])
    frame = LTCFrame(label=Timecode(h, m, s, fr, df), user_bits=int(f.user_bits[0]), drop_frame=df,
                     color_frame=bool(b[_CF_BIT]), bgf0=bool(b[i0]), bgf1=bool(b[i1]), bgf2=bool(b[i2]))
    return frame, bool(f.parity_ok[0])
