"""The patch stage of ``dome-calib reconstruct --images FOLDER``: after the people, the patch trajectory stream on the
cameras' own images, each patch given the body part it moves with, written as ``patches.parquet`` into the output
folder (staged with the people's files, :mod:`.stream_file`).

:func:`plan_patches` checks the images and the output place before any work; :meth:`PatchStage.run` takes the
people and returns what writes the file into the staged folder.
"""
from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from dome_calib.bundle import Bundle, SyncTable
from dome_calib.errors import OptionsError
from dome_calib.recon.errors import ReconError
from dome_calib.recon.people.commands import FurtherStage, ReconstructPlan
from dome_calib.recon.patches.images import ImageSource, open_images, with_shared_clock
from dome_calib.recon.patches.body import TieOptions, flag_joints, joint_ties
from dome_calib.recon.patches.model import PatchOptions, PatchTrajectories
from dome_calib.recon.patches.motion import part_motions
from dome_calib.recon.patches.page_layer import patch_layer
from dome_calib.recon.patches.parts import label_parts
from dome_calib.recon.patches.run import ID_STRIDE, patch_stream, reference_stream, seed_frames_in
from dome_calib.recon.patches.occlusion import BodyPrior, hold_unseen_parts
from dome_calib.recon.patches.seed_skeleton import choose_seed_method
from dome_calib.recon.patches.stream_file import FILE_NAME, patch_table, write_patch_table
from dome_calib.recon.project import view_set
from dome_calib.recon.streams import cameras_by_stream, frame_period_ms

logger = logging.getLogger(__name__)


