"""Which body model a detector's joint order fits: read in the right order, the joints make a body.

BODY_25 and BODY_25B both write 25 joints per person, in different orders, so a file cannot say which it is. Read
in the wrong order, every "joint" is still one real joint in every view: the triangulation is consistent (3.5 px
reprojection, no camera flagged) but each body's joints are other joints (42 cm from the person, median). The
images tell the orders apart before any work: bones keep their proportions.

For each detected person and each bone whose two ends the model detects directly (joints19 bones plus the shoulder
and hip cross bones; a derived joint, a midpoint, would make its two bones equal by construction), the bone's
length in the image over its adult length (:data:`~dome_calib.recon.body_models.BONE_LENGTH_CM`), then over the
person's median of these (its scale in the image): near 1 where the joints are read in their order (foreshortening
aside; left and right limbs alike), far from it where a "bone" joins two joints that are not neighbours (its
length changes with the pose and from person to person). The misfit of a model is ``exp(median |log ratio|)``
over every bone of every person: measured 1.12 (real Pose2Sim BODY_25B read as BODY_25B) and 1.20 (synthetic
BODY_25 detections with 2 px noise, swaps and false people, read as BODY_25) against 2.21 and 1.55 in the other
order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.recon.body_models import (BONE_LENGTH_CM, DERIVED, JOINT_NAMES, JOINTS19, BodyModel,
                                          models_with_joints, to_joints19)

#: A joint counts from this confidence up.
MIN_CONFIDENCE = 0.1
#: A person counts with at least this many bones measured.
MIN_BONES = 6
#: People needed before the orders are judged (fewer: no verdict).
MIN_PEOPLE = 20
#: The named model is refused when its misfit is at least this high ...
REFUSE_MISFIT = 1.35
#: ... and its log misfit at least this many times another model's (measured: 2.4 and 6.7 between the orders).
REFUSE_RATIO = 1.8


@dataclass(frozen=True)
class OrderFit:
    """How well the joints read in ``model``'s order make bodies: ``misfit`` = exp(median |log(bone ratio)|) over
    ``people`` people (see the module docstring); NaN with too few people."""

    model: BodyModel
    misfit: float
    people: int


def order_fit(keypoints: np.ndarray, model: BodyModel) -> OrderFit:
    """(N, J, 3) ``[x_px, y_px, c]`` people of one detector, read in ``model``'s order -> :class:`OrderFit`."""
    j19 = to_joints19(np.asarray(keypoints, dtype=float).reshape(-1, len(JOINT_NAMES[model]), 3), model)
    derived = set(DERIVED[model])
    bones = [(JOINTS19.index(a), JOINTS19.index(b), cm) for (a, b), cm in BONE_LENGTH_CM.items()
             if a not in derived and b not in derived]
    a, b, cm = (np.array(x) for x in zip(*bones))
    seen = (j19[:, a, 2] > MIN_CONFIDENCE) & (j19[:, b, 2] > MIN_CONFIDENCE)
    length = np.linalg.norm(j19[:, a, :2] - j19[:, b, :2], axis=-1)
    seen &= length > 0
    with np.errstate(divide="ignore"):
        ratio = np.where(seen, np.log(np.where(seen, length, 1.0) / cm), np.nan)
    people = seen.sum(1) >= MIN_BONES
    if people.sum() < MIN_PEOPLE:
        return OrderFit(model=model, misfit=float("nan"), people=int(people.sum()))
    r = ratio[people]
    r = r - np.nanmedian(r, axis=1, keepdims=True)
    return OrderFit(model=model, misfit=float(np.exp(np.nanmedian(np.abs(r)))), people=int(people.sum()))


def order_fits(keypoints: np.ndarray) -> list[OrderFit]:
    """The fit of every model with this many joints, best first (ties by name)."""
    kp = np.asarray(keypoints, dtype=float)
    fits = [order_fit(kp, m) for m in models_with_joints(kp.shape[-2])]
    return sorted(fits, key=lambda f: (not np.isfinite(f.misfit), round(f.misfit, 3), f.model.value))


def better_order(keypoints: np.ndarray, named: BodyModel) -> tuple[OrderFit, OrderFit] | None:
    """(named model's fit, the fit of a model that fits clearly better) when the joints read in ``named``'s order
    do not make bodies and another model's do; None when ``named`` fits, no other model has this many joints, or
    too few people were seen to tell."""
    fits = {f.model: f for f in order_fits(keypoints)}
    mine = fits.get(named)
    if mine is None or not np.isfinite(mine.misfit) or mine.misfit < REFUSE_MISFIT:
        return None
    others = [f for f in fits.values() if f.model != named and np.isfinite(f.misfit)]
    best = min(others, key=lambda f: (round(f.misfit, 3), f.model.value), default=None)
    if best is None or np.log(mine.misfit) < REFUSE_RATIO * np.log(best.misfit):
        return None
    return mine, best
