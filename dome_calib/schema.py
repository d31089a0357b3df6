"""Every file a user hands us is read through one schema, declared once (pydantic v2).

A schema is a class deriving from :class:`FileSchema`: strict types (``true`` is not a channel number, ``"2"`` is not
a number), unknown fields refused, NaN and infinities refused, bounds as field constraints
(``Annotated[int, Field(ge=0)]``). Fixed-size arrays are lists with a length (``Vec3``, ``Matrix3``), not tuples, so
that JSON, TOML and YAML read the same. Where another tool's file carries fields we do not use, its schema derives
from :class:`OpenSchema` (unknown fields ignored), and says so.

The readers (:func:`read_json`, :func:`read_toml`, :func:`read_yaml`, :func:`validate`) turn the first failure into
one line naming the file, the field path and what was expected, e.g.::

    session.json: ltc.vga_channel: expected an integer >= 0, got false

What is expected is read from the schema itself (its JSON schema at the failing field), so the message and the
documentation of the file (:func:`describe_schema`) cannot drift apart. Every value shown is the file's own,
``repr``-quoted and cut to 40 characters: a message is plain text, never markup.

pydantic was chosen against msgspec by ``bench/schema_choice.py``: the same speed on 100,000 OpenPose files, and
pydantic's errors carry the failing field as a path, the input and the failed constraint, which msgspec gives only as
an English sentence (and without a position for truncated JSON).
"""
from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar

import pydantic
from pydantic import BaseModel, ConfigDict, Field

from dome_calib.errors import DomeCalibError

__all__ = ["FileSchema", "OpenSchema", "InputFileError", "Finite", "NonNegInt", "PosInt", "PosFinite",
           "NonNegFinite", "Vec", "Vec3", "Matrix3", "Matrix4", "read_json", "read_toml", "read_yaml", "validate",
           "parse_json", "field_path", "describe_schema", "Field"]

M = TypeVar("M", bound=BaseModel)


class InputFileError(DomeCalibError, ValueError):
    """A file a user handed us does not match its schema; the message names the file and the field path."""


class FileSchema(BaseModel):
    """Base of every input file's schema: strict types, unknown fields refused, NaN/inf refused, immutable."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True,
                              validate_default=False, hide_input_in_errors=False)


class OpenSchema(FileSchema):
    """A schema for another tool's file whose extra fields are none of our business (they are ignored)."""

    model_config = ConfigDict(extra="ignore")


Finite = Annotated[float, Field(allow_inf_nan=False)]
PosFinite = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFinite = Annotated[float, Field(ge=0, allow_inf_nan=False)]
#: Integers go into numpy int64 arrays: bounded so that a 400-digit number is refused, not overflowed.
INT64_MAX = 2**63 - 1
NonNegInt = Annotated[int, Field(ge=0, le=INT64_MAX)]
PosInt = Annotated[int, Field(ge=1, le=INT64_MAX)]


def Vec(n: int, item: Any = Finite) -> Any:  # noqa: N802 (a type constructor)
    """A list of exactly ``n`` items (default: finite numbers)."""
    return Annotated[list[item], Field(min_length=n, max_length=n)]


Vec3 = Vec(3)
Matrix3 = Vec(3, Vec3)
Matrix4 = Vec(4, Vec(4))


# ---- reading --------------------------------------------------------------------------------------------------

def parse_json(source: str | Path, data: bytes, schema: type[M], *, error: type[Exception] = InputFileError) -> M:
    """``data`` (the bytes of the JSON file ``source``) validated by ``schema``; ``error`` with one line otherwise."""
    try:
        return schema.model_validate_json(data)
    except pydantic.ValidationError as exc:
        raise error(one_line(source, exc, schema)) from None


def read_json(path: str | Path, schema: type[M], *, error: type[Exception] = InputFileError) -> M:
    """The JSON file ``path`` validated by ``schema``; ``error`` naming the file and the field otherwise."""
    return parse_json(path, _read_bytes(path, error), schema, error=error)


