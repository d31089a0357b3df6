"""Part labels of saved patch streams, relabelled with PartOptions variants (issue 49: the creases).

Run: .venv/bin/python bench/patch_labels.py FILE.npz [FILE2.npz ...] [--variants 'base:;crease:crease_cm=1.0']
         [--noise 1.5] [--draws 1] [--seed 0]

Each FILE is a ``bench/patches.py --save`` stream (its trajectories and the renderer's truth: each patch's true
person and part, the true joints at the stream's times). Per file and variant the patches are labelled
(:func:`dome_calib.recon.patches.parts.label_parts`) with the true skeleton and with the truth plus ``--noise`` cm
per joint coordinate (``--draws`` draws, seeded), and judged as ``bench/patches.py`` judges them (patches alive at
least ``min_frames``): the share labelled, the share of the labelled given their true person and part, and the
wrong ones by (true part -> label) pair. Prints one JSON object per line.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
from collections import Counter

import numpy as np

from dome_calib.recon.patches.parts import BONES, PartOptions, label_parts


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def parse_variants(text: str) -> dict[str, dict]:
    """``NAME:FIELD=VALUE,...;NAME2:...`` (values JSON) -> {name: PartOptions fields}."""
    out = {}
    for item in text.split(";"):
        name, _, fields = item.partition(":")
        out[name.strip()] = {k: json.loads(v) for k, v in (f.split("=", 1) for f in fields.split(",") if f)}
    return out


def judge(saved, joints: np.ndarray, o: PartOptions) -> dict:
    X, normal, alive = saved["X_cm"][:, :, 0], saved["normal"], saved["alive"]
    lab = label_parts(X, normal, alive, joints, o)
    judged = alive.sum(1) >= o.min_frames
    given = judged & (lab.bone >= 0)
    right = given & (lab.person == saved["person"]) & (lab.bone == saved["part"])
    wrong = Counter(f"{BONES[int(t)][0]}->{BONES[int(b)][0]}" for t, b in
                    zip(saved["part"][given & ~right], lab.bone[given & ~right]))
    return {"right": round(float(right.sum() / max(given.sum(), 1)), 4),
            "labelled": round(float(given.sum() / max(judged.sum(), 1)), 4), "judged": int(judged.sum()),
            "wrong": int((given & ~right).sum()), "wrong_pairs": dict(wrong.most_common(8))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--variants", default="base:", help="NAME:FIELD=VALUE,...;... (PartOptions fields, JSON values)")
    ap.add_argument("--noise", type=float, default=1.5, help="cm per joint coordinate added to the true skeleton")
    ap.add_argument("--draws", type=int, default=1, help="draws of the joint noise")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    variants = parse_variants(args.variants)
    emit(bench="patch_labels", load=[round(x, 2) for x in os.getloadavg()])
    for path in args.files:
        saved = dict(np.load(path))
        Xj = saved["joints_cm"]
        for name, fields in variants.items():
            o = dataclasses.replace(PartOptions(), **fields)
            rng = np.random.default_rng(args.seed)
            noisy = [judge(saved, Xj + rng.normal(0.0, args.noise, Xj.shape), o) for _ in range(args.draws)]
            emit(file=os.path.basename(path), variant=name, options=fields, true_skeleton=judge(saved, Xj, o),
                 noise_cm=args.noise, with_noise={k: (round(float(np.mean([d[k] for d in noisy])), 4)
                                                      if k in ("right", "labelled") else noisy[0][k])
                                                  for k in noisy[0]})


if __name__ == "__main__":
    main()
