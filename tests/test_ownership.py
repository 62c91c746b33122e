"""Output ownership (issue 35, items 5-7 and the batch messages of item 10): a run or merge
replaces only what it owns — its own study's dataset, never another configuration's (also after
waiting for the lock), never a file that is not a wavebrdf dataset without ``--force`` — and
``merge`` decides before it moves anything."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.parts import OutputLock

BIN = Path(sys.executable).parent
STUDY = """
[study]
name = "{name}"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 4.0
cells = 32
rms_height_um = 0.04
correlation_um = 0.8
seed = {seed}

[material]
name = "gold"

[illumination]
wavelengths_um = [0.55, 0.65]
directions_deg = [[0, 0], [25, 10], [50, 90]]
waist_um = 0.8

[model]
name = "kirchhoff"

[output]
resolution = 16
"""
N_TASKS = 6


def write_study(folder: Path, name: str, seed: int, output: str = "out.h5") -> Path:
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(STUDY.format(name=name, out=folder / output, seed=seed)))
    return path


def error_line(err: str) -> str:
    """The one ``wavebrdf: error:`` line of ``err`` (no traceback)."""
    lines = [line for line in err.splitlines() if line.startswith("wavebrdf: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tree(folder: Path) -> dict:
    """Every path under ``folder`` with its content hash (folders: None)."""
    return {str(p.relative_to(folder)): digest(p) if p.is_file() else None for p in sorted(folder.rglob("*"))}


def run(*args) -> int:
    return main(["run", *map(str, args), "-q", "--no-render"])


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished dataset of study ``a`` (seed 3), to copy where a test needs one."""
    folder = tmp_path_factory.mktemp("finished")
    assert run(write_study(folder, "a", 3)) == 0
    return folder / "out.h5"


# --- item 5: --wait re-checks ownership under the lock ---------------------------------------------


def wait_then_finish(tmp_path: Path, finished: Path, config: Path, *flags) -> subprocess.CompletedProcess:
    """Hold the output's lock (a run of study ``a`` in progress), start ``wavebrdf run config --wait``,
    and once it waits, put study ``a``'s finished dataset in place and release the lock (that run
    finished)."""
    output = tmp_path / "out.h5"
    lock = OutputLock(output).acquire()
    try:
        proc = subprocess.Popen([str(BIN / "wavebrdf"), "run", str(config), "-q", "--no-render", "--wait", *flags],
                                stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        said = ""
        for line in proc.stderr:  # until it waits for the lock
            said += line
            if "waiting for it to end" in line:
                break
        assert "waiting for it to end" in said, said
        output.write_bytes(finished.read_bytes())
    finally:
        lock.release()
    out, err = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, said + err)


def test_item5_run_wait_refuses_another_configs_dataset_finished_meanwhile(tmp_path, finished):
    config = write_study(tmp_path, "b", seed=4)
    result = wait_then_finish(tmp_path, finished, config)
    line = error_line(result.stderr)
    output = tmp_path / "out.h5"
    assert result.returncode == 2, result.stderr
    assert str(output) in line and "another configuration" in line and "surface.seed 3 -> 4" in line, line
    with h5py.File(finished) as h5:
        fingerprint = h5.attrs["fingerprint"]
    assert "study 'a'" in line and fingerprint in line and "--force" in line, line
    assert digest(output) == digest(finished)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.toml", "out.h5"]  # no parts, no lock
    assert run(config, "--force") == 0  # what the message offers
    with h5py.File(output) as h5:
        assert h5.attrs["study"] == "b" and set(h5["tasks/status"][()].astype(str)) == {"done"}


def test_item5_run_wait_of_the_same_study_finds_it_up_to_date(tmp_path, finished):
    config = write_study(tmp_path, "a", seed=3)
    result = wait_then_finish(tmp_path, finished, config)
    output = tmp_path / "out.h5"
    assert result.returncode == 0 and "is up to date" in result.stderr, result.stderr
    assert digest(output) == digest(finished)
    assert "wrote" not in result.stdout


