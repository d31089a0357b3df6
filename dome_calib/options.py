"""Option objects declare their bounds as field constraints (pydantic dataclasses), checked where they are built.

Every ``*Options`` class of the code is declared with :func:`options`::

    @options
    class TriangulationOptions:
        inlier_threshold_px: PosFinite = 8.0
        min_views: Annotated[int, Field(ge=2)] = 2

and is then a pydantic dataclass: strict types (``True`` is not a count, ``"2"`` is not a number), NaN and infinities
refused, the bounds of :mod:`dome_calib.schema`'s aliases or of ``Field(...)`` checked on construction, on
:func:`dataclasses.replace` and on assignment. A value outside them raises :class:`OptionsError`, one line naming
the class, the field, the value and what is expected (read from the declaration, so the message and the bound
cannot drift apart)::

    TriangulationOptions: min_views 1: expected an integer >= 2

A command that builds options from its flags names the flag the user typed instead
(:func:`dome_calib.errors.flags`, light enough for the CLI shells to import)::

    --min-views 1: expected an integer >= 2

Why pydantic dataclasses and not a hand-made check of ``Annotated`` metadata: ``bench/options_construction.py``
measured both against the stdlib dataclasses with the hand checks they replace (docs/benchmarks.md): pydantic's
compiled validator costs about what the hand checks cost (1.07 x with two fields given, 0.84 x with the defaults;
a few microseconds, and no stage builds options per item), the hand-made reader of the same bounds 1.33 x; and its
errors carry the field, the input and the failed constraint, which the message is made of.
"""
from __future__ import annotations

import functools
from fractions import Fraction
from collections.abc import Callable
from typing import Annotated, Any, TypeVar

import pydantic
from pydantic import ConfigDict, Field, model_validator
from pydantic.dataclasses import dataclass as pydantic_dataclass
from pydantic.json_schema import WithJsonSchema

from dome_calib.errors import OptionsError
from dome_calib.schema import expected_at, field_path, show

__all__ = ["OPTIONS_CONFIG", "AtLeast", "Field", "Lax", "OptionsError", "PosFraction", "UnitInterval", "options",
           "options_classes", "require"]

T = TypeVar("T")

#: Strict types, finite numbers, objects of any class allowed as values (a progress callback, a board), checked on
#: assignment too.
OPTIONS_CONFIG = ConfigDict(strict=True, allow_inf_nan=False, arbitrary_types_allowed=True, validate_assignment=True,
                            revalidate_instances="never", extra="forbid")

def AtLeast(n: int) -> Any:  # noqa: N802 (a type constructor)
    """An integer >= ``n`` (a count, a number of views, iterations)."""
    return Annotated[int, Field(ge=n)]


#: A fraction or a confidence: a finite number in [0, 1].
UnitInterval = Annotated[float, Field(ge=0, le=1)]

#: An exact positive rate (a frame rate as a Fraction).
PosFraction = Annotated[Fraction, Field(gt=0), WithJsonSchema({"type": "number", "exclusiveMinimum": 0})]

#: A field taken in its usual spellings: an enum by its value (``"huber"``), a path as a string.
Lax = Field(strict=False)

_CLASSES: list[type] = []


def _error(cls: type, exc: pydantic.ValidationError) -> OptionsError:
    err = exc.errors(include_url=False)[0]
    loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and not p.isidentifier()))
    where = field_path(loc)
    owner = cls.__name__
    if err["type"] in ("value_error", "assertion_error"):  # a check across fields: its own words
        text = str(err.get("ctx", {}).get("error", err["msg"])).removeprefix("Value error, ")
        return OptionsError(f"{owner}: {text}", owner=owner, field=where)
    if err["type"] == "unexpected_keyword_argument":
        return OptionsError(f"{owner}: {where}: no such option", owner=owner, field=where)
    expected, shown = expected_at(cls, loc, err), show(err.get("input"))
    return OptionsError(f"{owner}: {where} {shown}: expected {expected}", owner=owner, field=where, shown=shown,
                        expected=expected)


def options(cls: type[T]) -> type[T]:
    """Declare an options class (module docstring): a keyword-only pydantic dataclass with the project's config,
    whose construction raises :class:`OptionsError` in one line."""
    made = pydantic_dataclass(cls, kw_only=True, config=OPTIONS_CONFIG)
    init = made.__init__

    @functools.wraps(init)
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        try:
            init(self, *args, **kwargs)
        except pydantic.ValidationError as exc:
            raise _error(type(self), exc) from None

    setter = made.__setattr__

    def __setattr__(self, name: str, value: Any) -> None:
        try:
            setter(self, name, value)
        except pydantic.ValidationError as exc:
            raise _error(type(self), exc) from None

    made.__init__ = __init__
    made.__setattr__ = __setattr__
    _CLASSES.append(made)
    return made


def require(predicate: Callable[[Any], bool], message: str | Callable[[Any], str]) -> Any:
    """A check across fields of an options class, declared in its body::

        _overlap = require(lambda o: o.overlap_times < o.chunk_times,
                           "overlap_times {o.overlap_times} must be below chunk_times {o.chunk_times}")

    ``message`` is formatted with the object as ``o`` (or is a function of it)."""

    def check(self: Any) -> Any:
        if not predicate(self):
            raise ValueError(message(self) if callable(message) else message.format(o=self))
        return self

    return model_validator(mode="after")(check)


def options_classes() -> list[type]:
    """Every class declared with :func:`options` so far (in the modules imported)."""
    return list(_CLASSES)