@dataclass
class PatchStage:
    """The checked images and the bundle (with one clock) the patch stream is run on."""

    source: ImageSource
    bundle: Bundle
    cameras: list[str]
    options: PatchOptions
    ties_options: TieOptions | None = None
    auto_seeds: bool = False  # --patch-seeds auto: the seeding picked from the reference stream's geometry at run
    summary: str = ""  # what the run gave, one line (set by run, completed once the people are refined)

    def run(self, times_ms: np.ndarray, bodies: list, progress: Callable[[int, int], None] | None = None, *,
            executor=None, hidden_from: list | None = None, first: PatchTrajectories | None = None,
            first_prior: BodyPrior | None = None) -> FurtherStage:
        """The stream over the people's times (``bodies[t]``: a time's people, with ``ids`` and ``X_cm``; its seeding
        and tracking tasks on ``executor``: ``reconstruct``'s ``--workers`` / ``--scheduler``, None here), labelled
        by part (with ``seed_method="skeleton"`` the people, at the reference stream's times, are the seeds' depth
        prior; with ``body_occlusion`` the occluders of the views), the parts' motions as ties on the patches' times
        (the people's own where the images' reference stream is the people's; a tie on another time ties nothing)
        -> the :class:`FurtherStage` whose ``write`` puts ``patches.parquet`` into the staged output folder. With
        ``reseed_hidden`` its ``again(people fitted with the ties)`` runs the stream a second time, the joints no
        detection saw taken from those people (:func:`body_prior`'s ``hidden_from``; ``first``, the first stream, and
        ``first_prior``, the prior it ran on: only its clouds whose seeds' prior changed are streamed again,
        :func:`reseed_clouds`), and gives the stage to write and fit with instead."""
        t = np.asarray(times_ms, dtype=float)
        stream = reference_stream(self.bundle, self.cameras)
        options, seeding = self.seeding(stream)
        body = None
        clock = cameras_by_stream(self.bundle, self.cameras)[1][stream]
        if options.seed_method == "skeleton" or options.body_occlusion:
            # the people at the stream's times: the seeds' depth prior, the occluders of the views
            at = clock.univ_time_ms[(clock.univ_time_ms >= t[0]) & (clock.univ_time_ms <= t[-1])]
            body = body_prior(t, bodies, at, hidden_from)
        span = (float(t[0]), float(t[-1]))
        if first is None:
            traj = patch_stream(self.bundle, self.source, self.cameras, span, options, stream=stream, body=body,
                                executor=executor, progress=progress)
        else:  # the second stream: the clouds whose seeds' prior the fitted people changed
            frames = seed_frames_in(clock.index, clock.univ_time_ms, span, options.seed_every_frames)
            traj = reseed_clouds(first, frames, np.array([clock.time_of(int(f)) for f in frames]), first_prior, body,
                                 lambda again: patch_stream(self.bundle, self.source, self.cameras, span, options,
                                                            stream=stream, seed_frames=again, body=body,
                                                            executor=executor, progress=progress))
        joints, ids = people_at(t, bodies, traj.times_ms)
        labels = label_parts(traj.X_cm[:, :, 0], traj.normal, traj.alive, joints)
        motions = part_motions(traj.X_cm, traj.alive, labels.person, labels.bone)
        ties = joint_ties(motions, ids, traj.times_ms, joints, self.ties_options)
        on_times = np.isin(ties.from_ms, t) & np.isin(ties.to_ms, t)
        table = patch_table(traj, labels, ids, reference_stream=stream, size_cm=options.size_cm,
                            axis_cm=options.axis_cm, seeding=seeding)
        second = options.reseed_hidden and hidden_from is None
        if not second:  # the images are read again by the second stream
            self.source.close()
        labelled = int(np.sum(labels.bone >= 0))
        seeds = seeding["method"] + (f", auto: {seeding['reason']}" if self.auto_seeds else "")
        self.summary = (f"patches: {len(traj.ids)} trajectories ({table.num_rows} patch-times) at {len(traj.times_ms)} "
                        f"times of stream {stream} from {len(self.cameras)} cameras (seeds: {seeds}), {labelled} "
                        f"given a body part -> {FILE_NAME}; {len(motions.bone)} part motions, "
                        f"{int(on_times.sum())} joint ties on the people's times")
        again = (lambda fitted: self.run(times_ms, bodies, progress, executor=executor,
                                         hidden_from=fitted.bodies, first=traj, first_prior=body)) if second else None
        return FurtherStage(write=lambda staging: write_patch_table(Path(staging) / FILE_NAME, table), ties=ties,
                            refined=self.report_flags, page_layer=patch_layer(traj, labels), again=again)

    def seeding(self, stream: str) -> tuple[PatchOptions, dict]:
        """The options the stream runs with and how it was seeded (the patch file's ``seeding`` metadata): the
        options' ``seed_method`` as given, or with ``auto_seeds`` the one :func:`~.seed_skeleton.choose_seed_method`
        picks from the reference stream's cameras (logged, one line, with why)."""
        if not self.auto_seeds:
            return self.options, {"method": self.options.seed_method, "chosen": "given"}
        choice = choose_seed_method(view_set(self.bundle, cameras_by_stream(self.bundle, self.cameras)[0][stream]),
                                    stream)
        logger.info("patch seeds: %s (auto): %s", choice.method, choice.reason)
        return replace(self.options, seed_method=choice.method), choice.as_dict()

    def report_flags(self, first, final) -> None:
        """The people fitted again with the ties -> the summary line says how many per-frame joints (the tracked
        people before the body over time) that body finds wrong (:func:`~.body.flag_joints`), and of whom."""
        per_frame = first.tracked if first.tracked is not None else first
        flagged, judged, who = 0, 0, {}
        for a, b in zip(per_frame.bodies, final.bodies):
            ids = np.asarray(b.ids)
            for row, i in enumerate(np.asarray(a.ids)):
                at = np.flatnonzero(ids == i)
                if i < 0 or not len(at):
                    continue
                f = flag_joints(a.X_cm[row], b.X_cm[at[0]], b.confidence[at[0]], self.ties_options)
                judged += int(np.isfinite(a.X_cm[row]).all(-1).sum())
                flagged += int(f.sum())
                if f.any():
                    who[int(i)] = who.get(int(i), 0) + int(f.sum())
        shown = ", ".join(f"person {i}: {n}" for i, n in sorted(who.items()))
        self.summary += (f"; the body refined with them flags {flagged} of {judged} per-frame joints as wrong"
                         + (f" ({shown})" if shown else ""))


