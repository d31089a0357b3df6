"""The house: imports follow the data (foundation <- stages <- pipelines <- CLI), checked on the source (AST).

- no circle of files (module-level imports, and in-function ones too);
- ``projector`` (the SfM front end) never imports the solver, the pipelines, the report or the synthetic generators;
- production code never imports a synthetic generator (only the commands that run them: ``synth``, ``kinect-synth``,
  ``demo``);
- an import inside a function only where it saves start-up time, each listed here with its reason;
- the folders show the floors: foundation (the flat modules of ``dome_calib`` and ``timecode``, and
  ``dome_calib.executor``) <- stages (one room each: ``projector``, ``dome_calib.ba``, ``dome_calib.kinect``,
  ``timecode.decode``, ...) <- pipelines (``dome_calib.pipeline``, ``timecode.sync.pipeline``) <- CLI (the ``cli``
  folders); nothing imports a floor above its own, and only the pipelines, the CLI and the synthetic generators
  import across rooms (a stage uses its own room and the foundation);
- rich and typer only under the ``cli`` folders; ``import dome_calib.cli`` / ``timecode.cli`` and ``timecode --help``
  load neither numpy nor scipy nor pydantic (run in a subprocess).
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dome_calib", "projector", "timecode")

CLI_REASON = "CLI shell: a command's stages load only when it runs, so `--help` and the other commands start fast"
#: file -> why imports inside its functions are allowed (and how many it has: a new one must be listed here).
IN_FUNCTION_ALLOWED = {
    "dome_calib/cli/__init__.py": (10, CLI_REASON),
    "dome_calib/cli/kinect.py": (8, CLI_REASON),
    "dome_calib/cli/recon.py": (5, CLI_REASON),
    "dome_calib/cli/synth.py": (5, CLI_REASON),
    "dome_calib/cli/session.py": (5, CLI_REASON),
    "dome_calib/cli/people.py": (5, CLI_REASON),
    "dome_calib/cli/interop.py": (4, CLI_REASON),
    "dome_calib/cli/skeletons.py": (4, CLI_REASON),
    "timecode/cli/__init__.py": (3, CLI_REASON),
    "dome_calib/__init__.py": (1, "dome_calib.load_bundle / write_bundle without loading numpy on `import dome_calib`"),
    "projector/__init__.py": (1, "projector.run_sfm without loading pycolmap on `import projector`"),
    "dome_calib/report/build.py": (1, "matplotlib (~0.5 s) only when a report with plots is written"),
    "dome_calib/pipeline/cluster.py": (2, "dask.distributed (~0.5 s) only when a run is given --scheduler"),
    "dome_calib/schema.py": (1, "opencv only where a YAML file is read: the schemas load without it"),
}
#: The commands that run the synthetic generators (and only they, besides tests and bench, may import them).
SYNTH_ENTRY_POINTS = {"dome_calib.cli.synth", "dome_calib.cli.kinect", "dome_calib.pipeline.demo"}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str, path: Path) -> list[tuple[str, int, bool]]:
    """(imported project module, line, inside a function) for every import of the file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    in_function = {id(sub) for fn in ast.walk(tree) if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef))
                   for sub in ast.walk(fn) if isinstance(sub, (ast.Import, ast.ImportFrom))}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = module if path.name == "__init__.py" else module.rpartition(".")[0]
                for _ in range(node.level - 1):
                    pkg = pkg.rpartition(".")[0]
                base = f"{pkg}.{base}" if base else pkg
            # `from pkg import sub` imports the submodule; `from mod import name` the module
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for t in targets:
            target = _resolve(t)
            if target and target != module:
                found.append((target, node.lineno, id(node) in in_function))
    return found


IMPORTS = {m: _imports(m, p) for m, p in MODULES.items()}


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    graph = {m: sorted({t for t, _, _ in imps}) for m, imps in IMPORTS.items()}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_circle_of_files():
    assert _cycles() == []


def test_the_checker_sees_a_circle():
    """The check can fail: a made-up back edge from the foundation to a pipeline is a circle."""
    IMPORTS["dome_calib.bundle"].append(("dome_calib.pipeline.full", 0, False))
    try:
        assert any("dome_calib.bundle" in c and "dome_calib.pipeline.full" in c for c in _cycles())
    finally:
        IMPORTS["dome_calib.bundle"].pop()


def test_projector_does_not_know_the_solver_pipelines_report_or_synth():
    banned = ("dome_calib.ba", "dome_calib.pipeline", "dome_calib.report", "dome_calib.synth")
    bad = [(m, t, line) for m, imps in IMPORTS.items() if m.split(".")[0] == "projector"
           for t, line, _ in imps if t.startswith(banned)]
    assert bad == []


def test_production_does_not_import_synthetic_generators():
    bad = [(m, t, line) for m, imps in IMPORTS.items()
           if not m.startswith("dome_calib.synth") and m not in SYNTH_ENTRY_POINTS
           for t, line, _ in imps if t.startswith("dome_calib.synth")]
    assert bad == []


