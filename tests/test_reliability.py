"""Reliability of the batch layer (issue 17): no lost or mixed results under concurrency, damage,
kills or full disks; user errors answered with one line.

Each ``test_defect<N>_...`` reproduces defect N of the issue (it failed before the fix). The
20-trial concurrency check is ``test_two_simultaneous_runs_20_trials`` (``-m slow``).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from dataclasses import replace

import h5py
import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.solver.approx.kirchhoff import KirchhoffModel

BIN = Path(sys.executable).parent
STUDY = """
[study]
name = "rel"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 4.0
cells = 32
rms_height_um = 0.04
correlation_um = 0.8
seed = 3

[material]
name = "gold"

[illumination]
wavelengths_um = {wavelengths}
directions_deg = [[0, 0], [25, 10], [50, 90]]
waist_um = 0.8

[model]
name = "kirchhoff"

[output]
resolution = 48
{extra}
"""
N_TASKS = 6  # 2 wavelengths x 3 directions


def write_study(folder: Path, name: str = "rel", wavelengths=(0.55, 0.65), extra: str = "") -> Path:
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(STUDY.format(out=folder / f"{name}.h5", wavelengths=list(wavelengths),
                                                 extra=extra)))
    return path


def read(path: Path) -> dict:
    with h5py.File(path, "r") as h5:
        return {"brdf": h5["brdf"][()], "albedo": h5["albedo"][()], "wavelength_um": h5["wavelength_um"][()],
                "status": h5["tasks/status"][()].astype(str), "ids": h5["tasks/id"][()]}


def assert_same(a: dict, b: dict) -> None:
    """Same tasks, all done, bit-identical results (the runs are deterministic)."""
    assert sorted(a["ids"]) == sorted(b["ids"]) and set(a["status"]) == set(b["status"]) == {"done"}
    assert np.array_equal(a["wavelength_um"], b["wavelength_um"])
    assert np.array_equal(a["brdf"], b["brdf"], equal_nan=True) and np.array_equal(a["albedo"], b["albedo"])


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    """An uninterrupted run of the study, per wavelength set."""
    folder = tmp_path_factory.mktemp("reference")
    out = {}
    for wavelengths in ((0.55, 0.65), (0.55, 0.60)):
        cfg = write_study(folder, f"ref{len(out)}", wavelengths)
        assert main(["run", str(cfg), "-q", "--no-render"]) == 0
        out[wavelengths] = read(folder / f"ref{len(out)}.h5")
    return out


LOG_LINE = re.compile(r"^\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2} ")  # a batch log line (one per finished task)


def one_line_error(err: str) -> str:
    """The single error line of ``err``; the timestamped per-task log lines a run writes to a
    non-terminal stderr (docs/batch.md) are not part of the error."""
    lines = [line for line in err.strip().splitlines() if not LOG_LINE.match(line)]
    assert len(lines) == 1 and lines[0].startswith("wavebrdf: error:") and "Traceback" not in err, err
    return lines[0]


def tree(folder: Path) -> set:
    return {(str(p.relative_to(folder)), p.stat().st_size if p.is_file() else -1) for p in folder.rglob("*")}


def wavebrdf(*args) -> list[str]:
    return [str(BIN / "wavebrdf"), *map(str, args)]


# --- defect 1: concurrent runs on one output ------------------------------------------------------


def wait_for(predicate, timeout=120.0, proc=None):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        if proc is not None and proc.poll() is not None:
            return predicate()
        time.sleep(0.01)
    return False


def test_defect1_second_run_on_the_same_output_is_refused(tmp_path, capsys, reference):
    """While one run works on an output, a second one says who holds it and exits 2 (no --wait),
    or waits and then completes the study (--wait)."""
    cfg = write_study(tmp_path)
    first = subprocess.Popen(wavebrdf("run", cfg, "-q", "--no-render"), stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: (tmp_path / "rel.h5.parts").is_dir(), proc=first), first.stderr.read()
        code = main(["run", str(cfg), "-q", "--no-render"])
        line = one_line_error(capsys.readouterr().err)
        assert code == 2 and f"pid {first.pid}" in line and "--wait" in line, line
        assert main(["run", str(cfg), "-q", "--no-render", "--wait"]) == 0
    finally:
        first.wait(timeout=120)
    assert first.returncode == 0
    assert_same(read(tmp_path / "rel.h5"), reference[(0.55, 0.65)])
    assert not (tmp_path / "rel.h5.parts").exists() and not (tmp_path / "rel.h5.lock").exists()


def simultaneous_runs(folder: Path, reference: dict, trial: int) -> tuple[int, int]:
    """Start two runs of one study at once; whatever their order, nothing is lost or mixed."""
    cfg = write_study(folder, f"c{trial}")
    procs = [subprocess.Popen(wavebrdf("run", cfg, "-q", "--no-render"), stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(code for code, _ in results)
    for code, err in results:
        assert code in (0, 2), err
        if code == 2:
            assert "is in use by" in one_line_error(err)
    assert 0 in codes, results
    assert_same(read(folder / f"c{trial}.h5"), reference[(0.55, 0.65)])
    leftovers = [p.name for p in folder.iterdir() if p.name.startswith((f".c{trial}", f"c{trial}.h5."))]
    assert leftovers == [], leftovers
    return tuple(codes)


def test_defect1_two_simultaneous_runs_3_trials(tmp_path, reference):
    for trial in range(3):
        simultaneous_runs(tmp_path, reference, trial)


@pytest.mark.slow
def test_two_simultaneous_runs_20_trials(tmp_path, reference):
    outcomes = [simultaneous_runs(tmp_path, reference, trial) for trial in range(20)]
    print("exit codes of the two runs per trial:", outcomes)


@pytest.mark.mpi
def test_defect1_mpi_run_refused_while_the_output_is_held(tmp_path):
    """Under MPI rank 0 takes the lock before any rank works; a held output stops every rank."""
    from wavebrdf.jobs.parts import OutputLock

    cfg = write_study(tmp_path)
    env = {**os.environ, "PATH": f"{BIN}:{os.environ['PATH']}"}
    with OutputLock(tmp_path / "rel.h5").acquire():
        result = subprocess.run([str(BIN / "mpiexec"), "-n", "2", *wavebrdf("run", cfg, "-q", "--no-render")],
                                capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 2, result.stderr[-2000:]
    assert f"pid {os.getpid()}" in one_line_error(result.stderr)
    assert not (tmp_path / "rel.h5.parts").exists() and not (tmp_path / "rel.h5").exists()


# --- defect 2: a parts folder without its manifest --------------------------------------------------

KILL_IN_CLEANUP = """
import os, shutil, signal, sys
from pathlib import Path
from wavebrdf.jobs import parts

