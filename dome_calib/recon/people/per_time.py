"""The per-time association: the people of a batch of times -> each time's bodies (without ids) and the cameras'
tallies (steps 2-6 of :mod:`~dome_calib.recon.people.run`), each rule in one place.

- :func:`associate_batch`: the per-frame pass: proposals and assignment
  (:func:`~dome_calib.recon.people.assign.associate`), then :func:`bodies_of`, then the tallies of the bodies kept;
- :func:`bodies_of`: assigned detections -> bodies: one robust triangulation call for the batch
  (:func:`~dome_calib.recon.people.bodies.triangulate_people`), the joint check
  (:func:`~dome_calib.recon.people.joint_check.check_joints`), the depth witness at each time
  (:mod:`~dome_calib.recon.people.depth_witness`), then :func:`~dome_calib.recon.people.bodies.build_bodies`;
- :meth:`BatchBodies.agreement`: how each camera agrees with the bodies a caller uses
  (:func:`~dome_calib.recon.people.agreement.tally_agreement`).

The bridging of the tracks' gaps (:mod:`~dome_calib.recon.people.bridging`) runs the same stage on the detections
no body took: it assigns them with the same rules (:func:`~dome_calib.recon.people.assign.leftover`,
:func:`~dome_calib.recon.people.assign.assign_passes`), calls :func:`bodies_of`, and tallies only the bodies a track
takes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dome_calib.recon.kernel import CameraKernel
from dome_calib.recon.people.agreement import CameraAgreement, tally_agreement
from dome_calib.recon.people.assign import associate
from dome_calib.recon.people.bodies import Bodies, PeopleTriangulation, build_bodies, triangulate_people
from dome_calib.recon.people.depth_witness import DepthWitness
from dome_calib.recon.people.joint_check import check_joints
from dome_calib.recon.people.options import PeopleOptions
from dome_calib.recon.people.proposals import AssociationOptions
from dome_calib.recon.project import ViewSet


@dataclass(frozen=True)
class BatchBodies:
    """The bodies of a batch of T times from their assigned detections: tri (B people triangulated), ok (B, 19) the
    joints kept (joint check, then the depth witness), bodies[t] (ids -1), kept (B,) the people that became bodies;
    depth_joints: the joints the views agreed on that the depth witness judged, depth_rejected: of them those it
    saw through (both 0 without a witness)."""

    tri: PeopleTriangulation
    ok: np.ndarray
    bodies: list[Bodies]
    kept: np.ndarray
    depth_joints: int = 0
    depth_rejected: int = 0

    def agreement(self, views: ViewSet, kp: np.ndarray, used: np.ndarray, options: AssociationOptions
                  ) -> CameraAgreement:
        """The cameras' tallies of the batch (kp (T, V, N, 19, 3)) counting the people ``used`` (B,) as bodies."""
        return tally_agreement(views, kp, self.tri, self.ok, used, min_joint_conf=options.min_joint_conf,
                               min_common_joints=options.min_common_joints)


def bodies_of(views: ViewSet, kp: np.ndarray, assigned: list[np.ndarray], options: PeopleOptions, *,
              times_ms: np.ndarray | None = None, depth: DepthWitness | None = None) -> BatchBodies:
    """kp (T, V, N, 19, 3) and each time's (V, P_t) assignment -> :class:`BatchBodies`. With ``depth`` (and the
    batch's ``times_ms``), the joints the Kinects see through at each time are dropped before the bodies are
    built."""
    tri = triangulate_people(views, kp, assigned, options.triangulation)
    ok = check_joints(tri.X_cm, tri.n_inliers, options.joint_check)
    before = int(ok.sum())
    if depth is not None:
        for k in range(len(tri.sizes) - 1):
            sl = slice(tri.sizes[k], tri.sizes[k + 1])
            ok[sl] &= depth.keep(np.where(ok[sl, :, None], tri.X_cm[sl], np.nan), float(times_ms[k]))
    bodies, kept = build_bodies(tri, ok, min_body_joints=options.min_body_joints,
                                duplicate_cm=options.association.duplicate_cm)
    if depth is None:
        return BatchBodies(tri=tri, ok=ok, bodies=bodies, kept=kept)
    return BatchBodies(tri=tri, ok=ok, bodies=bodies, kept=kept, depth_joints=before,
                       depth_rejected=before - int(ok.sum()))


def associate_batch(views: ViewSet, kernel: CameraKernel, pairs: np.ndarray, kp: np.ndarray,
                    options: PeopleOptions, *, times_ms: np.ndarray | None = None, depth: DepthWitness | None = None
                    ) -> tuple[list[Bodies], CameraAgreement]:
    """(T, V, N, 19, 3) people at T times -> the bodies of each time (ids -1, each with its assigned detections) and
    the cameras' agreement (steps 2-6 of :mod:`~dome_calib.recon.people.run`; with ``depth`` and the batch's
    ``times_ms``, step 4 also drops the joints the Kinects see through)."""
    assigned = associate(views, kernel, pairs, kp, options.association, min_body_joints=options.min_body_joints)
    found = bodies_of(views, kp, assigned, options, times_ms=times_ms, depth=depth)
    agreement = found.agreement(views, kp, found.kept, options.association)
    if depth is not None:
        agreement.depth_joints, agreement.depth_rejected = found.depth_joints, found.depth_rejected
    return found.bodies, agreement
