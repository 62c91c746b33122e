"""What a run keeps on disk beside its output: the per-output lock, the parts folder
``<output>.parts/`` of finished task outputs (for resume and the final assembly), atomic writes.

- **Lock** (:class:`OutputLock`): ``<output>.lock``, an ``fcntl.flock`` held by one run for its
  whole duration (final write and PNGs included) and released by the kernel when the process
  dies; a second run on the same output is refused, naming the holder, or waits (``--wait``).
- **Atomic writes** (:func:`atomic_write`): under a temporary name, fsync, rename. A write that
  fails (disk full, I/O error, file too large) removes its temporary file and raises
  :class:`StorageError` naming the path: the previous state is kept.
- **Parts folder** (:class:`PartsFolder`): created complete with its ``manifest.json`` (built
  under a temporary name, then renamed into place) and removed by renaming it away first, so a
  folder without a valid manifest is never one of ours half-made or half-deleted: it is refused.
  The manifest records the plan's fingerprint: a folder of another configuration is refused.
  Every part file carries its identity (task id, task key, plan fingerprint) and a SHA-256
  checksum of its arrays; :meth:`PartsFolder.verify` checks every part before any new work
  starts and moves a bad one (foreign, edited, truncated, garbage) to ``rejected/``, with one
  log line, to be recomputed. Files: ``task-<id>.npz`` (result tasks: arrays + JSON
  diagnostics), ``patch-<id>.npz`` (sub-area far fields, kept until the dataset is written),
  ``failed-<id>.json`` (diagnostics of a task that failed for good), ``ran-<id>.json`` (where and
  how a finished task ran: rank, threads, dispatch wait, kernel build; the task table's columns).

Temporary names (all removed by the next run on the output, under its lock): ``.<name>.<pid>.tmp``
(files), ``.<output>.parts.<pid>.new`` / ``.old`` (the folder being created / removed).
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import re
import shutil
import socket
import threading
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from wavebrdf._version import __version__
from wavebrdf.solver.farfield import FarField

logger = logging.getLogger(__name__)

__all__ = ["OutputBusy", "OutputLock", "PartsFolder", "ResumeError", "StorageError", "atomic_write",
           "fsync_folder", "remove_leftovers", "storage_error", "temporary_path"]


class ResumeError(RuntimeError):
    """Existing partial results cannot be used (another configuration, no valid manifest)."""


class StorageError(OSError):
    """A file could not be written (disk full, I/O error, file too large); nothing was replaced."""


class OutputBusy(RuntimeError):
    """Another run holds the output's lock."""


class _BadPart(Exception):
    """A part file that cannot be used; the message says why."""


def storage_error(path: Path, exc: OSError) -> StorageError:
    """One-line error for a failed write of ``path``."""
    if isinstance(exc, StorageError):
        return exc
    code = f"[Errno {exc.errno}] " if exc.errno else ""
    reason = exc.strerror or str(exc) or type(exc).__name__
    fix = ("make the folder writable or write elsewhere" if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS)
           else "free space or fix the file system")
    return StorageError(f"cannot write {path}: {code}{reason}; nothing was replaced ({fix}, then re-run the same "
                        "command)")


def temporary_path(path: Path) -> Path:
    """Where ``path`` is written before its rename: ``.<name>.<pid>.<thread>.tmp`` beside it."""
    return path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")


def _discard(path: Path) -> None:
    try:
        path.unlink()
    except OSError:
        pass


def fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: some file systems refuse it)."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path: Path, write) -> None:
    """Write ``path`` through ``write(file)`` under a temporary name, fsync, then rename; on any
    failure the temporary file is removed and an OSError becomes a :class:`StorageError`."""
    path = Path(path)
    tmp = temporary_path(path)
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        _discard(tmp)
        if isinstance(exc, OSError):
            raise storage_error(path, exc) from None
        raise


_LEFTOVER = r"\.{name}\.(\d+(\.\d+)?|[a-z0-9_]{{8}})\.tmp|\.{name}\.parts\.\d+\.(new|old)"


def remove_leftovers(output: Path) -> list[Path]:
    """Remove what killed runs on ``output`` left behind: temporary datasets and parts folders
    being created or removed. Only call it holding the output's lock."""
    output = Path(output)
    pattern = re.compile(_LEFTOVER.format(name=re.escape(output.name)))
    removed = []
    for entry in output.parent.iterdir():
        if pattern.fullmatch(entry.name):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                _discard(entry)
            removed.append(entry)
    return removed


