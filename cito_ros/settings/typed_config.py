"""Typed, frozen configuration dataclasses read from nested parameter trees.

A configuration class is a frozen dataclass whose fields are declared with
`setting()` (a description and the admissible range) and carry no defaults:
`parse` builds it from a nested mapping (YAML or ROS parameters), converting
and checking every value and naming a bad one by its dotted path; a class may
add cross-field checks in a `check(path)` method. `unparse` gives the tree back.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from dataclasses import field, fields
from typing import Any, Mapping


def setting(description: str, *, minimum: float | None = None, positive: bool = False,
            choices: tuple[str, ...] | None = None, convert: typing.Callable[[Any, str], Any] | None = None,
            unconvert: typing.Callable[[Any], Any] | None = None):
    """A settings field: its description and the range every value must lie in (`convert` and
    `unconvert` for a field whose parameter is not stored as it is read)."""
    return field(metadata={"description": description, "minimum": minimum, "positive": positive,
                           "choices": choices, "convert": convert, "unconvert": unconvert})


def require_finite(name: str, value: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
    """`value` as a float, or a ValueError naming `name` and what is wrong."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {number}")
    if positive and number <= 0:
        raise ValueError(f"{name} must be positive, got {number}")
    if nonnegative and number < 0:
        raise ValueError(f"{name} must be non-negative, got {number}")
    return number


def dotted(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def optional_type(annotation) -> tuple[bool, Any]:
    """(whether None is admissible, the type without None)."""
    arguments = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType) and type(None) in arguments:
        return True, next(a for a in arguments if a is not type(None))
    return False, annotation


@functools.cache
def _type_hints(cls) -> dict[str, Any]:
    """typing.get_type_hints(cls), once per class: evaluating them was a quarter of a settings parse, and the
    planner derives settings (with_overrides) many times a solve."""
    return typing.get_type_hints(cls)


def parse(cls, raw: Any, path: str):
    if not isinstance(raw, Mapping):
        raise ValueError(f"{path or 'the parameters'} must be a section (a mapping), got {raw!r}")
    hints = _type_hints(cls)
    names = [f.name for f in fields(cls) if not f.metadata.get("internal")]
    unknown = sorted(set(raw) - set(names))
    if unknown:
        raise ValueError(f"{dotted(path, unknown[0])}: unknown parameter ({path or 'the top level'} has {names})")
    values = {}
    for f in fields(cls):
        if f.metadata.get("internal"):
            continue
        name = dotted(path, f.name)
        optional, annotation = optional_type(hints[f.name])
        if raw.get(f.name) is None:
            if optional:
                values[f.name] = None
                continue
            raise ValueError(f"{name}: missing")
        values[f.name] = _convert(annotation, raw[f.name], name, f.metadata)
    instance = cls(**values)
    if hasattr(instance, "check"):
        instance.check(path)
    return instance


def _convert(annotation, value: Any, name: str, meta: Mapping[str, Any]):
    if meta.get("convert"):
        return meta["convert"](value, name)
    if dataclasses.is_dataclass(annotation):
        return parse(annotation, value, name)
    if typing.get_origin(annotation) is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{name} must be a list, got {value!r}")
        item = typing.get_args(annotation)[0]
        return tuple(_convert(item, v, f"{name}[{i}]", meta) for i, v in enumerate(value))
    if annotation is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        minimum = meta.get("minimum")
        if minimum is not None and value < minimum:
            kind = "a positive integer" if minimum == 1 else f"an integer >= {minimum:g}"
            raise ValueError(f"{name} must be {kind}, got {value!r}")
        return value
    if annotation is float:
        number = require_finite(name, value, positive=bool(meta.get("positive")))
        minimum = meta.get("minimum")
        if minimum is not None and number < minimum:
            raise ValueError(f"{name} must be non-negative, got {number}" if minimum == 0
                             else f"{name} must be at least {minimum:g}, got {number}")
        return number
    if annotation is str:
        if not isinstance(value, str):
            raise ValueError(f"{name} must be a string, got {value!r}")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
        return value
    raise TypeError(f"{name}: unsupported settings type {annotation!r}")  # a bug in this module


def unparse(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        tree = {}
        for f in fields(value):
            item = getattr(value, f.name)
            if item is not None and not f.metadata.get("internal"):
                unconvert = f.metadata.get("unconvert")
                tree[f.name] = unconvert(item) if unconvert else unparse(item)
        return tree
    if isinstance(value, tuple):
        return [unparse(v) for v in value]
    return value
