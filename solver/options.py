"""Typed options: frozen dataclasses whose fields state their type, range and choices.

Every table of settings is declared once, as a dataclass of :func:`option` fields — a model's
``[model]`` / ``[model.<name>]`` options, a surface generator's keys (solver/surface.py), each
section of a study config (jobs/sections.py) — and parsed by :func:`parse_options`, which
refuses unknown keys (naming the nearest valid one) and bad values with a one-line message
naming the table, the key, the value and what is allowed::

    @dataclass(frozen=True)
    class MyOptions:
        tolerance: float = option(1e-4, low=0, low_open=True, high=1, high_open=True,
                                  doc="relative residual of the solve")
        solver: str = option("gmres", choices=("gmres", "csym"))
        waist_um: float | None = option(None, limits=LENGTH_UM, doc="beam waist")

    parse_options(MyOptions, {"tolerance": -1}, "model")
    # OptionsError: [model] tolerance = -1: must be > 0

Field types, and what a value must be:

- ``bool``; ``str`` (non-empty; one of ``choices`` when given); a nested options dataclass
  (a sub-table, e.g. ``[model.aim]``);
- ``int`` / ``float``: a finite number within ``limits``, a :class:`Limits` (its domain and, for
  a physical quantity, the magnitudes that are physics rather than a typo or a unit slip, in
  its unit). A float setting bounded only by ``low``/``high`` is also refused outside
  :data:`FLOAT_SPAN`: no setting means 1e-300 or 1e300;
- ``tuple[float, float]``: that many numbers; ``tuple[float, ...]``: a non-empty list
  (``distinct``: no value twice); ``float | tuple[float, float]``: a number or a pair;
- ``tuple[tuple[float, ...], ...]`` with ``columns = ((name, Limits), ...)``: rows, e.g.
  [[θ, φ], ...] (``row`` names one in messages; ``distinct``: no row twice, or a function giving
  each row's identity, e.g. a direction's);
- anything else through ``parse``: a function that returns the value or raises ValueError
  with the problem.

``X | None`` marks a key that may be absent, ``required=True`` one that may not. ``expand``
rewrites a value before it is checked (the config's ``{start, stop, count}`` ranges). Checks
that involve several fields stay in the dataclass's ``__post_init__``; their ``ValueError`` is
reported under the table's name, naming the key when one key alone is refused.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

__all__ = [
    "ANGLE_DEG",
    "FLOAT_SPAN",
    "LENGTH_UM",
    "WAVELENGTH_UM",
    "Limits",
    "NoOptions",
    "OptionField",
    "OptionsError",
    "describe_options",
    "option",
    "option_fields",
    "parse_open_options",
    "parse_options",
]


FLOAT_SPAN = (1e-15, 1e15)  # the magnitudes a float setting may take (besides 0)
INTEGER_LIMIT = 2**63  # TOML integers are unbounded; numpy and HDF5 are not


class OptionsError(ValueError):
    """A bad option value; the message names the table, the key and the value."""


@dataclass(frozen=True)
class NoOptions:
    """A model without settings of its own."""


def _interval(low, high, low_open=False, high_open=False) -> str:
    lo = "(-inf" if low is None else f"{'(' if low_open else '['}{low:g}"
    hi = "inf)" if high is None else f"{high:g}{')' if high_open else ']'}"
    return f"{lo}, {hi}"


@dataclass(frozen=True)
class Limits:
    """The accepted values of a number: its domain and, for a physical quantity, its range.

    ``low``/``high`` (``*_open``: excluded) are the domain (a negative length is refused as
    "must be > 0"); ``span`` = (smallest, largest) non-zero magnitude that is physics rather
    than a typo or a unit slip (lengths from 1 pm to 1 m), in ``unit``, explained by ``note``.
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    span: tuple[float, float] | None = None
    unit: str = ""
    note: str = ""

    @property
    def range_text(self) -> str:
        """The accepted values in words, e.g. "0.001 to 1000 µm (vacuum wavelengths: 1 nm to 1 mm)"."""
        unit = f" {self.unit}" if self.unit else ""
        note = f" ({self.note})" if self.note else ""
        if self.span is None:
            return f"{_interval(self.low, self.high, self.low_open, self.high_open)}{unit}{note}"
        zero_allowed = self.low is None or (self.low == 0 and not self.low_open)
        zero = "0 or " if zero_allowed and self.span[0] > 0 else ""
        sign = "±" if self.low is None or self.low < 0 else ""
        return f"{zero}{sign}{self.span[0]:g} to {sign}{self.span[1]:g}{unit}{note}"

    @property
    def domain_text(self) -> str:
        """The domain in words: "> 0", "in [0, 90)", or "" (any number)."""
        if self.high is not None:
            return f"in {_interval(self.low, self.high, self.low_open, self.high_open)}"
        return "" if self.low is None else f"{'>' if self.low_open else '>='} {self.low:g}"

    def problem(self, value, integer: bool = False) -> str | None:
        """Why ``value`` is refused (None: accepted): type, size, finiteness, domain, span."""
        ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
        if isinstance(value, bool) or not ok_type:
            return f"must be {'an integer' if integer else 'a number'}"
        if integer and abs(value) >= INTEGER_LIMIT:
            return "is too large (integers must lie within ±2**63)"
        if not integer and not math.isfinite(value):
            return "must be finite (not NaN/inf)"
        low, high = self.low, self.high
        if low is not None and (value <= low if self.low_open else value < low):
            return f"must be {'>' if self.low_open else '>='} {low:g}"
        if high is not None and (value >= high if self.high_open else value > high):
            unit = f" {self.unit}" if self.unit else ""
            note = f" ({self.note})" if self.note else ""
            return f"must be {'<' if self.high_open else '<='} {high:g}{unit}{note}"
        if self.span is not None and value != 0 and not self.span[0] <= abs(value) <= self.span[1]:
            return f"is {'below' if abs(value) < self.span[0] else 'above'} the physical range {self.range_text}"
        return None


