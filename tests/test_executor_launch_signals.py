"""An interrupt while the local pool launches a worker takes effect right after the launch, not inside it: a worker
interrupted between its spawn and its start-up data printed ``EOFError: Ran out of input`` with a traceback (seen
in the hostile matrix's demo-sigterm case)."""
from __future__ import annotations

import os
import signal

from dome_calib.executor.local import _interrupts_after_launch


def test_a_signal_during_the_launch_reaches_its_handler_after_it():
    seen: list[tuple[int, str]] = []
    kept = signal.getsignal(signal.SIGTERM)
    handler = lambda signum, frame: seen.append((signum, "handler"))  # noqa: E731
    signal.signal(signal.SIGTERM, handler)
    try:
        with _interrupts_after_launch():
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # Python runs the handler at the next bytecode boundaries
                pass
            seen.append((0, "launch done"))
        assert seen == [(0, "launch done"), (signal.SIGTERM, "handler")]
        assert signal.getsignal(signal.SIGTERM) is handler  # the handler in place before is back
    finally:
        signal.signal(signal.SIGTERM, kept)


def test_no_signal_leaves_the_handlers_as_they_were():
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with _interrupts_after_launch():
        pass
    assert {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)} == before


def test_a_process_launched_inside_starts_with_sigint_ignored():
    """Ctrl-C reaches the whole process group: a worker still importing (before its initializer ignores SIGINT)
    printed a KeyboardInterrupt traceback. Launched inside, it ignores SIGINT from its first instruction (an ignored
    disposition survives exec, Python's own handler is then not installed)."""
    import subprocess
    import sys

    kept = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
    try:
        with _interrupts_after_launch():
            out = subprocess.run([sys.executable, "-c", "import signal; print(int(signal.getsignal(signal.SIGINT)))"],
                                 capture_output=True, text=True, check=True).stdout
        assert int(out) == int(signal.SIG_IGN)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the parent's handler is back
    finally:
        signal.signal(signal.SIGINT, kept)
