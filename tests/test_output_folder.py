"""The output-folder rule: ``wavebrdf`` creates at most the last missing folder level of an
output path; a deeper missing chain is refused with one line naming the path, and nothing is
created (jobs/output_path.py ``make_output_folder``, used by ``run`` and ``compare``)."""

from __future__ import annotations

import pytest

from test_models import refused, write_study
from wavebrdf.jobs.config import ConfigError
from wavebrdf.jobs.output_path import make_output_folder


def _tree(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_one_missing_level_is_created(tmp_path):
    make_output_folder(tmp_path / "new" / "x.h5")
    assert (tmp_path / "new").is_dir()
    make_output_folder(tmp_path / "new" / "y.h5")  # existing: nothing to do


def test_two_missing_levels_are_refused_and_nothing_is_created(tmp_path):
    before = _tree(tmp_path)
    with pytest.raises(ConfigError, match="does not exist") as info:
        make_output_folder(tmp_path / "a" / "b" / "x.h5")
    message = str(info.value)
    assert "\n" not in message and str(tmp_path / "a" / "b") in message
    assert _tree(tmp_path) == before


def test_a_file_in_place_of_the_folder_is_refused(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError, match="not a folder"):
        make_output_folder(tmp_path / "f" / "x.h5")


def test_compare_out_two_missing_levels_exits_2(tmp_path, capsys):
    """`compare --out` never went through the config's output check: the rule is enforced where the
    folder is made (it used to end in a FileNotFoundError traceback)."""
    cfg = write_study(tmp_path, "cmp", "kirchhoff")
    before = _tree(tmp_path)
    stem = tmp_path / "a" / "b" / "cmp"
    refused(capsys, ["compare", str(cfg), "--out", str(stem), "--models", "kirchhoff", "-q"],
            str(tmp_path / "a" / "b"), "does not exist")
    assert _tree(tmp_path) == before
