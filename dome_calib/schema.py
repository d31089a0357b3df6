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

import functools
import json
import math
import re
import tomllib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar, Union

from typing_extensions import TypeAliasType

import pydantic
from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from pydantic.json_schema import GenerateJsonSchema

from dome_calib.errors import DomeCalibError

__all__ = ["FileSchema", "OpenSchema", "InputFileError", "FieldError", "Finite", "NonNegInt", "PosInt", "PosFinite",
           "NonNegFinite", "JsonData", "Vec", "Vec3", "Matrix3", "Matrix4", "PlainName", "CameraName", "Unique",
           "read_json", "read_toml", "read_yaml", "validate", "parse_json", "field_path", "describe_schema",
           "json_schema", "show", "refuse_alias_bombs", "words", "Field", "name_problem", "path_of_name",
           "NAME_MAX_CHARS"]

M = TypeVar("M", bound=BaseModel)


class InputFileError(DomeCalibError, ValueError):
    """A file a user handed us does not match its schema; the message names the file and the field path."""


class FieldError(ValueError):
    """Raised by a schema's own check (a ``model_validator``) to name the field it is about, below the validated
    object: ``FieldError(("nodes", "node08"), "camera 07_01 is also under node07")`` -> ``nodes.node08: ...``."""

    def __init__(self, loc: tuple[int | str, ...], message: str) -> None:
        super().__init__(message)
        self.loc = tuple(loc)


class FileSchema(BaseModel):
    """Base of every input file's schema: strict types, unknown fields refused, NaN/inf refused, immutable."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True,
                              validate_default=False, hide_input_in_errors=False, defer_build=True)


class OpenSchema(FileSchema):
    """A schema for another tool's file whose extra fields are none of our business (they are ignored)."""

    model_config = ConfigDict(extra="ignore")


def words(expected: str) -> dict:
    """``Field(**words("a camera name"))``: what a field accepts, in the words of the one-line errors and the docs
    (where its JSON schema alone would say only "a string")."""
    return {"json_schema_extra": {"expected": expected}}


Finite = Annotated[float, Field(allow_inf_nan=False)]
PosFinite = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFinite = Annotated[float, Field(ge=0, allow_inf_nan=False)]
#: Integers go into numpy int64 arrays: bounded so that a 400-digit number is refused, not overflowed.
INT64_MAX = 2**63 - 1
NonNegInt = Annotated[int, Field(ge=0, le=INT64_MAX)]
PosInt = Annotated[int, Field(ge=1, le=INT64_MAX)]


#: Any JSON data without NaN or infinities: the type of fields kept as written (another tool's extras).
JsonData = TypeAliasType("JsonData", Annotated[
    Union[bool, int, Finite, str, None, list["JsonData"], dict[str, "JsonData"]],
    Field(**words("any JSON data without NaN or infinities"))])


def Vec(n: int, item: Any = Finite) -> Any:  # noqa: N802 (a type constructor)
    """A list of exactly ``n`` items (default: finite numbers)."""
    return Annotated[list[item], Field(min_length=n, max_length=n)]


Vec3 = Vec(3)
Matrix3 = Vec(3, Vec3)
Matrix4 = Vec(4, Vec(4))


