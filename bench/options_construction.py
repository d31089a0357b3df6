"""What checking an options object's bounds costs where it is built: the options declared with
:func:`dome_calib.options.options` (pydantic dataclasses, the choice) against the alternative considered (a small
mechanism that reads the same ``Annotated`` bounds and checks them in ``__post_init__``) and against the code
before (stdlib dataclasses with hand checks, at the revision ``--baseline-rev``), then how many options
objects a reconstruction builds per time step, so that the cost is seen against the work.

Run: .venv/bin/python bench/options_construction.py [--baseline-rev 2a6a476] [--repeat 20000]

Prints one JSON object per line: setup (load average, commits); per (class, variant) the microseconds to build
one object with its defaults, with two fields given, and by ``dataclasses.replace``; then per variant the mean over
the classes and the ratio to the baseline; then the reconstruction's count (a small synthetic group on the panel
dome, every options construction counted) and the share of its time those constructions take at the measured cost.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import timeit
import typing
from pathlib import Path

import annotated_types as at
import pydantic

ROOT = Path(__file__).resolve().parents[1]

#: (modules where the class is, newest first; class; two fields given) of options built per call of a stage or per
#: chunk (the people modules became a package after the baseline).
CLASSES = [(["dome_calib.recon.triangulate"], "TriangulationOptions", {"inlier_threshold_px": 10.0, "min_views": 3}),
           (["dome_calib.recon.people.proposals", "dome_calib.recon.people_assoc"], "AssociationOptions",
            {"min_person_views": 3, "max_ray_gap_cm": 9.0}),
           (["dome_calib.recon.people.tracking", "dome_calib.recon.tracking"], "TrackingOptions",
            {"gate_cm": 30.0, "smooth_half_window": 2}),
           (["dome_calib.align"], "AlignOptions", {"max_error_cm": 1.0, "estimate_scale": False}),
           (["timecode.sync.tables"], "SyncOptions", {"max_extrapolation_s": 1.0, "device_break_ms": 40.0}),
           (["dome_calib.ba.solver"], "BAOptions", {"outlier_rounds": 2, "loss_scale_px": 1.5})]

_MEASURE = """
import dataclasses, importlib, json, sys, timeit
classes, repeat = json.loads(sys.argv[1]), int(sys.argv[2])

def find(modules, name):
    for m in modules:
        try:
            return getattr(importlib.import_module(m), name)
        except ImportError:
            continue

out = {}
for modules, name, given in classes:
    cls = find(modules, name)
    made = cls()
    t = lambda f: min(timeit.repeat(f, number=repeat, repeat=5)) / repeat * 1e6
    out[name] = {"default_us": t(cls), "given_us": t(lambda: cls(**given)),
                 "replace_us": t(lambda: dataclasses.replace(made, **given))}
print(json.dumps(out))
"""


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def measure_in(checkout: Path, repeat: int) -> dict:
    """The construction times of CLASSES as the code of ``checkout`` declares them (a fresh process)."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    done = subprocess.run([sys.executable, "-c", _MEASURE, json.dumps(CLASSES), str(repeat)], env=env,
                          capture_output=True, text=True, check=True, cwd=checkout)
    return json.loads(done.stdout)


# ---- the alternative: a stdlib dataclass whose __post_init__ checks the Annotated bounds of its fields ----------

_OPS = {at.Gt: lambda v, b: v > b, at.Ge: lambda v, b: v >= b, at.Lt: lambda v, b: v < b, at.Le: lambda v, b: v <= b}


def _rules(cls: type) -> tuple:
    hints = typing.get_type_hints(cls, include_extras=True)
    rules = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        meta = []
        if typing.get_origin(hint) is typing.Annotated:
            base = hint.__origin__
            for m in hint.__metadata__:
                meta += m.metadata if isinstance(m, pydantic.fields.FieldInfo) else [m]
        else:
            base = hint
        bounds = tuple((_OPS[type(m)], getattr(m, type(m).__name__.lower())) for m in meta if type(m) in _OPS)
        rules.append((f.name, base, bounds))
    return tuple(rules)


def annotated_checker(cls: type) -> type:
    """``cls``'s fields and bounds as a stdlib dataclass checking them by hand in ``__post_init__``."""
    rules = _rules(cls)

    def __post_init__(self) -> None:  # noqa: N807
        for name, base, bounds in rules:
            v = getattr(self, name)
            if base is float and (type(v) is bool or not isinstance(v, (int, float)) or not math.isfinite(v)):
                raise ValueError(name)
            if base is int and (type(v) is bool or not isinstance(v, int)):
                raise ValueError(name)
            for op, b in bounds:
                if not op(v, b):
                    raise ValueError(name)

    fields = [(f.name, typing.Any, dataclasses.field(default=f.default, default_factory=f.default_factory))
              for f in dataclasses.fields(cls)]
    return dataclasses.make_dataclass(f"Annotated{cls.__name__}", fields, kw_only=True,
                                      namespace={"__post_init__": __post_init__})


