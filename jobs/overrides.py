"""Config overrides — ``wavebrdf run CONFIG --set key=value`` and ``wavebrdf.run(config, **overrides)``
— and configs given as dicts. Both go through :func:`apply_overrides`.

A key is a dotted TOML key: ``surface.rms_height_um``, ``model.aim.tolerance``,
``sweep."surface.seed"`` (a swept key is quoted, as in the file). A command-line value is a TOML
value — ``0.1``, ``[0.45, 0.55]``, ``{start = 0.4, stop = 0.7, count = 4}``, ``"gold"`` — and a
bare word (``gold``, ``aluminium-bemsim``) is taken as a string. An override sets its key,
creating the tables on its way; a table given for a key that holds a table is merged into it key
by key (``surface = {rms_height_um = 0.1}`` changes one key); any other value replaces. The
result is validated as the file would be, so a bad value is refused naming its key and value.

The config text stored in the dataset is the overridden config written back as TOML (the file's
comments are dropped) under a header naming the file and the overrides, so the dataset's
``config`` attribute reproduces the study.
"""

from __future__ import annotations

import copy
import json
import math
import re
import tomllib
from pathlib import Path
from typing import Any, Iterable

from wavebrdf.jobs.errors import ConfigError
from wavebrdf.solver.options import shortened

__all__ = ["apply_overrides", "assignment_text", "check_nesting", "dict_config_text", "dump_toml", "overridden_text",
           "parse_assignment", "parse_toml"]

BARE_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_.+-]*")
BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
MAX_NESTING = 32  # levels of tables and arrays; a config needs a handful (section, table, rows, row)


def _show(value: Any) -> str:
    try:
        text = _value(value)
    except TypeError:
        text = repr(value)
    return shortened(text)


def check_nesting(data: Any, where: str = "") -> None:
    """Refuse ``data`` nested more than MAX_NESTING tables/arrays deep (checked without recursion)."""
    stack = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        children = value.values() if isinstance(value, dict) else value if isinstance(value, (list, tuple)) else ()
        for child in children:
            if isinstance(child, (dict, list, tuple)):
                if depth + 1 > MAX_NESTING:
                    raise ConfigError(f"{where}tables or arrays nested more than {MAX_NESTING} levels deep; a config "
                                      "nests a few (sections, their tables, lists of rows)")
                stack.append((child, depth + 1))