#: The longest name that becomes a file name: ``<camera>_000000000001_keypoints.json`` stays within the 255 bytes
#: of a file name (4 bytes per character of UTF-8 at most).
NAME_MAX_CHARS = 50
PLAIN_NAME_HELP = f"no '/', not '.' or '..', printable, at most {NAME_MAX_CHARS} characters"


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be one component of a path (None: it can). The one rule for every name from a file that
    becomes a file or folder name: camera names of every file kind, scenes, capture nodes, plots."""
    if not isinstance(name, str) or not name:
        return "empty"
    if "/" in name or "\\" in name:
        return "holds a path separator"
    if name in (".", ".."):
        return "is a folder reference"
    if not name.isprintable():
        return "holds a control character"
    if len(name) > NAME_MAX_CHARS:
        return f"is longer than {NAME_MAX_CHARS} characters"
    return None


def _plain_name(name: str) -> str:
    problem = name_problem(name)
    if problem is not None:
        raise ValueError(f"expected a plain name ({PLAIN_NAME_HELP}), got {show(name)}: it {problem}")
    return name


#: A name that becomes part of a path (a scene folder, a sequence, a capture node, a camera): :func:`name_problem`.
PlainName = Annotated[str, AfterValidator(_plain_name), Field(min_length=1, **words("a plain name (no '/')"))]
#: A camera's name in every file kind that carries one (calibration, report, peers' files): it becomes a file name
#: (``<camera>.png``, an OpenPose folder, a plot), so it is a :data:`PlainName`.
CameraName = PlainName


def path_of_name(folder: str | Path, name: str, suffix: str = "") -> Path:
    """``folder / (name + suffix)`` for a name from a file: the last guard of every place a name becomes a path
    (the schemas refuse such names first). DomeCalibError naming the name otherwise."""
    problem = name_problem(name)
    if problem is not None:
        raise DomeCalibError(f"name {show(name)}: not a file name: it {problem}")
    return Path(folder) / f"{name}{suffix}"


def _unique(values: list) -> list:
    seen: set = set()
    for i, v in enumerate(values):
        key = json.dumps(v, sort_keys=True) if isinstance(v, (list, dict)) else v
        if key in seen:
            raise FieldError((i,), f"{show(v)} is listed twice")
        seen.add(key)
    return values


def Unique(item: Any, min_length: int = 0) -> Any:  # noqa: N802 (a type constructor)
    """A list of ``item`` in which no value comes twice (at least ``min_length`` of them)."""
    return Annotated[list[item], Field(min_length=min_length), AfterValidator(_unique)]


# ---- reading --------------------------------------------------------------------------------------------------

def parse_json(source: str | Path, data: bytes, schema: type[M], *, error: type[Exception] = InputFileError) -> M:
    """``data`` (the bytes of the JSON file ``source``) validated by ``schema``; ``error`` with one line otherwise."""
    try:
        return schema.model_validate_json(data)
    except pydantic.ValidationError as exc:
        raise error(one_line(source, exc, schema, raw=data)) from None


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
    except (cv2.error, SystemError) as exc:  # SystemError: OpenCV's parser failed inside the constructor
        why = str(exc.__cause__ or exc).strip().splitlines()
        raise error(f"{path}: not a YAML file OpenCV can read ({why[-1] if why else 'unreadable'})") from None
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
        raise error(one_line(source, exc, schema, data=data)) from None


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

_PLAIN_KEY = re.compile(r"[A-Za-z0-9_\-<>]{1,40}")


def field_path(loc: tuple[int | str, ...]) -> str:
    """pydantic's ``loc`` as a path: ``("ltc", "vga_channel")`` -> ``ltc.vga_channel``, ``("cameras", 3, "K")``
    -> ``cameras[3].K``; a key from the file that is not a plain word is quoted (``kinect.color["node one"]``)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not _PLAIN_KEY.fullmatch(part):
            out += f"[{show(part)}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def show(value: Any, limit: int = 40) -> str:
    """A value from a file as the message shows it: JSON spelling (``false``, ``null``, ``"text"``), cut. Spelt
    token by token and cut while it is spelt (:func:`_spelling`): a value of a billion items (a YAML alias bomb, a
    huge list) costs the first ``limit`` characters, never its whole serialisation."""
    text = ""
    for token in _spelling(value, limit):
        text += token
        if len(text) > limit:
            break
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _spelling(value: Any, limit: int) -> Iterator[str]:
    """The JSON spelling of ``value`` in pieces, each at most about ``limit`` characters (strings and numbers are
    cut before they are spelt)."""
    if isinstance(value, float) and not math.isfinite(value):
        yield "NaN" if math.isnan(value) else "Infinity" if value > 0 else "-Infinity"
    elif isinstance(value, bool) or value is None or isinstance(value, float):
        yield json.dumps(value)
    elif isinstance(value, int):
        yield str(value) if value.bit_length() <= 4 * limit else f"<an integer of {value.bit_length()} bits>"
    elif isinstance(value, str):
        yield json.dumps(value[: limit + 1], ensure_ascii=True)
    elif isinstance(value, (list, tuple)):
        yield "["
        for i, item in enumerate(value):
            yield ", " if i else ""
            yield from _spelling(item, limit)
        yield "]"
    elif isinstance(value, Mapping):
        yield "{"
        for i, (key, item) in enumerate(value.items()):
            yield ", " if i else ""
            yield json.dumps(str(key)[: limit + 1], ensure_ascii=True) + ": "
            yield from _spelling(item, limit)
        yield "}"
    else:
        yield repr(value)[: limit + 1]


#: The most values (containers and scalars, each alias counted where it is used) a file of another tool may expand
#: to: real ones hold thousands. A YAML alias bomb (836 bytes) expands to 10^9.
MAX_EXPANDED_VALUES = 1_000_000


