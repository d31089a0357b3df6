"""The hostile matrix (issue 50): every command of the `dome-calib` and `timecode` applications, enumerated from the
applications themselves, crossed with the situation kinds of :mod:`.catalogue`, judged by :mod:`.oracle`.

The refusal kinds run for every command; the kinds whose run may go through (names as paths, an output inside an
input) are sampled with a fixed seed, and SIGTERM is sent to the long runs, so the matrix stays within CI's time.
Each command that reads files is crossed with a sample of the input-content kinds (:mod:`.contents`: a non-finite or
huge number, an empty file, a file cut in half, sequences of one frame), one file of its inputs changed in the case's
sandbox copy; a refusal must then name that file.
A command without a catalogue entry fails :func:`test_every_command_has_a_catalogue_entry`.
"""
from __future__ import annotations

import logging
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import typer.main

from ..cli_runner import run_in_process
from .catalogue import ENTRIES, KINDS, NAME_VALUES, REFUSE, Entry
from .contents import CONTENT_KINDS, NUMBER_VALUES, files_of, mutate
from .inputs import Inputs, rooted
from .oracle import judge, snapshot
from .same_bytes import REFUSED, run_twice, seconds_hidden

ROOT = Path(__file__).resolve().parents[2]
SEED = 50  # the number: the sample is the same on every run and machine
NAMES_PER_COMMAND = 3
INSIDE_INPUT_CASES = 6
CONTENTS_PER_COMMAND = 3  # input-content kinds of each entry that reads files (a number's value drawn too)


def _commands() -> dict[str, str]:
    """Command name -> its program, from the typer applications themselves."""
    from dome_calib.cli import app as dome_app
    from timecode.cli import app as timecode_app

    found = {}
    for prog, app in (("dome-calib", dome_app), ("timecode", timecode_app)):
        for name in typer.main.get_command(app).commands:
            found[name] = prog
    return found


def test_every_command_has_a_catalogue_entry():
    commands = _commands()
    missing = sorted(set(commands) - set(ENTRIES))
    assert not missing, f"commands without a hostile-matrix entry (tests/hostile/catalogue.py): {missing}"
    assert sorted(set(ENTRIES) - set(commands)) == [], "catalogue entries of commands that do not exist"
    for name, entries in ENTRIES.items():
        assert all(e.prog == commands[name] for e in entries), name


def _kinds(entry: Entry) -> list[str]:
    if entry.output == "none":
        return ["reads only"]
    kinds = ["foreign", "symlink", "wrong type"]
    if not (entry.out_at is not None and os.geteuid() == 0):  # as root only a path outside the sandbox is read-only
        kinds.append("read-only")
    if _has_inputs(entry):
        kinds.append("equals input")
    return kinds


def _has_inputs(entry: Entry) -> bool:
    return entry.inputs is not None and entry.out_at is None


def _reads(entry: Entry):
    return entry.reads or entry.inputs


def _cases() -> list[tuple[str, int, str, str]]:
    """(command, entry index, kind, value): every refusal kind, and the sample of the others."""
    rng = random.Random(SEED)
    content_rng = random.Random(f"{SEED}:contents")  # its own: the other kinds' sample is unchanged by it
    cases, optional = [], []
    for name, entries in sorted(ENTRIES.items()):
        for k, entry in enumerate(entries):
            cases += [(name, k, kind, "") for kind in _kinds(entry)]
            if entry.names is not None:
                cases += [(name, k, "names", v) for v in rng.sample(NAME_VALUES, NAMES_PER_COMMAND)]
            if entry.long is not None:
                cases.append((name, k, "sigterm", ""))
            if entry.output != "none" and _has_inputs(entry):
                optional.append((name, k, "inside input", ""))
            if _reads(entry) is not None:
                for kind in content_rng.sample(entry.contents, min(CONTENTS_PER_COMMAND, len(entry.contents))):
                    cases.append((name, k, kind, content_rng.choice(NUMBER_VALUES) if kind == "number" else ""))
    return cases + rng.sample(optional, min(INSIDE_INPUT_CASES, len(optional)))


CASES = _cases()


def _unwritable(sandbox: Path) -> Path:
    if os.geteuid() != 0:
        ro = sandbox / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        return ro
    return Path("/sys") / "dome-calib-hostile"  # sysfs refuses new entries to root too


def _situation(entry: Entry, kind: str, i: Inputs, sandbox: Path, rng: random.Random) -> tuple[Path, tuple[str, ...]]:
    """Make the situation; returns the output path and what a refusal may name instead of it."""
    out = entry.out_at(sandbox) if entry.out_at is not None else sandbox / entry.out_name
    if kind == "foreign":
        if entry.output == "file":
            out.write_text("someone else's file")
            return out, ()
        for rel in entry.ours:
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            (out / rel).write_text(f"someone else's {rel}")
        return out, tuple(Path(rel).parts[0] for rel in entry.ours) + entry.ours
    if kind == "symlink":
        shutil.rmtree(out, ignore_errors=True)
        if entry.output == "file":
            (sandbox / "elsewhere.txt").write_text("theirs")
            out.symlink_to(sandbox / "elsewhere.txt")
        else:
            (sandbox / "elsewhere").mkdir()
            (sandbox / "elsewhere" / "theirs.txt").write_text("theirs")
            out.symlink_to(sandbox / "elsewhere", target_is_directory=True)
        return out, ()
    if kind == "wrong type":
        shutil.rmtree(out, ignore_errors=True)
        if entry.output == "file":
            out.mkdir()
            (out / "theirs.txt").write_text("theirs")
        else:
            out.write_text("someone's file")
        return out, ()
    if kind == "read-only":
        if entry.out_at is not None:
            out.parent.chmod(0o555)
            return out, ()
        return _unwritable(sandbox) / entry.out_name, ()
    if kind == "equals input":
        return rng.choice(entry.inputs(i)), ()
    if kind == "inside input":
        folders = [p if p.is_dir() else p.parent for p in entry.inputs(i)]
        return rng.choice(folders) / entry.out_name, ()
    return out, ()


