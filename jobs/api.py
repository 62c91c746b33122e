"""Python API: ``wavebrdf.run(config, **overrides)`` runs a study as ``wavebrdf run`` does and
returns the opened dataset.

::

    import wavebrdf
    with wavebrdf.run("configs/default.toml", **{"output.resolution": 128, "study.output": "out/spectrum.h5",
                                                 "illumination.wavelengths_um": {"start": 0.4, "stop": 0.7,
                                                                                 "count": 7}}) as ds:
        ds.to_xarray().albedo.sel(theta_i=30)

``config`` is a TOML file or a dict of sections as TOML would load it. ``overrides`` are config
keys, dotted (``**{"surface.rms_height_um": 0.1}``) or a section's table merged into it
(``surface={"rms_height_um": 0.1}``), applied as ``--set`` applies them (jobs/overrides.py). The
same command runs underneath (resume, lock, "up to date", executors), so its errors are raised
as the CLI's one-line exceptions (:class:`~wavebrdf.jobs.config.ConfigError`, ...).
"""

from __future__ import annotations

import warnings
from pathlib import Path

from wavebrdf.jobs.cli import build_parser, detect_mpi_launch
from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.store import open_dataset

__all__ = ["run"]


def run(config, /, *, device: str | None = None, progress: bool = False, render: bool = False,
        wait: bool = False, force: bool = False, **overrides):
    """Run the study ``config`` (path or dict) with ``overrides``; return the dataset opened with
    :func:`wavebrdf.open` (close it, or use ``with``). ``device``: OpenCL device (as
    ``WAVEBRDF_DEVICE``); ``progress``: show the progress bar; ``render``: also write the PNGs;
    ``wait``: wait for another run holding the output instead of raising; ``force``: recompute
    an up-to-date output or replace another configuration's (refused otherwise, naming
    ``force=True``). Under ``mpiexec`` every rank calls it; rank 0 gets the dataset, the others
    None. Failed tasks are NaN in the dataset and raise a warning naming how many."""
    study = load_config(config if isinstance(config, dict) else Path(config), overrides=overrides or None)
    flags = ["--quiet"] * (not progress) + ["--no-render"] * (not render) + ["--wait"] * wait + ["--force"] * force
    args = build_parser().parse_args(["run", str(study.path or "config.toml"), *flags]
                                     + (["--device", device] if device else []))
    args.config, args.set = study, None  # validated once, above
    args.force_flag = "force=True"  # what refusals and "up to date" name to force a run
    code = args.func(args)
    launch = detect_mpi_launch()
    if launch is not None and launch.rank != 0:
        return None
    dataset = open_dataset(study.output)
    if code != 0:
        status = [s.decode() if isinstance(s, bytes) else str(s) for s in dataset.tasks.get("status", [])]
        warnings.warn(f"{status.count('failed')} of {len(status)} task(s) of {study.output} failed; their results "
                      "are NaN (see dataset.tasks); run again to retry them", RuntimeWarning, stacklevel=2)
    return dataset