# ---------------------------------------------------------------------------------------------
# The lock


class OutputLock:
    """Exclusive lock of one output: ``fcntl.flock`` on ``<output>.lock`` (pid, host and start time
    of the holder inside). Use ``with OutputLock(path).acquire(wait): ...``; the file is removed on
    release (the inode check in :meth:`acquire` keeps that race-free)."""

    def __init__(self, output: Path):
        self.output = Path(output)
        self.path = self.output.with_name(self.output.name + ".lock")
        self._fd: int | None = None

    def holder(self) -> str:
        """Who holds the lock, as written in the lock file."""
        try:
            info = json.loads(self.path.read_text())
            return f"pid {info['pid']} on host {info['host']}, started {info['started']}"
        except (OSError, ValueError, KeyError, TypeError):
            return "holder unknown"

    def acquire(self, wait: bool = False) -> OutputLock:
        """Take the lock; if another process holds it, raise :class:`OutputBusy` naming it, or
        (``wait``) block until it is released."""
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
            except OSError as exc:
                raise storage_error(self.path, exc) from None
            try:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    busy = f"{self.output} is in use by another wavebrdf run ({self.holder()})"
                    if not wait:
                        raise OutputBusy(f"{busy}; wait for it to end, or add --wait to wait for it") from None
                    logger.warning("%s; waiting for it to end", busy)
                    fcntl.flock(fd, fcntl.LOCK_EX)
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            except OSError as exc:  # e.g. ENOLCK: a file system without flock
                os.close(fd)
                raise StorageError(f"cannot lock {self.path}: {exc.strerror or exc} (the file system does not "
                                   "support flock?); write the output to another folder") from None
            except BaseException:
                os.close(fd)
                raise
            if same:
                break
            os.close(fd)  # the previous holder removed the file meanwhile: lock the new one
        started = datetime.now(timezone.utc).isoformat(timespec="seconds")
        info = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": started}).encode()
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, info, 0)
        except OSError:  # a full disk: the lock holds all the same, only its description is missing
            pass
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            if os.fstat(self._fd).st_ino == os.stat(self.path).st_ino:
                self.path.unlink()
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> OutputLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


# ---------------------------------------------------------------------------------------------
# The parts folder


