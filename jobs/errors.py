"""The config's one-line refusals, shared by the modules that read config values
(jobs/config.py, jobs/sections.py, jobs/input_files.py, jobs/overrides.py, jobs/ranges.py,
jobs/executors.py, ...): ``[section] key = value: problem``."""

from __future__ import annotations

from typing import Any

from wavebrdf.solver.options import shortened

__all__ = ["ConfigError", "exactly_one", "fail", "fmt"]


class ConfigError(ValueError):
    """Invalid configuration; the message names the key, the value and what is allowed."""


def fmt(value: Any) -> str:
    """``value`` as a refusal shows it: strings in double quotes, others as ``repr``, at most 80
    characters (cut in the middle)."""
    return shortened(repr(value) if not isinstance(value, str) else f'"{value}"')


def fail(section: str, key: str, value: Any, problem: str) -> ConfigError:
    """The refusal of ``[section] key = value``."""
    return ConfigError(f"[{section}] {key} = {fmt(value)}: {problem}")


def exactly_one(section: str, values, keys: tuple[str, ...]) -> None:
    """Refuse ``[section]`` unless exactly one of ``keys`` is set (not None) on ``values``."""
    given = [k for k in keys if getattr(values, k) is not None]
    if len(given) != 1:
        raise ConfigError(f"[{section}]: give exactly one of {', '.join(keys)} (got {', '.join(given) or 'none'})")
