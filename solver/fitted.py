"""Fitted constants of the cost models, read from data files with the run each came from.

A file ``solver/data/<name>.csv`` holds one row per constant: ``name``, ``value``, ``unit``,
``meaning`` and the run it was fitted to — ``command`` (what was run), ``commit`` (the code it
ran) and ``machine`` (where). The estimates read the values (:func:`fitted`); a refit rewrites
the rows it measured again and keeps the others with their own provenance (:func:`write_fitted`;
``tools/refit_aim_cost.py`` for the AIM planner's). What a constant was before is in the file's
git history, not in the code.
"""

from __future__ import annotations

import csv
import functools
import os
from pathlib import Path

__all__ = ["COLUMNS", "DATA", "fitted", "fitted_rows", "write_fitted"]

DATA = Path(__file__).parent / "data"
COLUMNS = ("name", "value", "unit", "meaning", "command", "commit", "machine")


def fitted_rows(name: str, path: str | Path | None = None) -> list[dict]:
    """The rows of ``solver/data/<name>.csv`` (or ``path``), in file order."""
    path = Path(path) if path is not None else DATA / f"{name}.csv"
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    for row in rows:
        if set(row) != set(COLUMNS):
            raise ValueError(f"{path}: columns {sorted(row)}, expected {list(COLUMNS)}")
    return rows


@functools.cache
def fitted(name: str) -> dict[str, float]:
    """{constant: value} of ``solver/data/<name>.csv`` (read once per process)."""
    out = {}
    for row in fitted_rows(name):
        try:
            out[row["name"]] = float(row["value"])
        except ValueError:
            raise ValueError(f"{DATA / (name + '.csv')}: {row['name']} = {row['value']!r} is not a number") from None
    return out


def write_fitted(rows: list[dict], path: str | Path) -> None:
    """Write ``rows`` (dicts of :data:`COLUMNS`) to ``path``, replacing it only once complete."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows({k: row[k] for k in COLUMNS} for row in rows)
    os.replace(tmp, path)
