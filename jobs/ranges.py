"""Ranges in configs: a ``{start, stop, count}`` table wherever a list of numbers goes, and
direction grids.

::

    wavelengths_um = {start = 0.4, stop = 0.7, count = 31}     # 0.40, 0.41, ..., 0.70 (both ends)
    theta_i_deg = {start = 0, stop = 60, count = 3}            # fibers: 0, 30, 60
    directions_deg = {theta = {start = 0, stop = 60, count = 4}, phi = [0, 45]}
    [sweep]
    "surface.rms_height_um" = {start = 0.02, stop = 0.1, count = 5}

A range is ``count`` evenly spaced values from ``start`` to ``stop``, both included (``count =
1``: ``start`` alone), rounded to 12 significant digits so that 0.4 + 3 × 0.1 is 0.7 and
``.sel(wavelength_um=0.55)`` finds its value; integer ends with an integer step give integers
(``"surface.seed" = {start = 1, stop = 4, count = 4}``). A direction grid is every (θ, φ) of
``theta`` × ``phi`` (each a number, a list or a range), θ-major; θ = 0 is one direction whatever
φ, and φ + 360° the direction of φ, so each appears once, with its first φ (``phi = {start = 0,
stop = 360, count = 13}`` gives 12 azimuths). Anything else is returned as it is, for the key's own
check.
"""

from __future__ import annotations

import math

from wavebrdf.jobs.errors import fail

__all__ = ["RANGE_KEYS", "direction_identity", "expand_directions", "expand_range"]

RANGE_KEYS = ("start", "stop", "count")


def expand_range(section: str, key: str, value):
    """``value`` with a ``{start, stop, count}`` table replaced by its list of numbers."""
    if not isinstance(value, dict):
        return value
    if set(value) != set(RANGE_KEYS):
        raise fail(section, key, value, "a range is a table {start = a, stop = b, count = n} (exactly these keys)")
    start, stop, count = (value[k] for k in RANGE_KEYS)
    for name, x in (("start", start), ("stop", stop)):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise fail(section, key, value, f"range {name} must be a finite number")
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 100_000:
        raise fail(section, key, value, "range count must be an integer from 1 to 100000")
    if count == 1:
        return [start]
    if start == stop:
        raise fail(section, key, value, "a range of count > 1 needs start != stop")
    if all(isinstance(x, int) for x in (start, stop)) and (stop - start) % (count - 1) == 0:
        step = (stop - start) // (count - 1)  # integers stay integers (seeds, cells)
        return [start + i * step for i in range(count)]
    step = (stop - start) / (count - 1)
    return [float(f"{start + i * step:.12g}") for i in range(count)]


def expand_directions(section: str, key: str, value):
    """``value`` with a ``{theta = ..., phi = ...}`` grid replaced by its list of [θ, φ] pairs."""
    if not isinstance(value, dict):
        return value
    if set(value) != {"theta", "phi"}:
        raise fail(section, key, value, "a direction grid is a table {theta = ..., phi = ...} (each a number, "
                                         "a list or a range {start, stop, count}), or list [[theta, phi], ...]")
    axes = []
    for name in ("theta", "phi"):
        axis = expand_range(section, f"{key}.{name}", value[name])
        axes.append(axis if isinstance(axis, list) else [axis])
    pairs, seen = [], set()
    for theta in axes[0]:
        for phi in axes[1]:
            try:
                identity = direction_identity((theta, phi))
            except (TypeError, ValueError):  # not numbers: the key's own check names them
                identity = object()
            if identity not in seen:  # θ = 0 whatever φ, or φ a full turn from one listed: once, its first φ
                seen.add(identity)
                pairs.append([theta, phi])
    return pairs


def direction_identity(direction) -> tuple[float, float]:
    """An incident direction (θ, φ) in degrees as the direction it is: φ modulo 360°, and θ = 0
    the one direction whatever φ, both to 10⁻⁹° (two rows with the same identity are one direction
    listed twice)."""
    theta, phi = round(float(direction[0]), 9), float(direction[1])
    return (theta, round(phi % 360.0, 9) % 360.0 if theta > 0 else 0.0)  # 10.1 and 370.1 alike
