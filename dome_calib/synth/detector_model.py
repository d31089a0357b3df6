"""What the synthetic OpenPose-like detector (:mod:`dome_calib.synth.detector`) does wrong, and how often: its
options, with defaults measured on real OpenPose output, and the tally of what it did.

The defaults come from :mod:`dome_calib.synth.detector_stats` run on Pose2Sim's demo capture (real OpenPose
BODY_25B output of one person, 4 phone cameras, 1088 x 1920, 100 frames at 60 fps; ``bench/detector_stats.py``
prints them, ``docs/synthetic-groups.md`` states them, a test keeps these defaults equal to what the bench fits).
Sizes are relative to the person's height in the image (``h_px = fy * 170 cm * scale / depth``); durations are
lognormal (:class:`Lognormal`) in universal time, so they mean the same at 25, 30 or 60 fps.

Five options are read low or high by the measuring itself (the fit absorbs part of a bias, a track of 100 frames
shortens a correlation time, a fitted body sometimes calls a hidden face joint visible): a synthetic twin of the
capture (the same cameras, a person of the same size where the real one stood) measured the same way shows by how
much, and those defaults (marked ``*``) are set so that the twin reads what the real capture read.

What that capture cannot tell (one person, nobody else in front of anybody, no left/right swap in 400 images) is
chosen, and said so beside the option: misses of joints another person hides, a neighbour's limb, swap rates
(set within what the 400 images allow), false people, the border, how noise grows for small people.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from dome_calib.errors import DomeCalibError


class DetectorError(DomeCalibError, ValueError):
    """A camera the detector cannot see through (unknown, not a colour camera, no sync table), or bad options."""


@dataclass(frozen=True)
class Lognormal:
    """A lognormal distribution: ``median`` (in the unit its name states: ``_ms``, ``_rel``) and ``log_sd`` (of
    the natural log)."""

    median: float
    log_sd: float

    @property
    def mean(self) -> float:
        return self.median * math.exp(0.5 * self.log_sd ** 2)


#: Percentiles of the confidence tables (as :data:`dome_calib.synth.detector_stats.CONF_PERCENTILES`).
CONF_PERCENTILES = (0.5, 5.0, 10.0, 25.0, 50.0, 75.0, 90.0, 95.0, 99.5)
#: Joint classes (joints19 order) whose outlier and miss rates differ: 0 wrists, 1 the other body joints, 2 face.
JOINT_CLASS19 = np.array([1, 2, 1, 1, 1, 0, 1, 1, 1, 1, 1, 0, 1, 1, 1, 2, 2, 2, 2])
#: Measured per-coordinate noise / person height of each joint (joints19 order; left and right averaged; the neck
#: and body centre, which BODY_25B derives, take the shoulders' and hips' values).
NOISE_REL19 = (0.0073, 0.0091, 0.0151, 0.0073, 0.0108, 0.0089, 0.0151, 0.0089, 0.0083, 0.0073, 0.0108, 0.0089,
               0.0151, 0.0089, 0.0083, 0.0071, 0.0059, 0.0071, 0.0059)
_OUTLIER_MS = Lognormal(32.3, 0.85)
#: The options (marked * below) set through the twin (bench/detector_stats.py), not read off the real capture.
TWIN_CORRECTED = ("hidden_noise", "noise_bias_share", "noise_tau_ms", "miss_base", "outlier_size_rel")


@dataclass(kw_only=True)
class DetectorModel:
    """Rates, sizes and durations of OpenPose's failure modes (defaults measured; see the module docstring)."""

    # pixel noise: per coordinate, noise_rel19[j] x height at noise_ref_net_px network rows; split into a part
    # constant per (camera, person, joint) (the person's bias), an exponentially correlated part and a white part
    noise_rel19: tuple[float, ...] = NOISE_REL19
    noise_ref_net_px: float = 156.0  # the measured people's height in the 368-row network input
    net_height_px: float = 368.0
    noise_small_px: float = 120.0  # chosen: noise doubles (against a large person) at this height in the network
    # (* : measured through the fit, which reads these settings low or high: set so the twin reads what the real
    # capture read, see the module docstring)
    hidden_noise: float = 2.5  # * hidden joints that are detected anyway: noise x this (read 1.6)
    noise_bias_share: float = 0.31  # * (read 0.18)
    noise_white_share: float = 0.08
    noise_tau_ms: float = 166.0  # * (read 151)
    # outliers: a joint placed off by size_rel x height in a direction, both held for the episode (the size drawn
    # from the lognormal above k_outlier sigmas: an episode the statistics would not see is not one)
    outlier_wrists: float = 0.046
    outlier_limbs: float = 0.001
    outlier_face: float = 0.001
    outlier_ms: Lognormal = _OUTLIER_MS
    outlier_size_rel: Lognormal = Lognormal(0.31, 0.82)  # * x height, each episode's largest (read 0.25)
    k_outlier: float = 5.0
    # misses
    miss_base: float = 0.00015  # * visible joints (read 0.0021: the fit alone reads ~0.003 from ~0)
    miss_ms: Lognormal = Lognormal(18.4, 0.33)
    miss_self_face: float = 0.43  # face joints the person's own head hides (turned away)
    miss_self_body: float = 0.004  # body joints the person's own body hides
    miss_self_ms: Lognormal = Lognormal(61.4, 1.56)
    miss_occluded: float = 0.6  # chosen: joints another person hides (the capture has nobody in front of anybody)
    miss_border_px: float = 20.0  # chosen: the border zone, image pixels
    miss_border: float = 0.5  # chosen: extra miss probability on the border itself (linear to 0 across the zone)
    # left/right swaps: none in the capture's 400 person-images (95 % upper bound 0.75 %): chosen within it,
    # lasting as the measured outliers do
    swap_lr: float = 0.0025
    swap_limb: float = 0.005
    swap_ms: Lognormal = _OUTLIER_MS
    # a neighbour's limb (chosen: the capture has one person)
    neighbour_limb: float = 0.06
    neighbour_near: float = 0.25
    neighbour_ms: Lognormal = _OUTLIER_MS
    # false people: none in 400 images (95 % upper bound 0.0075 per image): chosen at the bound, 100 ms median
    false_people_per_view: float = 0.0075
    false_ms: Lognormal = Lognormal(100.0, 1.0)
    # a coordinate written as exactly 0 (x) with a confidence: 6 of 6,401 detected joints, runs of 5 and 1 frames
    zero_coordinate: float = 0.00094
    zero_ms: Lognormal = Lognormal(37.3, 1.14)
    # confidence: percentiles (CONF_PERCENTILES) of visible inliers, hidden inliers and outliers, drawn through a
    # unit latent with a part constant per (camera, person, joint), an exponentially correlated part (tau) and a
    # white part; a few above 1 (the 5-camera capture: 5 of 113,750 keypoints at 1.004-1.037)
    conf_visible: tuple[float, ...] = (0.232, 0.436, 0.503, 0.599, 0.641, 0.668, 0.694, 0.72, 0.804)
    conf_hidden: tuple[float, ...] = (0.054, 0.076, 0.09, 0.143, 0.283, 0.602, 0.654, 0.676, 0.775)
    conf_outlier: tuple[float, ...] = (0.058, 0.061, 0.073, 0.16, 0.3, 0.498, 0.627, 0.649, 0.668)
    conf_bias_share: float = 0.31
    conf_white_share: float = 0.04
    conf_tau_ms: float = 288.0
    conf_above_1: float = 4.4e-5
    min_joints: int = 4
    truncate_border: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        probabilities = ("outlier_wrists", "outlier_limbs", "outlier_face", "miss_base", "miss_self_face",
                         "miss_self_body", "miss_occluded", "miss_border", "swap_lr", "swap_limb", "neighbour_limb",
                         "zero_coordinate", "conf_above_1", "noise_bias_share", "noise_white_share", "conf_bias_share",
                         "conf_white_share")
        for name in probabilities:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise DetectorError(f"detector model: {name}={value} but expected a probability in [0, 1]")
        for name in ("outlier_wrists", "outlier_limbs", "outlier_face", "miss_base", "miss_self_face",
                     "miss_self_body", "miss_occluded", "swap_lr", "swap_limb", "neighbour_limb", "zero_coordinate"):
            if getattr(self, name) >= 1.0:  # an episode that never ends: the off time would be 0
                raise DetectorError(f"detector model: {name}={getattr(self, name)} but expected below 1 (a share "
                                    "of time spent in episodes that end)")
        for what in ("noise", "conf"):
            if getattr(self, f"{what}_bias_share") + getattr(self, f"{what}_white_share") > 1.0:
                raise DetectorError(f"detector model: {what}_bias_share + {what}_white_share must be <= 1")
        for name in ("noise_ref_net_px", "noise_small_px", "hidden_noise", "noise_tau_ms", "miss_border_px",
                     "false_people_per_view", "neighbour_near", "conf_tau_ms", "k_outlier"):
            if not getattr(self, name) >= 0.0:
                raise DetectorError(f"detector model: {name}={getattr(self, name)} but expected >= 0")
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Lognormal) and not (value.median > 0 and value.log_sd >= 0):
                raise DetectorError(f"detector model: {f.name}={value} but expected median > 0, log_sd >= 0")
        for name in ("conf_visible", "conf_hidden", "conf_outlier"):
            table = np.asarray(getattr(self, name), dtype=float)
            if table.shape != (len(CONF_PERCENTILES),) or np.any(np.diff(table) < 0) or table[0] < 0:
                raise DetectorError(f"detector model: {name} must be {len(CONF_PERCENTILES)} non-decreasing "
                                    "confidences >= 0 (at the percentiles CONF_PERCENTILES)")
        if len(self.noise_rel19) != 19 or min(self.noise_rel19) < 0:
            raise DetectorError("detector model: noise_rel19 must be 19 values >= 0 (joints19 order)")
        if self.net_height_px <= 0 or self.min_joints < 1:
            raise DetectorError("detector model: net_height_px must be > 0 and min_joints >= 1")

    def outlier_rate19(self) -> np.ndarray:
        """(19,) share of time each joint is an outlier (by its class)."""
        return np.array([self.outlier_wrists, self.outlier_limbs, self.outlier_face])[JOINT_CLASS19]

    def miss_self19(self) -> np.ndarray:
        """(19,) share of time a joint its own body hides is missed."""
        return np.where(JOINT_CLASS19 == 2, self.miss_self_face, self.miss_self_body)