# The physical quantities many tables share (µm, degrees): what the solvers are meant for, with
# room to spare; a value outside is a typo or a unit slip (nm for µm).
LENGTH_UM = Limits(low=0, low_open=True, span=(1e-6, 1e6), unit="µm", note="lengths: 1 pm to 1 m")
WAVELENGTH_UM = Limits(low=0, low_open=True, span=(1e-3, 1e3), unit="µm", note="vacuum wavelengths: 1 nm to 1 mm")
ANGLE_DEG = Limits(low=-360, high=360, unit="degrees")


def option(default, *, doc: str = "", required: bool = False, low=None, high=None, low_open: bool = False,
           high_open: bool = False, limits: Limits | None = None, choices: Iterable | None = None,
           length: int | None = None, distinct: bool | Callable = False, columns: tuple | None = None, row: str = "row",
           expand: Callable | None = None, parse: Callable | None = None, record_absent: bool = True):
    """A dataclass field with its checks in the metadata (see the module docstring).

    ``limits`` (a physical quantity) or ``low``/``high``/``*_open`` (a setting's bounds);
    ``choices``: the accepted strings (a registry's live ``keys()`` view stays current);
    ``length``: a tuple's fixed length when the type does not say it; ``record_absent``: False
    keeps the key out of a study's record while it is not given (jobs/sections.py), so that a
    key added later leaves the fingerprints of existing datasets as they were.
    """
    if isinstance(default, (list, dict, set)):
        raise TypeError("option defaults must be immutable (use a tuple)")
    if limits is not None and (low is not None or high is not None):
        raise TypeError("give limits or low/high, not both")
    quantity = limits is not None
    if limits is None:
        limits = Limits(low=low, high=high, low_open=low_open, high_open=high_open)
    metadata = {"doc": doc, "required": required, "limits": limits, "quantity": quantity, "choices": choices,
                "length": length, "distinct": distinct, "columns": columns, "row": row, "expand": expand,
                "parse": parse, "record_absent": record_absent}
    return field(default=default, metadata=metadata)


def shortened(text: str, limit: int = 80) -> str:
    """``text`` cut in the middle to at most ``limit`` characters, keeping both ends (a long path
    keeps its file name)."""
    if len(text) <= limit:
        return text
    head = (limit - 3) // 2
    return text[:head] + "..." + text[len(text) - (limit - 3 - head):]


def _fmt(value: Any) -> str:
    return shortened(f'"{value}"' if isinstance(value, str) else repr(value))


def _fail(table: str, key: str, value: Any, problem: str) -> OptionsError:
    return OptionsError(f"[{table}] {key} = {_fmt(value)}: {problem}")


def _without_none(kind):
    """``X | None`` → X (a key that may be absent is checked as X when given)."""
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        args = tuple(a for a in typing.get_args(kind) if a is not type(None))
        return args[0] if len(args) == 1 else typing.Union[args]
    return kind