def plan_patches(plan: ReconstructPlan, options: PatchOptions | None = None, *,
                 seed_method: str | None = None) -> PatchStage:
    """Check the images of a reconstruction's plan (``--images``, which :func:`plan_reconstruction` checked as an
    input place beside the others): every camera's file, its frames and size (:func:`~.images.open_images`); a
    bundle without sync tables takes the detections' rate ``plan.fps``. ``seed_method`` (``--patch-seeds``)
    replaces the options' seeding method; ``"auto"`` picks it when the stage runs, from the reference stream's
    cameras (:meth:`PatchStage.seeding`)."""
    if plan.images is None:
        raise ValueError("plan_patches: the plan has no images (plan_reconstruction(..., images=FOLDER))")
    options = options or PatchOptions()
    auto = seed_method == "auto"
    if seed_method is not None and not auto:
        try:
            options = replace(options, seed_method=seed_method)
        except OptionsError as exc:
            raise ReconError(f"--patch-seeds {seed_method!r}: expected \"auto\" or {exc.expected}") from None
    source = open_images(plan.images, plan.bundle)
    clocked = with_shared_clock(plan.bundle, source, plan.fps)
    if len(source.names) < 2:
        raise ReconError(f"--images {plan.images}: images of {len(source.names)} camera; patches are triangulated "
                         "from two cameras or more")
    cameras_by_stream(clocked, source.names)  # every camera's sync table, before any work
    return PatchStage(source=source, bundle=clocked, cameras=source.names, options=options, auto_seeds=auto)


