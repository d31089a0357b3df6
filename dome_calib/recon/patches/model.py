"""Options and results of the patch trajectory stage.

Units: world cm (Panoptic frame), pixels of the camera as imaged, universal time ms. A patch is a triplet of world
points: its centre ``X0`` and two points ``X1 = X0 + axis_cm * u``, ``X2 = X0 + axis_cm * v`` on its plane (u, v
orthonormal); its normal ``u x v`` points to the cameras that see it; its appearance is a square of side
``size_cm`` round the centre.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np

from dome_calib.options import AtLeast, Field, UnitInterval, options, require
from dome_calib.schema import PosFinite


@options
class PatchOptions:
    """How patches are seeded, tracked and judged visible (defaults: the CVPR 2014 method's sizes)."""

    size_cm: PosFinite = 6.0  # side of the patch's square
    # side of the square its appearance is compared on (the visibility, and the seeds' roles below unless they have
    # their own); 4 cm gains precision and recall on the bench's scenes (docs/benchmarks.md, issue 49; the paper's 6)
    ncc_size_cm: PosFinite = 4.0
    # the seeds' own square (None: ncc_size_cm): seed_ncc_size_cm the seeds' checks (seed_skeleton's depth search and
    # agreement, seed_features.square_ncc), refine_ncc_size_cm the normals' photometric refinement (refine.py: at the
    # seeds only); the visibility (MAP, seed appearance) keeps ncc_size_cm (read them through seed_square_cm and
    # refine_square_cm below).
    # The refinement on 6 cm: with the visibility's 4 cm the panel's occluded spans fall 80 -> 45 % (the seeds per part
    # are the same; the left thigh's motion no longer ties the knee), back to 80 % with this alone (docs/benchmarks.md,
    # branch split62)
    seed_ncc_size_cm: PosFinite | None = None
    refine_ncc_size_cm: PosFinite | None = 6.0
    axis_cm: PosFinite = 3.0  # distance of the two plane points from the centre
    seed_every_frames: AtLeast(1) = 20  # a new cloud every 20th frame of the reference stream
    track_frames: AtLeast(0) = 30  # each cloud tracked this many reference frames backward and forward
    # seeding (reference stream's cameras at the seed frame): "sweep" corners put in 3D by a depth sweep scored in
    # nearby cameras (seed.py: a dense rig); "features" SIFT matched along epipolar lines and triangulated
    # (seed_features.py: cameras far apart); "skeleton" corners on the people put in 3D by the body's capsules and
    # refined photometrically within seed_depth_window_cm (seed_skeleton.py: a few cameras far apart; needs the
    # people, ``patch_stream(..., body=)``)
    seed_method: Literal["sweep", "features", "skeleton"] = "sweep"
    seed_features: AtLeast(1) = 400  # corners per camera (cv2.goodFeaturesToTrack)
    seed_min_distance_px: PosFinite = 5.0
    # reference cameras: every camera of the reference stream (0), or a cover of them spaced this far apart as seen
    # from the capture volume's centre (seed.reference_cameras): in a dense dome neighbours' seeds are the same
    seed_reference_spacing_deg: Annotated[float, Field(ge=0, lt=180)] = 0.0
    # which streams seed ("sweep", "skeleton", and the Kinects' depth): "all", every stream with at least
    # seed_min_views cameras, each at its own frame nearest the seed time, its seeds then carried to the seed time
    # by one tracking step
    # (run.place_seeds: a dome's VGA do not see the legs its HD and Kinect colour cameras see), and with depth each
    # Kinect's colour camera from its own depth (seed_depth.seed_from_own_kinect); "reference": the reference
    # stream alone ("features" always seeds from the reference stream; "skeleton" seeds from every stream as
    # "sweep" does, on the people at the stream's own frame time, BodyPrior.at)
    seed_streams: Literal["all", "reference"] = "all"
    seed_neighbours: AtLeast(2) = 4  # cameras the depth sweep is scored in
    seed_step_cm: PosFinite = 1.5  # depth sweep step along the ray
    seed_window_px: AtLeast(3) = 7  # NCC window of the sweep (odd)
    seed_min_ncc: UnitInterval = 0.8
    seed_views: AtLeast(2) = 12  # cameras nearest the reference in which a seed is refined by optical flow
    seed_min_views: AtLeast(2) = 3
    seed_sift_features: AtLeast(1) = 4000  # "features": SIFT keypoints per camera
    seed_match_px: PosFinite = 3.0  # "features": epipolar band of a match and triangulation inliers
    seed_ratio: Annotated[float, Field(gt=0, le=1)] = 0.8  # "features": nearest / second nearest descriptor
    seed_depth_window_cm: PosFinite = 6.0  # "skeleton": depths searched this far either side of the body's surface
    seed_depth_step_cm: PosFinite = 0.5  # "skeleton": the search's coarse step (then a fifth of it)
    seed_spacing_cm: PosFinite = 1.5  # one seed per cell of this size
    normal_radius_cm: PosFinite = 4.0  # seeds within this distance give the normal (least principal axis)
    normal_min_points: AtLeast(3) = 5
    # the seeds' normal from those points: "plane", their least principal axis (the CVPR 2014 paper's); "quadric", a
    # quadric fitted to them in that axis' frame, its normal at the seed (seed._normals: the plane leans towards the
    # side that has seeds where a curved surface is seeded on one side only)
    normal_fit: Literal["plane", "quadric"] = "plane"
    # a sweep seed whose neighbours (within normal_radius_cm, in its plane) leave a gap round it wider than this
    # (deg) is dropped: the seeded cloud ends on one side of it, there the plane leans towards the side that has
    # seeds and its normal cannot be had (seed.neighbour_gap_deg; 360: none dropped; 210 the default since split62)
    normal_max_gap_deg: Annotated[float, Field(gt=0, le=360)] = 210.0
    refine_normals: bool = True  # then refined photometrically in the cameras that see the seed (refine.py)
    # the refinement's first tilt step (deg); each later step halves it down to 2 deg (8: steps 8, 4, 2, reaching
    # 14 deg about each plane axis; 16: 16, 8, 4, 2, reaching 30 deg)
    normal_refine_reach_deg: Annotated[float, Field(ge=2, le=45)] = 8.0
    # the refinement in every stream's cameras (each at its nearest frame, the patch not moved: a seed has no motion
    # yet), not the seeding stream's alone: a dome's VGA panels see some surface from one side only
    normal_refine_all_streams: bool = False
    volume_radius_cm: PosFinite = 250.0  # the capture volume: a vertical cylinder on the floor
    volume_height_cm: PosFinite = 220.0
    # seeding from Kinect depth (seed_depth.py): points of the capture volume this far above the floor (y = 0)
    depth_floor_cm: Annotated[float, Field(ge=0)] = 2.0
    # optical flow
    lk_window_px: AtLeast(5) = 15
    lk_levels: AtLeast(0) = 3
    lk_fb_px: PosFinite = 0.5  # forward-backward check
    # the check's backward flow (seed._lk, for every caller): False (default), started at the point it must return
    # to, which passes more easily; True, never there: at the forward's end moved back by the guess's displacement,
    # or at the forward's end itself. Off: on the bench's walkers it loses 2.7 points of 10-frame reach (52.9 ->
    # 50.2 %) with the survivors no more accurate; the conversation scenes unchanged (docs/benchmarks.md, issue 49)
    lk_fb_strict: bool = False
    # Lucas-Kanade's termination per pyramid level: at most this many iterations, or a step below lk_eps_px
    lk_iterations: AtLeast(1) = 30
    lk_eps_px: PosFinite = 0.01
    # prediction (track.py): from a patch's second step on, each point's flow starts where its last step's 3D
    # velocity puts it at the camera's next frame (cv2.OPTFLOW_USE_INITIAL_FLOW; the backward flow's start: see
    # lk_fb_strict); lk_levels_predicted pyramid levels then follow the
    # rest of the motion (the first step from a seed, without a velocity: lk_levels), except a point whose predicted
    # image motion in the frame step is at least lk_levels_full_px (0: none is): lk_levels. On the bench's walkers
    # the prediction with 1 level reaches 10 frames 42 -> 53 %, on the conversation scenes the same figures, for
    # 25-37 % less tracking CPU (docs/benchmarks.md, issue 49); 0 levels: the default since split62 (one setting meets
    # issue 49's visibility aims and the body's, docs/benchmarks.md)
    lk_predict: bool = True
    lk_levels_predicted: AtLeast(0) = 0
    lk_levels_full_px: Annotated[float, Field(ge=0)] = 0.0
    # a point whose flow fails in a camera where another point of its patch is tracked is flown again from its
    # position moved by those points' mean image motion (track.refind_lost): on the few-camera rig 92 % of the limb
    # patches that end at a step's triangulation lost one flow to the forward-backward check (docs/benchmarks.md).
    # Off: alone it moved the few-camera rig by 0.001 and scene 1 not at all, and on the full dome its second flow
    # call per camera raised the LK calls 12,684 -> 20,548 and a patch-step ~2.5 -> ~2.9 ms (docs/benchmarks.md)
    lk_refind: bool = False
    # a patch flown in at most min_visible cameras (no view to spare): a flown view is a failed flow in the
    # visibility's motion term (3 sigmas) when its centre was lost there, its residual over the points tracked
    # (track.motion_term): a plane point lost alone (on a limb it may fall past the outline) moves with the centre,
    # as in the triangulation. Other patches, or False: when any of the three points was lost (the old rule; on the
    # few-camera rig it ended two-view limb patches whose centre was tracked in both views; on the dome's scene 1,
    # applied to every patch, it cost 0.18 points of precision: docs/benchmarks.md)
    view_lost_with_centre: bool = True
    # a patch flown in at most min_visible cameras (no view to spare) whose centre's flow failed in a view: its lost
    # points there flown again, started where its body part's motion (the body over time: the part whose capsule
    # surface is nearest the centre, that bone's move) carries them (track.refind_from_body). Needs the people
    # (patch_stream(..., body=)); without them, or False, nothing changes
    # The carry (refind_from_body, refind_carry_steps=10, refind_window_px=9, carry_unseen) and reseed_hidden are
    # the defaults since merge63: with the anchor's defaults, few-camera seeds 1 / 2 (choosing) 0.817 / 0.414 / 87.2
    # -> 0.808 / 0.347 / 91.1 %, 0.798 / 0.373 / 87.2 -> 0.778 / 0.323 / 87.8 %; seeds 3 / 4 (checks) 68.3 -> 78.3 %,
    # 83.3 -> 87.8 %; the panel 0.874 / 0.406 / 80 % either way (docs/benchmarks.md, "The defaults since merge63")
    refind_from_body: bool = True
    # with refind_from_body: a patch whose centre is still lost is kept at most this many steps in a row where its
    # part's motion carries it (predicted: not alive there, no position written, no view counted), flown from there
    # at the next step in the views it was last seen in (0: it ends, as before)
    refind_carry_steps: Annotated[int, Field(ge=0)] = 10
    # with refind_carry_steps: a patch seen by fewer than min_visible cameras after the MAP cut (its centre
    # triangulated, its views lost; one with no view to spare, as refind_from_body's) is carried by its part's motion
    # as one whose centre was lost (predicted: not alive there, no position written, no view counted), flown at the
    # next step in the views it was last seen in. Measured alone (limb63, before it was the default): on the
    # few-camera rig it lowers MPJPE and acceleration and lengthens the forearms' lives, but the occluded spans of
    # seeds 1-2 stay 87.2 % (docs/benchmarks.md, "Why the limb ends' patches end")
    carry_unseen: bool = True
    # with refind_from_body: the re-flight's Lucas-Kanade window (px; 0: lk_window_px, the same bits) and pyramid levels
    # (-1: the prediction's, lk_levels_predicted). The re-flight starts where the body carries the point, within 3.5 px
    # of the truth for 95 % of the lost centres, and the flow's own 15 px window, wider than a limb's outline, passes
    # its forward-backward check there for 6-19 % of them; a 9 px one for 48 % (9 since merge63, with the carry).
    # refind62 left it unset: with the carry, 7 px (chosen on the few-camera seeds 1-2) raises three clouds' occluded
    # spans 80.6 -> 81.7 % and 85.0 -> 87.8 %, but the unseen seed's one cloud loses 62.8 -> 62.2 % (docs/benchmarks.md,
    # branch refind62)
    refind_window_px: Annotated[int, Field(ge=0)] = 9
    refind_levels: Annotated[int, Field(ge=-1)] = -1
    _refind_window = require(lambda o: o.refind_window_px == 0 or o.refind_window_px >= 5,
                             "refind_window_px {o.refind_window_px}: expected 0 (lk_window_px) or at least 5")
    # each step tracks a patch by optical flow in at most this many of the cameras that saw it (track.py
    # best_views: the most face-on, spread in direction; 0: all); visibility is still judged in every camera
    track_views: Annotated[int, Field(ge=0)] = 8
    track_view_spread_deg: Annotated[float, Field(ge=0, lt=90)] = 10.0  # views closer than this to a chosen one pay
    triangulation_px: PosFinite = 2.5  # inlier threshold of the patches' points
    # visibility (MAP): unary costs of "visible" against "not visible" (the latter 0), Potts prior
    ncc_threshold: Annotated[float, Field(ge=-1, le=1)] = 0.6  # photometric: NCC above this favours "visible"
    # photometric term of the MAP: True, the best NCC against the reference and the previously visible neighbours
    # (visibility.neighbour_ncc), judged against map_ncc_threshold (0.75); False: the reference alone, ncc_threshold.
    # Alone it gains recall but its extra views make patches drift (docs/benchmarks.md); with the slid patches' end,
    # the people as occluders and the 4 cm square it is the default since split62 (one setting meets issue 49's
    # visibility aims and the body's, docs/benchmarks.md)
    neighbour_ncc: bool = True
    map_ncc_threshold: Annotated[float, Field(ge=-1, lt=1)] = 0.75
    photometric_weight: PosFinite = 2.0
    motion_sigma_px: PosFinite = 1.5  # motion: flow against the reprojected 3D motion
    motion_weight: PosFinite = 1.0
    min_cos_view: Annotated[float, Field(ge=0, lt=1)] = 0.2  # geometric: the normal faces the camera
    # geometric: a camera whose image the patch's square crosses the border of is a candidate too when the square's
    # centre and at least half its samples are inside (visibility.MIN_BORDER_SAMPLES), every NCC of it then over the
    # samples inside both images; False: the whole square must be inside (the old rule). On the bench (10 frames)
    # recall +0.40 / +1.46 / +5.10 / +0.53 points on scenes 1, 2, the walkers and an unseen scene, precision -0.03 /
    # +0.03 / -0.15 / -0.01 (docs/benchmarks.md, issue 49)
    border_squares: bool = True
    geometric_weight: PosFinite = 1.0
    # geometric: the people as occluders (occlusion.py; needs the body over time, patch_stream(..., body=)): a camera
    # whose ray to the patch centre, stopped occlusion_stop_cm short of it (half the patch's side), passes through a
    # part's capsule (a generic adult's radius less occluder_margin_cm: skeleton noise, parts not round) is no
    # candidate. On by default (split62); without a body nothing changes
    body_occlusion: bool = True
    occluder_margin_cm: Annotated[float, Field(ge=0)] = 3.0
    occlusion_stop_cm: Annotated[float, Field(ge=0)] = 3.0
    # a second stream where the body over time is fitted with the ties (reconstruct --images' stage, through
    # FurtherStage.again; bench/patches_body.py): the body fitted with the first stream's ties is the prior of the
    # joints no detection saw (stage.body_prior(hidden_from=)), so a hidden limb's skeleton seeds and occluders sit
    # where the patches carried it, not where occlusion.hold_unseen_parts guessed it; the clouds whose seeds' prior
    # that changes are streamed again, the others kept (stage.reseed_clouds), and that stream's ties are fitted. On
    # the few-camera rig the clouds inside a span seed their hidden forearm or shin 87 -> 118 times (12 cases, seeds
    # 1-4), occluded joints within 3 cm 87.2 -> 91.1 / 87.2 -> 87.8 % (seeds 1 / 2), 68.3 -> 70.0 / 83.3 -> 83.9 %
    # (seeds 3 / 4, checks), the panel the same figures, for one cloud of three streamed again (docs/benchmarks.md,
    # branch hidden63). On by default since merge63; False: one stream
    reseed_hidden: bool = True
    prior_weight: Annotated[float, Field(ge=0)] = 0.3  # Potts weight between neighbouring cameras
    prior_neighbours: AtLeast(1) = 4
    # drift (track.SeedViews): each flown point realigned by optical flow from the camera's seed image (where the
    # patch was at the seed) when within anchor_flow_px of the flow; farther: rejected in that camera (anchor_reject).
    # Off: on the few-camera rig it rejects two-view limb points as the limb turns (three clouds, occluded spans 87.2
    # -> 77.8 / 78.9 % on seeds 1 / 2), for +0.16 point of precision on scene 1 (docs/benchmarks.md, branch split62).
    # On by default since merge63 with anchor_warp, anchor_levels=0 and anchor_min_views=4 (below): only patches
    # with views to spare are anchored
    anchor_flow: bool = True
    anchor_flow_px: PosFinite = 1.0
    # the realignment's pyramid levels above the image (cv2 maxLevel): it starts at the flown point and keeps an
    # answer within anchor_flow_px of it, so the image alone can do (0): on the full dome its flow's CPU 0.39 -> 0.21
    # ms per patch-step, 4.5 % fewer points rejected, the visibility aims moved within 0.05 point but scene 1's
    # precision with best 97.01 -> 96.99 %; 1, the rule so far (docs/benchmarks.md, branch fast61)
    anchor_levels: AtLeast(0) = 0  # (default 0 since merge63, with anchor_flow)
    # the seed image warped, before the realignment, by each patch's seed-to-now map in that camera (the affine map
    # of its triplet's projections at the seed to those of its current triplet: its turn and foreshortening since
    # the seed, warp.seed_to_now / warped_flow), so a turned patch is compared with its seed appearance as its plane
    # is seen now. False: the seed square as it was at the seed (the rule so far). On the few-camera rig with the
    # visibility's setting ("cand", docs/patches.md) 4.6-5.8 % of the flown points were rejected (2 % of a still
    # part's, 23-26 % of a part's turned 10-20 deg, 41-55 % at 20-45), two thirds not aligned at all; a point of
    # a two-view limb patch rejected ends it; with the warp its occluded spans (three clouds) 75.6 -> 82.2 % (seed 1),
    # 78.9 -> 84.4 % (seed 2), 58.3 -> 67.8 % (seed 3, a check), the visibility aims kept (scene 1 97.36 / 92.56,
    # scene 2 98.09 / 92.10, unseen 98.28 / 91.42) (docs/benchmarks.md, branch anchor62)
    anchor_warp: bool = True  # (default since merge63, with anchor_flow)
    # ... for the patches whose map moves a corner of the flow's window (lk_window_px) farther than this from where
    # a plain shift leaves it (warp.warp_px; 0.5 px: a turn of ~3 deg): the others, most of them, are aligned as
    # without the warp, bit for bit (and the warp's resampling is paid only where it matters)
    anchor_warp_px: Annotated[float, Field(ge=0)] = 0.5
    # the anchor flow only for the patches flown this step in at least this many cameras (track.anchored; 0: every
    # patch, the same bits): a patch with views to spare is not ended by one rejected view, and on the few-camera rig
    # the anchor's rejections were 80-83 % in two-view patches (branch anchor62). With anchor_flow, anchor_warp,
    # anchor_levels=0 and 4: scene 1 over 30 frames each way 96.99 -> 97.26 % precision (97.26 with the anchor on
    # every patch; the dome's patches are flown in 8 cameras), the few-camera rig (5 cameras) as without the anchor:
    # occluded spans (three clouds) seeds 1 / 2 / 3 87.2 / 87.2 / 68.3 % (78.3 / 84.4 with it on every patch; 86.7 /
    # 87.8 / 68.9 with 3) (docs/benchmarks.md, branch prec63)
    anchor_min_views: AtLeast(0) = 4  # (default since merge63)
    anchor_reject: bool = True
    anchor_reject_unaligned: bool = True  # also reject a point the seed image cannot be aligned at (else kept)
    # drift (track.py, visibility.off_seed): a patch ends when its visible views no longer show its seed
    # appearance (median NCC, over the visible cameras that saw it at the seed, of its square now against its square
    # there at the seed, below ncc_threshold): it slid off the surface point it was seeded on (on by default: split62)
    seed_appearance_end: bool = True
    # ... judged against this NCC (None: ncc_threshold, the same bits). 0.7, probed once on top of the anchor where
    # a patch has views to spare (anchor_min_views=3 above; 3 and 4 gave the same scenes' figures): precision 97.26
    # -> 97.57 % on scene 1 over 30 frames each way, 98.05 -> 98.24 % on scene 2, unseen 97.62 both; scene 1's
    # median length 30 -> 29 of 30; few-camera seed 2's occluded spans 87.8 -> 87.2 % (docs/benchmarks.md, branch
    # prec63)
    seed_appearance_ncc: Annotated[float, Field(ge=-1, le=1)] | None = None
    min_visible: AtLeast(2) = 2  # a patch seen by fewer cameras ends
    max_stretch: Annotated[float, Field(gt=0, lt=1)] = 0.3  # a patch whose plane points move this much ends


def seed_square_cm(o: PatchOptions) -> float:
    """The side of the square the seeds' checks compare (``seed_ncc_size_cm``, else ``ncc_size_cm``)."""
    return float(o.ncc_size_cm if o.seed_ncc_size_cm is None else o.seed_ncc_size_cm)


def refine_square_cm(o: PatchOptions) -> float:
    """The side of the square the normals' refinement compares (``refine_ncc_size_cm``, else ``ncc_size_cm``)."""
    return float(o.ncc_size_cm if o.refine_ncc_size_cm is None else o.refine_ncc_size_cm)


@dataclass(frozen=True)
class PatchTrajectories:
    """Patches over reference times: N patches, T times, V cameras (``cameras`` order).

    ids (N,) int64 ``cloud * 100000 + k``; seed_time_ms (N,); times_ms (T,) reference stream times;
    X_cm (N, T, 3, 3) the three points (centre, two plane points), NaN where the patch is not alive;
    normal (N, T, 3); visible (N, T, V) bool (the MAP labels); photometric (N, T, V) bool (NCC above the
    threshold alone: the CVPR 2014 baseline, same patches and times); alive (N, T) bool; carried (N, T) bool or
    None: the patch was kept at that time by its part's motion alone (``refind_carry_steps``: predicted, not
    measured; not alive there, nothing else written; not in the stream file).
    """

    ids: np.ndarray
    seed_time_ms: np.ndarray
    times_ms: np.ndarray
    cameras: list[str]
    X_cm: np.ndarray
    normal: np.ndarray
    visible: np.ndarray
    photometric: np.ndarray
    alive: np.ndarray
    carried: np.ndarray | None = None
