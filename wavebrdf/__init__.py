"""wavebrdf: wave-optics BRDFs of microgeometry, from Kirchhoff to full-wave BEM.

Subpackages: ``wavebrdf.solver`` (numerics), ``wavebrdf.kernels`` (OpenCL C sources),
``wavebrdf.jobs`` (configs, planning, scheduling, HDF5 storage, CLI).
"""

from __future__ import annotations

from wavebrdf._version import __version__

__all__ = ["__version__", "open", "run"]

# open and run import the batch layer when called: importing any subpackage (wavebrdf.solver...)
# runs this file, which must not load h5py and the jobs modules for it


def open(path):  # noqa: A001 - mirrors xarray.open_dataset / h5py.File usage
    """Open a wavebrdf HDF5 dataset; returns a :class:`wavebrdf.jobs.store.Dataset`."""
    from wavebrdf.jobs.store import open_dataset

    return open_dataset(path)


def run(config, /, **kwargs):
    """Run a study (TOML path or dict of sections) with config overrides and return the opened
    dataset; see :func:`wavebrdf.jobs.api.run`."""
    from wavebrdf.jobs.api import run as _run

    return _run(config, **kwargs)