def read_toml(path: str | Path, schema: type[M], *, error: type[Exception] = InputFileError) -> M:
    """The TOML file ``path`` validated by ``schema``; ``error`` naming the file and the field otherwise."""
    raw = _read_bytes(path, error)
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise error(f"{path}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None
    return validate(data, schema, source=path, error=error)


def read_yaml(path: str | Path, schema: type[M], *, error: type[Exception] = InputFileError) -> M:
    """The OpenCV FileStorage YAML file ``path`` (matrices as ``!!opencv-matrix``) read with OpenCV, validated by
    ``schema`` (matrices as nested lists, top-level keys as fields)."""
    import cv2  # noqa: PLC0415 (opencv only where a YAML file is read: the schemas load without it)

    _read_bytes(path, error)  # a missing or unreadable file named as such, not as OpenCV's message
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV 5's binding raises SystemError for some parse errors
        raise error(f"{path}: not a YAML file OpenCV can read ({str(exc).strip().splitlines()[-1]})") from None
    try:
        if not fs.isOpened():
            raise error(f"{path}: not a YAML file OpenCV can read")
        data = {key: _node_value(fs.getNode(key)) for key in fs.root().keys()}
    finally:
        fs.release()
    return validate(data, schema, source=path, error=error)


def _node_value(node: Any) -> Any:
    """An OpenCV FileNode as plain Python: a matrix as nested lists, a sequence as a list, a map as a dict."""
    if node.isMap():
        mat = node.mat()
        if mat is not None:
            return mat.tolist()
        return {key: _node_value(node.getNode(key)) for key in node.keys()}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def validate(data: Any, schema: type[M], *, source: str | Path, error: type[Exception] = InputFileError) -> M:
    """Already-parsed ``data`` (from TOML, YAML, a JSON object inside another) validated by ``schema``."""
    try:
        return schema.model_validate(data)
    except pydantic.ValidationError as exc:
        raise error(one_line(source, exc, schema)) from None


def _read_bytes(path: str | Path, error: type[Exception]) -> bytes:
    try:
        return Path(path).read_bytes()
    except IsADirectoryError:
        raise error(f"{path}: is a folder, expected a file") from None
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror})") from None


# ---- the one line -----------------------------------------------------------------------------------------------

