"""EasyMocap ``intri.yml`` + ``extri.yml`` (OpenCV FileStorage YAML; ``easymocap/mytools/camera_utils.py``).

``intri.yml``: ``names`` (list of camera names, the camera order), per camera ``K_<name>`` (3x3, px, OpenCV
pixel centres), ``dist_<name>`` (1x5 [k1, k2, p1, p2, k3]), ``H_<name>`` / ``W_<name>`` (image size).
``extri.yml``: ``names``, per camera ``R_<name>`` (3x1 Rodrigues vector), ``Rot_<name>`` (3x3 matrix), ``T_<name>``
(3x1), all world to camera (``x_cam = R X + T``), T in metres (EasyMocap's documentation: "The metric of T must
be meter"). Both files are written and read with ``cv2.FileStorage`` (full double precision; EasyMocap's own
writer prints 6 decimals). On import, ``R_`` is used as EasyMocap's ``read_camera`` does (``Rot_`` if ``R_`` is
absent); when both are present they must agree.
"""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from dome_calib import panoptic_io as pio
from dome_calib.interop.common import ForeignCamera, InteropError
from dome_calib.rotation import matrix_to_rotvec, rotation_angle_deg, rotvec_to_matrix

UNIT = "m"
FILES = ("intri.yml", "extri.yml")
#: ``R_`` and ``Rot_`` of one camera may differ by this much (EasyMocap writes both with 6 decimals).
ROTATION_AGREEMENT_DEG = 1e-3
#: Names that make valid FileStorage keys (``K_<name>``) and survive EasyMocap's ``name.split('.')[0]``.
_KEY_NAME = re.compile(r"[A-Za-z0-9_-]+")


def _write_names(fs: cv2.FileStorage, names: list[str]) -> None:
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for name in names:
        fs.write("", name)
    fs.endWriteStruct()


def write_easymocap(cams: list[ForeignCamera], folder: Path) -> list[Path]:
    """Write ``intri.yml`` and ``extri.yml`` into ``folder`` (translations already in metres)."""
    for cam in cams:
        if not _KEY_NAME.fullmatch(cam.name):
            raise InteropError(f"camera {cam.name!r}: field 'name': EasyMocap's YAML keys (K_<name>, ...) take "
                               "letters, digits, '_' and '-' only; rename it with --names")
    names = [c.name for c in cams]
    intri = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    _write_names(intri, names)
    for cam in cams:
        intri.write(f"K_{cam.name}", np.asarray(cam.K, dtype=float))
        intri.write(f"dist_{cam.name}", np.asarray(cam.dist, dtype=float).reshape(1, 5))
        intri.write(f"H_{cam.name}", int(cam.size[1]))
        intri.write(f"W_{cam.name}", int(cam.size[0]))
    intri.release()
    extri = cv2.FileStorage(str(folder / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    _write_names(extri, names)
    for cam in cams:
        extri.write(f"R_{cam.name}", matrix_to_rotvec(cam.R).reshape(3, 1))
        extri.write(f"Rot_{cam.name}", np.asarray(cam.R, dtype=float))
        extri.write(f"T_{cam.name}", np.asarray(cam.t, dtype=float).reshape(3, 1))
    extri.release()
    return [folder / f for f in FILES]


def _open(path: Path) -> cv2.FileStorage:
    if not path.is_file():
        raise InteropError(f"{path}: missing (an EasyMocap calibration is a folder with {' and '.join(FILES)})")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):  # OpenCV 5's binding raises SystemError for a parse error
        fs = None
    if fs is None or not fs.isOpened():
        raise InteropError(f"{path}: not an OpenCV FileStorage YAML file (expected EasyMocap's {path.name})")
    return fs


def _names(fs: cv2.FileStorage, path: Path) -> list[str]:
    node = fs.getNode("names")
    if node.empty() or not node.isSeq() or node.size() == 0:
        raise InteropError(f"{path}: field 'names': missing or empty (expected the list of camera names)")
    out = []
    for i in range(node.size()):
        item = node.at(i)
        out.append(item.string() if item.isString() else str(int(item.real())))  # as EasyMocap: numbers too
    return out


def _matrix(fs: cv2.FileStorage, key: str, w: pio._Where, shapes: tuple[tuple[int, ...], ...], limit: float,
            required: bool = True) -> np.ndarray | None:
    node = fs.getNode(key)
    if node.empty():
        if required:
            raise w.fail(key, "missing")
        return None
    mat = node.mat()
    if mat is None:
        raise w.fail(key, "expected an !!opencv-matrix")
    return w.numbers(np.asarray(mat, dtype=float).tolist(), key, shapes, limit)


def _size(fs: cv2.FileStorage, name: str, w: pio._Where) -> tuple[int, int]:
    values = []
    for key in (f"W_{name}", f"H_{name}"):
        node = fs.getNode(key)
        if node.empty() or not node.isInt():
            raise w.fail(key, "missing or not an integer (the image size is needed to know the image's extent)")
        values.append(int(node.real()))
    return w.size(values, f"W_{name}/H_{name}")


def read_easymocap(folder: Path) -> list[ForeignCamera]:
    """Cameras in the order of ``intri.yml``'s ``names``, translations in metres."""
    if not folder.is_dir():
        raise InteropError(f"{folder}: not a folder (an EasyMocap calibration is a folder with "
                           f"{' and '.join(FILES)})")
    intri_path, extri_path = folder / FILES[0], folder / FILES[1]
    intri, extri = _open(intri_path), _open(extri_path)
    names = _names(intri, intri_path)
    extri_names = _names(extri, extri_path)
    missing = [n for n in names if n not in extri_names]
    if missing:
        raise InteropError(f"{extri_path}: camera {missing[0]}: field 'names': listed in intri.yml but not here")
    cams = []
    for name in names:
        wi = pio._Where(intri_path).at(f"camera {pio._label(name)}")
        we = pio._Where(extri_path).at(f"camera {pio._label(name)}")
        dist = _matrix(intri, f"dist_{name}", wi, None, pio.LIMITS["dist"], required=False)
        if dist is None:
            dist = _matrix(intri, f"D_{name}", wi, None, pio.LIMITS["dist"], required=False)
        if dist is None:
            raise wi.fail(f"dist_{name}", "missing")
        if dist.size not in (4, 5):
            raise wi.fail(f"dist_{name}", f"{dist.size} terms, expected 5 [k1, k2, p1, p2, k3] (or 4)")
        rvec = _matrix(extri, f"R_{name}", we, ((3, 1), (1, 3), (3,)), 1e3, required=False)
        rot = _matrix(extri, f"Rot_{name}", we, ((3, 3),), 2.0, required=rvec is None)
        R = rotvec_to_matrix(rvec.ravel()) if rvec is not None else we.rotation(rot, f"Rot_{name}")
        if rvec is not None and rot is not None:
            gap = float(rotation_angle_deg(R, rot))
            if not gap <= ROTATION_AGREEMENT_DEG:
                raise we.fail(f"Rot_{name}", f"disagrees with R_{name} by {gap:.3g} deg (not the same rotation)")
        cams.append(ForeignCamera(
            name=name, size=_size(intri, name, wi),
            K=_matrix(intri, f"K_{name}", wi, ((3, 3),), pio.LIMITS["K_px"]),
            dist=np.concatenate([dist.ravel(), np.zeros(5 - dist.size)]), R=R,
            t=_matrix(extri, f"T_{name}", we, ((3, 1), (1, 3), (3,)), pio.LIMITS["t_cm"]).ravel()))
    intri.release()
    extri.release()
    return cams
