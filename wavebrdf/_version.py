"""The installed package's version (its metadata; "0+unknown" in a source tree without install),
in a module of its own so that the modules that stamp it on their files need not import the
``wavebrdf`` facade."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version as _version

__all__ = ["__version__"]

try:
    __version__ = _version("wavebrdf")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"
