"""SMPTE linear timecode (LTC): exact codec, sub-sample audio encoder and decoder, clock alignment and sync tables.

Public API (see each module):
    rates:    FrameRate, RATES, parse_rate, rate_from            exact rates as Fractions
    labels:   Timecode, label_to_frames, frames_to_label, ...    labels <-> frame counts (drop frame)
    frame:    LTCFrame, frame_to_bits, bits_to_frame, pack_bits  80-bit LTC words
    encoder:  encode_ltc, encode_ltc_labels, EncoderOptions      audio with exact edge times (ground truth)
    decoder:  decode_file, decode_samples, DecodeOptions         audio -> ChannelDecode (result.py): square waves
                                                                 and impulse trains, frames at the file's edges
"""
from timecode.decoder import DecodeOptions, RateMismatchError, decode_file, decode_samples
from timecode.encoder import EncodedLTC, EncoderOptions, encode_ltc, encode_ltc_labels, label_range
from timecode.frame import LTCFrame, bits_to_frame, frame_to_bits
from timecode.labels import Timecode, frames_to_label, label_to_frames
from timecode.rates import RATES, FrameRate, parse_rate, rate_from
from timecode.result import ChannelDecode, DecodedFrame, Direction, Extrapolated, Reading

__all__ = [
    "ChannelDecode", "DecodeOptions", "DecodedFrame", "Direction", "EncodedLTC", "EncoderOptions", "Extrapolated",
    "FrameRate", "LTCFrame", "RATES", "RateMismatchError", "Reading", "Timecode", "bits_to_frame", "decode_file",
    "decode_samples", "encode_ltc",
    "encode_ltc_labels", "frame_to_bits", "frames_to_label", "label_range", "label_to_frames", "parse_rate",
    "rate_from",
]
