"""A path reaches the user only at its final place: the one rule, and the one place that knows it.

Outputs are written in a staging place beside their final place and renamed into it (:mod:`dome_calib.io_utils`,
:mod:`dome_calib.ownership`, :func:`dome_calib.bundle_io.staging_folder`, the report's staging folder). Each staging
place is recorded with the place it is renamed to when it is made (:func:`stage`), and :func:`said` turns any text
naming a staged path (``.../.out.new.<tag>.<random>/index.html``) into the text naming its final place
(``.../out/index.html``), nested staging folders included (calibrate's report, staged inside the staged bundle, is
said at ``OUT/report``). The commands' one exit (:func:`dome_calib.errors.run_cli`) passes every log line
(:func:`dome_calib.errors.console_handler`) and the error line through it: library code logs the path it writes,
and the user reads where the output is once the command has exited. A new command needs nothing more.

:data:`STAGING_MARK` matches every name given to a staging place; the hostile matrix's judge refuses a printed line
holding one (tests/hostile/oracle.py).
"""
from __future__ import annotations

import os
import re
import threading
from collections import OrderedDict
from pathlib import Path

#: Every name given to a staging place: ``.<name>.new.<tag>.<random>`` / ``.old.``
#: (:func:`dome_calib.io_utils.atomic_folder`; the report's ``.report.new.<random>``), ``.<name>.staging`` /
#: ``.aside`` (:func:`dome_calib.bundle_io.staging_folder`), ``.<name>.<random>.tmp``
#: (:func:`dome_calib.io_utils.atomic_path`). A printed text holding one names a place that is gone when the command exits.
STAGING_MARK = re.compile(r"\.(?:new|old)\.|\.(?:staging|aside)\b|\.tmp\b")

#: staging path -> the path it is renamed to (both as given and absolute); see :func:`said`. Bounded: a process that
#: writes for ever (a library user's server) keeps only the latest places; a command makes a few dozen.
_FINAL: OrderedDict[str, str] = OrderedDict()
_FINAL_KEPT = 4096
_FINAL_LOCK = threading.Lock()


def stage(staging: str | os.PathLike[str], final: str | os.PathLike[str]) -> Path:
    """Record that ``staging`` (a file or folder being written) becomes ``final`` when renamed into place, so that
    any message naming it is said at ``final`` (:func:`said`); returns ``staging``. Every staging helper calls
    it; a writer staging by other means calls it too (the hostile matrix fails a command that prints a staging name)."""
    staging, final = Path(staging), Path(final)
    with _FINAL_LOCK:
        _FINAL[str(staging)] = str(final)
        _FINAL[os.path.abspath(staging)] = os.path.abspath(final)
        while len(_FINAL) > _FINAL_KEPT:
            _FINAL.popitem(last=False)  # the oldest first
    return staging


def said(text: str) -> str:
    """``text`` with every staged path in it (:func:`stage`) replaced by its final place, nested staging folders
    resolved (a report folder staged inside a staged bundle: the bundle's final place). A text naming no staging
    place is returned as it is (the common case: one regular-expression search)."""
    if not STAGING_MARK.search(text):
        return text
    with _FINAL_LOCK:
        pairs = sorted(_FINAL.items(), key=lambda kv: -len(kv[0]))  # the longest first: a nested one before its parent
    for _ in range(8):  # staging folders nest a few deep at most
        before = text
        for staging, final in pairs:
            if staging in text:
                text = text.replace(staging, final)
        if text == before:
            break
    return text


def final_path(path: str | os.PathLike[str]) -> Path:
    """Where ``path`` (maybe inside a staging place) will be once everything above it is renamed into place."""
    return Path(said(str(path)))