def rmtree(path, *args, **kwargs):  # delete the manifest and one task file, then die
    folder = Path(path)
    for name in ("manifest.json", "task-000000.npz"):
        (folder / name).unlink(missing_ok=True)
    os.kill(os.getpid(), signal.SIGKILL)

parts.shutil.rmtree = rmtree
from wavebrdf.jobs.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_defect2_sigkill_in_cleanup_then_changed_wavelength_is_never_mixed(tmp_path, capsys, reference):
    cfg = write_study(tmp_path, wavelengths=(0.55, 0.65))
    killed = subprocess.run([sys.executable, "-c", KILL_IN_CLEANUP, "run", str(cfg), "-q", "--no-render"],
                            capture_output=True, text=True)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    cfg = write_study(tmp_path, wavelengths=(0.55, 0.60))  # the user changes λ and runs again
    code = main(["run", str(cfg), "-q", "--no-render"])
    err = capsys.readouterr().err
    if code == 2:  # refused: the parts folder cannot be tied to a configuration, or the finished
        line = one_line_error(err)  # dataset holds another configuration (named, with what changed)
        assert "rel.h5.parts" in line or ("rel.h5" in line and "wavelengths_um" in line), line
    else:  # or recomputed: every slot holds the 0.60 µm result
        assert code == 0, err
        assert_same(read(tmp_path / "rel.h5"), reference[(0.55, 0.60)])


@pytest.mark.parametrize("manifest", [None, b"", b"\x00\xffgarbage{", b"[1, 2]", b'{"fingerprint": 3}'],
                         ids=["missing", "empty", "garbage", "not-an-object", "incomplete"])
