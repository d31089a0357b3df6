"""The one oracle of the hostile matrix: no traceback; a failure is a non-zero exit with one line naming the thing;
nothing outside the output written; nothing that was there before lost or changed; no page that runs a file's
text; no printed text naming a staging place, and after a run that went through, every path it printed in the
sandbox is there (a path reaches the user only at its final place)."""
from __future__ import annotations

import hashlib
import os
import re
import stat
import subprocess
from pathlib import Path

from dome_calib.final_place import STAGING_MARK
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


#: Where a printed path ends: white space, quotes, brackets, a comma or semicolon.
_PATH_END = re.compile(r"[\s'\"()\[\]{},;]")


def printed_paths(text: str, sandbox: Path, known: set[str] = frozenset()) -> list[str]:
    """The paths in ``text`` that lie in the sandbox, relative to it: absolute ones (from the sandbox's own path on)
    and relative ones (a word whose first part, up to a ``/`` if it holds one, is ``known``: the sandbox's entries,
    the commands' working folder), each up to white space, a quote, a bracket, a comma or a semicolon, without the punctuation that
    ends a sentence or a name (``.``, ``:``)."""
    root, found = str(sandbox), []
    for start in (m.start() for m in re.finditer(re.escape(root), text)):
        rest = _PATH_END.split(text[start:], maxsplit=1)[0]
        found.append(os.path.relpath(rest.rstrip(".:"), root))
    for word in _PATH_END.split(text):
        word = word.rstrip(".:")
        if not word.startswith("/") and word.split("/", 1)[0] in known:
            found.append(os.path.normpath(word))
    return found


def judge_printed(done: subprocess.CompletedProcess, sandbox: Path, before: dict[str, str],
                  after: dict[str, str]) -> None:
    """No printed line names a staging place (:data:`dome_calib.final_place.STAGING_MARK`: gone when the command
    exits); after a run that went through, every path it printed that lies in the sandbox is there (or is the
    start of one cut at white space: a name holding a newline or a space)."""
    text = done.stdout + done.stderr
    for line in text.splitlines():
        assert not STAGING_MARK.search(line), f"printed a staging place: {line}"
    if done.returncode != 0:
        return
    known = {Path(k).parts[0] for k in (*before, *after)}
    there = set(after) | {"."}
    gone = [p for p in printed_paths(text, sandbox, known)
            if p not in there and not any(k.startswith(p) and k[len(p)].isspace() for k in after if len(k) > len(p))]
    assert gone == [], f"printed paths that are not there after the run: {gone[:5]}\n{text}"


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
    judge_printed(done, sandbox, before, after)
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

