"""Every kernel of kernels/*.cl once, on small inputs, through the models that launch them.

    python tools/kernel_check.py --save out.npz        # run the cases on the chosen device
    python tools/kernel_check.py --compare a.npz b.npz # largest difference per case (family)
    python tools/kernel_check.py --oclgrind            # the cases under Oclgrind; exit 1 on a report

Each case runs one model on a tiny scene (the full-wave solvers at their lowest quadrature orders,
one kernel's host function where no model reaches it) and saves its outputs. The kernels a case
launches are recorded: the run fails when one differs from LAUNCHES or a kernel of kernels/*.cl
is launched by none. tools/oclgrind-check.sh runs the cases under Oclgrind; comparing two saved
runs gives the largest difference between two OpenCL implementations.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

KERNELS = Path(__file__).resolve().parent.parent / "kernels"
RELATIVE_FLOOR = 1e-300
# Oclgrind's device limits set like a GPU's: 48 KiB of local memory, work-groups <= 256
GPU_LIMITS = {"max_wgsize": 256, "local_mem_size": 49152}
# pyopencl asks the device for optional properties at each build and handles the refusal; Oclgrind's
# API check reports each such query as this block, which is not a defect of ours
PYOPENCL_PROBE = ("Oclgrind - OpenCL runtime error detected", "\tFunction: clGetDeviceInfo",
                  "\tError:    CL_INVALID_VALUE", "\tFor argument 'param_name'")


def kernels_in_sources() -> set[str]:
    """Names of every kernel function in kernels/*.cl."""
    pattern = re.compile(r"__kernel\s+void\s+(\w+)")
    return {name for path in KERNELS.glob("*.cl") for name in pattern.findall(path.read_text())}


def _surface_scene(precision="double", rms=0.03):
    """An 8 x 8-cell aluminium-like patch of 0.8 µm at λ = 0.5 µm, 16² output pixels."""
    from wavebrdf.solver.farfield import HemisphereGrid
    from wavebrdf.solver.models import SurfaceScene
    from wavebrdf.solver.surface import generate

    surface = generate("gaussian", cells=8, size_um=0.8, seed=4, rms_height_um=rms, correlation_um=0.25)
    return SurfaceScene(surface, 0.5, complex(0.9, -5.0), 0.35, 0.2, 0.25, HemisphereGrid(16), precision=precision)


def _run_model(ctx, name: str, scene, options=None) -> dict[str, np.ndarray]:
    from wavebrdf.solver.models import get_model

    result = get_model(name, options).run(ctx, scene)
    if hasattr(result, "arrays"):
        return result.arrays()
    return {"intensity": np.asarray(result.intensity())}


# element integrals at the lowest orders: the kernels' code paths, in seconds under Oclgrind
COARSE_QUADRATURE = {"tolerance": 0.5, "static_order": 2, "min_order": 1, "max_order": 2, "rhs_order": 2,
                     "farfield_order": 2}


def _bem(ctx, method: str, precision: str = "double"):
    from wavebrdf.solver.bem3d.driver import BEMSolver
    from wavebrdf.solver.farfield import HemisphereGrid
    from wavebrdf.solver.surface import generate

    surface = generate("gaussian", cells=4, size_um=0.3, seed=4, rms_height_um=0.02, correlation_um=0.1)
    aim = {"precision": precision} if method == "aim" else None
    solver = BEMSolver(ctx, surface, 0.5, complex(0.9, -5.0), method=method, quadrature=COARSE_QUADRATURE,
                       aim=aim)
    far = solver.farfield(0.35, 0.2, HemisphereGrid(8), waist_um=0.08)
    return {"intensity": np.asarray(far.intensity())}


def _fiber(ctx):
    from wavebrdf.solver.fiber import circle
    from wavebrdf.solver.models import FiberScene

    scene = FiberScene(circle(0.3, 24), 0.5, complex(1.55, -0.05), 0.5, (0.0, 1.0), 2, 16, radius_um=0.3)
    return _run_model(ctx, "fiber-bem", scene)


def _hankel(ctx, precision="double"):
    from wavebrdf.solver.fiber.hankel import hankel2_01_cl
    from wavebrdf.solver.precision import Precision

    z = np.concatenate([np.linspace(0.01, 30.0, 40), np.linspace(0.5, 20.0, 24) * (1 - 0.3j)])
    h0, h1 = hankel2_01_cl(ctx, z, Precision(precision))
    return {"h0": h0, "h1": h1}


def _bem_list(ctx):
    from wavebrdf.solver.bem3d.assembly import basis_entries_opencl

    rng = np.random.default_rng(2)
    tables = rng.normal(size=(6, 2, 33)) + 1j * rng.normal(size=(6, 2, 33))
    pair_map = np.arange(9, dtype=np.int32).reshape(3, 3) % 6
    row_elem, col_elem = rng.integers(0, 3, (5, 2)), rng.integers(0, 3, (6, 2))
    row_slot, col_slot = rng.integers(0, 4, (5, 2)), rng.integers(0, 4, (6, 2))
    coef = rng.normal(size=9) + 1j * rng.normal(size=9)
    rows, cols = rng.integers(0, 5, 8), rng.integers(0, 6, 8)
    ee, mm, em = basis_entries_opencl(ctx, tables, pair_map, row_elem, row_slot, col_elem, col_slot, coef,
                                      rows=rows, cols=cols)
    return {"ee": ee, "mm": mm, "em": em}


# case name -> function of a ComputeContext returning the case's named output arrays
CASES = {
    "kirchhoff": lambda ctx: _run_model(ctx, "kirchhoff", _surface_scene()),
    "kirchhoff-single": lambda ctx: _run_model(ctx, "kirchhoff", _surface_scene("single")),
    "ohs": lambda ctx: _run_model(ctx, "ohs", _surface_scene()),
    "ghs": lambda ctx: _run_model(ctx, "ghs", _surface_scene()),
    "po": lambda ctx: _run_model(ctx, "po", _surface_scene()),
    "po-beam": lambda ctx: _run_model(ctx, "po", _surface_scene(), {"incidence": "beam"}),
    "gs": lambda ctx: _run_model(ctx, "gs", _surface_scene(rms=0.1), {"rays": 4096}),
    "gm": lambda ctx: _run_model(ctx, "gm", _surface_scene(rms=0.1), {"rays": 4096}),
    "ws-v": lambda ctx: _run_model(ctx, "ws-v", _surface_scene()),
    "ws-v-beam": lambda ctx: _run_model(ctx, "ws-v", _surface_scene(), {"incidence": "beam"}),
    "wm": lambda ctx: _run_model(ctx, "wm", _surface_scene(rms=0.1), {"rays": 4096}),
    "bem-dense": lambda ctx: _bem(ctx, "dense"),
    "bem-list": _bem_list,
    "bem-aim": lambda ctx: _bem(ctx, "aim"),
    "bem-aim-single": lambda ctx: _bem(ctx, "aim", "single"),
    "fiber-bem": _fiber,
    "hankel": _hankel,
    "hankel-single": lambda ctx: _hankel(ctx, "single"),
}


def _planted(source: str, local_size):
    """A case running ``source``'s kernel ``planted`` over 16 ints: a defect the checker must see."""
    def run(ctx):
        import pyopencl as cl

        data = np.zeros(16, np.int32)
        buf = cl.Buffer(ctx.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=data)
        cl.Kernel(cl.Program(ctx.context, source).build(), "planted")(ctx.queue, (16,), local_size, buf)
        cl.enqueue_copy(ctx.queue, data, buf)
        return {"data": data}
    return run


# defects planted to show that the Oclgrind run reports them (not part of the default run)
PLANTED = {
    "planted-out-of-bounds": _planted("__kernel void planted(__global int *a) { a[get_global_id(0) + 1] = 1; }",
                                      None),
    "planted-race": _planted("__kernel void planted(__global int *a) { a[0] = (int)get_global_id(0); }", (4,)),
}


KIRCHHOFF = {"kirchhoff_fields", "kirchhoff_accumulate"}
HARVEY_SHACK = {"kirchhoff_fields", "hs_farfield", "sgrid_rows", "sgrid_columns"}
RAYS = {"trace_paths", "path_weights", "visibility"}
BEM = {"bem_regular_pairs", "bem_singular_pairs"}
AIM = BEM | {"bem_basis_list", "aim_scatter", "aim_gather", "aim_fourier",
             "aim_near_correct", "aim_plane_wave_moments", "near_tiles", "near_move"}
# the kernels each case launches (run_cases checks it)
LAUNCHES = {
    "kirchhoff": KIRCHHOFF | {"kirchhoff_farfield"},
    "kirchhoff-single": KIRCHHOFF | {"kirchhoff_farfield"},
    "ohs": HARVEY_SHACK,
    "ghs": HARVEY_SHACK,
    "po": KIRCHHOFF | {"po_currents", "po_farfield", "visibility"},
    "po-beam": KIRCHHOFF | {"po_beam_currents", "po_farfield", "visibility"},
    "gs": RAYS,
    "gm": RAYS,
    "ws-v": KIRCHHOFF | {"visibility", "wsv_masked_sum"},
    "ws-v-beam": KIRCHHOFF | {"visibility", "wsv_masked_sum", "wsv_beam_sums"},
    "wm": KIRCHHOFF | RAYS | {"wsv_masked_sum"},
    "bem-dense": BEM | {"bem_basis_block", "bem_radiation_integrals"},
    "bem-list": {"bem_basis_list"},
    "bem-aim": AIM,
    "bem-aim-single": AIM,
    "fiber-bem": {"fiber_pair_moments", "fiber_assemble"},
    "hankel": {"hankel2_eval"},
    "hankel-single": {"hankel2_eval"},
}


def record_launches(ctx, current: dict) -> dict[str, set]:
    """Make ``ctx`` note the kernels it hands out under the case ``current["case"]``; returns
    {case: kernel names}."""
    seen: dict[str, set] = {}
    original = ctx.kernel

    def kernel(source, name, defines=None):
        seen.setdefault(current["case"], set()).add(name)
        return original(source, name, defines)

    ctx.kernel = kernel
    return seen


def run_cases(names=None, save: str | None = None) -> dict:
    """Run the cases ``names`` (default all) on WAVEBRDF_DEVICE's device; returns a report."""
    from wavebrdf.solver.opencl import create_context

    ctx = create_context()
    current = {"case": None}
    seen = record_launches(ctx, current)
    arrays, seconds = {}, {}
    for case in names or CASES:
        current["case"] = case
        t0 = time.perf_counter()
        for key, value in {**CASES, **PLANTED}[case](ctx).items():
            arrays[f"{case}/{key}"] = np.asarray(value)
        seconds[case] = round(time.perf_counter() - t0, 3)
        print(f"[kernel-check] {case}: {len(seen.get(case, ()))} kernels ({seconds[case]} s)", flush=True)
    launched = set().union(*seen.values()) if seen else set()
    report = {"device": ctx.describe(), "seconds": seconds, "launched": sorted(launched),
              "missing": sorted(kernels_in_sources() - launched) if names is None else [],
              "undeclared": {c: sorted(k ^ LAUNCHES[c]) for c, k in seen.items() if k != LAUNCHES.get(c, k)}}
    if save:
        np.savez(save, **arrays, _report=json.dumps(report))
    return report


def compare(a_path: str, b_path: str) -> dict[str, float]:
    """Largest |a - b| / max|a| per case between two saved runs."""
    a, b = np.load(a_path), np.load(b_path)
    out: dict[str, float] = {}
    for key in sorted(set(a.files) & set(b.files) - {"_report"}):
        x, y = a[key], b[key]
        scale = max(float(np.nanmax(np.abs(x))), RELATIVE_FLOOR)
        diff = float(np.nanmax(np.abs(x - y))) / scale
        case = key.split("/")[0]
        out[case] = max(out.get(case, 0.0), diff)
    return out


def _blocks(text: str) -> list[str]:
    """Oclgrind's reports in ``text``: a heading line and its indented details (blank lines may
    stand between them)."""
    blocks: list[str] = []
    for block in re.split(r"\n[ \t]*\n", text):
        block = block.strip("\n")
        if block and block[0] in " \t" and blocks:
            blocks[-1] += "\n" + block
        elif block.strip():
            blocks.append(block)
    return blocks


def run_under_oclgrind(cases=None, max_wgsize=GPU_LIMITS["max_wgsize"],
                       local_mem_size=GPU_LIMITS["local_mem_size"], save: str | None = None) -> dict:
    """The cases under Oclgrind with its memory, data-race and API checks and the given device
    limits; returns {"reports": [...], "probes": n ignored pyopencl probes, "returncode", "output"}."""
    oclgrind = shutil.which("oclgrind")
    if oclgrind is None:
        raise FileNotFoundError("oclgrind is not installed (Debian/Ubuntu: apt-get install oclgrind)")
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp, "oclgrind.log")
        command = [oclgrind, "--check-api", "--data-races", "--max-wgsize", str(max_wgsize),
                   "--local-mem-size", str(local_mem_size), "--num-threads", "1", "--log", str(log),
                   sys.executable, "-W", "ignore", str(Path(__file__).resolve())]
        if cases:
            command += ["--cases", ",".join(cases)]
        if save:
            command += ["--save", save]
        proc = subprocess.run(command, capture_output=True, text=True)
        logged = log.read_text() if log.exists() else ""
    found = _blocks(logged) + [b for b in _blocks(proc.stderr) if b.upper().startswith("OCLGRIND")]
    reports = [b for b in found if tuple(b.splitlines()) != PYOPENCL_PROBE]
    return {"reports": reports, "probes": len(found) - len(reports), "returncode": proc.returncode,
            "output": proc.stdout + proc.stderr}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--save", help="write the outputs to this .npz")
    parser.add_argument("--cases", help="comma-separated case names (default: all)")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two saved runs")
    parser.add_argument("--oclgrind", action="store_true", help="run the cases under Oclgrind's checks")
    parser.add_argument("--max-wgsize", type=int, default=GPU_LIMITS["max_wgsize"], help="with --oclgrind")
    args = parser.parse_args(argv)
    cases = args.cases.split(",") if args.cases else None
    if args.oclgrind:
        t0 = time.perf_counter()
        result = run_under_oclgrind(cases, max_wgsize=args.max_wgsize, save=args.save)
        print("\n".join(line for line in result["output"].splitlines() if line.startswith("[kernel-check]")))
        print("\n\n".join(result["reports"]))
        print(f"[kernel-check] Oclgrind (work-groups <= {args.max_wgsize}, {GPU_LIMITS['local_mem_size']} B local "
              f"memory): {len(result['reports'])} report(s), {result['probes']} pyopencl probe(s) ignored, "
              f"exit {result['returncode']}, {time.perf_counter() - t0:.0f} s")
        return int(bool(result["reports"]) or result["returncode"] != 0)
    if args.compare:
        for case, diff in compare(*args.compare).items():
            print(f"{case:16s} {diff:.2e}")
        return 0
    report = run_cases(cases, args.save)
    print(f"[kernel-check] device {report['device']}: {len(report['launched'])} of "
          f"{len(kernels_in_sources())} kernels launched")
    if report["missing"]:
        print(f"[kernel-check] kernels no case launched: {report['missing']}", file=sys.stderr)
    if report["undeclared"]:
        print(f"[kernel-check] launches that differ from LAUNCHES: {report['undeclared']}", file=sys.stderr)
    return int(bool(report["missing"] or report["undeclared"]))


if __name__ == "__main__":
    sys.exit(main())
