"""SMPTE linear timecode (LTC): exact codec, sub-sample audio encoder and decoder, clock alignment and sync tables.

Public API (see each module; loaded on first use, so `timecode --help` and `import timecode` start without
numpy and scipy):
    rates:    FrameRate, RATES, parse_rate, rate_from            exact rates as Fractions
    labels:   Timecode, label_to_frames, frames_to_label, ...    labels <-> frame counts (drop frame)
    frame:    LTCFrame, frame_to_bits, bits_to_frame, pack_bits  80-bit LTC words
    encoder:  encode_ltc, encode_ltc_labels, EncoderOptions      audio with exact edge times (ground truth)
    decode:   decode_file, decode_samples, DecodeOptions         audio -> ChannelDecode (decode.result): square
                                                                 waves and impulse trains, frames at the file's edges
Packages: :mod:`timecode.decode` (the decoder), :mod:`timecode.sync` (clocks, sync tables), :mod:`timecode.cli`.
"""
from __future__ import annotations

import importlib  # the modules are loaded on first use (PEP 562): `timecode --help` without numpy and scipy

#: public name -> the module that defines it
_HOMES = {
    **dict.fromkeys(("DecodeOptions", "RateMismatchError", "decode_file", "decode_samples"), "timecode.decode.decoder"),
    **dict.fromkeys(("EncodedLTC", "EncoderOptions", "encode_ltc", "encode_ltc_labels", "label_range"),
                    "timecode.encoder"),
    **dict.fromkeys(("LTCFrame", "bits_to_frame", "frame_to_bits"), "timecode.frame"),
    **dict.fromkeys(("Timecode", "frames_to_label", "label_to_frames"), "timecode.labels"),
    **dict.fromkeys(("RATES", "FrameRate", "parse_rate", "rate_from"), "timecode.rates"),
    **dict.fromkeys(("ChannelDecode", "DecodedFrame", "Direction", "Extrapolated", "Reading"), "timecode.decode.result"),
}

__all__ = sorted(_HOMES)


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'timecode' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
