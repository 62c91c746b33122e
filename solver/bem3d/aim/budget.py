"""AIM settings that fit a memory budget: :func:`fit_to_budget`.

The largest memory of an AIM solve is its preconditioner (the sparse LU of the near block, whose
fill grows with the patch), then the near field, the FFT grids and the Krylov basis
(estimate.py). Given the memory one task may use, the planner tries, from the settings as given,
the settings that trade time for memory — single precision (kernels, FFTs, grid spectra and
projections; the accuracy cost is measured in docs/aim.md), the LU on tiles of the patch
(restricted additive Schwarz: more products, less fill), the local inverses of 4-cell tiles
(~1.15 KB per unknown, GMRES restarted every 30 products: 32 vectors), the flat patch's inner solve
(flat_patch.py: ~120 B per unknown, FGMRES(30): 61 vectors), no preconditioner (the
complex-symmetric MINRES "csym", six vectors), and for a lossy material whose
interior field is still on the grid, the near radius at which it decays within the near field
(green.py ``grid_media``: the interior then leaves the grid, halving its FFTs, spectra and
projections for a larger near field), each also without the static tables a worker keeps for a
patch's next wavelength (``reuse_setup``, 2.3 KB per element) — and keeps the one with the shortest
predicted time among those that fit (a cold task's time, ``estimate_aim`` ``seconds``; of equal
times, the first listed: with the tables kept). The given precision is kept whenever some settings
at that precision fit: single precision is an accuracy trade, taken for memory only. Settings that
fit (the given ones, or else the given ones without the kept tables) stay unless another is
predicted at least ``SPEED_MARGIN`` faster (the time model's error on the runs measured is
4–25 %, docs/aim.md) by an estimate within its fit (``outside_fit`` empty: on relief steeper than
the product count was fitted on, the flat patch's count is likely low); ``fit_speed = false``
keeps them whenever they fit. So with memory to spare
the benchmark's rough 12 µm sub-area in double precision gets the flat patch (predicted 266 s,
8.9 GiB), not the whole near LU it is given (1 490 s, 34 GiB). It says what it changed and what
that costs (:meth:`BudgetFit.summary`). When nothing fits it returns the settings of the smallest
need (``fits`` false), which the batch layer's memory check then refuses (jobs/plan.py
``check_memory``), naming that need. ``[model.aim] fit_memory = false`` keeps the settings as
given (refused there if they do not fit).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from wavebrdf.solver.bem3d.aim.estimate import estimate_aim
from wavebrdf.solver.bem3d.aim.flat_patch import FLAT_INNER_STEPS
from wavebrdf.solver.bem3d.aim.green import grid_media
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField

__all__ = ["BudgetFit", "FITTED_KEYS", "SPEED_MARGIN", "candidate_options", "fit_to_budget",
           "given_options", "interior_leaves_grid_cells"]

FITTED_KEYS = ("precision", "near_cells", "preconditioner", "preconditioner_tile_cells", "solver", "restart",
               "deflate", "flat_inner_steps", "reuse_setup")
LOCAL_RESTART = 30  # GMRES restart with the local inverses: products as with 60, half the vectors (docs/aim.md);
# FGMRES's with the flat patch too (it needs ~10 products: the restart only bounds the vectors)
MIN_TILE_CELLS = 24  # smaller LU tiles barely cut the products (docs/aim.md)
SPEED_MARGIN = 0.25  # the given settings give way for speed alone to settings predicted this much faster


@dataclass(frozen=True)
class BudgetFit:
    """The settings chosen for a budget, their estimate, and those given with theirs."""

    options: AIMOptions
    estimate: dict
    given: AIMOptions
    given_estimate: dict
    budget_bytes: float
    fits: bool = True

    @property
    def changed(self) -> dict:
        """{key: (given, chosen)} of the settings the fit changed."""
        return {k: (getattr(self.given, k), getattr(self.options, k)) for k in FITTED_KEYS
                if getattr(self.given, k) != getattr(self.options, k)}

    def summary(self) -> str:
        """One line: what was chosen, its memory and time, and the given settings' need."""
        gib = 2**30
        e, g = self.estimate, self.given_estimate
        within = ("with no memory limit" if self.budget_bytes == float("inf")
                  else f"within {self.budget_bytes / gib:.1f} GiB")
        chosen = (f"{e['bytes'] / gib:.2f} GiB, {e['seconds']:.0f} s, ~{e['iterations_guess']} products per "
                  f"polarization")
        if not self.fits:
            return (f"no aim settings fit {self.budget_bytes / gib:.1f} GiB; the smallest need: "
                    f"{', '.join(f'{k} = {getattr(self.options, k)!r}' for k in FITTED_KEYS)} ({chosen})")
        if not self.changed:
            return f"aim settings as given, {within}: {chosen}"
        what = ", ".join(f"{k} {a!r} -> {b!r}" for k, (a, b) in self.changed.items())
        why = "faster than given" if g["bytes"] <= self.budget_bytes else "fitted to the memory"
        return (f"aim settings {why}, {within}: {what} ({chosen}; as given {g['bytes'] / gib:.2f} GiB, "
                f"{g['seconds']:.0f} s)")


