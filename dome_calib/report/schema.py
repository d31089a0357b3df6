"""``report/report.json``, declared once (:class:`Report`, layout version 3): what the plots, the page, the `report`
command and a rebuild read, and what the calibration writes (built as plain data, validated through this schema,
then written from it: the writer cannot write what the reader refuses).

Reasons to check a camera are ``{"code", "text"}`` (:mod:`dome_calib.reasons`); what the calibration found beyond
the report's own rules (its reasons, the cameras it could not calibrate, the cameras it held) is its own section,
``found`` (:class:`Findings`), which a rebuild keeps; the rules' reasons are recomputed.

Older layouts are read through an explicit migration (:func:`read_report`), not refused: they were written by
earlier versions of this tool and sit in bundles on disk, and refusing them would force a recalibration (minutes
to hours) only to rebuild a page. Each is declared as it was (:class:`ReportV2`, :class:`ReportV1`), so a damaged
old file is refused in one line like a new one, and the texts of their reasons (the only meaning they carry) are
turned into codes by :data:`V2_TEXTS`, frozen: today's messages may be reworded freely.

- version 1 (no ``report_version``): reasons as texts in ``to_check`` only (the rules' and the calibration's
  mixed), no ``found``, ``expected_per_type``, panels, image sizes or held cameras;
- version 2: ``found`` added, reasons still texts;
- version 3: reasons ``{code, text}``.

An edited file is one line naming the file and the field (``report.json: found.reasons.01_02: expected a list of
objects with code, text, got "moved"``), never a traceback; a string is never read as a list of its letters.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Literal, TypeVar

import numpy as np
from pydantic import BaseModel

from dome_calib.bundle import CameraType, camera_type_from_name
from dome_calib.errors import ReportError
from dome_calib.reasons import RULE_CODES, Reason, ReasonCode
from dome_calib.schema import (CameraName, Field, FileSchema, Finite, NonNegFinite, NonNegInt, PlainName, PosFinite,
                               PosInt, Vec, Vec3, parse_json)

REPORT_VERSION = 3
M = TypeVar("M", bound=BaseModel)

Name = Annotated[str, Field(min_length=1)]
Text = str


class TypeCount(FileSchema):
    """Cameras of one type calibrated against those the capture expected."""

    calibrated: NonNegInt
    expected: NonNegInt


class TypeStats(FileSchema):
    """One camera type: its cameras and (with residuals) observations, RMS per coordinate and median norm (px)."""

    cameras: NonNegInt
    observations: NonNegInt | None = None
    rms_px: NonNegFinite | None = None
    median_px: NonNegFinite | None = None


class Rules(FileSchema):
    """The report's rules for the cameras to check (:class:`dome_calib.report.ReportOptions`)."""

    min_observations: NonNegInt
    high_rms_factor: PosFinite
    high_rms_floor_px: NonNegFinite


class ToCheck(FileSchema):
    """A camera to check (``type`` null: expected but not calibrated) and why."""

    name: CameraName
    type: CameraType | None
    reasons: Annotated[list[Reason], Field(min_length=1)]


class CameraRow(FileSchema):
    """One calibrated camera's figures. ``panel``, ``resolution``, ``view_dir`` (optical axis, world) and
    ``held`` (why it was taken as it was) are null in a report of layout 1."""

    type: CameraType
    center_cm: Vec3
    observations: NonNegInt | None
    rms_px: NonNegFinite | None
    panel: NonNegInt | None = None
    resolution: Vec(2, PosInt) | None = None
    view_dir: Vec3 | None = None
    held: Text | None = None
    lens_free: list[Name] | None = None
    lens_held: list[Name] | None = None


class Findings(FileSchema):
    """What the calibration found beyond the report's rules: reasons per camera, cameras not calibrated (why),
    cameras held (why). A rebuild keeps it."""

    reasons: dict[CameraName, Annotated[list[Reason], Field(min_length=1)]] = {}
    missing: dict[CameraName, Text] = {}
    held: dict[CameraName, Text] = {}


class WorldFrame(FileSchema):
    """The similarity that put the cameras in the Panoptic frame (:meth:`dome_calib.normalize.Normalized.as_dict`)."""

    reference: Text
    reference_source: Text
    shared_cameras: NonNegInt
    inliers: NonNegInt
    outliers: list[CameraName]
    scale: PosFinite
    residual_rms_cm: NonNegFinite
    not_aligned: list[CameraName]
    description: Text


class LensDecision(FileSchema):
    group: Text
    terms: list[Name]
    free: bool
    reason: Text
    sigma_px: Finite | None = None
    wald_chi2: Finite | None = None
    penalty_chi2: Finite | None = None


class CameraLens(FileSchema):
    free: list[Name]
    held: list[Name]
    decisions: list[LensDecision] = []


class LensModelSection(FileSchema):
    """The lens terms each camera refined or held (:meth:`dome_calib.ba.lens_model.LensModel.as_dict`)."""

    rule: Text
    max_sigma_px: PosFinite | None = None
    max_principal_point_sigma_px: PosFinite | None = None
    needed_p_value: PosFinite | None = None
    noise_px: Finite | None = None
    solves: NonNegInt | None = None
    iterations_per_solve: list[NonNegInt] = []
    note: Text = ""
    cameras: dict[CameraName, CameraLens] = {}


