"""Which validation library reads the inputs: pydantic v2 against msgspec on a folder of OpenPose files.

Run: .venv/bin/python bench/schema_choice.py [--files 100000] [--people 3]

Writes ``--files`` OpenPose BODY_25 files shaped like real OpenPose 1.3 output (``version``, ``person_id``, the
face, hand and 3D arrays empty, ``part_candidates`` absent) into a temporary folder, then reads them all with each
library's strict schema of the same file (unknown fields refused, numbers not booleans), and with the reader this
project had before the schemas (``json.loads`` and hand checks), and with the schema it ships
(``dome_calib.recon.openpose_io.OpenPoseFile``: pydantic, every OpenPose field, confidences checked per joint). Then decodes the same set of broken files with each
and prints the error each library gives (its text names the field path, or not).

Prints one JSON object per line: setup, one line per reader (seconds, files per second, ratio to msgspec), one
line per broken file with both libraries' messages.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np
import pydantic


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


# --- the same file, declared once per library --------------------------------------------------------------

class MsPerson(msgspec.Struct, forbid_unknown_fields=True):
    pose_keypoints_2d: list[float]
    person_id: list[int] | int = -1
    face_keypoints_2d: list[float] = []
    hand_left_keypoints_2d: list[float] = []
    hand_right_keypoints_2d: list[float] = []
    pose_keypoints_3d: list[float] = []
    face_keypoints_3d: list[float] = []
    hand_left_keypoints_3d: list[float] = []
    hand_right_keypoints_3d: list[float] = []


class MsFile(msgspec.Struct, forbid_unknown_fields=True):
    people: list[MsPerson]
    version: float | str | None = None
    part_candidates: list[dict[str, list[float]]] = []


_STRICT = pydantic.ConfigDict(extra="forbid", strict=True)
Number = Annotated[float, pydantic.Field(allow_inf_nan=False)]


class PdPerson(pydantic.BaseModel):
    model_config = _STRICT
    pose_keypoints_2d: list[Number]
    person_id: list[int] | int = -1
    face_keypoints_2d: list[Number] = []
    hand_left_keypoints_2d: list[Number] = []
    hand_right_keypoints_2d: list[Number] = []
    pose_keypoints_3d: list[Number] = []
    face_keypoints_3d: list[Number] = []
    hand_left_keypoints_3d: list[Number] = []
    hand_right_keypoints_3d: list[Number] = []


class PdFile(pydantic.BaseModel):
    model_config = _STRICT
    people: list[PdPerson]
    version: float | str | None = None
    part_candidates: list[dict[str, list[Number]]] = []


# --- readers ---------------------------------------------------------------------------------------------

def read_msgspec(paths: list[Path]) -> int:
    decoder = msgspec.json.Decoder(MsFile)
    n = 0
    for p in paths:
        f = decoder.decode(p.read_bytes())
        n += sum(len(q.pose_keypoints_2d) for q in f.people)
    return n


def read_pydantic(paths: list[Path]) -> int:
    n = 0
    for p in paths:
        f = PdFile.model_validate_json(p.read_bytes())
        n += sum(len(q.pose_keypoints_2d) for q in f.people)
    return n


def read_shipped(paths: list[Path]) -> int:
    """The schema this project ships (pydantic, with the per-joint confidence check)."""
    from dome_calib.recon.openpose_io import OpenPoseFile
    from dome_calib.schema import parse_json

    n = 0
    for p in paths:
        f = parse_json(p, p.read_bytes(), OpenPoseFile)
        n += sum(len(q.body()) for q in f.people)
    return n


def read_by_hand(paths: list[Path]) -> int:
    """The reader before the schemas: json.loads, then isinstance checks per field and per value."""
    n = 0
    for p in paths:
        data = json.loads(p.read_text(encoding="utf-8"))
        if not isinstance(data, dict) or not isinstance(data.get("people"), list):
            raise ValueError(p)
        for person in data["people"]:
            kp = person.get("pose_keypoints_2d") if isinstance(person, dict) else None
            if not isinstance(kp, list) or not all(type(v) in (int, float) or v is None for v in kp):
                raise ValueError(p)
            n += len(kp)
    return n


# --- the data --------------------------------------------------------------------------------------------

def openpose_file(rng: np.random.Generator, people: int) -> bytes:
    """One file like OpenPose 1.3 writes (its C++ writer: 3 significant decimals on pixels, 6 on confidences)."""
    out = []
    for _ in range(people):
        kp = np.column_stack([rng.uniform(0, 640, 25), rng.uniform(0, 480, 25), rng.uniform(0.05, 1.02, 25)])
        kp[rng.random(25) < 0.1] = 0.0  # joints not detected: 0, 0, 0
        values = ",".join(f"{x:.3f},{y:.3f},{c:.6f}".replace(".000,", ",") for x, y, c in kp)
        out.append('{"person_id":[-1],"pose_keypoints_2d":[' + values + '],"face_keypoints_2d":[],'
                   '"hand_left_keypoints_2d":[],"hand_right_keypoints_2d":[],"pose_keypoints_3d":[],'
                   '"face_keypoints_3d":[],"hand_left_keypoints_3d":[],"hand_right_keypoints_3d":[]}')
    return ('{"version":1.3,"people":[' + ",".join(out) + "]}").encode()


BROKEN = {
    "boolean as a keypoint": b'{"version":1.3,"people":[{"pose_keypoints_2d":[1.0,2.0,true]}]}',
    "string as a keypoint": b'{"version":1.3,"people":[{"pose_keypoints_2d":[1.0,"2",0.5]}]}',
    "null people": b'{"version":1.3,"people":null}',
    "people missing": b'{"version":1.3}',
    "unknown person field": b'{"people":[{"pose_keypoints_2d":[1,2,0.5],"pose_keypoint_2d":[]}]}',
    "NaN keypoint": b'{"people":[{"pose_keypoints_2d":[NaN,2,0.5]}]}',
    "400-digit number": b'{"people":[{"pose_keypoints_2d":[1' + b"0" * 400 + b',2,0.5]}]}',
    "malformed JSON": b'{"people":[{"pose_keypoints_2d":[1,2,0.5]}',
}


def error_of(decode, data: bytes) -> str:
    try:
        decode(data)
    except (msgspec.MsgspecError, pydantic.ValidationError) as exc:
        return " | ".join(str(exc).splitlines())
    return "accepted"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=100_000)
    ap.add_argument("--people", type=int, default=3, help="people per file")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = []
        for i in range(args.files):
            p = folder / f"cam{i % 100:02d}_{i // 100:012d}_keypoints.json"
            p.write_bytes(openpose_file(rng, args.people))
            paths.append(p)
        size = sum(p.stat().st_size for p in paths)
        emit(setup="schema_choice", files=args.files, people_per_file=args.people, bytes=size,
             msgspec=msgspec.__version__, pydantic=pydantic.VERSION)
        read_by_hand(paths[:1000])  # warm the page cache and the imports
        times = {}
        for name, reader in (("msgspec", read_msgspec), ("pydantic", read_pydantic), ("by_hand", read_by_hand),
                             ("shipped", read_shipped)):
            t0 = time.perf_counter()
            n = reader(paths)
            times[name] = time.perf_counter() - t0
            emit(reader=name, seconds=round(times[name], 3), files_per_s=round(args.files / times[name]),
                 values=n)
        emit(ratio_pydantic_to_msgspec=round(times["pydantic"] / times["msgspec"], 2),
             ratio_by_hand_to_msgspec=round(times["by_hand"] / times["msgspec"], 2),
             ratio_shipped_to_by_hand=round(times["shipped"] / times["by_hand"], 2))
    ms = msgspec.json.Decoder(MsFile).decode
    for case, data in BROKEN.items():
        emit(broken=case, msgspec=error_of(ms, data), pydantic=error_of(PdFile.model_validate_json, data))


if __name__ == "__main__":
    main()
