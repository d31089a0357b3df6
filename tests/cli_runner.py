"""Run an installed command's ``main`` in this process, as the console script does (no second Python)."""
from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable


def run_in_process(main: Callable[[], object], prog: str, args, monkeypatch, capsys) -> subprocess.CompletedProcess:
    """``prog ARGS`` through ``main`` with ``sys.argv`` set; returns (returncode, stdout, stderr) as a
    CompletedProcess. A ``SystemExit`` code that is not an int counts as 1 (None as 0), as Python's own exit."""
    monkeypatch.setattr(sys, "argv", [prog, *map(str, args)])
    capsys.readouterr()
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out = capsys.readouterr()
    return subprocess.CompletedProcess([prog, *map(str, args)], code, out.out, out.err)
