"""Errors of the timecode package (all are user errors: bad audio, no LTC, bad options)."""
from __future__ import annotations


class TimecodeError(Exception):
    """Base of every timecode error a user can cause."""


class NoLTCError(TimecodeError):
    """An audio channel in which no LTC frame could be decoded."""
