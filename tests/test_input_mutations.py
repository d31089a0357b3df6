"""Every input file's schema under mutation (issue 42): each field of a valid example set to another type, null,
NaN, infinity, out of range, removed, duplicated, or an unknown field added (hypothesis, derandomized: the same
examples on every run). Reading the mutated file either gives a result or fails with the reader's own error in one
line that starts with the file and, for a schema refusal, names the field that was changed; never another
exception. The examples and readers are the registry of docs/inputs.md (tests/input_schemas.py)."""
from __future__ import annotations

import copy
import json
import math
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dome_calib.schema import field_path

from .input_schemas import FILES, example

SETTINGS = settings(derandomize=True, database=None, max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

RETYPES = ["x", "", None, True, False, [], [1], {}, {"a": 1}, 0, -1, 1.5, 10**30, "10:00:00:00"]
NUMBERS = [math.nan, math.inf, -math.inf, 1e308, -1e308, -1, 2**63, 2**64]
SCHEMA_WORDS = ("expected", "missing", "unknown field")


def _places(obj, prefix=()):
    """Every place in a JSON document (a tuple of keys and indices)."""
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _places(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _places(v, (*prefix, i))
    return out


def _parent(obj, place):
    for key in place[:-1]:
        obj = obj[key]
    return obj


@st.composite
def mutated(draw, base):
    """(document, the places changed): 1-2 mutations of the base."""
    doc = copy.deepcopy(base)
    changed = []
    for _ in range(draw(st.integers(1, 2))):
        places = _places(doc)
        kind = draw(st.sampled_from(["retype", "number", "remove", "unknown", "duplicate"]))
        if kind == "unknown":
            objects = [()] + [p for p in places if isinstance(_parent(doc, (*p, None)), dict)]
            place = draw(st.sampled_from(objects))
            target = _parent(doc, (*place, None))
            target["zz_unknown"] = draw(st.sampled_from(RETYPES))
            changed.append((*place, "zz_unknown"))
            continue
        if not places:
            break
        place = draw(st.sampled_from(places))
        parent, key = _parent(doc, place), place[-1]
        if kind == "retype":
            parent[key] = copy.deepcopy(draw(st.sampled_from(RETYPES)))
        elif kind == "number":
            parent[key] = draw(st.sampled_from(NUMBERS))
        elif kind == "remove":
            del parent[key]
        elif kind == "duplicate" and isinstance(parent, list):
            parent.insert(key, copy.deepcopy(parent[key]))
        elif kind == "duplicate":
            continue
        changed.append(place)
    return doc, changed


def _check(f, doc, changed, base=None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        try:
            _, result = f.read(folder, doc)
        except Exception as exc:  # noqa: BLE001 - which one is the point
            assert isinstance(exc, f.error()), f"{f.name}: {type(exc).__name__}: {exc}"
            message = str(exc)
            assert "\n" not in message and "\r" not in message and len(message) < 700, message
            assert message.startswith(str(folder)), message  # names the file (or the file a field names)
            if any(w in message for w in SCHEMA_WORDS) and f.file_name in message.split(": ")[0]:
                # the place changed, or (a check across fields) another field of the file, or the file itself
                heads = {field_path(place[:1]) for place in changed} | {"the file"}
                heads |= {field_path((k,)) for k in (base if isinstance(base, dict) else {})}
                assert any(f": {h}" in message for h in heads), (message, changed)
            return
    assert result is not None


@pytest.mark.parametrize("f", FILES, ids=[f.name for f in FILES])
def test_the_unchanged_example_reads(f):
    _check(f, example(f), [])
    with tempfile.TemporaryDirectory() as tmp:
        assert f.read(Path(tmp), example(f))[1] is not None


@pytest.mark.parametrize("f", FILES, ids=[f.name for f in FILES])
def test_a_mutated_file_reads_or_fails_in_one_line_naming_file_and_field(f):
    @SETTINGS
    @given(mutated(example(f)))
    def run(case):
        doc, changed = case
        _check(f, doc, changed, example(f))

    run()


def _refusal(f, doc) -> str:
    """The one line reading ``doc`` gives (it must be refused)."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            f.read(Path(tmp), doc)
        except Exception as exc:  # noqa: BLE001
            assert isinstance(exc, f.error()), f"{f.name}: {type(exc).__name__}: {exc}"
            assert "\n" not in str(exc)
            return str(exc)
    raise AssertionError(f"{f.name}: read without complaint: {json.dumps(doc)[:300]}")


def _schema_node(f, place):
    from dome_calib.schema import _node_at, _resolve

    node, defs = _node_at(f.schema(), tuple(place))
    return None if node is None else _resolve(node, defs)


@pytest.mark.parametrize("f", FILES, ids=[f.name for f in FILES])
def test_each_field_set_to_null_nan_or_removed_or_joined_by_an_unknown_one(f):
    """Every place of the example, one at a time: NaN at a number is refused naming the place, a required field
    removed is refused as missing, an unknown field in an object whose schema is closed is refused as unknown
    (where the schema keeps or ignores others' fields, it reads); null and removal anywhere read or fail in one
    line."""
    base = example(f)
    for place in _places(base):
        leaf = _parent(base, place)[place[-1]]
        for value in (None, math.nan, "removed"):
            doc = copy.deepcopy(base)
            parent = _parent(doc, place)
            if value == "removed":
                del parent[place[-1]]
            else:
                parent[place[-1]] = value
            _check(f, doc, [place], base)
            if value is math.nan and isinstance(leaf, (int, float)) and not isinstance(leaf, bool):
                message = _refusal(f, doc)
                # a column written [[a], [b], ...] is read flat: its place is then named without the last index
                named = f"{field_path(place)}: " in message or f"{field_path(place[:-1])}: " in message
                assert named and "NaN" in message, message
            container = _schema_node(f, place[:-1])
            if value == "removed" and container and place[-1] in container.get("required", []):
                message = _refusal(f, doc)
                assert f"{field_path(place)}: missing" in message, message
    for place in [()] + [p for p in _places(base) if isinstance(_parent(base, (*p, None)), dict)]:
        doc = copy.deepcopy(base)
        _parent(doc, (*place, None))["zz_unknown"] = 1
        _check(f, doc, [(*place, "zz_unknown")], base)
        node = _schema_node(f, place)
        if node is not None and node.get("additionalProperties") is False:
            message = _refusal(f, doc)
            assert f"{field_path((*place, 'zz_unknown'))}: unknown field" in message, message
