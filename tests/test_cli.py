"""The quick-start path of the README: run the default config, inspect, render."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from wavebrdf.jobs.cli import main

ROOT = Path(__file__).resolve().parent.parent


def test_default_config_end_to_end(tmp_path, capsys):
    out = tmp_path / "default.h5"
    assert main(["run", str(ROOT / "configs" / "default.toml"), "--output", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    pngs = [Path(line.split(" ", 1)[1]) for line in printed.splitlines() if line.endswith(".png")]
    assert out.is_file() and len(pngs) == 11 and all(p.stat().st_size > 10_000 for p in pngs)  # docs/pictures.md
    import h5netcdf  # noqa: F401  (dev dependency: engine="h5netcdf" below; a missing one fails)
    import xarray as xr

    ds = xr.open_dataset(out, engine="h5netcdf")
    assert ds["brdf"].shape == (3, 3, 512, 512)
    # rough aluminium: albedo a little below the flat-surface Fresnel value (~0.92)
    assert float(ds["albedo"].min()) > 0.8 and float(ds["albedo"].max()) < 0.95
    import wavebrdf

    with wavebrdf.open(out) as d:  # the quick start is within its model's validity: no task warns
        assert [w for w in d.tasks["warnings"] if w] == []

    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "albedo" in text and "wavelength_um" in text
    assert main(["render", str(out), "--out", str(tmp_path / "png"), "--plots", "maps"]) == 0
    assert len(list((tmp_path / "png").glob("*.png"))) == 3


def test_heightfield_example_config(tmp_path):
    out = tmp_path / "bumps.h5"
    assert main(["run", str(ROOT / "configs" / "heightfield_file.toml"), "-o", str(out), "-q", "--no-render"]) == 0
    assert out.is_file()


def test_devices_and_console_script():
    result = subprocess.run([sys.executable, "-m", "wavebrdf", "devices"], capture_output=True, text=True)
    assert result.returncode == 0 and "fp64=" in result.stdout


def test_no_opencl_platform_names_the_fix(tmp_path):
    """With no ICD visible, the error says how to install PoCL (not a raw pyopencl trace)."""
    env = {"OCL_ICD_VENDORS": str(tmp_path), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    result = subprocess.run([sys.executable, "-m", "wavebrdf", "devices"], capture_output=True, text=True, env=env)
    if result.returncode == 0:
        pytest.skip("an OpenCL ICD is visible despite OCL_ICD_VENDORS (e.g. the pocl wheel)")
    assert result.returncode == 2
    assert "pocl-opencl-icd" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_plan_reports_progress_while_it_estimates_many_tasks(monkeypatch, capsys):
    """A long plan (the flagship's 2 025 full-wave patches take minutes) says how far it is on
    stderr while it estimates; the table itself is unchanged on stdout."""
    import wavebrdf.jobs.plan as planning

    monkeypatch.setattr(planning, "ESTIMATE_PROGRESS_S", 0.0)
    config = ROOT / "configs" / "default.toml"
    assert main(["plan", str(config)]) == 0
    captured = capsys.readouterr()
    done = [int(line.split("estimated ")[1].split(" of 9 tasks")[0]) for line in captured.err.splitlines()
            if "estimated" in line]
    assert done == list(range(1, 9)), captured.err  # each task, the last one said by the table itself
    assert "estimated" not in captured.out and "total: 9 tasks" in captured.out
