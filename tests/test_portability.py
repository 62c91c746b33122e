"""What a GPU would refuse, shown on the CPU device: no shared host memory, small work-groups, no
fp64 (a ComputeContext whose DeviceInfo says so), and every kernel under Oclgrind's checks."""

from __future__ import annotations

import dataclasses
import importlib.util
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.kernels import load_source
from wavebrdf.solver.opencl import ComputeContext, OpenCLUnavailable

ROOT = Path(__file__).resolve().parent.parent


def _kernel_check():
    spec = importlib.util.spec_from_file_location("kernel_check", ROOT / "tools" / "kernel_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


kernel_check = _kernel_check()


def limited(ctx: ComputeContext, **info) -> ComputeContext:
    """A context on ``ctx``'s device that behaves as a device with the DeviceInfo changes ``info``."""
    return ComputeContext(context=ctx.context, queue=ctx.queue, info=dataclasses.replace(ctx.info, **info))


def _relative(a: dict, b: dict) -> float:
    return max(float(np.max(np.abs(a[k] - b[k])) / np.max(np.abs(b[k]))) for k in b)


def test_discrete_gpu_copies_buffers_and_honours_its_work_group_size(cl_ctx):
    """A discrete GPU with work-groups of at most 4: buffers are copies (no USE_HOST_PTR), the
    element kernels launch groups of 4, one work-item per item (WB_VW = 1), and the full-wave
    solvers and Kirchhoff give the CPU device's results."""
    import pyopencl as cl

    from wavebrdf.solver.bem3d.elements import launch_size

    gpu = limited(cl_ctx, kind="GPU", unified_memory=False, max_work_group_size=4)
    host = np.arange(6.0)
    assert not gpu.host_buffer(host).flags & cl.mem_flags.USE_HOST_PTR
    assert cl_ctx.host_buffer(host).flags & cl.mem_flags.USE_HOST_PTR
    assert gpu.vector_lanes() == 1 and launch_size(gpu, 10) == ((12,), (4,))
    for case in ("bem-dense", "bem-aim", "kirchhoff"):
        assert _relative(kernel_check.CASES[case](gpu), kernel_check.CASES[case](cl_ctx)) < 1e-9, case


def test_device_without_fp64_runs_single_precision_and_names_what_needs_double(cl_ctx):
    no_fp64 = limited(cl_ctx, fp64=False)
    single = kernel_check.CASES["kirchhoff-single"](no_fp64)
    assert all(np.all(np.isfinite(v)) for v in single.values())
    for case in ("kirchhoff", "bem-aim-single"):  # double kernels; the BEM assembly is double at any precision
        with pytest.raises(OpenCLUnavailable, match=r"no double precision \(cl_khr_fp64\).*BEM's assembly"):
            kernel_check.CASES[case](no_fp64)


def test_run_on_a_device_without_fp64_starts_single_precision_studies_only(monkeypatch, tmp_path, capsys):
    """`wavebrdf run`: a study at precision "single" runs on a device without fp64; one at
    "double" is refused before any task, naming both ways out."""
    from wavebrdf.jobs.cli import main
    from wavebrdf.solver import opencl

    describe = opencl._describe
    monkeypatch.setattr(opencl, "_describe", lambda *a: dataclasses.replace(describe(*a), fp64=False))
    small = ["--set", "surface.cells=32", "--set", "surface.size_um=4.0", "--set", "illumination.waist_um=0.8",
             "--set", "illumination.wavelengths_um=[0.5]", "--set", "illumination.directions_deg=[[20, 0]]",
             "--set", "output.resolution=16", "--executor", "serial", "--no-render"]
    out = tmp_path / "single.h5"
    code = main(["run", str(ROOT / "configs/default.toml"), "--set", f"study.output='{out}'",
                 "--set", "model.precision=single", *small])
    assert code == 0 and out.exists()
    capsys.readouterr()
    refused = tmp_path / "double.h5"
    assert main(["run", str(ROOT / "configs/default.toml"), "--set", f"study.output='{refused}'", *small]) == 2
    assert re.search(r'no double precision.*precision = "single"', capsys.readouterr().err)
    assert not refused.exists()


def test_single_precision_builds_use_no_double():
    """Every kernel source preprocessed as a device without fp64 builds it (WB_FP64=0, scalar
    and 8-lane vectors) names no double type, conversion or the fp64 extension."""
    if shutil.which("cpp") is None:
        pytest.skip("no C preprocessor (cpp) on this machine")
    for path in sorted((ROOT / "kernels").glob("*.cl")):
        for lanes in (1, 8):
            out = subprocess.run(["cpp", "-P", "-undef", "-DWB_FP64=0", f"-DWB_VW={lanes}", "-DNEAR_FP64=0"],
                                 input=load_source(path.name), capture_output=True, text=True, check=True)
            assert not re.findall(r"\b(double\d*|convert_double\w*|cl_khr_fp64)\b", out.stdout), path.name


def test_every_kernel_has_a_check_case():
    """tools/kernel_check.py names the kernels it covers per case; kernels/*.cl has no other."""
    covered = set().union(*kernel_check.LAUNCHES.values())
    assert covered == kernel_check.kernels_in_sources()


def _needs_oclgrind():
    if shutil.which("oclgrind") is None:
        pytest.skip("oclgrind is not installed (apt-get install oclgrind)")


@pytest.mark.oclgrind
def test_oclgrind_reports_planted_defects():
    """The check sees an out-of-bounds write and a write-write race (kernels planted for it)."""
    _needs_oclgrind()
    result = kernel_check.run_under_oclgrind(["planted-out-of-bounds", "planted-race"])
    headings = [r.splitlines()[0] for r in result["reports"]]
    assert headings.count("Invalid write of size 4 at global memory address 0x1000000000040") == 1
    assert sum(h.startswith("Write-write data race") for h in headings) == len(headings) - 1 > 0


@pytest.mark.oclgrind
@pytest.mark.slow
@pytest.mark.parametrize("max_wgsize", [256, 4])
def test_every_kernel_passes_oclgrind(max_wgsize):
    """Every kernel once under Oclgrind (invalid memory accesses, data races, API misuse; 48 KiB of
    local memory, work-groups <= 256), and the kernels with explicit work-groups at <= 4: no report."""
    _needs_oclgrind()
    cases = None if max_wgsize == 256 else ["bem-dense", "bem-aim"]
    result = kernel_check.run_under_oclgrind(cases, max_wgsize=max_wgsize)
    assert result["returncode"] == 0, result["output"][-3000:]
    assert not result["reports"], "\n\n".join(result["reports"])