def refuse_alias_bombs(value: Any, source: str | Path, error: type[Exception] = InputFileError) -> Any:
    """``value`` (a loaded YAML document) if it expands to at most :data:`MAX_EXPANDED_VALUES` values, else
    ``error`` naming ``source``: YAML aliases share one object, so a small file can stand for a billion values,
    which every later walk (the schema, a message) would visit. Cost: at most that many steps."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > MAX_EXPANDED_VALUES:
            raise error(f"{source}: its aliases expand to more than {MAX_EXPANDED_VALUES:,} values (a YAML alias "
                        "bomb, not a calibration)")
        if isinstance(item, Mapping):
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
    return value


_NO_DATA = object()


def one_line(source: str | Path, exc: pydantic.ValidationError, schema: type[BaseModel], *, data: Any = _NO_DATA,
             raw: bytes | None = None) -> str:
    """The first failure of ``exc`` as ``source: [owner: ]field.path: expected ..., got ...`` (+ how many more).

    ``data`` (the parsed input) or ``raw`` (the file's bytes, parsed here: only on failure) lets the line name the
    owner of the field, the ``name`` of the list item it sits in (``camera 01_03: cameras[2].K``), and drops
    pydantic's own tags (union members, validators) from the path."""
    errors = exc.errors(include_url=False)
    err = errors[0]
    kind = err["type"]
    if raw is not None and kind != "json_invalid":
        data = _loads(raw)
    if data is not _NO_DATA:  # a union's branches fail at one place: that is one failure, not several
        places = {_data_loc(data, tuple(e["loc"]), e["type"]): e for e in errors}
        leaves = [p for p in places if not any(q[:len(p)] == p and q != p for q in places)]
        n_more = len(leaves) - 1  # a union branch failing above another's failure is the same failure
        first = next(iter(places))  # of the failures in the first field, the deepest (inside a union's branch)
        err = max((e for p, e in places.items() if p[:1] == first[:1]), key=lambda e: len(
            _data_loc(data, tuple(e["loc"]), e["type"])))
        kind = err["type"]
    else:
        n_more = len(errors) - 1
    more = f" (and {n_more} more)" if n_more > 0 else ""
    if kind == "json_invalid":
        if raw is not None and not _is_utf8(raw):
            return f"{source}: not a UTF-8 text file"
        return f"{source}: not valid JSON ({err['msg'].removeprefix('Invalid JSON: ')}){more}"
    loc = tuple(err["loc"])
    if isinstance(err.get("ctx", {}).get("error"), FieldError):  # a schema's own check, naming its field
        loc += err["ctx"]["error"].loc
    loc = _data_loc(data, loc, kind) if data is not _NO_DATA else loc
    owner = _owner(data, loc) if data is not _NO_DATA else ""
    where = f"{source}: {owner + ': ' if owner else ''}{field_path(loc) or 'the file'}"
    if kind == "missing":
        return f"{where}: missing (expected {expected_at(schema, loc)}){more}"
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):  # the latter: a dataclass's
        known = _known_fields(schema, loc[:-1])
        hint = f" (known fields: {', '.join(known)})" if known else ""
        return f"{where}: unknown field{hint}{more}"
    if kind in ("value_error", "assertion_error"):  # a model's own check: its message says what is wrong
        msg = str(err.get("ctx", {}).get("error", err["msg"])).removeprefix("Value error, ")
        return f"{where}: {msg}{more}"
    return f"{where}: expected {expected_at(schema, loc, err)}, got {show(err.get('input'))}{more}"


def _is_utf8(raw: bytes) -> bool:
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def _loads(raw: bytes) -> Any:
    """The file's JSON as Python (for naming the owner of a failing field), or _NO_DATA if that fails too."""
    try:
        return json.loads(raw)
    except (ValueError, RecursionError):
        return _NO_DATA


def _data_loc(data: Any, loc: tuple, kind: str) -> tuple:
    """pydantic's ``loc`` less its own tags (union members such as ``int`` or ``list[float]``, validators): the
    parts that step into ``data``, and the last part of a missing or unknown field."""
    out: list[int | str] = []
    node = data
    for i, part in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        elif isinstance(node, dict) and isinstance(part, str) and part in node:
            node = node[part]
        elif last and kind in ("missing", "extra_forbidden", "unexpected_keyword_argument"):
            node = None
        else:
            continue
        out.append(part)
    return tuple(out)


def _owner(data: Any, loc: tuple) -> str:
    """The innermost list item on the path that carries a string ``name``: ``camera 01_03`` (the list's field name,
    singular), or ""."""
    owner, node, parent = "", data, ""
    for part in loc:
        try:
            node = node[part]
        except (KeyError, IndexError, TypeError):
            break
        if isinstance(part, int) and isinstance(node, dict) and isinstance(node.get("name"), str) and node["name"]:
            what = parent[:-1] if parent.endswith("s") else "item"
            name = node["name"]
            owner = f"{what} {name if name.isprintable() and len(name) <= 40 else show(name)}"
        if isinstance(part, str):
            parent = part
    return owner


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


class _AnyObjectSchema(GenerateJsonSchema):
    """JSON schema of a class whose fields may hold any object (an options dataclass's callback): those are ``{}``."""

    def handle_invalid_for_json_schema(self, schema: Any, error_info: str) -> dict:
        return {}


