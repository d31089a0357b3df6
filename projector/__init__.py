"""Projector random patterns and the projector-pattern structure-from-motion front end.

``from projector import run_sfm`` (lazy: importing the package does not load pycolmap).
"""
from __future__ import annotations

_SFM_NAMES = ("run_sfm", "SfmOptions", "SfmResult", "CameraFailure")


def __getattr__(name: str):
    if name in _SFM_NAMES:
        # in-function import: `import projector` (patterns, the CLI) must not load pycolmap
        from projector import sfm

        return getattr(sfm, name)
    raise AttributeError(f"module 'projector' has no attribute {name!r}")
