"""OpenCL C sources of wavebrdf (``*.cl``, ``*.h``) and their loader.

Kernels are plain ``.cl`` files next to this module. Local headers are pulled in with
``#include "name.h"``; :func:`load_source` inlines them (each header once) so the text handed to
the OpenCL compiler is self-contained. That makes the driver's build cache key complete: PoCL and
NVIDIA key their caches on the source text and options only, and would otherwise miss a header
edit.
"""

from __future__ import annotations

import hashlib
import re
from functools import lru_cache
from pathlib import Path

__all__ = ["KERNEL_DIR", "load_source", "source_hash"]

KERNEL_DIR = Path(__file__).resolve().parent
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$', re.MULTILINE)


def _expand(name: str, seen: set[str]) -> str:
    path = KERNEL_DIR / name
    if not path.is_file():
        raise FileNotFoundError(f"OpenCL source {name!r} not found in {KERNEL_DIR}")
    text = path.read_text()

    def include(match: re.Match) -> str:
        header = match.group(1)
        if header in seen:
            return f"/* {header}: already included */"
        seen.add(header)
        return f"/* begin {header} */\n{_expand(header, seen)}\n/* end {header} */"

    return _INCLUDE.sub(include, text)


@lru_cache(maxsize=None)
def load_source(name: str) -> str:
    """Return the text of ``kernels/<name>`` with its local ``#include "..."`` headers inlined."""
    return _expand(name, {name})


def source_hash(text: str) -> str:
    """Short SHA-256 of a kernel text, used in build cache keys."""
    return hashlib.sha256(text.encode()).hexdigest()[:16]
