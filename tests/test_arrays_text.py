"""Numbers become text through dome_calib.arrays.fixed_text, never numpy's vectorised string calls: np.char.mod
(numpy 2.4.6) swallowed the KeyboardInterrupt our SIGTERM handler raised while it ran, and export-people ran to the
end with exit 0 (its SIGTERM test, under load)."""
from __future__ import annotations

import gc
import re
import signal
from pathlib import Path

import numpy as np
import pytest

from dome_calib.arrays import fixed_text

PACKAGES = [Path(__file__).resolve().parents[1] / name for name in ("dome_calib", "timecode")]


def test_fixed_text_is_printf_fixed_point_with_missing_values():
    a = np.array([[1.0, -0.0, np.nan], [1e-7, -2.5000004, 123456.1234565]])
    assert fixed_text(a, 6) == [["%.6f" % v for v in row] for row in a.tolist()]
    assert fixed_text(a, 3, missing="")[0] == ["1.000", "-0.000", ""]
    assert fixed_text(np.zeros((0, 3)), 6) == [] and fixed_text(np.zeros((2, 0)), 6) == [[], []]


def test_an_interrupt_while_numbers_become_text_is_not_lost():
    """A handler's exception raised during the formatting ends it (np.char.mod finished and dropped it)."""
    hits: list[int] = []

    def interrupt(signum, frame):
        hits.append(signum)
        raise KeyboardInterrupt

    kept = signal.signal(signal.SIGALRM, interrupt)
    # no collection while the timer runs: a signal landing in a gc callback (hypothesis registers one) raises there,
    # and Python drops that exception as unraisable (the loop then ran its 200 rounds and the test failed, 18 s)
    collecting = gc.isenabled()
    gc.disable()
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.02)
        with pytest.raises(KeyboardInterrupt):
            for _ in range(200):  # ~0.1 s each: the timer lands inside
                fixed_text(np.random.default_rng(0).random((1000, 60)), 6)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, kept)
        if collecting:
            gc.enable()
    assert hits == [signal.SIGALRM]


def test_no_module_formats_numbers_with_numpys_vectorised_string_calls():
    found = [f"{path}:{k}" for package in PACKAGES for path in sorted(package.rglob("*.py"))
             for k, line in enumerate(path.read_text().splitlines(), 1)
             if re.search(r"\b(np|numpy)\.(char|strings)\.", line.split("#")[0])]
    assert not found, found
