"""Typed model options: frozen dataclasses whose fields state their type, range and choices.

A model declares its settings once, as a dataclass of :func:`option` fields; the config layer
parses ``[model]`` / ``[model.<name>]`` tables into it with :func:`parse_options`, which refuses
unknown keys and bad values with a one-line message naming the table, the key and the value::

    @dataclass(frozen=True)
    class MyOptions:
        tolerance: float = option(1e-4, low=0, low_open=True, high=1, high_open=True,
                                  doc="relative residual of the solve")
        solver: str = option("gmres", choices=("gmres", "csym"))

A float setting whose magnitude lies outside :data:`FLOAT_SPAN` (other than 0) is refused
whatever its own range: no setting of a model means 1e-300 or 1e300, so such a value is a typo.

Field types understood: ``bool``, ``int``, ``float`` (finite), ``str``, ``tuple[int, ...]`` (a
list of integers, with ``length`` in the metadata when it is fixed) and a nested options
dataclass (a sub-table, e.g. ``[model.aim]``). Checks that involve several fields stay in the
dataclass's ``__post_init__``; their ``ValueError`` is reported under the table's name.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import typing
from dataclasses import dataclass, field
from typing import Any

__all__ = ["NoOptions", "OptionsError", "describe_options", "option", "parse_options"]


FLOAT_SPAN = (1e-15, 1e15)  # the magnitudes a float setting may take (besides 0)
INTEGER_LIMIT = 2**63  # TOML integers are unbounded; numpy and HDF5 are not


class OptionsError(ValueError):
    """A bad option value; the message names the table, the key and the value."""


@dataclass(frozen=True)
class NoOptions:
    """A model without settings of its own."""


def option(default, *, doc: str = "", low=None, high=None, low_open: bool = False, high_open: bool = False,
           choices: tuple | None = None, length: int | None = None):
    """A dataclass field with its checks in the metadata (see the module docstring)."""
    metadata = {"doc": doc, "low": low, "high": high, "low_open": low_open, "high_open": high_open,
                "choices": choices, "length": length}
    if isinstance(default, (list, dict, set)):
        raise TypeError("option defaults must be immutable (use a tuple)")
    return field(default=default, metadata=metadata)


def _fmt(value: Any) -> str:
    text = f'"{value}"' if isinstance(value, str) else repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _fail(table: str, key: str, value: Any, problem: str) -> OptionsError:
    return OptionsError(f"[{table}] {key} = {_fmt(value)}: {problem}")


def _check_range(table: str, key: str, value, meta: dict):
    low, high = meta.get("low"), meta.get("high")
    if low is not None and (value <= low if meta.get("low_open") else value < low):
        raise _fail(table, key, value, f"must be {'>' if meta.get('low_open') else '>='} {low:g}")
    if high is not None and (value >= high if meta.get("high_open") else value > high):
        raise _fail(table, key, value, f"must be {'<' if meta.get('high_open') else '<='} {high:g}")
    return value


def _convert(table: str, key: str, value: Any, kind, meta: dict):
    """Check ``value`` against the field type ``kind`` and its metadata; return it converted."""
    if dataclasses.is_dataclass(kind):
        if not isinstance(value, dict):
            raise _fail(table, key, value, f"must be a table ([{table}.{key}] or {key} = {{...}})")
        return parse_options(kind, value, f"{table}.{key}")
    if kind is bool:
        if not isinstance(value, bool):
            raise _fail(table, key, value, "must be true or false")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(table, key, value, "must be an integer")
        if abs(value) >= INTEGER_LIMIT:
            raise _fail(table, key, value, "is too large (integers must lie within ±2**63)")
        return _check_range(table, key, int(value), meta)
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(table, key, value, "must be a number")
        if not math.isfinite(value):
            raise _fail(table, key, value, "must be finite (not NaN/inf)")
        _check_range(table, key, value, meta)
        if value != 0 and not FLOAT_SPAN[0] <= abs(value) <= FLOAT_SPAN[1]:
            raise _fail(table, key, value, f"lies outside the magnitudes {FLOAT_SPAN[0]:g} to {FLOAT_SPAN[1]:g} that a "
                                           "setting may take (a typo?)")
        return float(value)
    if kind is str:
        choices = meta.get("choices")
        if not isinstance(value, str) or (choices and value not in choices):
            allowed = f"one of {', '.join(_fmt(c) for c in choices)}" if choices else "a string"
            raise _fail(table, key, value, f"must be {allowed}")
        return value
    if typing.get_origin(kind) is tuple:
        length = meta.get("length")
        if (not isinstance(value, (list, tuple)) or (length is not None and len(value) != length)
                or any(isinstance(v, bool) or not isinstance(v, int) for v in value)):
            size = f"{length} " if length is not None else ""
            raise _fail(table, key, value, f"must be a list of {size}integers")
        if any(abs(v) >= INTEGER_LIMIT for v in value):
            raise _fail(table, key, value, "holds an integer too large (integers must lie within ±2**63)")
        return tuple(_check_range(table, key, int(v), meta) for v in value)
    raise TypeError(f"option {key!r}: unsupported field type {kind!r}")  # pragma: no cover - a model bug


def _field_types(cls) -> dict:
    hints = typing.get_type_hints(cls)
    return {f.name: (hints[f.name], f) for f in dataclasses.fields(cls)}


def parse_options(cls, values: dict | None, table: str):
    """An instance of the options dataclass ``cls`` from the config table ``values``.

    ``table`` names the table in messages (e.g. ``"model.aim"``). Absent keys take their
    defaults; a value that is already an instance of ``cls`` is returned as it is.
    """
    if isinstance(values, cls):
        return values
    values = dict(values or {})
    fields = _field_types(cls)
    for key in values:
        if key not in fields:
            close = difflib.get_close_matches(key, list(fields), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            allowed = ", ".join(fields) or "none"
            raise OptionsError(f"[{table}] {key}: unknown key{hint} (allowed: {allowed})")
    converted = {key: _convert(table, key, value, fields[key][0], dict(fields[key][1].metadata))
                 for key, value in values.items()}
    try:
        return cls(**converted)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, OptionsError):
            raise
        culprit = next((key for key in converted if not _accepted_alone(cls, key, converted[key])), None)
        if culprit is None:  # a combination of keys: name them all
            raise OptionsError(f"[{table}] {', '.join(converted) or '(defaults)'}: {exc}") from None
        raise _fail(table, culprit, values[culprit], str(exc)) from None


def _accepted_alone(cls, key: str, value) -> bool:
    """Whether ``cls`` accepts ``key = value`` with every other field at its default (to name the
    key that a check spanning several fields refuses)."""
    try:
        cls(**{key: value})
    except (TypeError, ValueError):
        return False
    return True


def describe_options(cls) -> list[tuple[str, str, Any, str]]:
    """(key, type, default, doc) of every field, for documentation and ``--help`` texts."""
    rows = []
    for name, (kind, f) in _field_types(cls).items():
        meta = dict(f.metadata)
        type_name = getattr(kind, "__name__", str(kind))
        if meta.get("choices"):
            type_name = " | ".join(_fmt(c) for c in meta["choices"])
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        rows.append((name, type_name, default, meta.get("doc", "")))
    return rows
