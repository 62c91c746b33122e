"""A finished study stays finished: ``run`` on an output whose dataset holds this plan's
complete results does nothing ("up to date", exit 0), unless ``--force``.

The dataset records the plan's fingerprint (root attribute ``fingerprint``, jobs/plan.py: every
config value that determines results). An output holding another configuration's results is
refused with the keys that changed and the study that wrote it; a file that is not a wavebrdf
dataset (a text file, someone's own HDF5 file) is refused too. ``--force`` (or another ``[study]
output``) overwrites either. Datasets without the attribute (older versions) are recomputed as
before. ``run`` and ``merge`` check again once they hold the output's lock: a run they waited for
may have written the output meanwhile.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import h5py
import numpy as np

from wavebrdf.jobs.parts import ResumeError
from wavebrdf.jobs.store import not_a_dataset

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


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _parts_of(plan, parts: Path) -> bool:
    """Whether the parts folder ``parts`` holds partial results of ``plan`` (read only)."""
    from wavebrdf.jobs.parts import PartsFolder

    if not parts.exists():
        return False
    try:
        PartsFolder(plan).check()
    except Exception:  # noqa: BLE001 - another configuration's, or no manifest: not this plan's to resume
        return False
    return True


def up_to_date(plan, force: bool = False, force_flag: str = "--force") -> bool:
    """True when ``plan``'s output already holds its complete results (nothing to run).
    ResumeError (unless ``force``) when the output is not a wavebrdf dataset or holds another
    configuration's results; its message names ``force_flag``, how the caller forces a run
    ("--force" on the command line, "force=True" in ``wavebrdf.run``)."""
    output = Path(plan.config.output)
    if force or not output.exists():
        return False
    problem = not_a_dataset(output)
    if problem is not None:
        raise ResumeError(f"{output} {problem}: it is not a wavebrdf dataset, so it is not replaced; move it "
                          f"away, set another [study] output, or add {force_flag} to overwrite it")
    try:
        with h5py.File(output, "r") as h5:
            found = h5.attrs.get("fingerprint")
            config, study = h5.attrs.get("config", ""), h5.attrs.get("study", "")
            status = h5["tasks/status"][()] if "tasks/status" in h5 else np.array([])
    except (OSError, KeyError, ValueError):
        return False  # a damaged dataset of ours: the run replaces it, as before
    if found is None:
        return False
    parts = output.with_name(output.name + ".parts")
    if _text(found) != plan.fingerprint:
        # checked before the parts folder: partial results beside a dataset they are not of do not replace it
        resume = (f" (the partial results in {parts.name} beside it resume with {force_flag}, replacing it)"
                  if _parts_of(plan, parts) else "")
        raise ResumeError(f"{output} holds the results of another configuration (study {_text(study)!r}, "
                          f"fingerprint {_text(found)}; changed: {changed_keys(_text(config), plan.config.text)}); "
                          f"add {force_flag} to overwrite it, or set another [study] output{resume}")
    if parts.exists():
        return False  # a run of this configuration to resume
    states = {_text(s) for s in status}
    return len(status) == len(plan.tasks) and states == {"done"}
