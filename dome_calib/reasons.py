"""Why a camera is to be checked: a reason is a code (what kind of finding, for programs) and a text (for people).

Programs key on the code, never on the text: `dome-calib report` recomputes the reasons its own rules give
(:data:`RULE_CODES`) and keeps every other one as the calibration found it, so rewording a message changes no
result. Reports written before the codes (report.json versions 1 and 2) are read through
:mod:`dome_calib.report.schema`'s migration, the only place that knows their texts.
"""
from __future__ import annotations

from enum import StrEnum
from typing import Annotated

from dome_calib.schema import Field, FileSchema


class ReasonCode(StrEnum):
    """What kind of finding a reason is."""

    TOO_FEW_OBSERVATIONS = "too_few_observations"  # the report's rule: an estimated camera seen too rarely
    HIGH_RMS = "high_rms"  # the report's rule: reprojection RMS far above its type's
    MOVED = "moved"  # against the prior (or the previous calibration): the centre moved
    ROTATED = "rotated"  # ... the orientation turned
    INTRINSICS_CHANGED = "intrinsics_changed"  # ... focal length or distortion changed: replaced?
    NEW_CAMERA = "new_camera"  # not in the prior
    RESIDUAL_UNDER_PRIOR = "residual_under_prior"  # the quick path: the prior no longer fits its observations
    NOT_CHECKED = "not_checked"  # the quick path: no usable image to check it against the prior; prior kept
    POSITION_UNCERTAIN = "position_uncertain"  # its centre's uncertainty is large (absolutely or against the dome's)
    NOT_CALIBRATED = "not_calibrated"  # expected but not in the bundle
    KEYPOINTS_NOT_REFINED = "keypoints_not_refined"  # an image of it no task could read: SIFT's keypoints kept
    NOTE = "note"  # a reason of an older report that none of the codes above names (kept as it was)


#: Codes the report's own rules give: a rebuild recomputes them; every other code came from the calibration.
RULE_CODES = frozenset({ReasonCode.TOO_FEW_OBSERVATIONS, ReasonCode.HIGH_RMS})


class Reason(FileSchema):
    """One reason to check a camera: ``{"code": "moved", "text": "moved 3.1 cm"}``."""

    code: ReasonCode
    text: Annotated[str, Field(min_length=1)]


def reason(code: ReasonCode, text: str) -> Reason:
    """A :class:`Reason` (the short spelling the producers use)."""
    return Reason(code=code, text=text)
