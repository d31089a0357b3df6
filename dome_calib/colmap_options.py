"""Every pycolmap options object the toolkit hands to COLMAP, made in one place: one thread and a fixed seed.

Why: COLMAP's threaded solvers (Ceres in GLOMAP's global positioning and bundle adjustment, the incremental
mapper's, the point triangulator's) sum in the order their threads finish, so two runs of the same mapping gave
models that differ in the last bits (measured: three GLOMAP runs of the tiny dome's scene in one process, three
different ``points3D.bin``; with one thread, three identical), and calibrate's bundle then differed in the 13th
digit. One thread and a seed make the same bytes on every run. A seed of -1 (COLMAP's default) draws one from the
clock: every ``random_seed`` in the object and the objects nested in it is set.

``tests/test_colmap_options.py`` refuses a ``pycolmap.*Options(`` made anywhere else in the package.
"""
from __future__ import annotations

from typing import TypeVar

T = TypeVar("T")

#: The seed every COLMAP options object gets unless a caller names another.
SEED = 0


def _nested(options: object) -> list[tuple[str, object]]:
    """The options objects held in ``options`` (attributes whose type is named ``*Options``), by name."""
    out = []
    for name in sorted(dir(options)):
        if name.startswith("_"):
            continue
        try:
            value = getattr(options, name)
        except Exception:  # noqa: BLE001 - a property pycolmap cannot give on this build
            continue
        if type(value).__name__.endswith("Options"):
            out.append((name, value))
    return out


def pin(options: T, seed: int = SEED) -> T:
    """Set ``num_threads`` to 1 and ``random_seed`` to ``seed`` in ``options`` and every options object nested in
    it (pycolmap returns nested options by reference: setting them sets ``options``'s own); returns ``options``."""
    if hasattr(options, "num_threads"):
        options.num_threads = 1
    if hasattr(options, "random_seed"):
        options.random_seed = seed
    for _, inner in _nested(options):
        pin(inner, seed)
    return options


def colmap_options(kind: type[T], *, seed: int = SEED, **fields) -> T:
    """A new pycolmap options object of ``kind`` (``pycolmap.GlobalPipelineOptions``, ``pycolmap.RANSACOptions``,
    ...) with ``fields`` set, then one thread and ``seed`` throughout (:func:`pin`)."""
    options = kind()
    for name, value in fields.items():
        setattr(options, name, value)
    return pin(options, seed)


def unpinned(options: object, seed: int = SEED, path: str = "") -> list[str]:
    """The fields of ``options`` (nested ones as ``a.b.num_threads``) whose thread count is not 1 or whose seed is
    not ``seed``: what :func:`pin` would change."""
    out = []
    if getattr(options, "num_threads", 1) != 1:
        out.append(f"{path}num_threads")
    if getattr(options, "random_seed", seed) != seed:
        out.append(f"{path}random_seed")
    for name, inner in _nested(options):
        out += unpinned(inner, seed, f"{path}{name}.")
    return out
