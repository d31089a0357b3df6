"""The input-content kinds of the hostile matrix change what they say they change (else the matrix's cases of them
could not fail)."""
from __future__ import annotations

import json
import random
import tomllib

from .contents import NUMBER_VALUES, empty, files_of, one_frame, put_number, truncated


def _folder(tmp_path):
    (tmp_path / "cam").mkdir(exist_ok=True)
    for f in range(3):
        (tmp_path / "cam" / f"cam_{f:06d}_keypoints.json").write_text(json.dumps({"people": [{"k": [1.5, 2]}]}))
    (tmp_path / "det.json").write_text(json.dumps({"cameras": {"a": {"frames": [0, 1, 2], "joints": [[1], [2], [3]],
                                                                     "name": "abc"}}}))
    (tmp_path / "calib.toml").write_text('[cam_0]\nsize = [ 640, 480 ]\nf = 1.25\n')
    return files_of([tmp_path])


def test_a_number_is_set_to_each_value(tmp_path):
    for value in NUMBER_VALUES:
        for seed in range(6):
            files = _folder(tmp_path)
            before = {f: f.read_text() for f in files}
            [f] = put_number(files, value, random.Random(seed))
            text = f.read_text()
            assert text != before[f]
            if f.suffix == ".toml":
                tomllib.loads(text)  # TOML spells the non-finite numbers its own way: it still parses
                assert {"NaN": "nan", "Infinity": "inf"}.get(value, value) in text
            else:
                assert value in text and json.loads(text) is not None


def test_empty_truncated_and_one_frame(tmp_path):
    files = _folder(tmp_path)
    [f] = empty(files, random.Random(1))
    assert f.read_bytes() == b""
    files = _folder(tmp_path)
    size = {f: f.stat().st_size for f in files}
    [f] = truncated(files, random.Random(2))
    assert f.stat().st_size == size[f] // 2
    files = _folder(tmp_path)
    changed = one_frame(files, random.Random(3))
    assert sorted(p.name for p in (tmp_path / "cam").iterdir()) == ["cam_000000_keypoints.json"]
    assert json.loads((tmp_path / "det.json").read_text())["cameras"]["a"] == {"frames": [0], "joints": [[1]],
                                                                               "name": "abc"}
    assert {p.name for p in changed} == {"cam", "det.json"}