@functools.cache
def json_schema(schema: type) -> dict:
    """The schema's JSON schema, made once (pydantic builds it anew on every call: ~ms for a file's schema); a
    pydantic dataclass's too (an options class, :mod:`dome_calib.options`: fields of any class described as ``{}``)."""
    if isinstance(schema, type) and issubclass(schema, BaseModel):
        return schema.model_json_schema()
    return pydantic.TypeAdapter(schema).json_schema(schema_generator=_AnyObjectSchema)


def _node_at(schema: type[BaseModel], loc: tuple) -> tuple[dict | None, dict]:
    root = json_schema(schema)
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


def describe_node(node: dict | None, defs: dict, depth: int = 0) -> str:
    """What a JSON-schema node accepts, in words: ``an integer >= 0``, ``a list of 3 numbers``, ``"vga" or "hd"``."""
    if node is None:
        return "a valid value"
    if depth > 8:  # a recursive type (any JSON data): say no more
        return "a value"
    node = _resolve(node, defs)
    if "expected" in node:
        return node["expected"]
    if "anyOf" in node:
        return " or ".join(dict.fromkeys(describe_node(o, defs, depth + 1) for o in node["anyOf"]))
    if "enum" in node:
        return " or ".join(json.dumps(v) for v in node["enum"])
    if "const" in node:
        return json.dumps(node["const"])
    kind = node.get("type")
    if kind == "object" and "properties" in node:
        return f"an object with {', '.join(node['properties'])}" if len(node["properties"]) <= 4 else "an object"
    if kind == "object" and isinstance(node.get("additionalProperties"), dict):
        return f"an object mapping names to {_plural(describe_node(node['additionalProperties'], defs, depth + 1))}"
    if kind == "array":
        lo, hi = node.get("minItems"), node.get("maxItems")
        count = (f"{lo} " if lo == hi and lo is not None else f"at least {lo} " if lo and lo > 1 else
                 f"at most {hi} " if hi is not None else "")
        article = "a non-empty list" if lo == 1 and hi is None else "a list"
        items = node.get("items") or (node.get("prefixItems") or [None])[0]
        if not items:
            return f"{article} of {count}items"
        each = describe_node(items, defs, depth + 1)
        if " or " in each:  # "a list of labels or nulls or null" would not say which is which
            return f"{article} of {count}items, each {each}"
        return f"{article} of {count}{_plural(each)}"
    words = _TYPES.get(kind, kind or "a value")
    bounds = [f"{op} {_number(node[key])}" for key, op in (("minimum", ">="), ("exclusiveMinimum", ">"),
                                                           ("maximum", "<="), ("exclusiveMaximum", "<")) if key in node]
    if kind == "string":
        if node.get("minLength") == 1:
            words = "a non-empty string"
        elif node.get("minLength"):
            bounds.append(f"of at least {node['minLength']} characters")
        if "pattern" in node:
            bounds.append(f"matching {node['pattern']}")
    return " ".join([words, " and ".join(bounds)]).strip()


#: Bounds written as powers of two: the int64 range, and the integers a float holds exactly.
_POWERS = {INT64_MAX: "2^63-1", -INT64_MAX - 1: "-2^63", 2**53: "2^53"}


def _number(value: float | int) -> str:
    if value in _POWERS:
        return _POWERS[value]
    return f"{value:g}" if isinstance(value, float) else str(value)


_NOUNS = ("number", "integer", "string", "list", "object", "value", "item", "name", "label", "path", "matrix")


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
    objects, lists of objects (``cameras[].K``) and maps (``streams.<name>.clock``) walked; a file that is itself a
    map (a RootModel of a dict) starts at ``<name>``."""
    root = json_schema(schema)
    defs = root.get("$defs", {})
    rows: list[tuple[str, str, bool, str]] = []

    def row(path: str, sub: dict, required: bool) -> None:
        rows.append((path, describe_node(sub, defs), required,
                     _resolve(sub, defs).get("description", sub.get("description", ""))))
        below(_resolve(sub, defs), path)

    def below(target: dict, path: str) -> None:
        for option in target.get("anyOf", [target]):
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
                    walk(value, f"{path}.<name>" if path else "<name>")

    def walk(node: dict, prefix: str) -> None:
        node = _resolve(node, defs)
        required = set(node.get("required", []))
        for name, sub in node.get("properties", {}).items():
            row(f"{prefix}.{name}" if prefix else name, sub, name in required)

    resolved = _resolve(root, defs)
    if "properties" not in resolved and isinstance(resolved.get("additionalProperties"), dict):
        row("<name>", resolved["additionalProperties"], True)
    else:
        walk(root, "")
    return rows