def test_a_parts_folder_beside_another_configs_dataset_does_not_let_a_run_replace_it(tmp_path, finished, capsys):
    """Partial results of study ``b`` beside the output (a run of it stopped there) while the output
    holds study ``a``'s finished dataset (copied in meanwhile): the run refuses, as without the
    folder, instead of resuming into that file."""
    config = write_study(tmp_path, "b", seed=4)
    output = tmp_path / "out.h5"
    output.write_bytes(finished.read_bytes())
    (tmp_path / "out.h5.parts").mkdir()
    assert run(config) == 2
    line = error_line(capsys.readouterr().err)
    assert "another configuration" in line and "surface.seed 3 -> 4" in line, line
    assert digest(output) == digest(finished)


# --- item 6: a file that is not a wavebrdf dataset -------------------------------------------------


def foreign_file(path: Path, kind: str) -> None:
    if kind == "text":
        path.write_text("my notes, not a dataset\n")
    else:
        with h5py.File(path, "w") as h5:
            h5["measured"] = [1.0, 2.0, 3.0]
            h5.attrs["lab"] = "mine"


@pytest.mark.parametrize("kind", ["text", "hdf5"])
def test_item6_run_refuses_a_file_that_is_not_a_wavebrdf_dataset(tmp_path, capsys, kind):
    config = write_study(tmp_path, "a", seed=3)
    output = tmp_path / "out.h5"
    foreign_file(output, kind)
    before = tree(tmp_path)
    assert run(config) == 2
    line = error_line(capsys.readouterr().err)
    assert str(output) in line and "not a wavebrdf dataset" in line and "--force" in line, line
    assert tree(tmp_path) == before  # no parts folder, no lock, the file's bytes as they were
    assert run(config, "--force") == 0
    with h5py.File(output) as h5:
        assert h5.attrs["format"] == "wavebrdf"


def two_shards(tmp_path: Path, config: Path) -> None:
    for shard in ("0/2", "1/2"):
        assert run(config, "--shard", shard) == 0


@pytest.mark.parametrize("kind", ["text", "hdf5"])
def test_item6_merge_refuses_a_file_that_is_not_a_wavebrdf_dataset(tmp_path, capsys, kind):
    config = write_study(tmp_path, "a", seed=3)
    two_shards(tmp_path, config)
    output = tmp_path / "out.h5"
    foreign_file(output, kind)
    before, _ = tree(tmp_path), capsys.readouterr()
    assert main(["merge", str(config), "--no-render"]) == 2
    line = error_line(capsys.readouterr().err)
    assert str(output) in line and "not a wavebrdf dataset" in line and "--force" in line, line
    assert tree(tmp_path) == before
    assert main(["merge", str(config), "--no-render", "--force"]) == 0
    with h5py.File(output) as h5:
        assert h5.attrs["format"] == "wavebrdf" and set(h5["tasks/status"][()].astype(str)) == {"done"}


# --- item 7: merge decides before it moves anything -----------------------------------------------


def test_item7_merge_of_another_config_moves_none_of_the_shards_parts(tmp_path, capsys):
    mine, other = write_study(tmp_path, "b", seed=4), write_study(tmp_path, "a", seed=3)
    two_shards(tmp_path, mine)
    before, _ = tree(tmp_path), capsys.readouterr()
    assert main(["merge", str(other), "--no-render"]) == 2
    line = error_line(capsys.readouterr().err)
    assert "out.shard-0-of-2.h5.parts" in line and "different configuration" in line, line
    assert tree(tmp_path) == before  # nothing moved to rejected/, nothing created
    assert main(["merge", str(mine), "--no-render"]) == 0
    out = capsys.readouterr()
    assert "recomputed" not in out.err and "wrote" in out.out
    with h5py.File(tmp_path / "out.h5") as h5:
        assert h5.attrs["study"] == "b" and set(h5["tasks/status"][()].astype(str)) == {"done"}


