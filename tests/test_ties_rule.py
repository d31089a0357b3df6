"""The class rule of :mod:`dome_calib.ties`: no choice rests on the last bits of a float, and every quantised choice
goes through ``ties`` with a named step. Read from the package's source (AST): a rounding written inline is either
on the short list below of named non-choice uses (a value written or displayed, an integer for a solver, an image
or grid index, a hash key) or refused; a rounding feeding a choice (argmax, argmin, a sort, a comparison) inline is
refused everywhere outside ``ties.py``."""
from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import dome_calib

PACKAGE = Path(dome_calib.__file__).parent
_ROUNDING = {"rint", "round", "around"}
_MAY_ROUND = re.compile(r"\b(np|numpy)\.(rint|round|around)\b")
_CHOICES = {"argmax", "argmin", "nanargmax", "nanargmin", "argsort", "lexsort", "sort", "sorted", "max", "min",
            "unique", "searchsorted", "argpartition", "partition"}

#: (module path, function) -> number of numpy roundings (``np.rint``, ``np.round``, ``np.around``) in it: the uses
#: that are not a choice, each with why.
ALLOWED_ROUNDING = {
    # values written, displayed or kept on a grid (no choice reads their last bits)
    ("recon/patches/page_layer.py", "patch_layer"): 2,  # mm and ms on the page
    ("recon/patches/track.py", "quantise_cm"): 1,  # the position quantum that makes the stream's positions exact
    ("recon/patches/parts.py", "part_radii"): 1,  # a part's radius kept on the 1e-4 cm grid
    ("recon/people/windows.py", "infer_unmeasured_bones"): 1,  # a guessed bone length on the BONE_STEP_CM grid
    ("recon/people/scene_io.py", "camera_report"): 6,  # figures in the report
    ("report/page.py", "arrows_of"): 2,  # pixels and centi-pixels on the page
    ("skeletons/page.py", "_cameras"): 1,  # cm on the page
    ("skeletons/page.py", "_detections"): 4,  # quarter pixels, confidences and ms on the page
    ("skeletons/page.py", "_mm_i16"): 1,  # mm on the page
    ("skeletons/page.py", "page_data"): 1,  # ms on the page
    ("synth/detector.py", "_detect"): 2,  # the detector's pixels and confidences as it writes them
    ("synth/detector.py", "feet_detections"): 1,  # the same for the feet
    ("synth/group_session.py", "truth_document"): 1,  # the truth file's joints
    ("synth/rays.py", "CameraRays.__init__"): 1,  # an error message
    # integers for a solver, a rasteriser, an image, a clock or a hash
    ("recon/patches/mincut.py", "quantise_costs"): 1,  # min-cut capacities (mincut.COST_SCALE)
    ("recon/triangulate.py", "point_keys"): 1,  # the integer hash of a RANSAC draw (named steps)
    ("recon/people/depth_witness.py", "judge_joints"): 2,  # the pixel a joint projects to
    ("kinect/board.py", "RayGrid.build"): 2,  # a pixel's nearest grid node
    ("kinect/board.py", "Checkerboard.reflectance_xy.ramp"): 1,  # distance to the nearest square edge (a value)
    ("kinect/depth_bias.py", "board_mask"): 1,  # a polygon in cv2's fixed point
    ("synth/kinect_boards.py", "render_depth"): 1,  # rendered depth image (uint16)
    ("synth/kinect_boards.py", "render_ir"): 1,  # rendered IR image (uint8)
    ("synth/render.py", "sensor_image"): 1,  # rendered image (uint8)
    ("synth/textured.py", "render_view"): 1,  # rendered image (uint8)
    ("synth/depth.py", "render_depth_mm"): 1,  # rendered depth image (uint16)
    ("synth/depth_people.py", "render_people_depth_mm"): 1,  # rendered depth image (uint16)
    ("synth/sync_session.py", "make_session"): 2,  # simulated clock stamps in integer ticks
    ("exact.py", "_atan_unit"): 1,  # the arctangent's table entry k/8 (either neighbour is exact)
    ("exact.py", "exp"): 1,  # the multiple k of ln 2 to reduce by (either neighbour is as exact)
    ("exact.py", "sincos"): 1,  # the quarter turn k to reduce by (either neighbour is as exact)
    # a compiled (numba) kernel cannot call ties: the same rule there, its step named (DIST2_QUANTUM_CM2)
    ("recon/patches/occlusion.py", "_below"): 2,
    # the same for a joint's strongest detections (ties.CONFIDENCE_QUANTUM); quantising before the call would need a
    # key array as large as the session's detections
    ("recon/people/compiled.py", "_fill_records"): 1,
}
#: Compiled (numba) kernels, where a quantised comparison is written out with a named step: ties cannot run there.
COMPILED_CHOICES = {("recon/patches/occlusion.py", "_below"), ("recon/people/compiled.py", "_fill_records")}