def _form(kind, meta: dict) -> tuple[str, type | None, int | None]:
    """(form, element type, fixed length) of a field type: form is one of "custom", "table",
    "bool", "str", "one", "fixed", "one_or_pair", "list", "rows"."""
    if meta.get("parse") is not None:
        return "custom", None, None
    if dataclasses.is_dataclass(kind):
        return "table", None, None
    if kind in (bool, str):
        return kind.__name__, None, None
    if kind in (int, float):
        return "one", kind, None
    args = typing.get_args(kind)
    if typing.get_origin(kind) in (typing.Union, types.UnionType) and len(args) == 2 and args[0] in (int, float):
        return "one_or_pair", args[0], len(typing.get_args(args[1]))
    if typing.get_origin(kind) is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return ("rows", float, None) if typing.get_origin(args[0]) is tuple else ("list", args[0], None)
        return "fixed", args[0], meta.get("length") or len(args)
    raise TypeError(f"unsupported option type {kind!r}")  # pragma: no cover - a declaration bug


@dataclass(frozen=True)
class OptionField:
    """One key of an options dataclass as :func:`parse_options` checks it (:func:`option_fields`):
    its declared type (without "| None"), default and :func:`option` settings, and its ``form``
    ("custom", "table", "bool", "str", "one", "fixed", "one_or_pair", "list" or "rows") with
    the element type (``integer``) and fixed ``length`` of number lists."""

    name: str
    kind: Any
    default: Any
    doc: str
    required: bool
    limits: Limits
    quantity: bool  # limits of a physical quantity (its own span), not a setting's bounds
    choices: Iterable | None
    distinct: bool | Callable  # rows: a callable gives each row's identity (rows of one identity repeat)
    columns: tuple | None
    row: str
    expand: Callable | None
    parse: Callable | None
    record_absent: bool
    form: str
    integer: bool
    length: int | None

    @classmethod
    def of(cls, f: dataclasses.Field, hint) -> OptionField:
        meta = dict(f.metadata)
        kind = _without_none(hint)
        form, element, length = _form(kind, meta)
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        return cls(f.name, kind, default, meta.get("doc", ""), meta.get("required", False),
                   meta.get("limits") or Limits(), meta.get("quantity", False), meta.get("choices"),
                   meta.get("distinct", False), meta.get("columns"), meta.get("row", "row"), meta.get("expand"),
                   meta.get("parse"), meta.get("record_absent", True), form, element is int, length)

    @property
    def numeric(self) -> bool:
        return self.form in ("one", "fixed", "one_or_pair", "list", "rows")

    def convert(self, table: str, value: Any):
        """``value`` checked and converted, or an OptionsError naming the table, key and value."""
        key = self.name
        if self.expand is not None:
            value = self.expand(table, key, value)
        form = self.form
        if form == "custom":
            try:
                return self.parse(value)
            except ValueError as exc:
                raise _fail(table, key, value, str(exc)) from None
        if form == "table":
            if not isinstance(value, dict):
                raise _fail(table, key, value, f"must be a table ([{table}.{key}] or {key} = {{...}})")
            return parse_options(self.kind, value, f"{table}.{key}")
        if form == "bool":
            if not isinstance(value, bool):
                raise _fail(table, key, value, "must be true or false")
            return value
        if form == "str":
            return self._string(table, value)
        if form == "rows":
            return self._rows(table, value)
        if form == "one" or (form == "one_or_pair" and not isinstance(value, (list, tuple))):
            problem = self._problem(value)
            if problem is not None:
                raise _fail(table, key, value, problem)
            return int(value) if self.integer else float(value)
        kind = "integers" if self.integer else "numbers"
        if form == "list":
            if not isinstance(value, (list, tuple)) or not value:
                raise _fail(table, key, value, f"must be a non-empty list of {kind}")
        elif not isinstance(value, (list, tuple)) or len(value) != self.length:
            either = f"{'an integer' if self.integer else 'a number'}, or " if form == "one_or_pair" else ""
            domain = f" {self.limits.domain_text}".rstrip()
            raise _fail(table, key, value, f"must be {either}a list of {self.length} {kind}{domain}")
        out = tuple(self._item(table, value, item) for item in value)
        if self.distinct and len(set(out)) != len(out):
            raise _fail(table, key, value, "values must be distinct")
        return out

    def _problem(self, value) -> str | None:
        problem = self.limits.problem(value, self.integer)
        if (problem is None and not self.integer and not self.quantity and value != 0
                and not FLOAT_SPAN[0] <= abs(value) <= FLOAT_SPAN[1]):
            return (f"lies outside the magnitudes {FLOAT_SPAN[0]:g} to {FLOAT_SPAN[1]:g} that a setting may take "
                    "(a typo?)")
        return problem

    def _item(self, table: str, whole, value):
        """One number of a list: converted, or a refusal naming the whole list and the bad value."""
        problem = self._problem(value)
        if problem is None:
            return int(value) if self.integer else float(value)
        if problem.startswith(("is ", "lies ")):
            problem = f"values must lie within the physical range {self.limits.range_text}"
        else:
            kind = "integers" if self.integer else "numbers"
            problem = f"values must be finite {kind} {self.limits.domain_text}".rstrip()
        raise _fail(table, self.name, whole, f"{problem} (bad: {_fmt(value)})")

    def _string(self, table: str, value):
        choices = self.choices
        if choices is not None:
            if not isinstance(value, str) or value not in choices:
                raise _fail(table, self.name, value, f"must be one of {', '.join(_fmt(c) for c in choices)}")
        elif not isinstance(value, str) or not value.strip():
            raise _fail(table, self.name, value, "must be a non-empty string")
        return value

    def _rows(self, table: str, value):
        columns = self.columns
        shape = "[" + ", ".join(name for name, _ in columns) + "]"
        if not isinstance(value, (list, tuple)) or not value:
            raise _fail(table, self.name, value, f"must be a non-empty list of {shape} rows")
        out = []
        for row in value:
            if not isinstance(row, (list, tuple)) or len(row) != len(columns):
                raise _fail(table, self.name, value, f"each {self.row} must be {shape} (bad: {_fmt(row)})")
            for (name, limits), x in zip(columns, row):
                problem = limits.problem(x)
                if problem is not None:
                    raise _fail(table, self.name, value, f"{name} {problem} (bad: {_fmt(x)} in {_fmt(row)})")
            out.append(tuple(float(x) for x in row))
        if self.distinct:
            same = self.distinct if callable(self.distinct) else tuple
            seen = {}
            for row in out:
                first = seen.setdefault(same(row), row)
                if first is not row:
                    how = f" ({_fmt(list(first))} and {_fmt(list(row))} are one {self.row})" if first != row else ""
                    raise _fail(table, self.name, value, f"{self.row}s must be distinct{how}")
        return tuple(out)