def test_item7_merge_refused_for_a_missing_shard_moves_nothing(tmp_path, capsys):
    config = write_study(tmp_path, "a", seed=3)
    assert run(config, "--shard", "1/2") == 0
    part = next((tmp_path / "out.shard-1-of-2.h5.parts").glob("task-*.npz"))
    part.write_bytes(part.read_bytes()[:-10])  # damaged: the shard's own run recomputes it
    before, _ = tree(tmp_path), capsys.readouterr()
    assert main(["merge", str(config), "--no-render"]) == 2
    line = error_line(capsys.readouterr().err)
    assert tree(tmp_path) == before, line
    assert "shard 0: 3 of 3 task(s) missing" in line and "shard 1: 1 of 3 task(s) missing" in line, line
    assert "--shard I/2' for I in 0, 1" in line, line


def test_shards_run_with_set_and_output_are_merged_by_the_command_they_print(tmp_path, capsys):
    """Shards run with --set and -o print the merge command with the same flags, and that command
    merges them (merge takes --set and -o as run does); without them merge finds no such shards."""
    import shlex

    config = write_study(tmp_path, "a", seed=3)
    flags = ["--set", "surface.seed=5", "--set", "illumination.wavelengths_um=[0.55]", "-o", str(tmp_path / "o.h5")]
    printed = []
    for shard in ("0/2", "1/2"):
        capsys.readouterr()
        assert run(config, *flags, "--shard", shard) == 0
        printed.append(capsys.readouterr().out.split("when every shard is done: ")[1].strip())
    assert printed[0] == printed[1] and "--set surface.seed=5" in printed[0] and "-o " in printed[0], printed
    command = shlex.split(printed[0])
    assert command[:2] == ["wavebrdf", "merge"]
    assert main([*command[1:], "--no-render"]) == 0
    with h5py.File(tmp_path / "o.h5") as h5:
        assert set(h5["tasks/status"][()].astype(str)) == {"done"} and len(h5["tasks/status"]) == 3
        assert "seed = 5" in h5.attrs["config"]


# --- item 10: messages -------------------------------------------------------------------------


def test_item10_a_wrong_task_count_is_named_as_such(tmp_path, capsys):
    config = write_study(tmp_path, "a", seed=3)
    assert run(config, "--shard", "0/2") == 0
    manifest = tmp_path / "out.shard-0-of-2.h5.parts" / "manifest.json"
    found = json.loads(manifest.read_text())
    manifest.write_text(json.dumps({**found, "tasks": 9}))
    before, _ = tree(tmp_path), capsys.readouterr()
    assert run(config, "--shard", "0/2") == 2
    line = error_line(capsys.readouterr().err)
    assert "task count 9 in the folder, 6 in this config" in line and "fingerprint" not in line, line
    assert tree(tmp_path) == before


@pytest.mark.parametrize("where", ["under a file", "a file", "missing folder"])
def test_item10_a_bad_render_out_is_an_output_problem(tmp_path, capsys, finished, where):
    (tmp_path / "notes").write_text("a file\n")
    out = {"under a file": tmp_path / "notes" / "png", "a file": tmp_path / "notes",
           "missing folder": tmp_path / "no" / "such" / "png"}[where]
    before = tree(tmp_path)
    assert main(["render", str(finished), "--out", str(out)]) == 2
    line = error_line(capsys.readouterr().err)
    assert "damaged" not in line and str(out) in line and "--out" in line, line
    assert tree(tmp_path) == before


def test_item10_an_unwritable_render_out_is_an_output_problem(tmp_path, capsys, finished, monkeypatch):
    def refuse(self, *args, **kwargs):  # what a folder without write permission answers (this may run as root)
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "mkdir", refuse)
    assert main(["render", str(finished), "--out", str(tmp_path / "png")]) == 2
    line = error_line(capsys.readouterr().err)
    assert "damaged" not in line and "Permission denied" in line and "free space" not in line, line
    assert "--out" in line or "writable" in line, line
    assert list(tmp_path.iterdir()) == []