def field_path(loc: tuple[int | str, ...]) -> str:
    """pydantic's ``loc`` as a path: ``("ltc", "vga_channel")`` -> ``ltc.vga_channel``, ``("cameras", 3, "K")``
    -> ``cameras[3].K``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def show(value: Any, limit: int = 40) -> str:
    """A value from a file as the message shows it: JSON spelling (``false``, ``null``, ``"text"``), cut."""
    if isinstance(value, float) and not math.isfinite(value):
        text = "NaN" if math.isnan(value) else "Infinity" if value > 0 else "-Infinity"
    else:
        try:
            text = json.dumps(value, ensure_ascii=True, default=str)
        except (TypeError, ValueError):
            text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def one_line(source: str | Path, exc: pydantic.ValidationError, schema: type[BaseModel]) -> str:
    """The first failure of ``exc`` as ``source: field.path: expected ..., got ...`` (+ how many more)."""
    errors = exc.errors(include_url=False)
    err = errors[0]
    loc = tuple(err["loc"])
    kind = err["type"]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    if kind == "json_invalid":
        return f"{source}: not valid JSON ({err['msg'].removeprefix('Invalid JSON: ')}){more}"
    where = field_path(loc) or "the file"
    if kind == "missing":
        return f"{source}: {where}: missing (expected {expected_at(schema, loc)}){more}"
    if kind == "extra_forbidden":
        known = _known_fields(schema, loc[:-1])
        hint = f" (known fields: {', '.join(known)})" if known else ""
        return f"{source}: {where}: unknown field{hint}{more}"
    if kind in ("value_error", "assertion_error"):  # a model's own check: its message says what is wrong
        msg = str(err.get("ctx", {}).get("error", err["msg"])).removeprefix("Value error, ")
        return f"{source}: {where}: {msg}{more}"
    got = show(err.get("input"))
    return f"{source}: {where}: expected {expected_at(schema, loc, err)}, got {got}{more}"


def _resolve(node: dict, defs: dict) -> dict:
    while "$ref" in node:
        node = {**defs[node["$ref"].rsplit("/", 1)[-1]], **{k: v for k, v in node.items() if k != "$ref"}}
    return node


def _step(node: dict, part: int | str, defs: dict) -> dict | None:
    """The JSON schema of ``part`` (a field name, list index or dict key) inside ``node``."""
    node = _resolve(node, defs)
    for option in node.get("anyOf", []):  # unions: the first branch that has the part
        sub = _step(option, part, defs)
        if sub is not None:
            return sub
    if isinstance(part, int):
        prefix = node.get("prefixItems")
        if prefix and part < len(prefix):
            return prefix[part]
        if "items" in node:
            return node["items"]
    if isinstance(part, str):
        if part in node.get("properties", {}):
            return node["properties"][part]
        extra = node.get("additionalProperties")
        if isinstance(extra, dict):
            return extra
    return None


def _node_at(schema: type[BaseModel], loc: tuple) -> tuple[dict | None, dict]:
    root = schema.model_json_schema()
    defs = root.get("$defs", {})
    node: dict | None = root
    for part in loc:
        if node is None:
            break
        node = _step(node, part, defs)
        if node is None and isinstance(part, str) and not part.isidentifier():
            continue  # pydantic's union/function tags in the loc ("function-after[...]", "list[float]")
    return node, defs


def _known_fields(schema: type[BaseModel], loc: tuple) -> list[str]:
    node, defs = _node_at(schema, loc)
    return sorted(_resolve(node, defs).get("properties", {})) if node is not None else []


#: Every number of a FileSchema is finite (its config refuses NaN and infinities).
_TYPES = {"integer": "an integer", "number": "a finite number", "string": "a string", "boolean": "true or false",
          "array": "a list", "object": "an object", "null": "null"}


def describe_node(node: dict | None, defs: dict) -> str:
    """What a JSON-schema node accepts, in words: ``an integer >= 0``, ``a list of 3 numbers``, ``"vga" or "hd"``."""
    if node is None:
        return "a valid value"
    node = _resolve(node, defs)
    if "anyOf" in node:
        return " or ".join(dict.fromkeys(describe_node(o, defs) for o in node["anyOf"]))
    if "enum" in node:
        return " or ".join(json.dumps(v) for v in node["enum"])
    if "const" in node:
        return json.dumps(node["const"])
    kind = node.get("type")
    if kind == "object" and "properties" in node:
        return f"an object with {', '.join(node['properties'])}" if len(node["properties"]) <= 4 else "an object"
    if kind == "object" and isinstance(node.get("additionalProperties"), dict):
        return f"an object of {_plural(describe_node(node['additionalProperties'], defs))}"
    if kind == "array":
        lo, hi = node.get("minItems"), node.get("maxItems")
        count = (f"{lo} " if lo == hi and lo is not None else f"at least {lo} " if lo else
                 f"at most {hi} " if hi is not None else "")
        items = node.get("items") or (node.get("prefixItems") or [None])[0]
        return f"a list of {count}{_plural(describe_node(items, defs))}" if items else f"a list of {count}items"
    words = _TYPES.get(kind, kind or "a value")
    bounds = [f"{op} {node[key]:g}" if isinstance(node[key], float) else f"{op} {node[key]}"
              for key, op in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="),
                              ("exclusiveMaximum", "<")) if key in node]
    if kind == "string":
        if node.get("minLength") == 1:
            words = "a non-empty string"
        elif node.get("minLength"):
            bounds.append(f"of at least {node['minLength']} characters")
        if "pattern" in node:
            bounds.append(f"matching {node['pattern']}")
    return " ".join([words, " and ".join(bounds)]).strip()


_NOUNS = ("number", "integer", "string", "list", "object", "value", "item")


def _plural(words: str) -> str:
    """``a finite number`` -> ``finite numbers``; ``a list of 3 numbers`` -> ``lists of 3 numbers``."""
    for article in ("an ", "a "):
        if words.startswith(article):
            words = words[len(article):]
            break
    else:
        return words
    head, sep, tail = words.partition(" of ")
    tokens = head.split(" ")
    for i, token in enumerate(tokens):
        if token in _NOUNS:
            tokens[i] = token + "s"
            break
    return " ".join(tokens) + sep + tail


def expected_at(schema: type[BaseModel], loc: tuple, err: Mapping | None = None) -> str:
    """What the schema expects at ``loc``: read from its JSON schema; a few constraints pydantic reports only in
    the error (finite numbers) are added from ``err``."""
    node, defs = _node_at(schema, loc)
    words = describe_node(node, defs)
    if err is not None and err["type"] == "finite_number" and "finite" not in words:
        words = f"{words} (finite)"
    return words


def describe_schema(schema: type[BaseModel]) -> list[tuple[str, str, bool, str]]:
    """The documentation of a file: (field path, what it accepts, required, description) for every field, nested
    objects and lists of objects walked (``cameras[].K``)."""
    root = schema.model_json_schema()
    defs = root.get("$defs", {})
    rows: list[tuple[str, str, bool, str]] = []

    def walk(node: dict, prefix: str) -> None:
        node = _resolve(node, defs)
        required = set(node.get("required", []))
        for name, sub in node.get("properties", {}).items():
            path = f"{prefix}.{name}" if prefix else name
            rows.append((path, describe_node(sub, defs), name in required, _resolve(sub, defs).get(
                "description", sub.get("description", ""))))
            target = _resolve(sub, defs)
            options = target.get("anyOf", [target])
            for option in options:
                option = _resolve(option, defs)
                if option.get("type") == "object" and "properties" in option:
                    walk(option, path)
                elif option.get("type") == "array" and isinstance(option.get("items"), dict):
                    item = _resolve(option["items"], defs)
                    if item.get("type") == "object" and "properties" in item:
                        walk(item, f"{path}[]")
                elif option.get("type") == "object" and isinstance(option.get("additionalProperties"), dict):
                    value = _resolve(option["additionalProperties"], defs)
                    if value.get("type") == "object" and "properties" in value:
                        walk(value, f"{path}.<name>")

    walk(root, "")
    return rows
