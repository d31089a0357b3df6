"""The bundle-adjustment problem: cameras by name, 3D points per scene, observations from all scenes.

Parameters per camera (15, in this order, see :data:`CAMERA_PARAMS`):
``[r0, r1, r2, tx_cm, ty_cm, tz_cm, fx, fy, cx, cy, k1, k2, p1, p2, k3]`` where ``r`` is the cam_from_world
rotation vector (rad) and ``t`` the cam_from_world translation (cm): ``x_cam = R(r) @ X_world + t``.
Intrinsics and pixels follow OpenCV (centre of the top-left pixel at (0, 0)).

Points of all scenes are stacked into one array; ``scene_point_start`` gives the slice of each scene.
Observations reference cameras by position in ``camera_names`` and points by global index.

Every camera parameter can be held fixed individually (``free`` mask, (C, 15) bool); use
:meth:`BAProblem.fix` / :meth:`BAProblem.unfix` with :class:`ParamGroup` names.

Example (the SfM merge step builds the problem like this)::

    problem = BAProblem.from_cameras(
        cameras,                                  # dict name -> dome_calib.bundle.Camera (initial values)
        {"scene_01": pts1_cm, "scene_02": pts2_cm},  # (P_s, 3) points per scene, world frame, cm
        camera_index=cam_idx, point_index=pt_idx,  # (M,) ints; cameras by position in list(cameras)
        uv_px=uv,                                  # (M, 2) OpenCV pixels
    )
    problem.fix(ParamGroup.DISTORTION)            # e.g. a first pass without distortion
"""
from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np

from dome_calib.bundle import Bundle, Camera
from dome_calib.camera import intr_to_K
from dome_calib.errors import DomeCalibError
from dome_calib.rotation import matrix_to_rotvec, rotvec_to_matrix

#: Names of the 15 parameters of one camera, in storage order.
CAMERA_PARAMS = ("r0", "r1", "r2", "tx_cm", "ty_cm", "tz_cm", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
N_CAMERA_PARAMS = len(CAMERA_PARAMS)
ROT, TRANS, INTR, DIST = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 15)


class BAProblemError(DomeCalibError, ValueError):
    """The bundle-adjustment problem is malformed (shapes, indices, unknown camera or parameter group)."""


class ParamGroup(StrEnum):
    """Groups of camera parameters that can be fixed or freed together."""

    ROTATION = "rotation"
    TRANSLATION = "translation"
    POSE = "pose"
    FOCAL = "focal"
    PRINCIPAL_POINT = "principal_point"
    INTRINSICS = "intrinsics"  # focal + principal point
    DISTORTION = "distortion"  # all five
    K1 = "k1"
    K2 = "k2"
    P1 = "p1"
    P2 = "p2"
    K3 = "k3"
    ALL = "all"


_GROUP_COLUMNS: dict[ParamGroup, tuple[int, ...]] = {
    ParamGroup.ROTATION: (0, 1, 2),
    ParamGroup.TRANSLATION: (3, 4, 5),
    ParamGroup.POSE: (0, 1, 2, 3, 4, 5),
    ParamGroup.FOCAL: (6, 7),
    ParamGroup.PRINCIPAL_POINT: (8, 9),
    ParamGroup.INTRINSICS: (6, 7, 8, 9),
    ParamGroup.DISTORTION: (10, 11, 12, 13, 14),
    ParamGroup.K1: (10,),
    ParamGroup.K2: (11,),
    ParamGroup.P1: (12,),
    ParamGroup.P2: (13,),
    ParamGroup.K3: (14,),
    ParamGroup.ALL: tuple(range(N_CAMERA_PARAMS)),
}


def group_columns(groups: ParamGroup | str | Iterable[ParamGroup | str]) -> list[int]:
    """Parameter columns (0..14) of one or several :class:`ParamGroup` names."""
    if isinstance(groups, str):
        groups = [groups]
    cols: set[int] = set()
    for g in groups:
        try:
            cols.update(_GROUP_COLUMNS[ParamGroup(g)])
        except ValueError:
            valid = ", ".join(p.value for p in ParamGroup)
            raise BAProblemError(f"unknown parameter group {g!r}; valid: {valid}") from None
    return sorted(cols)


def camera_to_params(camera: Camera) -> np.ndarray:
    """(15,) parameter vector of a :class:`Camera`."""
    return np.concatenate([matrix_to_rotvec(camera.R), camera.t_cm, camera.intr, camera.dist]).astype(float)


