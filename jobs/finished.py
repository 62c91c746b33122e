"""A finished study stays finished: ``run`` on an output whose dataset holds this plan's
complete results does nothing ("up to date", exit 0), unless ``--force``.

The dataset records the plan's fingerprint (root attribute ``fingerprint``, jobs/plan.py: every
config value that determines results). An output holding another configuration's results is
refused with the keys that changed; ``--force`` (or another ``[study] output``) overwrites it.
Datasets without the attribute (older versions) are recomputed as before.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import h5py
import numpy as np

from wavebrdf.jobs.parts import ResumeError

__all__ = ["changed_keys", "up_to_date"]

IGNORED_SECTIONS = ("study", "run")  # output, name and how it runs do not change results


def _flat(table: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flat(value, name + "."))
        else:
            out[name] = value
    return out


def changed_keys(old_text: str, new_text: str, limit: int = 6) -> str:
    """The config keys whose values differ ("surface.rms_height_um 0.09 -> 0.1, ..."), sections
    [study] and [run] aside."""
    try:
        old, new = (_flat(tomllib.loads(t)) for t in (old_text, new_text))
    except tomllib.TOMLDecodeError:
        return "the stored config is unreadable"
    keys = sorted(k for k in set(old) | set(new)
                  if k.split(".")[0] not in IGNORED_SECTIONS and old.get(k) != new.get(k))
    if not keys:
        return "a file it reads (surface or points file) changed"
    missing = "(unset)"
    items = [f"{k} {old.get(k, missing)!r} -> {new.get(k, missing)!r}" for k in keys[:limit]]
    return ", ".join(items) + (f" and {len(keys) - limit} more" if len(keys) > limit else "")


def up_to_date(plan, force: bool = False) -> bool:
    """True when ``plan``'s output already holds its complete results (nothing to run).
    ResumeError when it holds another configuration's results (and not ``force``)."""
    output = Path(plan.config.output)
    parts = output.with_name(output.name + ".parts")
    if force or not output.is_file() or parts.exists():
        return False  # nothing yet, or a run to resume
    try:
        with h5py.File(output, "r") as h5:
            found = h5.attrs.get("fingerprint")
            config = h5.attrs.get("config", "")
            status = h5["tasks/status"][()] if "tasks/status" in h5 else np.array([])
    except (OSError, KeyError, ValueError):
        return False  # not a readable dataset: the run replaces it, as before
    if found is None:
        return False
    found = found.decode() if isinstance(found, bytes) else str(found)
    if found != plan.fingerprint:
        config = config.decode() if isinstance(config, bytes) else str(config)
        raise ResumeError(f"{output} holds the results of another configuration (changed: "
                          f"{changed_keys(config, plan.config.text)}); add --force to overwrite it, or set "
                          "another [study] output")
    states = {s.decode() if isinstance(s, bytes) else str(s) for s in status}
    return len(status) == len(plan.tasks) and states == {"done"}