def test_defect2_parts_folder_without_a_valid_manifest_is_refused(tmp_path, capsys, manifest):
    cfg = write_study(tmp_path)
    folder = tmp_path / "rel.h5.parts"
    folder.mkdir()
    np.savez(folder / "task-000001.npz", brdf_sp=np.zeros((2, 48, 48), np.float32))
    if manifest is not None:
        (folder / "manifest.json").write_bytes(manifest)
    before = tree(tmp_path)
    assert main(["run", str(cfg), "-q", "--no-render"]) == 2
    line = one_line_error(capsys.readouterr().err)
    assert str(folder) in line and "delete" in line, line
    assert tree(tmp_path) == before


# --- defect 3: part files tied to their task ----------------------------------------------------------


def kept_parts(tmp_path: Path, monkeypatch) -> tuple[Path, Path]:
    """Run the study but keep its parts folder (as a run killed after its last task would)."""
    from wavebrdf.jobs.parts import PartsFolder

    cfg = write_study(tmp_path)
    with monkeypatch.context() as m:
        m.setattr(PartsFolder, "remove", lambda self: None)
        assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    (tmp_path / "rel.h5").unlink()
    return cfg, tmp_path / "rel.h5.parts"


def edit_brdf(path: Path) -> None:
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["brdf_sp"] = arrays["brdf_sp"] * 3.0
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


