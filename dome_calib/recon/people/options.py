"""The options of a people run (:class:`PeopleOptions`), below every stage that takes them: the per-time association
(:mod:`~dome_calib.recon.people.per_time`), the bridging of the tracks' gaps, the run and the chunks."""
from __future__ import annotations

from dataclasses import field
from typing import Annotated

from dome_calib.options import AtLeast, Field, PosFraction, options
from dome_calib.recon.people.joint_check import JointCheckOptions
from dome_calib.recon.people.proposals import AssociationOptions
from dome_calib.recon.people.temporal import TemporalOptions
from dome_calib.recon.people.tracking import TrackingOptions
from dome_calib.recon.triangulate import TriangulationOptions


@options
class PeopleOptions:
    """Options of :func:`~dome_calib.recon.people.run.reconstruct_people`. joint_check: which triangulated joints a
    body keeps (:mod:`~dome_calib.recon.people.joint_check`); min_body_joints: a body needs this many reconstructed
    joints; max_gap_frames: stream brackets wider than this many frame periods are not bridged; batch_times: times
    triangulated together; chunk_times: the times of one task of
    :func:`~dome_calib.recon.people.chunks.reconstruct_people_chunked`. Neither changes the result (only memory and
    speed). temporal: the body over time (:mod:`~dome_calib.recon.people.temporal`; ``enabled=False`` keeps the
    per-frame joints). triangulation: a view supports a joint within 15 px (3 sigma of the detector's noise: 3.5-5 px
    per camera measured on real OpenPose BODY_25B of 1080p phone video, Pose2Sim's balancing trial; Pose2Sim's own
    ``reproj_error_threshold_triangulation`` is 15 px). At 10 px three views that agree to 10-12 px lost to any two
    views (two always meet): the left hip of that trial had two inlier views in 66 of 99 frames, the pair changing
    from frame to frame."""

    association: AssociationOptions = field(default_factory=AssociationOptions)
    triangulation: TriangulationOptions = field(default_factory=lambda: TriangulationOptions(
        inlier_threshold_px=15.0, min_views=2, min_confidence=0.05))
    tracking: TrackingOptions = field(default_factory=TrackingOptions)
    joint_check: JointCheckOptions = field(default_factory=JointCheckOptions)
    temporal: TemporalOptions = field(default_factory=TemporalOptions)
    min_body_joints: AtLeast(1) = 6
    max_gap_frames: Annotated[float, Field(ge=1)] = 2.5
    batch_times: AtLeast(1) = 16
    chunk_times: AtLeast(1) = 600
    shared_fps: PosFraction | None = None
