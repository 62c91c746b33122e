"""Pictures of datasets (``wavebrdf render``): what each kind shows is in jobs/pictures/surface.py
and jobs/pictures/fiber.py (a study kind's ``pictures``, jobs/study_kinds.py); jobs/render.py
writes them."""

from __future__ import annotations

from functools import partial

import numpy as np

from wavebrdf.jobs.pictures.common import DECADES, Picture, PictureOptions

__all__ = ["DECADES", "Picture", "PictureOptions", "pictures"]


def _cases(ds):
    """(case index tuple, flat index, label) of every sweep case, C order."""
    keys, coords = ds.sweep_keys, ds.coords
    lead = ds.h5[ds.main_variable].shape[: len(keys)]
    for flat, index in enumerate(np.ndindex(*lead) if lead else [()]):
        yield index, flat, ", ".join(f"{k}={coords[k][i]}" for k, i in zip(keys, index))


def pictures(ds, opts: PictureOptions, module) -> list[Picture]:
    """Every picture ``opts`` asks for of open dataset ``ds`` (drawn later, one at a time), as the
    pictures ``module`` of its kind draws them (jobs/pictures/surface.py, fiber.py): the per-case
    kinds of every case first, then the per-direction kinds of every (case, direction) — the order
    a cap on their number keeps."""
    n_directions = ds.h5[ds.main_variable].shape[len(ds.sweep_keys) + 1]
    directions = range(n_directions) if opts.incidences is None else opts.incidences
    cases = [module.Case(ds, *case) for case in _cases(ds)]
    names = {id(c): "".join(f"_c{i}" for i in c.index) for c in cases}
    out = [Picture(names[id(c)] + suffix, kind, partial(draw, c, opts))
           for c in cases for kind, suffix, draw in module.PER_CASE
           if kind in opts.plots and module.available(c, kind)]
    out += [Picture(names[id(c)] + suffix.format(k=k), kind, partial(draw, c, k, opts))
            for c in cases for k in directions for kind, suffix, draw in module.PER_DIRECTION
            if kind in opts.plots and module.available(c, kind)]
    return out
