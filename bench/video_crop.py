"""Where a video's picture sits in its coded frame: per MP4 file, the video codec, the coded size and H.264's frame
crop (the evidence docs/patches.md gives for Pose2Sim's 1080-wide videos against a 1088-wide calibration).

    .venv/bin/python bench/video_crop.py ../shared/data/multiview/pose2sim_balancing/videos/*.mp4

One JSON object per file: ``codec`` (the sample entry: avc1, vp09, ...), ``display`` (the sample entry's width and
height), and for H.264 ``coded`` (the sequence parameter set's size in macroblocks x 16) and ``crop_px`` (left,
right, top, bottom, from its ``frame_crop_*_offset`` in chroma units: x2 for 4:2:0). A reading aid, not a reader
(the toolkit reads videos through OpenCV): the MP4 boxes and the H.264 SPS fields up to the crop, nothing more.
"""
from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

CONTAINERS = {"moov", "trak", "mdia", "minf", "stbl"}


def boxes(b: bytes, start: int, end: int):
    """(type, payload start, end) of the boxes in b[start:end], descending into the containers and sample entries."""
    i = start
    while i + 8 <= end:
        size, kind = struct.unpack(">I4s", b[i:i + 8])
        kind, head = kind.decode("latin-1"), 8
        if size == 1:
            size, head = struct.unpack(">Q", b[i + 8:i + 16])[0], 16
        size = size or end - i
        yield kind, i + head, i + size
        if kind in CONTAINERS:
            yield from boxes(b, i + head, i + size)
        elif kind == "stsd":
            yield from boxes(b, i + head + 8, i + size)
        elif kind in ("avc1", "avc3"):
            yield from boxes(b, i + head + 78, i + size)
        i += size


class Bits:
    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def u(self, n: int = 1) -> int:
        v = 0
        for _ in range(n):
            v = (v << 1) | ((self.data[self.pos >> 3] >> (7 - (self.pos & 7))) & 1)
            self.pos += 1
        return v

    def ue(self) -> int:
        zeros = 0
        while self.u() == 0:
            zeros += 1
        return (1 << zeros) - 1 + self.u(zeros)

    def se(self) -> int:
        k = self.ue()
        return (k + 1) // 2 if k & 1 else -(k // 2)


def sps_size(nal: bytes) -> dict:
    """An H.264 sequence parameter set (NAL with its header) -> coded size and crop (ITU-T H.264 7.3.2.1.1)."""
    raw, zeros = bytearray(), 0
    for x in nal[1:]:  # emulation prevention bytes out
        if zeros >= 2 and x == 3:
            zeros = 0
            continue
        raw.append(x)
        zeros = zeros + 1 if x == 0 else 0
    b = Bits(bytes(raw))
    profile = b.u(8)
    b.u(16)
    b.ue()
    chroma = 1
    if profile in (100, 110, 122, 244, 44, 83, 86, 118, 128, 138, 139, 134, 135):
        chroma = b.ue()
        if chroma == 3:
            b.u()
        b.ue(), b.ue(), b.u()
        if b.u():  # scaling matrices
            for k in range(8 if chroma != 3 else 12):
                if b.u():
                    last = nxt = 8
                    for _ in range(16 if k < 6 else 64):
                        if nxt:
                            nxt = (last + b.se() + 256) % 256
                        last = nxt or last
    b.ue()
    poc = b.ue()
    if poc == 0:
        b.ue()
    elif poc == 1:
        b.u(), b.se(), b.se()
        for _ in range(b.ue()):
            b.se()
    b.ue(), b.u()
    width, height_units = (b.ue() + 1) * 16, b.ue() + 1
    frames_only = b.u()
    if not frames_only:
        b.u()
    b.u()
    crop = [b.ue() for _ in range(4)] if b.u() else [0, 0, 0, 0]
    sub_x, sub_y = (2, 2) if chroma == 1 else (2, 1) if chroma == 2 else (1, 1)
    unit_y = sub_y * (2 - frames_only)
    return {"profile": profile, "coded": [width, height_units * 16 * (2 - frames_only)],
            "crop_px": [crop[0] * sub_x, crop[1] * sub_x, crop[2] * unit_y, crop[3] * unit_y]}


def describe(path: Path) -> dict:
    b = path.read_bytes()
    out: dict = {"file": path.name}
    for kind, start, end in boxes(b, 0, len(b)):
        if kind in ("avc1", "avc3", "vp09", "hvc1", "hev1", "av01", "mp4v") and "codec" not in out:
            out["codec"] = kind
            out["display"] = list(struct.unpack(">HH", b[start + 24:start + 28]))
        if kind == "avcC":
            n = struct.unpack(">H", b[start + 6:start + 8])[0]
            out.update(sps_size(b[start + 8:start + 8 + n]))
    return out


if __name__ == "__main__":
    for name in sys.argv[1:]:
        print(json.dumps(describe(Path(name))), flush=True)