def people_at(times_ms: np.ndarray, bodies: list, at_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """People at their times -> ((T', P, 19, 3) joints at ``at_ms``, (P,) ids in increasing order): linear between
    the two people times around each time (as the streams are brought to a time, gaps wider than 2.5 periods not
    bridged), NaN where a person or joint is missing on either side or the time is outside."""
    ids = np.unique(np.concatenate([np.asarray(b.ids, dtype=np.int64) for b in bodies] + [np.zeros(0, np.int64)]))
    ids = ids[ids >= 0]
    J = np.full((len(times_ms), len(ids), 19, 3), np.nan)
    for k, b in enumerate(bodies):
        for row, i in enumerate(np.asarray(b.ids, dtype=np.int64)):
            if i >= 0:
                J[k, np.searchsorted(ids, i)] = b.X_cm[row]
    table = SyncTable(index=np.arange(len(times_ms), dtype=np.int64), univ_time_ms=np.asarray(times_ms, float))
    i0, i1, w0, w1 = table.bracket(np.asarray(at_ms, dtype=float))
    wide = np.abs(table.univ_time_ms[i1] - table.univ_time_ms[i0]) > 2.5 * frame_period_ms(table) + 1e-9
    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        a = np.where((w0 > 0)[:, None, None, None], w0[:, None, None, None] * J[i0], 0.0)
        b = np.where((w1 > 0)[:, None, None, None], w1[:, None, None, None] * J[i1], 0.0)
        out = a + b
    out[~np.isfinite(w1) | wide] = np.nan
    return out, ids


def body_prior(times_ms: np.ndarray, bodies: list, at_ms: np.ndarray, hidden_from: list | None = None) -> BodyPrior:
    """The people at their times (``bodies[t]``: ``ids``, ``X_cm`` and ``n_inliers``, the detections each joint
    rests on) -> the patches' body prior at ``at_ms`` (:func:`people_at`), each joint the detections did not see
    (no inlier at either of the two people times around) carried by its parent from the times it was seen
    (:func:`~.occlusion.hold_unseen_parts`): the skeleton seeds' depth prior and the occluders of the views rest on
    what the detector saw. Bodies without ``n_inliers``: every joint seen.

    ``hidden_from`` (the same people at the same times, e.g. the body over time fitted again with a first patch
    stream's ties: ``PatchOptions.reseed_hidden``): a joint the detections did not see is taken from it where it
    puts the joint out, and carried by its parent only where it does not. The seen joints are ``bodies``' own, bit
    for bit; None: the rule above."""
    joints, ids = people_at(times_ms, bodies, at_ms)
    seen_only = [SimpleNamespace(ids=b.ids, X_cm=np.where((np.asarray(b.n_inliers) > 0)[..., None], b.X_cm, np.nan))
                 if getattr(b, "n_inliers", None) is not None else b for b in bodies]
    seen = np.isfinite(people_at(times_ms, seen_only, at_ms)[0]).all(-1)
    if hidden_from is not None:
        refit, refit_ids = people_at(times_ms, hidden_from, at_ms)
        on = np.searchsorted(refit_ids, ids).clip(0, max(len(refit_ids) - 1, 0))
        found = refit_ids[on] == ids if len(refit_ids) else np.zeros(len(ids), bool)
        fill = np.full_like(joints, np.nan)
        fill[:, found] = refit[:, on[found]]
        put = ~seen & np.isfinite(fill).all(-1)
        joints = np.where(put[..., None], fill, joints)
        seen = seen | put  # held as they are, and their children carried from them
    at = np.asarray(at_ms, dtype=float)
    return BodyPrior(times_ms=at, joints_cm=hold_unseen_parts(at, joints, seen))


def reseed_clouds(first: PatchTrajectories, frames: np.ndarray, frame_times_ms: np.ndarray, held: BodyPrior | None,
                  again: BodyPrior | None, stream: Callable[[list[int]], PatchTrajectories]) -> PatchTrajectories:
    """``reseed_hidden``'s second stream: of the first stream's clouds (``frames``, its seed frames in cloud order,
    at ``frame_times_ms``), those whose prior at their seed time differs between ``held`` (the first stream's) and
    ``again`` (the one from the fitted people) are streamed again (``stream(their frames)``, on ``again``), the
    others kept as they were (a patch depends on its own seed, the images and the prior only). No prior (None):
    ``first``."""
    if held is None or again is None:
        return first
    changed = [c for c, at in enumerate(frame_times_ms)
               if not np.array_equal(held.at(float(at)), again.at(float(at)), equal_nan=True)]
    if not changed:
        return first
    return with_clouds_replaced(first, stream([int(frames[c]) for c in changed]), changed)


def with_clouds_replaced(first: PatchTrajectories, second: PatchTrajectories, clouds: list[int]
                         ) -> PatchTrajectories:
    """``first`` with the patches of its clouds ``clouds`` replaced by ``second``'s (a stream of those clouds alone,
    in that order: its cloud i is cloud ``clouds[i]``, its ids renumbered so), ordered by id."""
    if not np.array_equal(first.times_ms, second.times_ms) or list(first.cameras) != list(second.cameras):
        raise ValueError("with_clouds_replaced: the two streams' times or cameras differ")
    cl = np.asarray(clouds, dtype=np.int64)
    keep = ~np.isin(first.ids // ID_STRIDE, cl)
    ids = np.concatenate([first.ids[keep], cl[second.ids // ID_STRIDE] * ID_STRIDE + second.ids % ID_STRIDE])
    order = np.argsort(ids, kind="stable")

    def joined(a, b):
        return np.concatenate([a[keep], b])[order]

    carried = (None if first.carried is None and second.carried is None else joined(
        *(np.zeros(x.alive.shape, bool) if x.carried is None else x.carried for x in (first, second))))
    return replace(first, ids=ids[order], seed_time_ms=joined(first.seed_time_ms, second.seed_time_ms),
                   X_cm=joined(first.X_cm, second.X_cm), normal=joined(first.normal, second.normal),
                   visible=joined(first.visible, second.visible),
                   photometric=joined(first.photometric, second.photometric), alive=joined(first.alive, second.alive),
                   carried=carried)