class ClusterStage(FileSchema):
    tasks: NonNegInt
    workers: dict[Name, NonNegInt]
    wall_s: NonNegFinite
    task_s: NonNegFinite
    mb_moved: NonNegFinite


class Cluster(FileSchema):
    """Where each stage ran (:func:`dome_calib.pipeline.cluster.cluster_section`)."""

    executor: Literal["local", "dask"]
    processes: PosInt | None = None
    description: Text | None = None
    scheduler: Text | None = None
    stages: dict[Name, ClusterStage] = {}
    on_this_machine: list[Text] = []


class PreviousCamera(FileSchema):
    moved_mm: NonNegFinite
    turned_deg: NonNegFinite
    focal_pct: Finite


class Previous(FileSchema):
    """Change since the previous calibration (:func:`dome_calib.report.previous.previous_section`); ``error``: it
    could not be compared."""

    source: Text
    seq: Text | None = None
    compared: Text | None = None
    added: list[CameraName] = []
    gone: list[CameraName] = []
    cameras: dict[CameraName, PreviousCamera] = {}
    error: Text | None = None


class CameraChangeRow(FileSchema):
    """A camera changed against the prior (:meth:`dome_calib.compare.CameraChange.as_dict`; null: not comparable)."""

    name: CameraName
    moved_cm: Finite | None
    rotated_deg: Finite | None
    focal_pct: Finite | None
    distortion_px: Finite | None
    reasons: list[Reason]


class Report(FileSchema):
    """report.json, layout 3 (module docstring)."""

    report_version: Literal[3]
    seq: Text
    calib_data_source: Text
    cameras: NonNegInt
    expected_per_type: dict[CameraType, TypeCount]
    has_residuals: bool
    rms_px: NonNegFinite | None
    per_type: dict[CameraType, TypeStats]
    rules: Rules | None  # null only in a report of layout 1 that did not record them
    to_check: list[ToCheck]
    per_camera: dict[CameraName, CameraRow]
    found: Findings
    plots: list[PlainName] = []
    # sections of what the calibration measured beyond the residuals (a rebuild keeps them)
    world_frame: WorldFrame | None = None
    stage_seconds: dict[Name, NonNegFinite] = {}
    center_sigma_cm: dict[CameraName, NonNegFinite] = {}
    rotation_sigma_deg: dict[CameraName, NonNegFinite] = {}
    previous: Previous | None = None
    lens_model: LensModelSection | None = None
    cluster: Cluster | None = None
    changes_vs_prior: dict[Name, CameraChangeRow] | None = None


#: The sections a rebuild keeps as the calibration wrote them (every other field is recomputed).
KEPT_SECTIONS = ("world_frame", "stage_seconds", "center_sigma_cm", "rotation_sigma_deg", "previous", "lens_model",
                 "cluster", "changes_vs_prior")


# ---- the older layouts, as they were -----------------------------------------------------------------------------

class ToCheckV2(FileSchema):
    name: CameraName
    type: CameraType | None
    reasons: list[Annotated[str, Field(min_length=1)]]


class FindingsV2(FileSchema):
    reasons: dict[Name, list[Annotated[str, Field(min_length=1)]]] = {}
    missing: dict[Name, Text] = {}
    held: dict[Name, Text] = {}


class CameraChangeRowV2(CameraChangeRow):
    reasons: list[Annotated[str, Field(min_length=1)]]


class ReportV2(Report):
    """report.json, layout 2: reasons as texts."""

    report_version: Literal[2]
    to_check: list[ToCheckV2]
    found: FindingsV2
    changes_vs_prior: dict[Name, CameraChangeRowV2] | None = None


class ReportV1(ReportV2):
    """report.json, layout 1 (no ``report_version``): no ``found`` or ``expected_per_type``; the first files also
    lacked the source, the rules and the figures per type."""

    report_version: Literal[1] = 1
    found: None = None
    expected_per_type: None = None
    calib_data_source: Text = ""
    cameras: NonNegInt | None = None
    has_residuals: bool = True
    rms_px: NonNegFinite | None = None
    per_type: dict[CameraType, TypeStats] = {}
    rules: Rules | None = None


#: The texts that layouts 1 and 2 wrote, by their beginning, and the code each meant (frozen: these versions are
#: done; today's texts are free to change). A text none of them begins is kept as a NOTE.
V2_TEXTS = (("too few observations", ReasonCode.TOO_FEW_OBSERVATIONS), ("high RMS", ReasonCode.HIGH_RMS),
            ("not calibrated: ", ReasonCode.NOT_CALIBRATED), ("moved ", ReasonCode.MOVED),
            ("rotated ", ReasonCode.ROTATED), ("intrinsics changed", ReasonCode.INTRINSICS_CHANGED),
            ("new intrinsics", ReasonCode.INTRINSICS_CHANGED), ("new camera", ReasonCode.NEW_CAMERA),
            ("residual ", ReasonCode.RESIDUAL_UNDER_PRIOR), ("not checked against the prior", ReasonCode.NOT_CHECKED),
            ("position poorly determined", ReasonCode.POSITION_UNCERTAIN),
            ("position much less determined", ReasonCode.POSITION_UNCERTAIN))