def parse_toml(text: str, where: str = "") -> dict:
    """``text`` as TOML data; a one-line ConfigError (prefixed by ``where``) for text that is not
    TOML or that nests too deeply (tomllib recurses per level: a RecursionError beyond ~1000)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{where}tables or arrays nested too deeply to read (more than {MAX_NESTING} levels); "
                          "a config nests a few (sections, their tables, lists of rows)") from None
    check_nesting(data, where)
    return data


def parse_assignment(text: str) -> tuple[str, Any]:
    """``"key=value"`` from the command line → (key, value); the value is TOML (or a bare word)."""
    key, sep, raw = text.partition("=")
    key, raw = key.strip(), raw.strip()
    if not sep or not key or not raw:
        raise ConfigError(f"--set {text}: expected key=value, e.g. --set surface.rms_height_um=0.1")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
        check_nesting(value, f"--set {key}: ")
    except RecursionError:
        raise ConfigError(f"--set {key}: the value nests arrays or tables too deeply to read (more than {MAX_NESTING} "
                          "levels)") from None
    except tomllib.TOMLDecodeError:
        if not BARE_WORD.fullmatch(raw):
            raise ConfigError(f"--set {key}={raw}: {raw} is not a TOML value (e.g. 0.5, [0.45, 0.55], \"text\", "
                              "{start = 0.4, stop = 0.7, count = 4})") from None
        value = raw
    return key, value


def assignment_text(key: str, value: Any) -> str:
    """``key=value`` as ``--set`` takes it (:func:`parse_assignment` reads it back as (key, value))."""
    return f"{key}={_value(value)}"


def _key_path(key: str) -> list[str]:
    """The parts of dotted TOML key ``key`` (quoted parts may hold dots)."""
    try:
        data = tomllib.loads(f"{key} = 0")
    except tomllib.TOMLDecodeError:
        raise ConfigError(f"override {key}: not a dotted config key (e.g. surface.rms_height_um or "
                          "sweep.\"surface.seed\")") from None
    path = []
    while isinstance(data, dict):
        (name, data), = data.items()
        path.append(name)
    return path


def _merge(target: dict, key: str, value: Any) -> None:
    if isinstance(value, dict) and isinstance(target.get(key), dict):
        for sub, inner in value.items():
            _merge(target[key], sub, inner)
    else:
        target[key] = copy.deepcopy(value)


def apply_overrides(data: dict, overrides: dict | Iterable[tuple[str, Any]]) -> dict:
    """A copy of config ``data`` (sections as TOML loads them) with ``overrides`` applied in order."""
    out = copy.deepcopy(data)
    items = overrides.items() if isinstance(overrides, dict) else overrides
    for key, value in items:
        path = _key_path(key)
        table = out
        for depth, name in enumerate(path[:-1]):
            table = table.setdefault(name, {})
            if not isinstance(table, dict):
                where = ".".join(path[: depth + 1])
                raise ConfigError(f"override {key} = {_show(value)}: {where} is {_show(table)}, not a table")
        check_nesting(value, f"override {key}: ")
        try:
            _value(value)
        except TypeError as exc:
            raise ConfigError(f"override {key} = {_show(value)}: {exc}") from None
        _merge(table, path[-1], value)
    return out


def overridden_text(text: str, overrides, path: Path | None = None) -> str:
    """Config ``text`` with ``overrides`` applied, as TOML text with a provenance header."""
    data = parse_toml(text, f"{path}: " if path else "")
    items = list(overrides.items() if isinstance(overrides, dict) else overrides)
    for key, value in items:  # before anything recurses into them
        check_nesting(value, f"override {key}: ")
    header = (f"# {path or 'config'} with overrides: "
              + "; ".join(f"{key} = {_show(value)}" for key, value in items))
    return f"{' '.join(header.splitlines())}\n{dump_toml(apply_overrides(data, items))}"


def dict_config_text(data: dict) -> str:
    """A config given as a dict (``wavebrdf.run({...})``) as TOML text."""
    if not isinstance(data, dict):
        raise ConfigError(f"a config is a TOML file or a dict of sections, not {type(data).__name__}")
    check_nesting(data, "config dict: ")
    try:
        return "# config given as a dict\n" + dump_toml(data)
    except TypeError as exc:
        raise ConfigError(f"config dict: {exc}") from None


# ---------------------------------------------------------------------------------------------
# TOML writing (configs only: tables, arrays, strings, numbers, booleans)


def _key(name: str) -> str:
    if not isinstance(name, str):
        raise TypeError(f"table keys must be strings, not {name!r}")
    return name if BARE_KEY.fullmatch(name) else json.dumps(name, ensure_ascii=False)


def _value(value: Any) -> str:
    if hasattr(value, "item") and callable(value.item) and getattr(value, "shape", None) == ():
        value = value.item()  # numpy scalars
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else
                                                          ("inf" if value > 0 else "-inf"))
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, Path):
        return json.dumps(str(value), ensure_ascii=False)
    if isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
        items = value.tolist() if hasattr(value, "tolist") else value
        return "[" + ", ".join(_value(v) for v in items) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"{type(value).__name__} is not a config value (numbers, strings, booleans, lists, tables)")


def dump_toml(data: dict) -> str:
    """``data`` (sections → keys → values) as TOML: one ``[section]`` per top-level table, deeper
    tables inline; ``tomllib.loads(dump_toml(d)) == d``."""
    lines = []
    plain = {k: v for k, v in data.items() if not isinstance(v, dict)}
    for key, value in plain.items():
        lines.append(f"{_key(key)} = {_value(value)}")
    for section, table in data.items():
        if isinstance(table, dict):
            lines.append(f"\n[{_key(section)}]")
            lines.extend(f"{_key(k)} = {_value(v)}" for k, v in table.items())
    return "\n".join(lines).lstrip("\n") + "\n"