def checksum(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 of named arrays (names, dtypes, shapes and bytes, in name order)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


SYNTHESIS_FRAME = "requested"  # a synth part's diagnostics["polarization_frame"] (jobs/steering.py)


def _diagnostics(arrays: dict) -> dict:
    try:
        found = json.loads(str(arrays.get("diagnostics", "{}")))
    except ValueError:
        return {}
    return found if isinstance(found, dict) else {}


class PartsFolder:
    """Finished task outputs next to the dataset (see the module docstring)."""

    def __init__(self, plan):
        self.plan = plan
        output = Path(plan.config.output)
        self.path = output.with_name(output.name + ".parts")
        self.manifest = self.path / "manifest.json"
        self.rejected = self.path / "rejected"

    def _expected(self) -> dict:
        return {"fingerprint": self.plan.fingerprint, "tasks": len(self.plan.tasks)}

    def open(self) -> None:
        """Create the folder with its manifest, or check that an existing one belongs to this plan.
        The caller holds the output's lock."""
        if not self.path.exists() and not self.path.is_symlink():
            self._create(self._expected())
            return
        if self.check() is None:  # an empty folder holds nothing to trust or distrust
            self.path.rmdir()
            self._create(self._expected())
            return
        for tmp in self.path.glob(".*.tmp"):  # writes of a killed run
            _discard(tmp)

    def check(self) -> dict | None:
        """The manifest of the existing folder, refused (:class:`ResumeError`) unless it is this
        plan's; None for an empty folder. Reads only: nothing is created, moved or removed."""
        if not self.path.is_dir():
            raise ResumeError(f"{self.path} is not a folder; remove it to run this study")
        if not self.manifest.is_file():
            files = list(self.path.iterdir())
            if not files:
                return None
            raise ResumeError(
                f"{self.path} has no manifest.json, so its {len(files)} file(s) cannot be tied to a "
                "configuration (a run killed while removing it, or files copied in); delete that folder "
                "to start over"
            )
        try:
            found = json.loads(self.manifest.read_bytes())
            if not isinstance(found, dict) or not {"fingerprint", "tasks"} <= set(found):
                raise ValueError("not a manifest object")
        except (ValueError, OSError) as exc:
            raise ResumeError(
                f"{self.manifest} is not a valid manifest ({type(exc).__name__}), so the results in {self.path} "
                "cannot be tied to a configuration; delete that folder to start over"
            ) from None
        names = {"fingerprint": "fingerprint", "tasks": "task count"}
        differ = [f"{names[k]} {found.get(k)} in the folder, {v} in this config"
                  for k, v in self._expected().items() if found.get(k) != v]
        if differ:
            raise ResumeError(
                f"{self.path} holds partial results of a different configuration ({'; '.join(differ)}); "
                "delete that folder to start over, or restore the original config to resume"
            )
        return found

    def _create(self, expected: dict) -> None:
        new = self.path.with_name(f".{self.path.name}.{os.getpid()}.new")
        payload = json.dumps({**expected, "software_version": __version__}).encode()
        try:
            new.mkdir()
            atomic_write(new / "manifest.json", lambda fh: fh.write(payload))
            os.rename(new, self.path)
            fsync_folder(self.path.parent)
        except OSError as exc:
            if new.exists():
                shutil.rmtree(new, ignore_errors=True)
            raise storage_error(self.path, exc) from None

    # --- part files ------------------------------------------------------------------------

    def _file(self, task) -> Path:
        prefix = "patch" if task.kind == "patch" else "task"
        return self.path / f"{prefix}-{task.id:06d}.npz"

    def identity(self, task) -> dict:
        """What a part file must say about itself: task id, task key, the plan's fingerprint."""
        return {"task": task.id, "key": task.key, "fingerprint": self.plan.fingerprint}

    def done(self, task) -> bool:
        return self._file(task).exists()

    def problem(self, task) -> str | None:
        """Why the part file of ``task`` cannot be used (None: it is good)."""
        try:
            self._read(task)
        except _BadPart as exc:
            return str(exc)
        return None

    def inspect(self) -> tuple[set[int], dict[int, str]]:
        """Check every part file (identity and checksum), moving nothing: the ids of the tasks whose
        part is good (done) and, per task whose part is bad, why."""
        good, bad = set(), {}
        for task in self.plan.tasks:
            if not self._file(task).exists():
                continue
            problem = self.problem(task)
            if problem is None:
                good.add(task.id)
            else:
                bad[task.id] = problem
        return good, bad

    def verify(self) -> set[int]:
        """:meth:`inspect`, then move the bad parts to ``rejected/`` with one log line each (they
        are recomputed). Returns the ids of the tasks whose part is good (done)."""
        good, bad = self.inspect()
        for task_id, problem in bad.items():
            path = self._file(self.plan.tasks[task_id])
            self.rejected.mkdir(exist_ok=True)
            os.replace(path, self.rejected / path.name)
            logger.warning("%s: %s; moved to %s/, the task will be recomputed", path, problem, self.rejected.name)
        return good

    def save_arrays(self, task, diagnostics: dict, **arrays: np.ndarray) -> None:
        """Store a task's arrays and diagnostics with its identity and checksum (atomic)."""
        payload = {**arrays, "diagnostics": np.array(json.dumps(diagnostics)),
                   "identity": np.array(json.dumps(self.identity(task), sort_keys=True))}
        payload["checksum"] = np.array(checksum(payload))
        atomic_write(self._file(task), lambda fh: np.savez(fh, **payload))

    def _read(self, task) -> dict[str, np.ndarray]:
        """The verified arrays of ``task``'s part (:class:`_BadPart` otherwise)."""
        try:
            with np.load(self._file(task), allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except Exception as exc:  # noqa: BLE001 - any failure to read untrusted bytes is damage
            raise _BadPart(f"unreadable ({type(exc).__name__}: {str(exc)[:80]})") from None
        stored, identity = arrays.pop("checksum", None), arrays.get("identity")
        if stored is None or identity is None or "diagnostics" not in arrays:
            raise _BadPart("carries no identity/checksum (not written by this version)")
        try:
            found = json.loads(str(identity))
        except ValueError:
            found = {}
        expected = self.identity(task)
        if not isinstance(found, dict) or found.get("fingerprint") != expected["fingerprint"]:
            raise _BadPart("belongs to another configuration")
        if found != expected:
            raise _BadPart(f"belongs to task {found.get('task')} ({found.get('key')}), not to task {task.id} "
                           f"({task.key})")
        if str(stored) != checksum(arrays):
            raise _BadPart("its arrays do not match their checksum (edited or damaged)")
        if task.kind == "synth" and _diagnostics(arrays).get("polarization_frame") != SYNTHESIS_FRAME:
            raise _BadPart("a steered synthesis in its basic direction's polarization frame (written before "
                           "syntheses answered the requested direction's s and p)")
        return arrays

    def load_arrays(self, task) -> tuple[dict, dict]:
        """A verified part's arrays and diagnostics (ResumeError if it was damaged meanwhile)."""
        try:
            arrays = self._read(task)
        except _BadPart as exc:
            raise ResumeError(f"{self._file(task)}: {exc}; re-run the same command to recompute it") from None
        diagnostics = json.loads(str(arrays.pop("diagnostics")))
        arrays.pop("identity")
        return arrays, diagnostics

    def save_farfield(self, task, ff: FarField, diagnostics: dict) -> None:
        arrays = {"E": ff.E, "incident_power": ff.incident_power,
                  "scalars": np.array([ff.wavelength_um, ff.exterior_index, ff.theta_i, ff.phi_i])}
        if ff.H is not None:
            arrays["H"] = ff.H
        self.save_arrays(task, diagnostics, **arrays)

    def load_farfield(self, task) -> FarField:
        arrays, diagnostics = self.load_arrays(task)
        lam, n1, theta, phi = arrays["scalars"]
        return FarField(grid=self.plan.grid, wavelength_um=float(lam), exterior_index=float(n1),
                        theta_i=float(theta), phi_i=float(phi), E=arrays["E"], H=arrays.get("H"),
                        incident_power=arrays["incident_power"], diagnostics=diagnostics)

    def adopt(self, task, other: PartsFolder) -> bool:
        """Copy ``task``'s part from ``other`` (a folder of the same plan, e.g. a shard's) into
        this folder, atomically, if it verifies there; True when copied."""
        if other.problem(task) is not None:
            return False
        source = other._file(task)
        atomic_write(self._file(task), lambda fh: fh.write(source.read_bytes()))
        ran = other.run_info(task)
        if ran:
            self.save_run_info(task, ran)
        return True

    def load_diagnostics(self, task) -> dict:
        return self.load_arrays(task)[1]

    # --- how each task ran ------------------------------------------------------------------

    def _run_file(self, task) -> Path:
        return self.path / f"ran-{task.id:06d}.json"

    def save_run_info(self, task, info: dict) -> None:
        """Where and how ``task`` ran (rank, threads, dispatch wait, kernel build: the task table's
        columns), kept beside its part so that a resumed or merged run's dataset has them too."""
        payload = json.dumps(info).encode()
        atomic_write(self._run_file(task), lambda fh: fh.write(payload))

    def run_info(self, task) -> dict:
        """What :meth:`save_run_info` kept for ``task`` ({} where nothing readable was)."""
        try:
            found = json.loads(self._run_file(task).read_bytes())
        except (OSError, ValueError):
            return {}
        return found if isinstance(found, dict) else {}

    # --- failures ---------------------------------------------------------------------------

    def _failure_file(self, task) -> Path:
        return self.path / f"failed-{task.id:06d}.json"

    def save_failure(self, task, diagnostics: dict) -> None:
        payload = json.dumps(diagnostics).encode()
        atomic_write(self._failure_file(task), lambda fh: fh.write(payload))

    def failure(self, task) -> dict | None:
        path = self._failure_file(task)
        if not path.exists():
            return None
        try:
            found = json.loads(path.read_bytes())
        except (ValueError, OSError):
            found = None
        return found if isinstance(found, dict) else {"error": f"{path.name} is unreadable"}

    def clear_failure(self, task) -> None:
        self._failure_file(task).unlink(missing_ok=True)

    def remove(self) -> None:
        """Remove the folder: renamed away first (atomic), then deleted."""
        if not self.path.is_dir():
            return
        old = self.path.with_name(f".{self.path.name}.{os.getpid()}.old")
        try:
            os.rename(self.path, old)
        except OSError as exc:
            if exc.errno != errno.ENOENT:
                logger.warning("cannot remove %s (%s); delete it by hand", self.path, exc)
            return
        shutil.rmtree(old, ignore_errors=True)