def _tile_sizes(cells: int) -> list[int]:
    """LU tile sides: the patch split into 2, 3, 4, 6, 8 … tiles per side, down to MIN_TILE_CELLS."""
    sizes = []
    for parts in (2, 3, 4, 6, 8, 12, 16):
        side = -(-cells // parts)
        if side < MIN_TILE_CELLS:
            break
        sizes.append(side)
    return sizes


def interior_leaves_grid_cells(options: AIMOptions, media: Media, spacing_um: float) -> float | None:
    """The smallest near radius (cells, in half cells up to twice ``near_cells``) at which the
    interior medium leaves the grid, or None (already off the grid, or never within that)."""
    def on_grid(cells):
        return 1 in grid_media(media, cells * spacing_um, options.interior_decay_tolerance)

    if not on_grid(options.near_cells):
        return None
    cells = options.near_cells
    while cells < 2 * options.near_cells:
        cells += 0.5
        if not on_grid(cells):
            return cells
    return None


def candidate_options(options: AIMOptions, cells: int, media: Media | None = None,
                      spacing_um: float | None = None) -> list[AIMOptions]:
    """The settings the planner may choose from, ``options`` first (see the module docstring);
    ``media`` and ``spacing_um`` (µm) allow the near radius that takes the interior off the grid."""
    out = [options]
    precisions = [options.precision] + ([Precision.SINGLE] if options.precision.fp64 else [])
    radii = [options.near_cells]
    if media is not None and spacing_um is not None:
        off = interior_leaves_grid_cells(options, media, spacing_um)
        radii += [] if off is None else [off]
    for precision in precisions:
        for radius in radii:
            base = replace(options, precision=precision, near_cells=radius)
            if base.preconditioner == "near":
                out.append(replace(base, preconditioner_tile_cells=0))
                out += [replace(base, preconditioner_tile_cells=t) for t in _tile_sizes(cells)]
            restart = min(base.restart, LOCAL_RESTART)
            out.append(replace(base, preconditioner="local", solver="gmres", restart=restart,
                               deflate=min(base.deflate, restart - 1)))
            # the flat patch's inner solve under FGMRES(30) with the inner steps its product count was
            # fitted at: ~120 B per unknown, twice the Krylov vectors
            out.append(replace(base, preconditioner="flat-patch", solver="gmres", restart=restart, deflate=0,
                               flat_inner_steps=FLAT_INNER_STEPS))
            # without a preconditioner: MINRES "csym" (six vectors; measured at 6.4·10⁵ unknowns),
            # not restarted GMRES, whose products at hundreds of iterations were never measured
            out.append(replace(base, preconditioner="none", solver="csym", deflate=0))
    if options.reuse_setup:  # each also without the static tables kept between wavelengths
        out = [v for o in out for v in (o, replace(o, reuse_setup=False))]
    unique = []
    for o in out:
        if o not in unique:
            unique.append(o)
    return unique


def given_options(mapping: dict) -> AIMOptions:
    """AIMOptions from settings a user gave (a benchmark's ``--aim``): when any are given, the fit
    changes them only where they do not fit the memory (``fit_speed`` false), not for speed."""
    return AIMOptions.from_mapping({"fit_speed": not mapping, **mapping})


def fit_to_budget(surface: HeightField, wavelength_um: float, index: complex, options: AIMOptions,
                  budget_bytes: float, *, exterior_index: float = 1.0, waist_um: float | None = None,
                  directions: int = 1, resolution: int = 512) -> BudgetFit:
    """The fastest predicted settings whose estimated memory fits ``budget_bytes`` (bytes; may be
    ``inf``), at the given precision when any fits there; the given ones (or else the given ones
    without the kept tables) when they fit and nothing is ``SPEED_MARGIN`` faster, or whenever
    they fit with ``options.fit_speed`` false; when none fits, those of the smallest need
    (``fits`` false). With ``options.fit_memory`` false only ``options`` is considered."""
    cache: dict = {}

    def estimate(o):
        return estimate_aim(surface, wavelength_um, index, exterior_index=exterior_index, aim=o,
                            directions=directions, waist_um=waist_um, resolution=resolution, cache=cache)

    given_estimate = estimate(options)
    tried = [(options, given_estimate)]
    if options.fit_memory:
        media = Media(wavelength_um, index, exterior_index)
        tried += [(o, estimate(o)) for o in candidate_options(options, surface.cells, media, surface.spacing_um)[1:]]
    fitting = [(o, e) for o, e in tried if e["bytes"] <= budget_bytes]
    if not fitting:
        smallest, e = min(tried, key=lambda oe: oe[1]["bytes"])
        return BudgetFit(smallest, e, options, given_estimate, budget_bytes, fits=False)
    same_precision = [(o, e) for o, e in fitting if o.precision == options.precision]
    as_given = [(o, e) for o, e in fitting if o in (options, replace(options, reuse_setup=False))]
    if not as_given:  # for the memory: the fastest that fits
        best, e = min(same_precision or fitting, key=lambda oe: oe[1]["seconds"])
        return BudgetFit(best, e, options, given_estimate, budget_bytes)
    # for speed alone: only on estimates within their fit (a count held at its fitted edge is likely low)
    kept, kept_estimate = as_given[0]
    trusted = [(o, e) for o, e in same_precision if not e["outside_fit"]] or [(kept, kept_estimate)]
    best, e = min(trusted, key=lambda oe: oe[1]["seconds"])
    margin = SPEED_MARGIN if options.fit_speed else 1.0
    if e["seconds"] > (1.0 - margin) * kept_estimate["seconds"]:
        best, e = kept, kept_estimate
    return BudgetFit(best, e, options, given_estimate, budget_bytes)