@dataclass(kw_only=True)
class DetectionCounts:
    """What the detector did (summed over images): the observed rates of each failure mode.

    joints_* count joints of present people in front of the camera and inside the image; people_in_view: present
    people with at least one such joint; people_cut: of those, cut by the image border. joints_hidden_* are hidden
    by another person; joints_self_* by the person's own body (and not by another).
    """

    images: int = 0
    people_in_view: int = 0
    people_cut: int = 0
    people_detected: int = 0
    people_cut_detected: int = 0
    joints_visible: int = 0  # not hidden, outside the border zone
    joints_visible_detected: int = 0
    joints_hidden: int = 0
    joints_hidden_detected: int = 0
    joints_self: int = 0
    joints_self_detected: int = 0
    joints_border: int = 0  # not hidden, inside the border zone
    joints_border_detected: int = 0
    joints_detected: int = 0  # of the people detected, their own joints as reported
    joints_outlier: int = 0
    joints_zero_coordinate: int = 0
    joints_above_1: int = 0
    swaps_whole: int = 0
    swaps_limb: int = 0
    neighbour_eligible: int = 0
    neighbour_limbs: int = 0
    false_people: int = 0

    def rates(self) -> dict[str, float]:
        """The observed rates (NaN where nothing was eligible)."""
        def r(a: int, b: int) -> float:
            return a / b if b else float("nan")
        return {"miss_visible": 1 - r(self.joints_visible_detected, self.joints_visible),
                "miss_hidden": 1 - r(self.joints_hidden_detected, self.joints_hidden),
                "miss_self_hidden": 1 - r(self.joints_self_detected, self.joints_self),
                "miss_border_zone": 1 - r(self.joints_border_detected, self.joints_border),
                "hidden_share": r(self.joints_hidden, self.joints_hidden + self.joints_visible + self.joints_border
                                  + self.joints_self),
                "people_detected": r(self.people_detected, self.people_in_view),
                "cut_people_detected": r(self.people_cut_detected, self.people_cut),
                "outlier": r(self.joints_outlier, self.joints_detected),
                "zero_coordinate": r(self.joints_zero_coordinate, self.joints_detected),
                "confidence_above_1": r(self.joints_above_1, self.joints_detected),
                "swap_whole": r(self.swaps_whole, self.people_in_view),
                "swap_limb": r(self.swaps_limb, self.people_in_view),
                "neighbour_limb_eligible": r(self.neighbour_eligible, self.people_in_view),
                "neighbour_limb": r(self.neighbour_limbs, self.neighbour_eligible),
                "false_people_per_view": r(self.false_people, self.images)}

    def add(self, other: DetectionCounts) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))