@functools.cache
def option_fields(cls) -> dict[str, OptionField]:
    """The keys of the options dataclass ``cls``, in declaration order."""
    hints = typing.get_type_hints(cls)
    return {f.name: OptionField.of(f, hints[f.name]) for f in dataclasses.fields(cls)}


def _refuse_unknown(table: str, values: dict, allowed: Iterable[str]) -> None:
    allowed = list(allowed)
    for key in values:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise OptionsError(f"[{table}] {key}: unknown key{hint} (allowed: {', '.join(allowed) or 'none'})")


def _table(table: str, values) -> dict:
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise OptionsError(f"[{table}] must be a table, got {_fmt(values)}")
    return values


def parse_options(cls, values: dict | None, table: str):
    """An instance of the options dataclass ``cls`` from the config table ``values``.

    ``table`` names the table in messages (e.g. ``"model.aim"``). Absent keys take their
    defaults; a value that is already an instance of ``cls`` is returned as it is.
    """
    if isinstance(values, cls):
        return values
    values = _table(table, values)
    _refuse_unknown(table, values, option_fields(cls))
    return _construct(cls, values, table)


def parse_open_options(cls, values: dict | None, table: str, others: Iterable[str] | None = None):
    """(``cls`` parsed from its own keys, the other keys as given) for a table whose other keys
    belong to a plug-in: the model of ``[model]``, the generator of ``[surface]``. ``others``:
    the only other keys allowed (None: any, which the plug-in then checks)."""
    values = _table(table, values)
    own = option_fields(cls)
    if others is not None:
        _refuse_unknown(table, values, [*own, *(k for k in others if k not in own)])
    rest = {k: v for k, v in values.items() if k not in own}
    return _construct(cls, {k: v for k, v in values.items() if k in own}, table), rest


def _construct(cls, values: dict, table: str):
    """``cls`` from known keys: each converted (declaration order), required ones present, then
    the dataclass's own checks."""
    converted = {}
    for key, f in option_fields(cls).items():
        if key in values:
            converted[key] = f.convert(table, values[key])
        elif f.required:
            raise OptionsError(f"[{table}] {key}: missing required key")
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
    for name, f in option_fields(cls).items():
        type_name = getattr(f.kind, "__name__", str(f.kind))
        if f.choices:
            type_name = " | ".join(_fmt(c) for c in f.choices)
        rows.append((name, type_name, f.default, f.doc))
    return rows