TAMPER = {
    "swapped": lambda f: shutil.copyfile(f / "task-000004.npz", f / "task-000001.npz"),
    "edited": lambda f: edit_brdf(f / "task-000001.npz"),
    "truncated": lambda f: os.truncate(f / "task-000001.npz", (f / "task-000001.npz").stat().st_size // 2),
    "empty": lambda f: os.truncate(f / "task-000001.npz", 0),
    "garbage": lambda f: (f / "task-000001.npz").write_bytes(os.urandom(3000)),
}


@pytest.mark.parametrize("how", list(TAMPER))
def test_defect3_tampered_part_is_recomputed(tmp_path, monkeypatch, caplog, reference, how):
    cfg, folder = kept_parts(tmp_path, monkeypatch)
    TAMPER[how](folder)
    caplog.set_level("WARNING")
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    said = [r.getMessage() for r in caplog.records if "task-000001.npz" in r.getMessage()]
    assert len(said) == 1 and "recomputed" in said[0], said
    assert_same(read(tmp_path / "rel.h5"), reference[(0.55, 0.65)])


def test_defect3_part_of_another_configuration_is_recomputed(tmp_path, monkeypatch, reference):
    """A part copied in from a run with another wavelength set (same task numbering) is foreign."""
    cfg, folder = kept_parts(tmp_path, monkeypatch)
    other = tmp_path / "other"
    other.mkdir()
    _, foreign = kept_parts(other, monkeypatch)
    shutil.rmtree(foreign.parent / "rel.h5.parts")
    write_study(other, wavelengths=(0.55, 0.60))
    from wavebrdf.jobs.parts import PartsFolder

    with monkeypatch.context() as m:
        m.setattr(PartsFolder, "remove", lambda self: None)
        assert main(["run", str(other / "rel.toml"), "-q", "--no-render"]) == 0
    shutil.copyfile(other / "rel.h5.parts" / "task-000003.npz", folder / "task-000003.npz")  # λ 0.60 slot
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    assert_same(read(tmp_path / "rel.h5"), reference[(0.55, 0.65)])


# --- defect 4: disk full -------------------------------------------------------------------------------

FILE_SIZE_LIMIT = """
import resource, signal, sys
from wavebrdf.jobs import parts, scheduler
limit, when = int(sys.argv[1]), sys.argv[2]
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG

def set_limit():
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))

if when == "final":  # the last HDF5 write
    write = scheduler.write_dataset
    scheduler.write_dataset = lambda *a, **k: (set_limit(), write(*a, **k))[1]
else:  # the part files, from the second one on (the OpenCL kernels are built by then)
    save, calls = parts.PartsFolder.save_arrays, []
    def save_arrays(self, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            set_limit()
        return save(self, *a, **k)
    parts.PartsFolder.save_arrays = save_arrays
from wavebrdf.jobs.cli import main
sys.exit(main(sys.argv[3:]))
"""


@pytest.mark.parametrize("when, limit", [("final", 20_000), ("final", 60_000), ("parts", 1_000)])
def test_defect4_disk_full_leaves_the_previous_state_and_one_line(tmp_path, reference, when, limit):
    cfg = write_study(tmp_path)
    previous = tmp_path / "rel.h5"
    previous.write_bytes(b"the previous dataset")  # not a dataset: only --force replaces it
    result = subprocess.run([sys.executable, "-c", FILE_SIZE_LIMIT, str(limit), when, "run", str(cfg), "-q",
                             "--no-render", "--force"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr[-3000:]
    line = one_line_error(result.stderr.split("\n", 1)[1])  # after the "study ...: N task(s)" line
    assert "File too large" in line and str(tmp_path) in line, line
    assert previous.read_bytes() == b"the previous dataset"
    assert not [p for p in tmp_path.rglob("*.tmp")], list(tmp_path.rglob("*"))
    # the finished parts are kept; the same command completes the study once space is back
    previous.unlink()
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    assert_same(read(previous), reference[(0.55, 0.65)])


# --- defect 6: plan sizes before allocating ------------------------------------------------------------


PEAK_PROBE = ("import sys\nfrom wavebrdf.jobs.cli import main\nrc = main(sys.argv[1:])\n"
              "status = open('/proc/self/status').read()\n"
              "sys.stderr.write('VmHWM ' + status.split('VmHWM:')[1].split()[0] + '\\n')\nsys.exit(rc)")


def plan_with_peak(cfg) -> tuple[subprocess.CompletedProcess, float]:
    """``wavebrdf plan cfg`` in a fresh interpreter, and that process's own peak resident memory
    (MB; VmHWM, not the largest of every child the test process ever had)."""
    result = subprocess.run([sys.executable, "-c", PEAK_PROBE, "plan", str(cfg)], capture_output=True, text=True,
                            timeout=120)
    lines = result.stderr.splitlines()
    peak = float(lines[-1].split()[1]) / 1024
    result.stderr = "\n".join(lines[:-1]) + "\n"
    return result, peak


@pytest.mark.parametrize("cells", ["100000", "99999999999999999999"])
def test_defect6_plan_refuses_huge_cells_before_allocating(tmp_path, cells):
    cfg = write_study(tmp_path)
    cfg.write_text(cfg.read_text().replace("cells = 32", f"cells = {cells}"))
    result, peak_mb = plan_with_peak(cfg)
    assert result.returncode == 2
    line = one_line_error(result.stderr)
    assert f"cells = {cells}" in line, line
    assert peak_mb < 1500, peak_mb


def test_defect6_plan_refuses_a_huge_height_file_from_its_header(tmp_path):
    """A 100001² .npy (80 GB, sparse here): refused from its header, never read."""
    path = tmp_path / "huge.npy"
    header = np.lib.format.header_data_from_array_1_0(np.zeros((2, 2)))
    header["shape"] = (100001, 100001)
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, header)
        fh.seek(fh.tell() + 100001**2 * 8 - 1)
        fh.write(b"\0")
    cfg = write_study(tmp_path)
    text = cfg.read_text()
    start, end = text.index("generator ="), text.index("[material]")
    cfg.write_text(text[:start] + 'file = "huge.npy"\nsize_um = 4.0\n\n' + text[end:])
    result, peak_mb = plan_with_peak(cfg)
    line = one_line_error(result.stderr)
    assert result.returncode == 2 and "huge.npy" in line and "100001" in line, line
    assert peak_mb < 1500, peak_mb


class BufferedModel(KirchhoffModel):
    """Kirchhoff, reporting a device buffer of 16 bytes per node and 32 bytes per node in all."""

    name = "buffered-test"

    def estimate(self, scene):
        nodes = (scene.surface.cells + 1) ** 2
        return replace(super().estimate(scene), largest_buffer_bytes=16.0 * nodes, device_bytes=32.0 * nodes)


def test_defect6_plan_checks_the_device_limits(tmp_path, capsys, monkeypatch):
    """A task whose largest buffer exceeds the device's max allocation, or whose device memory
    (times the tasks at once) exceeds the device's global memory, is refused by plan and run
    (it was left to fail on the device, as NaN)."""
    from wavebrdf.jobs import cli
    from wavebrdf.solver import models
    from wavebrdf.solver.opencl import choose_device, list_devices

    monkeypatch.setitem(models._REGISTRY, "buffered-test", f"{__name__}:BufferedModel")  # gone after the test
    device = choose_device("auto", list_devices())
    cfg = write_study(tmp_path)
    cfg.write_text(cfg.read_text().replace('name = "kirchhoff"', 'name = "buffered-test"'))
    buffer_gib = 16.0 * 33**2 / 2**30
    monkeypatch.setattr(cli, "device_info", lambda spec=None: replace(device, max_alloc_gib=0.9 * buffer_gib))
    assert main(["plan", str(cfg)]) == 2
    line = one_line_error(capsys.readouterr().err)
    assert "max allocation" in line and "GiB" in line, line
    assert main(["run", str(cfg), "-q", "--no-render"]) == 2
    assert "max allocation" in one_line_error(capsys.readouterr().err)
    small = replace(device, max_alloc_gib=buffer_gib, global_mem_gib=3.5 * buffer_gib)  # 2 tasks hold 4 buffers
    monkeypatch.setattr(cli, "device_info", lambda spec=None: small)
    assert main(["plan", str(cfg)]) == 0
    assert main(["plan", str(cfg), "--workers", "2"]) == 2
    assert "global memory" in one_line_error(capsys.readouterr().err)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("rel.h5")]


# --- defect 7: orphans ---------------------------------------------------------------------------------


def workers_of(pid: int) -> list[int]:
    """The multiprocessing workers (not the resource tracker) started by ``pid``."""
    try:
        children = [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []
    out = []
    for child in children:
        try:
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                out.append(child)
        except OSError:
            pass
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_defect7_process_workers_die_with_their_parent(tmp_path):
    """SIGKILL the parent of two busy workers (tasks of ~1.5 s each): both end at once, instead
    of living on, blocked on the queues of the dead pool."""
    cfg = write_study(tmp_path, wavelengths=(0.4,))
    text = cfg.read_text().replace("cells = 32", "cells = 800").replace("size_um = 4.0", "size_um = 12.0")
    text = text.replace("rms_height_um = 0.04", "rms_height_um = 0.3").replace("resolution = 48", "resolution = 512")
    cfg.write_text(text.replace("[[0, 0], [25, 10], [50, 90]]", "[[0, 0], [10, 0], [20, 0], [30, 0]]"))
    parent = subprocess.Popen(wavebrdf("run", cfg, "-q", "--no-render", "--executor", "processes", "--workers", "2"),
                              stderr=subprocess.DEVNULL)
    workers = []
    try:
        assert wait_for(lambda: len(workers_of(parent.pid)) >= 2, proc=parent)
        workers = workers_of(parent.pid)
        time.sleep(1.0)  # the workers are computing their first tasks
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        assert wait_for(lambda: not any(alive(w) for w in workers), timeout=10), [w for w in workers if alive(w)]
    finally:
        for w in workers:
            if alive(w):
                os.kill(w, signal.SIGKILL)


def test_defect7_no_temporary_dataset_left_after_a_resume(tmp_path):
    cfg = write_study(tmp_path)
    stale = tmp_path / ".rel.h5.k3v9q2x1.tmp"  # a final write killed half way (old naming)
    stale.write_bytes(b"\x89HDF\r\n\x1a\n half a dataset")
    (tmp_path / f".rel.h5.{os.getpid() + 1}.tmp").write_bytes(b"another")
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_defect7_render_checks_its_input_before_creating_the_folder(tmp_path, capsys):
    for target in (tmp_path / "garbage.h5", tmp_path / "folder.h5", tmp_path / "missing.h5"):
        if target.name == "garbage.h5":
            target.write_bytes(b"not hdf5")
        elif target.name == "folder.h5":
            target.mkdir()
        assert main(["render", str(target)]) == 2
        one_line_error(capsys.readouterr().err)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith("_png")]


def test_defect7_render_failure_leaves_no_partial_png_set(tmp_path, capsys, monkeypatch):
    cfg = write_study(tmp_path)
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    capsys.readouterr()
    import matplotlib.figure

    saved = []
    real_savefig = matplotlib.figure.Figure.savefig

    def savefig(self, *args, **kwargs):
        saved.append(args[0])
        if len(saved) == 3:
            raise OSError(28, "No space left on device", str(args[0]))
        return real_savefig(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    assert main(["render", str(tmp_path / "rel.h5"), "--plots", "maps"]) == 2
    assert "No space left" in one_line_error(capsys.readouterr().err)
    assert not [p for p in tmp_path.rglob("*.png")] and not [p for p in tmp_path.iterdir() if "png" in p.name]
    monkeypatch.undo()
    assert main(["render", str(tmp_path / "rel.h5"), "--plots", "maps"]) == 0
    assert len(list((tmp_path / "rel_png").glob("*.png"))) == 3


# --- defects 8 and 9: one-line errors for user mistakes -------------------------------------------------


def _npy(dtype_or_array):
    def make(folder: Path) -> str:
        value = dtype_or_array if isinstance(dtype_or_array, np.ndarray) else np.zeros((9, 9), dtype_or_array)
        np.save(folder / "z.npy", value)
        return "z.npy"
    return make


def _text_npy(folder: Path) -> str:
    (folder / "z.npy").write_text("0 0 0\n0 0 0\n0 0 0\n")
    return "z.npy"


HEIGHT_FILES = {
    "structured": (_npy(np.dtype([("a", "f8"), ("b", "i4")])), "structured"),
    "complex": (_npy(np.complex128), "complex"),
    "bool": (_npy(np.bool_), "bool"),
    "strings": (_npy(np.array([["a"] * 9] * 9)), "<U1"),
    "text-named-npy": (_text_npy, "not a .npy file"),
    "folder": (lambda f: (f / "zdir").mkdir() or "zdir", "is a folder"),
    "dev-null": (lambda f: "/dev/null", "not a regular file"),
}


@pytest.mark.parametrize("case", list(HEIGHT_FILES))
def test_defect8_9_bad_height_files(tmp_path, capsys, case):
    make, expected = HEIGHT_FILES[case]
    name = make(tmp_path)
    cfg = write_study(tmp_path)
    text = cfg.read_text()
    start, end = text.index("generator ="), text.index("[material]")
    cfg.write_text(text[:start] + f'file = "{name}"\nsize_um = 4.0\n\n' + text[end:])
    before = tree(tmp_path)
    assert main(["run", str(cfg), "-q", "--no-render"]) == 2
    line = one_line_error(capsys.readouterr().err)
    assert expected in line and name in line, line
    assert tree(tmp_path) == before


def _binary_config(folder: Path) -> list[str]:
    (folder / "bin.toml").write_bytes(bytes(range(256)))
    return ["run", str(folder / "bin.toml")]


def _config_with(folder: Path, old: str, new: str, command="run") -> list[str]:
    cfg = write_study(folder)
    cfg.write_text(cfg.read_text().replace(old, new, 1))
    return [command, str(cfg)]


def _dataset_without(folder: Path, variable: str, command: str) -> list[str]:
    path = folder / "d.h5"
    with h5py.File(path, "w") as h5:
        h5.attrs.update({"format": "wavebrdf", "format_version": 1, "kind": "surface", "config": ""})
        for name in ("brdf", "albedo"):
            if name != variable:
                h5[name] = np.zeros((1, 1, 4, 4))
    return [command, str(path)]


def _dataset_version(folder: Path) -> list[str]:
    path = folder / "d.h5"
    with h5py.File(path, "w") as h5:
        h5.attrs.update({"format": "wavebrdf", "format_version": 99, "kind": "surface"})
    return ["inspect", str(path)]


USER_ERRORS = {
    "binary config": (_binary_config, "not UTF-8 text"),
    "absurd integer": (lambda f: _config_with(f, "cells = 32", "cells = 99999999999999999999"), "cells = "),
    "workers -3": (lambda f: ["run", str(write_study(f)), "--workers", "-3"], "--workers -3"),
    "workers 0": (lambda f: ["run", str(write_study(f)), "--workers", "0"], "--workers 0"),
    "workers text": (lambda f: ["plan", str(write_study(f)), "--workers", "many"], "--workers"),
    "memory-gb -1": (lambda f: ["plan", str(write_study(f)), "--memory-gb", "-1"], "--memory-gb -1"),
    "memory-gb nan": (lambda f: ["plan", str(write_study(f)), "--memory-gb", "nan"], "--memory-gb nan"),
    "inspect without brdf": (lambda f: _dataset_without(f, "brdf", "inspect"), "'brdf'"),
    "render without albedo": (lambda f: _dataset_without(f, "albedo", "render"), "'albedo'"),
    "format_version 99": (_dataset_version, "format version 99"),
    "name ../../evil": (lambda f: _config_with(f, 'name = "rel"', 'name = "../../evil"'), "[study] name"),
    "name with slash": (lambda f: _config_with(f, 'name = "rel"', 'name = "a/b"'), "[study] name"),
    "output folder missing": (
        lambda f: _config_with(f, f'output = "{f}/rel.h5"', 'output = "/nonexistent/dir/x.h5"'), "does not exist"),
    "config is a folder": (lambda f: ["run", str(f)], "is a folder"),
    "config is /dev/null": (lambda f: ["run", "/dev/null"], "not a regular file"),
    "dataset is a folder": (lambda f: ["inspect", str(f)], "is a folder"),
    "dataset is /dev/null": (lambda f: ["inspect", "/dev/null"], "not a regular file"),
    "unknown command flag": (lambda f: ["run", str(write_study(f)), "--frobnicate"], "unrecognized arguments"),
}


@pytest.mark.parametrize("case", list(USER_ERRORS))
def test_defect8_9_user_errors_are_one_line(tmp_path, capsys, monkeypatch, case):
    monkeypatch.chdir(tmp_path)
    make, expected = USER_ERRORS[case]
    argv = make(tmp_path)
    before = tree(tmp_path)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    assert code == 2
    line = one_line_error(capsys.readouterr().err)
    assert expected in line, line
    assert tree(tmp_path) == before
    assert not Path("/nonexistent").exists()


# --- defect 10: file modes ------------------------------------------------------------------------------


def test_defect10_dataset_mode_follows_the_umask(tmp_path):
    """Datasets get the umask's mode (they were 0600); the one missing folder level of the output
    is created, as `mkdir` would (two levels are refused: see the user errors above)."""
    cfg = write_study(tmp_path)
    old = os.umask(0o022)
    try:
        assert main(["run", str(cfg), "-q", "--no-render", "-o", str(tmp_path / "new" / "rel.h5")]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "new" / "rel.h5").stat().st_mode & 0o777 == 0o644


def test_parts_carry_their_identity(tmp_path, monkeypatch):
    """Every part file names its task, its task key and the plan's fingerprint (and a checksum)."""
    cfg, folder = kept_parts(tmp_path, monkeypatch)
    manifest = json.loads((folder / "manifest.json").read_text())
    with np.load(folder / "task-000004.npz") as data:
        identity = json.loads(str(data["identity"]))
        assert "checksum" in data.files
    assert identity["task"] == 4 and identity["fingerprint"] == manifest["fingerprint"]
    assert identity["key"].startswith("direct:")


# --- defect 5: energy beyond a model's bound is loud ---------------------------------------------------

GRAZING_STUDY = """
[study]
name = "graze"
output = "{out}"
[surface]
generator = "gaussian"
size_um = 20.0
cells = 200
rms_height_um = 0.05
correlation_um = 1.0
[material]
name = "aluminium"
[illumination]
wavelengths_um = [0.4]
directions_deg = [[0, 0], [88, 0], [89.9, 0]]
waist_um = 3.5
[model]
name = "kirchhoff"
[output]
resolution = 256
"""


def test_defect5_energy_beyond_the_model_bound_is_warned(tmp_path, capsys):
    """Kirchhoff (no shadowing) on gently rough aluminium: albedo > 1 at 88° and 89.9° is recorded
    as an EnergyWarning in the task table and shown by `inspect`; the 0° slice (albedo < 1) is not."""
    import wavebrdf

    cfg = tmp_path / "graze.toml"
    cfg.write_text(GRAZING_STUDY.format(out=tmp_path / "graze.h5"))
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    with wavebrdf.open(tmp_path / "graze.h5") as ds:
        albedo = np.asarray(ds.albedo).ravel()
        warns = [w.decode() if isinstance(w, bytes) else str(w) for w in ds.tasks["warnings"]]
    assert albedo[0] < 1 and np.all(albedo[1:] > 1)
    assert "EnergyWarning" not in warns[0]
    assert all("EnergyWarning" in w and "kirchhoff" in w for w in warns[1:])
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "graze.h5")]) == 0
    shown = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("warning:")]
    assert any("EnergyWarning" in line for line in shown), shown
