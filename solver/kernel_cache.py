"""One build of each OpenCL program per node: the kernel cache shared by a node's processes.

PoCL keeps compiled programs in ``POCL_CACHE_DIR`` (default ``$XDG_CACHE_HOME/pocl``, else
``~/.cache/pocl``) and writes them there under temporary names renamed into place, so concurrent
writers are safe but, started together, every rank would compile the same program. Each build
therefore holds an exclusive ``flock`` on ``<cache>/wavebrdf-locks/<key>.lock``: the first process
builds (and fills the cache); the others wait, then find the program in the cache. Where the
folder cannot be created or locked (read-only, no ``flock``), builds run unlocked.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import time
from contextlib import contextmanager
from pathlib import Path

__all__ = ["LockedKernel", "build_lock", "cache_folder"]


def cache_folder() -> Path:
    """The kernel cache folder PoCL uses for this process."""
    if os.environ.get("POCL_CACHE_DIR", "").strip():
        return Path(os.environ["POCL_CACHE_DIR"]).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(xdg) if xdg else Path.home() / ".cache") / "pocl"


@contextmanager
def build_lock(*key: str):
    """Hold the node-wide build lock of the program identified by ``key`` (source hash, options,
    device) while the body builds it."""
    name = hashlib.sha256("\0".join(key).encode()).hexdigest()[:24]
    fd = None
    try:
        folder = cache_folder() / "wavebrdf-locks"
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(folder / f"{name}.lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        fcntl.flock(fd, fcntl.LOCK_EX)
    except OSError:
        if fd is not None:
            os.close(fd)
        fd = None
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)  # releases the lock


class LockedKernel:
    """A kernel whose first launch per local size holds the build lock until it has run: PoCL
    compiles a kernel for its work-group size at its first launch (into the same cache), so the
    node's other processes wait for that compilation instead of repeating it."""

    def __init__(self, kernel, key: str, account=None):
        self._kernel = kernel
        self._key = key
        self._launched: set = set()
        self._account = account  # account(seconds) of each first launch (compilation and wait included)

    def __call__(self, queue, global_size, local_size, *args, **kwargs):
        shape = None if local_size is None else tuple(local_size)
        if shape in self._launched:
            return self._kernel(queue, global_size, local_size, *args, **kwargs)
        t0 = time.perf_counter()
        with build_lock(self._key, repr(shape)):
            event = self._kernel(queue, global_size, local_size, *args, **kwargs)
            queue.finish()
        self._launched.add(shape)
        if self._account is not None:
            self._account(time.perf_counter() - t0)
        return event

    def __getattr__(self, name):
        return getattr(self._kernel, name)