def measure_here(repeat: int) -> tuple[dict, dict]:
    import importlib

    chosen, alternative = {}, {}
    for modules, name, given in CLASSES:
        cls = getattr(importlib.import_module(modules[0]), name)
        for out, make in ((chosen, cls), (alternative, annotated_checker(cls))):
            made = make()

            def t(f):
                return min(timeit.repeat(f, number=repeat, repeat=5)) / repeat * 1e6

            out[name] = {"default_us": t(make), "given_us": t(lambda: make(**given)),
                         "replace_us": t(lambda: dataclasses.replace(made, **given))}
    return chosen, alternative


def reconstruction_count() -> dict:
    """Options objects built while a 2-person group is reconstructed on the panel dome (1 s), and its time."""
    from dome_calib.options import options_classes
    from dome_calib.recon.people.run import PeopleOptions, reconstruct_people
    from dome_calib.recon.people.sources import people_streams
    from dome_calib.recon.project import view_set
    from dome_calib.synth.detector import DetectorModel, synth_detections
    from dome_calib.synth.dome import as_built_dome
    from dome_calib.synth.group import GroupOptions, make_group
    from dome_calib.synth.skeleton import synthetic_sync

    bundle = as_built_dome("panel", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=2000.0, seed=0)
    truth = make_group(GroupOptions(n_people=2, duration_ms=1000.0, start_ms=500.0, seed=0))
    cams = sorted(bundle.cameras)
    det = synth_detections(bundle, truth, cameras=cams, univ_time_ms=(400.0, 1600.0), model=DetectorModel(seed=0))
    streams = people_streams(bundle, det)
    table = bundle.sync.streams["vga"]
    times = table.univ_time_ms[(table.univ_time_ms >= 500.0) & (table.univ_time_ms <= 1500.0)]
    views = view_set(bundle, [n for s in streams for n in s.cameras])
    counts: dict[str, int] = {}
    originals = {}
    for cls in options_classes():
        init = cls.__init__
        originals[cls] = init

        def counting(self, *a, __init=init, __name=cls.__name__, **k):
            counts[__name] = counts.get(__name, 0) + 1
            __init(self, *a, **k)

        cls.__init__ = counting
    try:
        wall = time.perf_counter()
        reconstruct_people(views, streams, times, PeopleOptions())
        wall = time.perf_counter() - wall
    finally:
        for cls, init in originals.items():
            cls.__init__ = init
    return {"times": int(len(times)), "views": len(views.names), "seconds": round(wall, 2), "constructions": counts}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-rev", default="2a6a476", help="revision of the code before (hand checks)")
    ap.add_argument("--repeat", type=int, default=20000)
    args = ap.parse_args()
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    emit(setup="options construction", load_average=os.getloadavg(), commit=commit, baseline_rev=args.baseline_rev,
         repeat=args.repeat)
    with tempfile.TemporaryDirectory() as tmp:  # the baseline's tree, as git holds it
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline_rev], capture_output=True,
                                 check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        before = measure_in(Path(tmp), args.repeat)
    chosen, alternative = measure_here(args.repeat)
    variants = {"before (stdlib dataclass, hand checks)": before, "pydantic dataclass (chosen)": chosen,
                "Annotated bounds in __post_init__ (alternative)": alternative}
    for variant, table in variants.items():
        for name, t in table.items():
            emit(variant=variant, options=name, **{k: round(v, 3) for k, v in t.items()})
    for variant, table in variants.items():
        mean = {k: sum(t[k] for t in table.values()) / len(table) for k in ("default_us", "given_us", "replace_us")}
        base = {k: sum(t[k] for t in before.values()) / len(before) for k in mean}
        emit(variant=variant, mean_over=len(table), **{k: round(v, 3) for k, v in mean.items()},
             **{f"ratio_to_before_{k.removesuffix('_us')}": round(mean[k] / base[k], 2) for k in mean})
    count = reconstruction_count()
    n = sum(count["constructions"].values())
    per = sum(t["given_us"] for t in chosen.values()) / len(chosen)
    emit(reconstruction="panel dome, 2 people, 1 s", **count, total_constructions=n,
         constructions_per_time=round(n / max(count["times"], 1), 2),
         share_of_time_pct=round(100 * n * per * 1e-6 / count["seconds"], 5))


if __name__ == "__main__":
    main()
