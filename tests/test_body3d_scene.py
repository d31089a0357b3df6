"""The body3DScene file in one place (dome_calib.body3d_scene): no other module of the toolkit builds the files' names
(each writer and reader goes through it), and what it writes it reads back, with dome-calib's own fields."""
from __future__ import annotations

import ast
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from dome_calib.body3d_scene import (EXTRA_NAMES, read_scene, read_scene_file, scene_files, scene_json, scene_name,
                                     write_scene_folder)
from dome_calib.errors import PeopleFileError
from dome_calib.skeletons.scenes import read_people

ROOT = Path(__file__).resolve().parents[1]
ONE_MODULE = ROOT / "dome_calib" / "body3d_scene.py"


def _named_in_code(path: Path) -> list[int]:
    """Lines of ``path`` whose string constants (docstrings aside) name body3DScene files."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and id(n) not in docs and "body3DScene_" in n.value]


def test_only_the_one_module_names_body3dscene_files():
    """A second writer or reader of the files needs their names (a pattern, a glob, an f-string): only
    body3d_scene.py has them in its code; the commands' help texts (cli/) name them for the user."""
    assert _named_in_code(ONE_MODULE)  # the check sees names (it can fail)
    others = {str(p.relative_to(ROOT)): lines for p in sorted((ROOT / "dome_calib").rglob("*.py"))
              if p != ONE_MODULE and "cli" not in p.relative_to(ROOT).parts and (lines := _named_in_code(p))}
    assert others == {}


def test_what_is_written_reads_back(tmp_path):
    """Two times, two bodies (ids out of order), a missing joint, the extra joints, a custom rate and a lab's up
    axis: written by write_scene_folder, read by the one reader and as people."""
    rng = np.random.default_rng(0)
    extra = list(EXTRA_NAMES[2:5])
    scenes = []
    for k in range(2):
        X, c = rng.normal(0, 50, (2, 19, 3)), np.full((2, 19), 0.8)
        c[1, 4] = -1.0
        ex = (extra, rng.normal(0, 50, (2, 3, 3)), np.full((2, 3), 0.5), np.full((2, 3), 2))
        scenes.append(scene_json(1000.0 + 40 * k, np.array([7, 3]), X, c, np.full((2, 19), 4), "custom",
                                 body_model="BODY_25", extra=ex, lab_up="+z", fps=Fraction(60)))
    paths = write_scene_folder(tmp_path / "out", [250, 251], scenes)
    assert [p.name for p in paths] == [scene_name(250), scene_name(251)] == ["body3DScene_00000250.json",
                                                                            "body3DScene_00000251.json"]
    assert [f for f, _ in scene_files(tmp_path / "out")] == [250, 251]
    t_ms, bodies = read_scene(paths[1])
    assert t_ms == 1040.0 and sorted(bodies) == [3, 7]
    assert [b.id for b in read_scene_file(paths[0]).bodies] == [3, 7]  # sorted by id
    assert bodies[3][4].tolist() == [0.0, 0.0, 0.0, -1.0]  # id 3 is the second body: its joint 4 was missing
    people = read_people(tmp_path / "out")
    assert people.fps == 60 and people.lab_up == "+z" and people.extra == tuple(extra)
    assert people.body_model == "BODY_25" and sorted(people.tracks) == [3, 7]
    with pytest.raises(PeopleFileError, match="no body3DScene"):
        scene_files(tmp_path)
