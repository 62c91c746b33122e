"""Geometry of the example fiber scene: a wisp of gently curved fibers as Mitsuba B-spline curves.

World frame z up, as in :mod:`wavebrdf.mitsuba.scene` (camera on -y looking at the origin). The
fibers run roughly along z through the frame, fanned out in x and slightly in depth, each with
a smooth random wave; Mitsuba's ``bsplinecurve`` reads one control point "x y z radius" per
line, a blank line between curves (its dp_du goes around the fiber, dp_dv along it, which is
what the ``"wavebrdf_fiber"`` plugin's frame expects).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["GEOMETRIC_RADIUS", "write_fiber_wisp"]

GEOMETRIC_RADIUS = 0.006  # scene units: the fibers' geometric radius (the image is ~2.4 units wide)


def write_fiber_wisp(path: str | Path, radius: float, *, count: int = 48, seed: int = 3,
                     points: int = 12, lean_deg: float = 24.0) -> Path:
    """Write ``count`` curves of constant ``radius`` (the bounding radius the plugin needs) to
    ``path``; deterministic for a given ``seed``. The wisp leans ``lean_deg`` away from the camera
    (its axis toward +y), which puts the specular cone of the default sun into the camera."""
    rng = np.random.default_rng(seed)
    z = np.linspace(-1.6, 1.6, points)
    lines = []
    for k in range(count):
        x0 = -0.95 + 1.9 * (k + rng.uniform(0.2, 0.8)) / count
        y0 = rng.uniform(-0.25, 0.25)
        tilt = rng.uniform(-0.18, 0.18)
        amp, freq, phase = rng.uniform(0.02, 0.08), rng.uniform(0.6, 1.4), rng.uniform(0, 2 * np.pi)
        x = x0 + tilt * z + amp * np.sin(freq * z * np.pi + phase)
        y = y0 + 0.5 * amp * np.cos(freq * z * np.pi + phase)
        c, s = np.cos(np.deg2rad(lean_deg)), np.sin(np.deg2rad(lean_deg))
        y, zz = y * c + z * s, -y * s + z * c
        lines += [f"{a:.6f} {b:.6f} {h:.6f} {radius:.6f}" for a, b, h in zip(x, y, zz)]
        lines.append("")
    path = Path(path)
    path.write_text("\n".join(lines))
    return path
