"""The one oracle of the hostile matrix: no traceback; a failure is a non-zero exit with one line naming the thing;
nothing outside the output written; nothing that was there before lost or changed; no page that runs a file's
text."""
from __future__ import annotations

import hashlib
import os
import stat
import subprocess
from pathlib import Path

from dome_calib.ownership import RECORD

SCRIPT = "<script>alert(1)</script>"


def snapshot(root: Path) -> dict[str, str]:
    """Every entry under ``root`` (links not followed): relative path -> what it is (a file's sha256)."""
    out = {}
    for here, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(here) / name
            mode = os.lstat(p).st_mode
            if stat.S_ISLNK(mode):
                what = "link:" + os.readlink(p)
            elif stat.S_ISDIR(mode):
                what = "dir"
            elif stat.S_ISREG(mode):
                what = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                what = f"special:{stat.S_IFMT(mode)}"
            out[str(p.relative_to(root))] = what
    return out


def _inside(rel: str, places: list[str]) -> bool:
    return any(rel == p or rel.startswith(p + os.sep) for p in places)


def judge(done: subprocess.CompletedProcess, before: dict[str, str], after: dict[str, str], *, sandbox: Path,
          out: Path, also: list[Path], must_refuse: bool, names: tuple[str, ...] = (),
          named: tuple[str, ...] = ()) -> None:
    """Assert the oracle for one case (``before``/``after``: snapshots of ``sandbox``; ``out`` and ``also``: where
    the command may write; ``names``: what a refusal's line may name instead of the output path; ``named``: the
    inputs changed, one of which a refusal's line must name)."""
    prog = done.args[0]
    text = done.stdout + done.stderr
    assert "Traceback" not in text, text
    if must_refuse:
        assert done.returncode != 0, f"not refused (exit 0): {text}"
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    if done.returncode != 0:
        lines = [ln for ln in done.stderr.splitlines() if ln.startswith((f"{prog}: error:", f"{prog}: interrupted"))]
        assert len(lines) == 1, done.stderr
        said = [str(out), out.name, *names]
        if named:  # an input's content was changed: the refusal names it
            assert any(s in lines[0] for s in named), (named, lines[0])
        if must_refuse:  # it names the output (or what in it is not ours), and nothing changed
            assert "interrupted" in lines[0] or any(s and s in lines[0] for s in said), (said, lines[0])
            assert changed == [], f"refused, yet changed {changed[:5]}"
            return
    places = [str(p.relative_to(sandbox)) for p in (out, *also) if p.is_relative_to(sandbox)]
    record = str((out.parent / RECORD).relative_to(sandbox)) if out.parent.is_relative_to(sandbox) else None
    outside = [k for k in changed if not _inside(k, places) and k != record]
    assert outside == [], f"wrote outside the output: {outside[:5]}"
    lost = [k for k in before if k not in after or before[k] != after[k]]
    lost = [k for k in lost if not _inside(k, places) and k != record]
    assert lost == [], f"lost or changed: {lost[:5]}"
    for k in changed:
        if k.endswith(".html") and k in after:
            assert SCRIPT not in (sandbox / k).read_text(encoding="utf-8", errors="replace"), f"{k} runs a file's text"