def test_imports_inside_functions_are_listed_with_their_reason():
    counts: dict[str, int] = {}
    for path in MODULES.values():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        statements = {id(sub) for fn in ast.walk(tree) if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef))
                      for sub in ast.walk(fn) if isinstance(sub, (ast.Import, ast.ImportFrom))}
        if statements:  # import statements of any module, ours or not, inside a function
            counts[path.relative_to(ROOT).as_posix()] = len(statements)
    assert counts == {f: n for f, (n, _) in IN_FUNCTION_ALLOWED.items()}
    # 80 before the one-way-house refactor (29 after; + --scheduler's 1, `session`'s 4, synth --scheduler's 1;
    # calibrate's options from pipeline.types 1; the progress bars of calibrate, demo and session 3)
    assert sum(counts.values()) == 55  # + reconstruct's 4 (and --images' 1), export / import's 4, export-people / people-page's 4,
    # the schemas' YAML reader's 1, the scheduler check's 1, kinect's bundle file kinds 1


# ---- the floors ------------------------------------------------------------------------------------------------
FOUNDATION, STAGE, PIPELINE, CLI = 1, 2, 3, 4
CLI_FOLDERS = ("dome_calib.cli", "timecode.cli")
PIPELINES = ("dome_calib.pipeline", "timecode.sync.pipeline")
SYNTH = "dome_calib.synth"


def _under(module: str, packages: tuple[str, ...] | str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in ((packages,) if isinstance(packages, str)
                                                                 else packages))


def floor_and_room(module: str) -> tuple[int, str]:
    """(floor, room) of a module: the room is the package it belongs to (the foundation: its top package)."""
    parts = module.split(".")
    if _under(module, CLI_FOLDERS):
        return CLI, ".".join(parts[:2])
    if _under(module, PIPELINES) or _under(module, SYNTH):  # the generators stand apart, beside the pipelines
        return PIPELINE, ".".join(parts[:2])
    if parts[0] == "projector":
        return STAGE, "projector"
    if _under(module, "dome_calib.executor") or len(parts) == 1 or (
            len(parts) == 2 and parts[0] in ("dome_calib", "timecode") and MODULES[module].name != "__init__.py"):
        return FOUNDATION, parts[0]  # dome_calib.<module>.py, timecode.<module>.py, the packages' __init__
    return STAGE, ".".join(parts[:2])


def _house_violations(imports: dict[str, list[tuple[str, int, bool]]]) -> list[tuple[str, str, int]]:
    bad = []
    for module, imps in imports.items():
        floor, room = floor_and_room(module)
        for target, line, _ in imps:
            t_floor, t_room = floor_and_room(target)
            if t_floor > floor:  # up a floor
                bad.append((module, target, line))
            elif floor <= STAGE and t_room != room and t_floor != FOUNDATION:  # a stage reaching into another room
                bad.append((module, target, line))
    return bad


def test_floors_every_module_has_one():
    floors = {m: floor_and_room(m)[0] for m in MODULES}
    assert floors["dome_calib.camera"] == FOUNDATION and floors["dome_calib.executor.dask"] == FOUNDATION
    assert floors["timecode.rates"] == FOUNDATION and floors["projector.sfm"] == STAGE
    assert floors["dome_calib.ba.solver"] == STAGE and floors["timecode.decode.decoder"] == STAGE
    assert floors["dome_calib.pipeline.full"] == PIPELINE and floors["timecode.sync.pipeline"] == PIPELINE
    assert floors["dome_calib.cli"] == CLI and floors["timecode.cli.sync_command"] == CLI


def test_only_pipelines_cli_and_synth_import_across_rooms_and_nothing_imports_up():
    assert _house_violations(IMPORTS) == []


def test_the_house_check_can_fail():
    """A stage reaching into another stage's room, and the foundation importing a pipeline, are caught."""
    fake = {"projector.sfm": [("dome_calib.ba.solver", 1, False)],
            "dome_calib.camera": [("dome_calib.pipeline.full", 2, False)],
            "dome_calib.pipeline.full": [("projector.sfm", 3, False), ("dome_calib.ba.solver", 4, False)]}
    assert _house_violations(fake) == [("projector.sfm", "dome_calib.ba.solver", 1),
                                       ("dome_calib.camera", "dome_calib.pipeline.full", 2)]


def _third_party(path: Path) -> set[str]:
    """Top-level names of every module the file imports (at module level or in a function)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def test_rich_and_typer_only_under_the_cli_folders():
    users = {m for m, path in MODULES.items() if _third_party(path) & {"rich", "typer"}}
    assert users and all(_under(m, CLI_FOLDERS) for m in users), sorted(m for m in users if not _under(m, CLI_FOLDERS))


def _imported_by(code: str, *argv: str) -> set[str]:
    """Top-level modules that ``python -X importtime -c code argv...`` imports (its stderr's last column)."""
    run = subprocess.run([sys.executable, "-X", "importtime", "-c", code, *argv], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    return {line.rsplit("|", 1)[-1].strip().split(".")[0] for line in run.stderr.splitlines()
            if line.startswith("import time:") and "|" in line}


@pytest.mark.parametrize("module", ["dome_calib.cli", "timecode.cli", "timecode"])
def test_the_shells_start_without_numpy(module):
    loaded = _imported_by(f"import {module}")
    assert "typer" in loaded or module == "timecode"  # the check sees imports (it can fail)
    assert not loaded & {"numpy", "scipy", "pydantic"}, module  # the schemas load when a command reads a file


def test_timecode_help_loads_neither_numpy_nor_scipy():
    loaded = _imported_by("import sys; from timecode.cli import main; sys.argv = ['timecode', '--help']; main()")
    assert "typer" in loaded  # the check sees imports (it can fail)
    assert not loaded & {"numpy", "scipy"}