def reason_of_v2_text(text: str) -> Reason:
    """A reason as layouts 1 and 2 wrote it (a text) with its code (:data:`V2_TEXTS`)."""
    code = next((c for prefix, c in V2_TEXTS if text.startswith(prefix)), ReasonCode.NOTE)
    return Reason(code=code, text=text)


def _upgrade(old: ReportV2) -> Report:
    """Layout 1 or 2 as layout 3: reasons coded; for layout 1, the findings recovered from ``to_check`` (the
    rules' reasons left out: a rebuild recomputes them) and the expected cameras from the rows."""
    to_check = [ToCheck(name=r.name, type=r.type, reasons=[reason_of_v2_text(t) for t in r.reasons])
                for r in old.to_check if r.reasons]
    if old.found is not None:
        found = Findings(reasons={n: [reason_of_v2_text(t) for t in v] for n, v in old.found.reasons.items() if v},
                         missing=old.found.missing, held=old.found.held)
    else:
        missing = {r.name: r.reasons[0].text.removeprefix("not calibrated: ") for r in to_check
                   if r.type is None and r.reasons[0].code == ReasonCode.NOT_CALIBRATED}
        reasons = {r.name: kept for r in to_check if r.name not in missing
                   if (kept := [x for x in r.reasons if x.code not in RULE_CODES])}
        found = Findings(reasons=reasons, missing=missing,
                         held={n: c.held for n, c in old.per_camera.items() if c.held})
    expected = old.expected_per_type
    if expected is None:
        counts: dict[CameraType, TypeCount] = {}
        for name in [*old.per_camera, *found.missing]:
            t = old.per_camera[name].type if name in old.per_camera else camera_type_from_name(name)
            c = counts.setdefault(t, TypeCount(calibrated=0, expected=0))
            counts[t] = TypeCount(calibrated=c.calibrated + (name in old.per_camera), expected=c.expected + 1)
        expected = counts
    changes = None if old.changes_vs_prior is None else {
        n: CameraChangeRow(**{**c.model_dump(), "reasons": [reason_of_v2_text(t) for t in c.reasons]})
        for n, c in old.changes_vs_prior.items()}
    fields = {k: getattr(old, k) for k in Report.model_fields if k not in (
        "report_version", "to_check", "found", "expected_per_type", "changes_vs_prior", "cameras")}
    return Report(**fields, report_version=REPORT_VERSION, to_check=to_check, found=found, expected_per_type=expected,
                  changes_vs_prior=changes, cameras=old.cameras if old.cameras is not None else len(old.per_camera))


# ---- reading and writing ----------------------------------------------------------------------------------------

def parse_report(source: str | Path, data: bytes) -> tuple[Report, int]:
    """report.json's bytes -> (the report in layout 3, the layout the file had). ReportError of one line naming
    the file and the field."""
    try:
        raw = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ReportError(f"{source}: not valid JSON ({exc})") from None
    if not isinstance(raw, dict):
        raise ReportError(f"{source}: expected an object (a report), got a JSON {type(raw).__name__}")
    if "report_version" not in raw and ("found" in raw or "expected_per_type" in raw):
        raise ReportError(f"{source}: report_version: missing (expected 2 or 3: only the first layout has none, and "
                          'it has no "found" or "expected_per_type")')
    version = raw.get("report_version", 1)
    schema = {1: ReportV1, 2: ReportV2, 3: Report}.get(version) if type(version) is int else None
    if schema is None:
        raise ReportError(f"{source}: report_version: expected 2 or 3 (or absent: the first layout), got "
                          f"{json.dumps(version)[:40]}")
    parsed = parse_json(source, data, schema, error=ReportError)  # JSON mode: enums read from their values
    return (parsed if schema is Report else _upgrade(parsed)), version


def read_report(path: str | Path) -> tuple[Report, int]:
    """The report.json at ``path`` (any layout, :func:`parse_report`). ReportError naming the file otherwise."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ReportError(f"{path}: cannot be read ({exc.strerror})") from None
    return parse_report(path, data)


def checked(content: dict, schema: type[M], source: str) -> M:
    """A file's content built as plain data, through its schema as the file will be read back (JSON): what a
    writer makes is what a reader accepts, or the writer fails (ReportError naming the field) before writing."""
    return parse_json(source, json.dumps(content, allow_nan=False, default=_json_default).encode("utf-8"), schema,
                      error=ReportError)


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, BaseModel):  # a typed section (a rebuild's kept ones), a reason
        return obj.model_dump(mode="json", exclude_unset=True)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


__all__ = ["REPORT_VERSION", "KEPT_SECTIONS", "Report", "ReportV1", "ReportV2", "ToCheck", "Findings", "CameraRow",
           "Rules", "TypeStats", "TypeCount", "checked", "parse_report", "read_report", "reason_of_v2_text"]
