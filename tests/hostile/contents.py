"""The input-content kinds of the hostile matrix (issue 50 item 7): one file a command reads, changed in the case's
sandbox copy. A file "kind" is its name with frame numbers (3 digits or more) taken out, so one OpenPose frame stands
for all of them and every kind is as likely as another. The places of a JSON document are those of
:mod:`tests.test_input_mutations` (the schema mutations), so both mean the same by "a number of the file"."""
from __future__ import annotations

import json
import random
import re
from pathlib import Path

from dome_calib.ownership import RECORD

from ..test_input_mutations import _parent, _places

#: A non-finite or huge number, as a JSON file spells it; a TOML file spells the non-finite ones its own way.
NUMBER_VALUES = ("NaN", "Infinity", "1e400", "12345678901234567890")
_TOML_SPELLING = {"NaN": "nan", "Infinity": "inf"}
_FRAME = re.compile(r"\d{3,}")
_TOML_NUMBER = re.compile(r"(?<=[=\[,\s])-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?=\s*[,\]\n])")
_MARK = "\u0000hostile-number\u0000"


def files_of(places: list[Path]) -> list[Path]:
    """Every file the command reads, in a stable order (a folder: every file in it but hidden ones and our record)."""
    out = []
    for p in places:
        found = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
        out += [q for q in found if not q.name.startswith(".") and q.name != RECORD]
    return out


def _kinds(files: list[Path]) -> dict[str, list[Path]]:
    kinds: dict[str, list[Path]] = {}
    for f in files:
        kinds.setdefault(_FRAME.sub("#", f.name), []).append(f)
    return kinds


def _pick(files: list[Path], rng: random.Random) -> Path:
    kinds = _kinds(files)
    return rng.choice(kinds[rng.choice(sorted(kinds))])


def _numbers(doc) -> list[tuple]:
    return [p for p in _places(doc) if type(_parent(doc, p)[p[-1]]) in (int, float)]


def _has_number(f: Path) -> bool:
    try:
        if f.suffix == ".json":
            return bool(_numbers(json.loads(f.read_text())))
        return f.suffix == ".toml" and bool(_TOML_NUMBER.search(f.read_text()))
    except (ValueError, UnicodeDecodeError):
        return False


def put_number(files: list[Path], value: str, rng: random.Random) -> list[Path]:
    """One number of one JSON or TOML file set to ``value``; returns the file."""
    f = _pick([f for f in files if _has_number(f)], rng)
    text = f.read_text()
    if f.suffix == ".json":
        doc = json.loads(text)
        place = rng.choice(_numbers(doc))
        _parent(doc, place)[place[-1]] = _MARK
        f.write_text(json.dumps(doc).replace(json.dumps(_MARK), value))
    else:
        m = rng.choice(list(_TOML_NUMBER.finditer(text)))
        f.write_text(text[:m.start()] + _TOML_SPELLING.get(value, value) + text[m.end():])
    return [f]


def empty(files: list[Path], rng: random.Random) -> list[Path]:
    f = _pick(files, rng)
    f.write_bytes(b"")
    return [f]


def truncated(files: list[Path], rng: random.Random) -> list[Path]:
    """One file cut in half."""
    f = _pick(files, rng)
    data = f.read_bytes()
    f.write_bytes(data[:len(data) // 2])
    return [f]


def one_frame(files: list[Path], rng: random.Random) -> list[Path]:
    """Every sequence cut to its first frame: of the files numbered by frame, the first of each kind in each folder;
    in a JSON document, every ``frames`` list and the lists of the same length beside it."""
    changed = []
    groups: dict[tuple, list[Path]] = {}
    for f in files:
        if _FRAME.search(f.stem):
            groups.setdefault((f.parent, _FRAME.sub("#", f.name)), []).append(f)
    for group in groups.values():
        for f in group[1:]:
            f.unlink()
        if len(group) > 1:
            changed.append(group[0].parent)
    for f in files:
        if f.suffix == ".json" and f.exists() and _cut_frames(f):
            changed.append(f)
    return changed


def _cut_frames(f: Path) -> bool:
    try:
        doc = json.loads(f.read_text())
    except ValueError:
        return False
    cut = False
    for node in [_parent(doc, (*place, None)) for place in [()] + _places(doc)]:  # found before any is cut
        frames = node.get("frames") if isinstance(node, dict) else None
        if isinstance(frames, list) and len(frames) > 1:
            for key, v in node.items():
                if isinstance(v, list) and len(v) == len(frames):
                    node[key] = v[:1]
            cut = True
    if cut:
        f.write_text(json.dumps(doc))
    return cut


CONTENT_KINDS = {
    "number": "a number of a file it reads is NaN, Infinity, 1e400 or a 20-digit integer",
    "empty": "a file it reads is empty",
    "truncated": "a file it reads is cut in half",
    "one frame": "every sequence it reads holds one frame",
}


def mutate(kind: str, value: str, files: list[Path], rng: random.Random) -> list[Path]:
    """Apply one content kind to the files a command reads; returns what was changed (files or folders)."""
    if kind == "number":
        return put_number(files, value, rng)
    return {"empty": empty, "truncated": truncated, "one frame": one_frame}[kind](files, rng)