def params_to_camera(params: np.ndarray, template: Camera) -> Camera:
    """A copy of ``template`` with pose, K and distortion taken from a (15,) parameter vector."""
    p = np.asarray(params, dtype=float)
    return replace(template, K=intr_to_K(p[INTR]), dist=p[DIST].copy(), R=rotvec_to_matrix(p[ROT]),
                   t_cm=p[TRANS].copy())


@dataclass(kw_only=True)
class BAProblem:
    """Cameras, points and observations of a multi-scene bundle adjustment (see the module docstring).

    camera_names: C names; ``cameras`` the matching initial :class:`Camera` objects (type, resolution, panel,
    node are carried to the output). camera_params (C, 15); free (C, 15) bool, True = refined.
    points_cm (P, 3) world frame; scene_names (S,), scene_point_start (S + 1,) offsets into points_cm.
    camera_index (M,), point_index (M,) int; uv_px (M, 2) OpenCV pixels.
    """

    camera_names: list[str]
    cameras: list[Camera]
    camera_params: np.ndarray
    free: np.ndarray
    points_cm: np.ndarray
    scene_names: list[str]
    scene_point_start: np.ndarray
    camera_index: np.ndarray
    point_index: np.ndarray
    uv_px: np.ndarray
    _name_to_index: dict[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.validate()

    @classmethod
    def from_cameras(
        cls,
        cameras: Mapping[str, Camera] | Sequence[Camera],
        scene_points_cm: Mapping[str, np.ndarray],
        *,
        camera_index: np.ndarray,
        point_index: np.ndarray,
        uv_px: np.ndarray,
        camera_names: Sequence[str] | None = None,
    ) -> BAProblem:
        """Build a problem from initial cameras, per-scene points and observations.

        Args:
            cameras: initial cameras, a dict name -> Camera or a sequence of Camera (keyed by ``.name``).
            scene_points_cm: scene name -> (P_s, 3) world points in cm; stacked in the dict's order, so the
                global point index of point k of the second scene is ``len(first) + k``.
            camera_index: (M,) position of the observing camera in ``camera_names``.
            point_index: (M,) global point index (over all scenes, in the order above).
            uv_px: (M, 2) observed pixels, OpenCV convention.
            camera_names: order of cameras for ``camera_index``; default: the order of ``cameras``.
        Everything starts free; fix groups with :meth:`fix`. The gauge is chosen by the solver (see
        :mod:`dome_calib.ba.gauge`).
        """
        by_name = dict(cameras) if isinstance(cameras, Mapping) else {c.name: c for c in cameras}
        names = list(by_name) if camera_names is None else list(camera_names)
        missing = [n for n in names if n not in by_name]
        if missing:
            raise BAProblemError(f"camera_names lists {missing[0]!r} but no such camera was given")
        cams = [by_name[n] for n in names]
        params = np.stack([camera_to_params(c) for c in cams]) if cams else np.zeros((0, N_CAMERA_PARAMS))
        scene_names = list(scene_points_cm)
        pts = [np.asarray(scene_points_cm[s], dtype=float).reshape(-1, 3) for s in scene_names]
        starts = np.concatenate([[0], np.cumsum([len(p) for p in pts])]).astype(np.int64)
        return cls(
            camera_names=names, cameras=cams, camera_params=params, free=np.ones(params.shape, dtype=bool),
            points_cm=np.concatenate(pts) if pts else np.zeros((0, 3)), scene_names=scene_names,
            scene_point_start=starts,
            camera_index=np.asarray(camera_index, dtype=np.int64),
            point_index=np.asarray(point_index, dtype=np.int64), uv_px=np.asarray(uv_px, dtype=float),
        )

    # ----------------------------------------------------------------- validation and lookup
    def validate(self) -> None:
        """Check shapes and indices; raise :class:`BAProblemError` naming the field."""
        C, M = len(self.camera_names), len(self.camera_index)
        self.camera_params = np.asarray(self.camera_params, dtype=float)
        self.free = np.asarray(self.free, dtype=bool)
        self.points_cm = np.asarray(self.points_cm, dtype=float)
        checks = [
            (self.camera_params.shape == (C, N_CAMERA_PARAMS), f"camera_params {self.camera_params.shape=}, "
             f"expected ({C}, {N_CAMERA_PARAMS})"),
            (self.free.shape == (C, N_CAMERA_PARAMS), f"free {self.free.shape=}, expected ({C}, 15)"),
            (len(self.cameras) == C, f"{len(self.cameras)} cameras for {C} camera_names"),
            (len(set(self.camera_names)) == C, "camera_names has duplicates"),
            (self.points_cm.ndim == 2 and self.points_cm.shape[1] == 3, f"{self.points_cm.shape=}, expected (P, 3)"),
            (self.point_index.shape == (M,), f"point_index shape {self.point_index.shape}, expected ({M},)"),
            (self.uv_px.shape == (M, 2), f"uv_px shape {self.uv_px.shape}, expected ({M}, 2)"),
            (len(self.scene_point_start) == len(self.scene_names) + 1
             and self.scene_point_start[-1] == len(self.points_cm), "scene_point_start does not cover points_cm"),
        ]
        for ok, msg in checks:
            if not ok:
                raise BAProblemError(f"bundle-adjustment problem: {msg}")
        if M and (self.camera_index.min() < 0 or self.camera_index.max() >= C):
            raise BAProblemError(f"camera_index out of range [0, {C}): max {self.camera_index.max()}")
        if M and (self.point_index.min() < 0 or self.point_index.max() >= len(self.points_cm)):
            raise BAProblemError(f"point_index out of range [0, {len(self.points_cm)}): max {self.point_index.max()}")
        for what, arr in (("uv_px", self.uv_px), ("points_cm", self.points_cm), ("camera_params", self.camera_params)):
            if not np.all(np.isfinite(arr)):
                raise BAProblemError(f"bundle-adjustment problem: {what} has non-finite values")
        self._name_to_index = {n: i for i, n in enumerate(self.camera_names)}

    @property
    def n_cameras(self) -> int:
        return len(self.camera_names)

    @property
    def n_points(self) -> int:
        return len(self.points_cm)

    @property
    def n_observations(self) -> int:
        return len(self.camera_index)

    def camera_position(self, name: str) -> int:
        """Position of a camera in ``camera_names``; :class:`BAProblemError` if unknown."""
        try:
            return self._name_to_index[name]
        except KeyError:
            raise BAProblemError(f"no camera named {name!r} in the bundle-adjustment problem") from None

    def scene_points(self, scene: str) -> np.ndarray:
        """(P_s, 3) view of one scene's points."""
        s = self.scene_names.index(scene)
        return self.points_cm[self.scene_point_start[s]:self.scene_point_start[s + 1]]

    # ----------------------------------------------------------------- fixing / freeing
    def _set_free(self, groups: ParamGroup | str | Iterable[ParamGroup | str],
                  cameras: str | Iterable[str] | None, value: bool) -> None:
        cols = group_columns(groups)
        rows = range(self.n_cameras) if cameras is None else [self.camera_position(n) for n in (
            [cameras] if isinstance(cameras, str) else cameras)]
        for r in rows:
            self.free[r, cols] = value

    def fix(self, groups: ParamGroup | str | Iterable[ParamGroup | str] = ParamGroup.ALL,
            cameras: str | Iterable[str] | None = None) -> None:
        """Hold parameter groups constant on the named cameras (all cameras if ``cameras`` is None)."""
        self._set_free(groups, cameras, False)

    def unfix(self, groups: ParamGroup | str | Iterable[ParamGroup | str] = ParamGroup.ALL,
              cameras: str | Iterable[str] | None = None) -> None:
        """Refine parameter groups on the named cameras (all cameras if ``cameras`` is None)."""
        self._set_free(groups, cameras, True)

    # ----------------------------------------------------------------- output
    def copy(self) -> BAProblem:
        """Deep copy (parameters, masks and observations)."""
        return copy.deepcopy(self)

    def camera(self, name: str) -> Camera:
        """The camera with its current parameters."""
        i = self.camera_position(name)
        return params_to_camera(self.camera_params[i], self.cameras[i])

    def to_bundle(self, *, seq: str = "ba", base: Bundle | None = None, calib_data_source: str = "") -> Bundle:
        """The cameras with their current parameters as a :class:`Bundle` (frame: the problem's, i.e. the
        gauge of the solve; normalise to the Panoptic world frame afterwards). Cameras of ``base`` that are not in
        the problem are kept unchanged; its Kinect calibration and sync tables are carried over.
        """
        cams = dict(base.cameras) if base is not None else {}
        for n in self.camera_names:
            cams[n] = self.camera(n)
        if base is None:
            return Bundle(seq=seq, cameras=cams, calib_data_source=calib_data_source or "dome_calib.ba")
        return Bundle(seq=base.seq, cameras=cams, calib_data_source=calib_data_source or base.calib_data_source,
                      kinect=base.kinect, sync=base.sync)
