"""Where a study's dataset goes: ``[study] output`` checked at load (a .h5/.hdf5/.nc file in a
writable folder, at most the last folder level missing), and that one level created by
``wavebrdf run`` right before it writes. Nothing is created while a config is checked.
"""

from __future__ import annotations

import os
from pathlib import Path

from wavebrdf.jobs.errors import ConfigError, fail

__all__ = ["check_output_path", "make_output_folder"]


def check_output_path(raw_output: str) -> Path:
    """The dataset path: a .h5/.hdf5/.nc file name in a writable folder. The folder may be missing
    if its parent exists (``wavebrdf run`` creates that one level, as ``mkdir`` would: the shipped
    configs write to out/); deeper missing folders are refused, nothing is created here."""
    path = Path(raw_output).expanduser()
    if path.suffix not in (".h5", ".hdf5", ".nc"):
        raise fail("study", "output", raw_output, "must end in .h5 (or .hdf5/.nc)")
    parent = path.resolve().parent
    probe = parent
    while not probe.exists() and not probe.is_symlink():
        probe = probe.parent
    if not probe.is_dir():
        raise fail("study", "output", raw_output, f"folder {str(parent)!r} is not writable: {str(probe)!r} is "
                   "not a folder")
    if probe != parent and probe != parent.parent:
        raise fail("study", "output", raw_output, f"folder {str(parent)!r} does not exist, nor does "
                   f"{str(parent.parent)!r}; create the folder first")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise fail("study", "output", raw_output, f"folder {str(probe)!r} is not writable")
    if path.exists() and path.is_dir():
        raise fail("study", "output", raw_output, "is a folder")
    return path


def make_output_folder(output: Path) -> None:
    """Create the output's folder when it is the one missing level :func:`check_output_path`
    allows (``wavebrdf run`` only, right before it takes the output's lock). The rule holds here
    too, for paths that never went through it (``compare --out``) or whose folders vanished since:
    at most the last folder level is created; a deeper missing chain is a one-line ConfigError."""
    folder = Path(output).expanduser().resolve().parent
    if folder.is_dir():
        return
    if not folder.parent.is_dir():
        raise ConfigError(f"output {str(output)!r}: folder {str(folder)!r} does not exist, nor does "
                          f"{str(folder.parent)!r}; create the folder first (only the last level is created)")
    try:
        folder.mkdir()
    except FileExistsError:
        if not folder.is_dir():
            raise ConfigError(f"output {str(output)!r}: {str(folder)!r} is not a folder") from None
