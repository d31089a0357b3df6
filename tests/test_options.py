"""Issue 42: every options object declares its bounds as field constraints (dome_calib.options), and NaN,
infinities, values out of range or of the wrong type are refused in one line naming the class and the field, on
construction, on dataclasses.replace and on assignment. The classes are found in the source (every ``class
*Options``), so a new one cannot be forgotten; a command's flag is named as the user typed it."""
from __future__ import annotations

import ast
import dataclasses
import importlib
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.errors import OptionsError
from dome_calib.options import options_classes
from dome_calib.schema import json_schema

ROOT = Path(__file__).resolve().parents[1]


def _declared_options_classes() -> dict[str, type]:
    """Every ``class <Name>Options`` of the source, imported: ``module.Name`` -> class."""
    out = {}
    for pkg in ("dome_calib", "projector", "timecode"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            names = [n.name for n in tree.body if isinstance(n, ast.ClassDef) and n.name.endswith("Options")]
            if not names:
                continue
            module = importlib.import_module(".".join(path.relative_to(ROOT).with_suffix("").parts))
            out.update({f"{module.__name__}.{n}": getattr(module, n) for n in names})
    return out


DECLARED = _declared_options_classes()


def test_every_options_class_of_the_source_is_declared_with_its_bounds():
    assert len(DECLARED) >= 42  # the scan sees the classes (it can fail)
    undeclared = sorted(name for name, cls in DECLARED.items() if cls not in options_classes())
    assert undeclared == [], "declare these with @dome_calib.options.options"


def _resolve(node: dict, defs: dict) -> dict:
    while "$ref" in node:
        node = defs[node["$ref"].rsplit("/", 1)[-1]]
    return node


def _bad_values(node: dict, defs: dict) -> list:
    """Values a field of this JSON-schema node must refuse: wrong types, non-finite numbers, just out of range."""
    options = [_resolve(o, defs) for o in node.get("anyOf", [node])]
    nullable = any(o.get("type") == "null" for o in options)
    scalar = next((o for o in options if o.get("type") in ("number", "integer", "boolean", "string") or "enum" in o
                   or "const" in o), None)
    if scalar is None:
        return []
    bad: list = [[1, 2]] + ([] if nullable else [None])  # a list where one value belongs; null where none may be
    kind = scalar.get("type")
    if "enum" in scalar or "const" in scalar:
        return bad + ["<no such choice>"] + ([] if kind == "integer" else [0])
    if kind == "boolean":
        return bad + [1, "yes"]
    if kind == "string":
        return bad + [3]
    bad += [math.nan, math.inf, -math.inf, True, "2"]
    integer = kind == "integer"
    if integer:
        bad.append(2.5)
    if "minimum" in scalar:
        bad.append(scalar["minimum"] - 1 if integer else math.nextafter(scalar["minimum"], -math.inf))
    if "exclusiveMinimum" in scalar:
        bad.append(scalar["exclusiveMinimum"])
    if "maximum" in scalar:
        bad.append(scalar["maximum"] + 1 if integer else math.nextafter(scalar["maximum"], math.inf))
    if "exclusiveMaximum" in scalar:
        bad.append(scalar["exclusiveMaximum"])
    return bad


def _tuple_bad_values(node: dict, defs: dict) -> list:
    """A tuple field (``(width, height)``, ``(r1, r2, ...)``): the default's shape with its first item bad."""
    out = []
    for option in (_resolve(o, defs) for o in node.get("anyOf", [node])):
        if option.get("type") != "array":
            continue
        items = option.get("prefixItems") or [option.get("items", {})]
        n = len(option.get("prefixItems") or [None])
        good = [0.5] * n
        out += [tuple([bad] + good[1:]) for bad in _bad_values(_resolve(items[0], defs), defs) if bad is not None]
    return out


def _cases() -> list[tuple[str, str, object]]:
    cases = []
    for name, cls in sorted(DECLARED.items()):
        schema = json_schema(cls)
        defs = schema.get("$defs", {})
        for field, node in schema["properties"].items():
            cases += [(name, field, value) for value in _bad_values(node, defs) + _tuple_bad_values(node, defs)]
    return cases


CASES = _cases()


def test_every_class_has_fields_checked():
    checked = {name for name, _, _ in CASES}
    assert len(CASES) > 1000
    # classes whose every field is a nested options object, a free-form mapping or an object of a library class
    assert set(DECLARED) - checked <= {"dome_calib.pipeline.session.SessionOptions"}


def _one_line_refusal(cls: type, field: str, value: object, make) -> None:
    with pytest.raises(OptionsError) as exc:
        make()
    text = str(exc.value)
    assert "\n" not in text and text.startswith(f"{cls.__name__}: {field}") and text[len(cls.__name__) + len(field)
                                                                                  + 2] in " [", text
    assert "expected" in text, text


@settings(max_examples=400, derandomize=True, deadline=None)
@given(case=st.sampled_from(CASES))
def test_a_bad_value_in_any_options_field_is_refused_in_one_line(case):
    """NaN, infinities, out of range, wrong type, null: on construction, on replace and on assignment."""
    name, field, value = case
    cls = DECLARED[name]
    _one_line_refusal(cls, field, value, lambda: cls(**{field: value}))
    default = cls()
    _one_line_refusal(cls, field, value, lambda: dataclasses.replace(default, **{field: value}))
    _one_line_refusal(cls, field, value, lambda: setattr(default, field, value))
    assert dataclasses.asdict(default) == dataclasses.asdict(cls())  # the refused assignment changed nothing


@pytest.mark.parametrize("name", sorted(DECLARED))
def test_defaults_are_taken_and_an_unknown_option_is_refused(name):
    cls = DECLARED[name]
    made = cls()
    assert dataclasses.replace(made) == made
    with pytest.raises(OptionsError, match=rf"^{cls.__name__}: no_such_option: no such option$"):
        cls(no_such_option=1)


def test_the_situations_of_the_issue():
    """RefineOptions checked nothing (window_sigma = 0 divided by zero in the patch weights); a `<=` check let NaN
    through; a check across fields reads as one line too."""
    from dome_calib.recon.people.proposals import AssociationOptions
    from projector.refine import RefineOptions
    from timecode.sync.tables import SyncOptions

    with pytest.raises(OptionsError, match=r"^RefineOptions: window_sigma 0.0: expected a finite number > 0$"):
        RefineOptions(window_sigma=0.0)
    with pytest.raises(OptionsError, match=r"^SyncOptions: max_extrapolation_s NaN: expected a finite number >= 0$"):
        SyncOptions(max_extrapolation_s=math.nan)
    with pytest.raises(OptionsError, match=r"^AssociationOptions: bone_ratio \(1.5, 0.6\): expected \(low, high\) "
                                           r"with low <= high$"):
        AssociationOptions(bone_ratio=(1.5, 0.6))


@pytest.mark.parametrize("args, line", [
    (["triangulate", "DET", "--bundle", "DET", "--threshold-px", "nan"], "--threshold-px NaN: expected a finite "
                                                                          "number > 0"),
    (["triangulate", "DET", "--bundle", "DET", "--min-views", "1"], "--min-views 1: expected an integer >= 2"),
    (["synth", "OUT", "--workers", "0"], "--workers 0: expected an integer >= 1"),
    (["synth", "OUT", "--scenes", "0"], "--scenes 0: expected an integer >= 1 and <= 99"),
    (["demo", "-o", "OUT", "--people", "11"], "--people 11: expected an integer >= 0 and <= 10"),
])
def test_a_flag_out_of_bounds_is_named_as_typed(tmp_path, dome_calib_cli, args, line):
    """The issue's case: `--min-views 1` answered with four internal field names (reconstruct's own flags are
    named by recon.people.commands.people_options: tests/test_reconstruct_situations.py)."""
    args = [str(tmp_path / "x") if a in ("DET", "OUT") else a for a in args]
    done = dome_calib_cli(*args)
    assert done.returncode == 1 and done.stderr == f"dome-calib: error: {line}\n"
    assert not (tmp_path / "x").exists()


def test_timecode_sync_flag_is_named_as_typed(tmp_path, monkeypatch, capsys):
    from timecode.cli import main

    from .cli_runner import run_in_process

    done = run_in_process(main, "timecode", ["sync", tmp_path, "-o", tmp_path / "b", "--max-extrapolation", "-1"],
                          monkeypatch, capsys)
    assert done.returncode == 1 and done.stderr == "timecode: error: --max-extrapolation -1.0: expected a finite " \
                                                   "number >= 0\n"
