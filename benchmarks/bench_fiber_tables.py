"""Full BCSDF tables of issue 6: an elliptical fiber (semi-axes 0.4 × 0.25 µm) and a circular fiber
(radius 1 µm) over 31 wavelengths 0.40–0.70 µm, timed, optionally saved (.npz) and drawn (PNG).

    python benchmarks/bench_fiber_tables.py ellipse [--out ellipse.npz] [--png ellipse.png]
    python benchmarks/bench_fiber_tables.py circle --model bem|mie

Defaults: m = 1.55; θ_i = 0°, 9°, ..., 81° (10 angles, [F]'s grid 90°·j/10); 360 φ_r bins;
ellipse N = 96 segments (≥ 12 per interior wavelength at 0.4 µm) with 360 φ_i bins; circle N = 300
with one φ_i (rotation invariance). The PNG shows N_wave(φ_i, φ_r) (log scale) at 3 wavelengths
× 2 incidence angles, or N_wave(φ_r) curves for a single φ_i.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from wavebrdf.solver.fiber import FiberBEM, MieFiber, bcsdf_table, circle, ellipse
from wavebrdf.solver.opencl import create_context


def build_model(args, ctx):
    if args.shape == "circle" and args.model == "mie":
        return MieFiber(1.0)
    if args.model == "mie":
        raise SystemExit("the Mie model needs --shape circle")
    shape = ellipse(0.4, 0.25, args.segments or 96) if args.shape == "ellipse" else circle(1.0, args.segments or 300)
    return FiberBEM(ctx, shape)


def draw(table, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lam_idx = [0, table.wavelength_um.size // 2, table.wavelength_um.size - 1]
    th_idx = [0, table.theta_i.size // 2]
    fig, axes = plt.subplots(len(th_idx), len(lam_idx), figsize=(4 * len(lam_idx), 3.6 * len(th_idx)),
                             squeeze=False, constrained_layout=True)
    deg = np.degrees
    for r, ti in enumerate(th_idx):
        for c, li in enumerate(lam_idx):
            ax = axes[r, c]
            values = table.bcsdf[li, ti]
            title = f"λ = {table.wavelength_um[li]:.3f} µm, θ_i = {deg(table.theta_i[ti]):.0f}°"
            if table.phi_i.size == 1:
                ax.semilogy(deg(table.phi_r), values[0])
                ax.set_xlabel("φ_r (deg)")
                ax.set_ylabel("N_wave (1/rad)")
            else:
                im = ax.pcolormesh(deg(table.phi_r), deg(table.phi_i), np.log10(np.maximum(values, 1e-6)),
                                   shading="nearest", vmin=-3, vmax=1.5)
                ax.set_xlabel("φ_r (deg)")
                ax.set_ylabel("φ_i (deg)")
                fig.colorbar(im, ax=ax, label="log10 N_wave (1/rad)")
            ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shape", choices=["ellipse", "circle"])
    parser.add_argument("--model", choices=["bem", "mie"], default="bem")
    parser.add_argument("--segments", type=int, default=None)
    parser.add_argument("--wavelengths", type=int, default=31)
    parser.add_argument("--thetas", type=int, default=10)
    parser.add_argument("--phi-i", type=int, default=None, help="φ_i bins (default 360 ellipse, 1 circle)")
    parser.add_argument("--phi-r", type=int, default=360)
    parser.add_argument("--index", type=complex, default=1.55)
    parser.add_argument("--out", default=None, help="write the table arrays to this .npz")
    parser.add_argument("--png", default=None, help="draw φ_i-φ_r maps to this PNG")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    ctx = create_context() if args.model == "bem" else None
    model = build_model(args, ctx)
    lams = np.linspace(0.4, 0.7, args.wavelengths)
    thetas = np.radians(90.0 * np.arange(args.thetas) / args.thetas)
    n_phi_i = args.phi_i or (360 if args.shape == "ellipse" else 1)
    total = lams.size * thetas.size
    stamp = time.perf_counter()

    def progress(done, total_, sl):
        if done % max(1, total_ // 10) == 0 or done == total_:
            print(f"  {done}/{total_} solves, {time.perf_counter() - stamp:.1f} s", flush=True)

    print(f"{args.shape} ({args.model}), m = {args.index}: {lams.size} wavelengths x {thetas.size} theta_i "
          f"= {total} solves; {n_phi_i} phi_i bins, {args.phi_r} phi_r bins")
    table = bcsdf_table(model, lams, args.index, thetas, n_phi_i=n_phi_i, n_phi_r=args.phi_r,
                        progress=progress, model_name=f"{args.shape}-{args.model}")
    balance = table.power_balance_error
    print(f"table computed in {table.seconds:.1f} s ({table.seconds / total:.3f} s per (lambda, theta_i)); "
          f"bcsdf {table.bcsdf.shape} float32 = {table.bcsdf.nbytes / 2**20:.1f} MiB; "
          f"worst power balance {balance.max():.1e}; albedo range "
          f"{(table.C_sca.mean(2) / table.C_ext.mean(2)).min():.4f}..{(table.C_sca.mean(2) / table.C_ext.mean(2)).max():.4f}")
    if args.out:
        np.savez_compressed(args.out, wavelength_um=table.wavelength_um, theta_i=table.theta_i,
                            phi_i=table.phi_i, phi_r=table.phi_r, index=table.index, bcsdf=table.bcsdf,
                            dCs_dphi=table.dCs_dphi, C_ext=table.C_ext, C_sca=table.C_sca, C_abs=table.C_abs,
                            C_geom=table.C_geom)
        print(f"wrote {args.out}")
    if args.png:
        draw(table, args.png)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