def _is_np_rounding(node: ast.AST) -> bool:
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in _ROUNDING
            and isinstance(node.func.value, ast.Name) and node.func.value.id in ("np", "numpy"))


def _called(node: ast.Call) -> str:
    return node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")


def scan(source: str) -> tuple[dict[str, int], list[tuple[int, str, str]]]:
    """One module's source -> (numpy roundings per function qualname, [(line, function, code)] of inline
    roundings inside a choice: a call of argmax, argmin, a sort, min or max, or a comparison)."""
    roundings: dict[str, int] = {}
    choices: list[tuple[int, str, str]] = []

    def walk(node: ast.AST, qualname: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = qualname
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{qualname}.{child.name}" if qualname else child.name
            if _is_np_rounding(child):
                roundings[name] = roundings.get(name, 0) + 1
            if (isinstance(child, ast.Call) and _called(child) in _CHOICES) or isinstance(child, ast.Compare):
                if any(_is_np_rounding(n) for n in ast.walk(child) if n is not child):
                    choices.append((child.lineno, name, ast.unparse(child)[:100]))
            walk(child, name)

    walk(ast.parse(source), "")
    return roundings, choices


@functools.cache
def _package() -> dict[str, tuple[dict[str, int], list[tuple[int, str, str]]]]:
    """Every module of the package but ``ties.py`` (path under the package) -> its :func:`scan`."""
    texts = {p.relative_to(PACKAGE).as_posix(): p.read_text() for p in sorted(PACKAGE.rglob("*.py"))
             if p != PACKAGE / "ties.py"}
    return {path: scan(text) for path, text in texts.items() if _MAY_ROUND.search(text)}  # the rest: nothing to see


def test_no_inline_rounding_feeds_a_choice():
    found = [f"{path}:{line}: {code}" for path, (_, c) in _package().items() for line, fn, code in c
             if (path, fn) not in COMPILED_CHOICES]
    assert not found, "choose through dome_calib.ties (a named step), not inline:\n" + "\n".join(found)


def test_every_inline_rounding_is_a_named_non_choice_use():
    found = {(path, fn): n for path, (r, _) in _package().items() for fn, n in r.items()}
    allowed = ALLOWED_ROUNDING
    extra = {k: n for k, n in found.items() if n > allowed.get(k, 0)}
    assert not extra, f"numpy rounding outside ties.py and the allow-list (a choice? use ties): {extra}"
    stale = {k: n for k, n in allowed.items() if found.get(k, 0) < n}
    assert not stale, f"allow-list entries with fewer roundings left: lower or drop them {stale}"


def test_the_scan_sees_the_patterns_it_refuses():
    """The old inline forms (before ties took them) are caught: the rule can fail."""
    old = '''
def pick(score, mask, cos, limit, names, C):
    ref = np.argmax(np.where(mask, np.rint(score * 1e6), -1e9), axis=1)
    k = int(np.argmin(np.round(cos, 9)))
    ok = np.rint(cos * 1e9) <= np.rint(limit * 1e9)
    key = np.rint(np.linalg.norm(C, axis=1) * 100.0)
    order = sorted((key[j], names[j], j) for j in range(len(C)))
    return ref, k, ok, order
'''
    roundings, choices = scan(old)
    assert roundings == {"pick": 5}
    assert [line for line, _, _ in choices] == [3, 4, 5]