def _run_in_process(entry: Entry, args: list, monkeypatch, capsys) -> subprocess.CompletedProcess:
    """As the console script runs, its log lines on stderr too, through the commands' own handler (pytest's handlers
    keep run_cli from adding it: the log is judged like the rest of what is printed)."""
    from dome_calib.errors import console_handler

    if entry.prog == "timecode":
        from timecode.cli import main
    else:
        from dome_calib.cli import main
    root = logging.getLogger()
    handler = console_handler(entry.prog)  # on the captured stderr
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    try:
        return run_in_process(main, entry.prog, args, monkeypatch, capsys)
    finally:
        root.removeHandler(handler)
        root.setLevel(level)


def _run_and_stop(entry: Entry, args: list, sandbox: Path) -> subprocess.CompletedProcess:
    """Run in a process of its own and send SIGTERM once the run is midway (``entry.started``)."""
    module = "timecode.cli" if entry.prog == "timecode" else "dome_calib.cli"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", f"from {module} import main; main()", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=sandbox)
    deadline = time.monotonic() + 60
    while proc.poll() is None and not entry.started(sandbox) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess([entry.prog, *map(str, args)], proc.returncode, out, err)


@pytest.mark.parametrize("command,index,kind,value", CASES,
                         ids=[f"{c}{'[' + ENTRIES[c][k].variant + ']' if ENTRIES[c][k].variant else ''}-{kind}"
                              + (f"-{NAME_VALUES.index(v)}" if kind == "names" else f"-{v}" if v else "")
                              for c, k, kind, v in CASES])
def test_hostile_matrix(command, index, kind, value, hostile_inputs, tmp_path, monkeypatch, capsys):
    entry = ENTRIES[command][index]
    sandbox = tmp_path / "sandbox"
    sandbox.mkdir()
    i = rooted(hostile_inputs, sandbox / "in")
    shutil.copytree(hostile_inputs.root, i.root, symlinks=True)
    if entry.setup is not None:
        entry.setup(i, sandbox)
    rng = random.Random(f"{SEED}:{command}:{index}:{kind}")
    out, names = _situation(entry, kind, i, sandbox, rng)
    named = ()
    if kind in CONTENT_KINDS:  # a refusal names the file changed (or its folder)
        named = tuple(p.name for p in mutate(kind, value, files_of(_reads(entry)(i)), rng))
        named += (entry.stops,) if entry.stops else ()
    monkeypatch.chdir(sandbox)  # a default output lands in the sandbox
    before = snapshot(sandbox)
    try:
        if kind == "names":
            args = entry.names(i, out, value.format(sandbox=sandbox))
        elif kind == "sigterm":
            args = entry.long(i, out)
        else:
            args = entry.argv(i, out)
        if kind == "sigterm":
            done = _run_and_stop(entry, args, sandbox)
            assert done.returncode == 130, (done.returncode, done.stderr)
        else:
            done = _run_in_process(entry, args, monkeypatch, capsys)
    finally:
        if kind == "read-only" and entry.out_at is not None:
            out.parent.chmod(0o755)
        if (sandbox / "ro").exists():
            (sandbox / "ro").chmod(0o755)
    after = snapshot(sandbox)
    if kind == "sigterm" and out.is_dir() and not any(out.iterdir()):
        after.pop(str(out.relative_to(sandbox)), None)  # the output folder itself, left empty: nothing written
    if kind == "read-only" and not out.is_relative_to(sandbox):
        assert not os.path.lexists(out)
    judge(done, before, after, sandbox=sandbox, out=out, also=entry.also(out), must_refuse=kind in REFUSE | {"sigterm"},
          names=names, named=named)


def test_the_catalogue_names_its_kinds():
    assert {kind for _, _, kind, _ in CASES} <= set(KINDS)


def test_the_same_bytes_normalisation_hides_timings_only():
    doc = '{"stage_seconds": {"sfm": 23.8, "ba": 2.6}, "seconds": 1.5e-3, "focal": 1308.11}'
    assert seconds_hidden(doc) == '{"stage_seconds": T, "seconds": T, "focal": 1308.11}'


def _same_bytes(hostile_inputs, tmp_path, heavy: bool) -> None:
    runs = run_twice(hostile_inputs, tmp_path, heavy=heavy)
    assert runs.codes[0] == runs.codes[1], dict(zip(runs.labels, zip(*runs.codes)))
    refused = {label for label, code in zip(runs.labels, runs.codes[0]) if code != 0}
    expected = set() if heavy else set(REFUSED)
    assert refused == expected, f"these did not go through (nothing of theirs compared): {refused - expected}"
    differ = runs.differing()
    assert differ == [], f"not the same bytes in two runs: {differ}"


def test_every_command_writes_the_same_bytes_twice(hostile_inputs, tmp_path):
    """Every writer but the heavy ones, twice in two processes at once: every file the same (.same_bytes)."""
    _same_bytes(hostile_inputs, tmp_path, heavy=False)


@pytest.mark.slow
def test_the_heavy_commands_write_the_same_bytes_twice(hostile_inputs, tmp_path):
    """calibrate (five VGA images), synth and kinect-synth, twice in two processes at once (~1 min on 2 cores)."""
    _same_bytes(hostile_inputs, tmp_path, heavy=True)
