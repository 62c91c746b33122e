"""Refit the AIM planner's Krylov product count to the measured counts of
solver/data/aim_products.csv and rewrite its rows of solver/data/aim_cost.csv (value, meaning,
command, commit; the other rows stay as they are).

    .venv/bin/python tools/refit_product_counts.py             # fit and write
    .venv/bin/python tools/refit_product_counts.py --dry-run   # print the fit and each row's residual

The model (``estimate._products``), per polarization, for the unpreconditioned MINRES solve and
the local inverses with GMRES(30) at once:

    log P = log c + α ν + α₂ ν² + β log(L/λ) + (γ + δ ν) s  [+ log r + ε log(L / 10λ) with the local inverses]

s the rms slope of the relief finer than the wavelength (``HeightField.rms_slope_below``; every
row is in air, so its wavelength is the vacuum one:
roughness at and below λ couples nearby elements, and slows the solve more than long, gentle
relief of the same total slope; more on aluminium than on glass, hence δ), ν = log(|n| / n_ref)
the index contrast (|n| the modulus of the interior index: the count is not monotonic in it —
at a given fine slope aluminium at 0.55–0.65 µm takes fewer products than at 0.4 µm and glass
fewer still, gold more: docs/aim.md), L/λ the patch side in exterior
wavelengths (at least 1); fitted by least squares in log P
to the geometric mean of each row's s and p counts. A row of the data file is one measured solve:
its surface (``generate``'s arguments as JSON), wavelength, index, the preconditioner (``kind``:
``minres`` or ``local``), its ``role`` (``fit``: fitted; ``check``: a surface the fit has not
seen, measured by ``benchmarks/bench_aim.py planner``, whose error is printed, not fitted), the
products of both polarizations, and the command and commit that measured them.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "solver" / "data" / "aim_products.csv"
INDEX_REF = "products_minres_index_ref"
KINDS = ("minres", "local")
ROLES = ("fit", "check")
MEANINGS = {
    "products_minres": "MINRES products per polarization without a preconditioner = c e^(α ν + α₂ ν²) (L/λ)^β "
                       "e^((γ + δ ν) s) (ν = ln(|n|/n_ref); s: rms slope of the relief finer than λ), least squares in log products over solver/data/aim_products.csv (MINRES and "
                       "local-inverse rows at once)",
    "products_minres_index_exp": "(see products_minres): α",
    "products_minres_index_exp2": "(see products_minres): α₂",
    "products_minres_size_exp": "(see products_minres): β",
    "products_minres_slope_exp": "(see products_minres): γ",
    "products_minres_slope_index_exp": "(see products_minres): δ",
    "products_local_ratio": "GMRES(30) products with the local inverses over the MINRES count at L = 10 λ: r, fitted "
                            "with products_minres",
    "products_local_size_exp": "growth of that ratio with L/λ: (L/10λ)^ε, fitted with products_minres",
    "products_fine_slope_max": "the largest fine slope s of the fitted rows: the count is not extrapolated beyond it",
    "products_index_contrast_min": "the smallest ν = ln(|n|/n_ref) of the fitted rows: ν is held within the range",
    "products_index_contrast_max": "the largest ν = ln(|n|/n_ref) of the fitted rows",
}


def measured_counts(path: Path = DATA) -> list[dict]:
    """The data file's rows with their features: ``index_modulus``, ``size_waves``, ``fine_slope``,
    ``local`` (bool) and ``products`` (the geometric mean of s and p)."""
    from wavebrdf.solver.surface import generate

    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            for key, allowed in (("kind", KINDS), ("role", ROLES)):
                if row[key] not in allowed:
                    raise ValueError(f"{path}: {row['case']!r}: {key} must be one of {allowed}, got {row[key]!r}")
            spec = json.loads(row["surface"])
            surface = generate(spec.pop("generator"), **spec)
            lam = float(row["wavelength_um"])
            rows.append({**row, "index_modulus": abs(complex(row["index"].replace(" ", ""))),
                         "size_waves": max(surface.size_um / lam, 1.0), "fine_slope": surface.rms_slope_below(lam),
                         "local": row["kind"] == "local",
                         "products": float(np.sqrt(float(row["products_s"]) * float(row["products_p"])))})
    return rows


def fit(rows: list[dict], index_ref: float) -> dict[str, float]:
    """The eight constants of the model (module docstring) from the ``fit`` rows of
    :func:`measured_counts`."""
    rows = [r for r in rows if r["role"] == "fit"]
    local = np.array([r["local"] for r in rows], float)
    size = np.log([r["size_waves"] for r in rows])
    contrast = np.log([r["index_modulus"] / index_ref for r in rows])
    slope = np.array([r["fine_slope"] for r in rows])
    design = np.stack([np.ones(len(rows)), contrast, contrast**2, size, slope, slope * contrast, local,
                       local * (size - np.log(10.0))], axis=1)
    if not local.any() or local.all() or np.linalg.matrix_rank(design) < design.shape[1]:
        raise ValueError("the product counts do not determine the model: it needs MINRES and local rows that differ "
                         "in index, size and slope")
    coef, *_ = np.linalg.lstsq(design, np.log([r["products"] for r in rows]), rcond=None)
    names = ("products_minres", "products_minres_index_exp", "products_minres_index_exp2", "products_minres_size_exp",
             "products_minres_slope_exp", "products_minres_slope_index_exp", "products_local_ratio",
             "products_local_size_exp")
    values = dict(zip(names, map(float, coef)))
    for name in ("products_minres", "products_local_ratio"):  # fitted as logarithms
        values[name] = float(np.exp(values[name]))
    return values


def fitted_ranges(rows: list[dict], index_ref: float) -> dict[str, float]:
    """The ranges of the fine slope and of ν = ln(|n|/n_ref) over the ``fit`` rows: the estimate
    does not extrapolate its exponential and quadratic terms beyond them."""
    rows = [r for r in rows if r["role"] == "fit"]
    contrast = [float(np.log(r["index_modulus"] / index_ref)) for r in rows]
    return {"products_fine_slope_max": max(r["fine_slope"] for r in rows),
            "products_index_contrast_min": min(contrast), "products_index_contrast_max": max(contrast)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=str(DATA), help="the measured counts (CSV)")
    parser.add_argument("--out", default=str(ROOT / "solver" / "data" / "aim_cost.csv"), help="the file written")
    parser.add_argument("--dry-run", action="store_true", help="print the fit and its residuals, write nothing")
    args = parser.parse_args(argv)

    from wavebrdf.solver.bem3d.aim.estimate import _products
    from wavebrdf.solver.bem3d.aim.options import AIMOptions
    from wavebrdf.solver.fitted import fitted, fitted_rows, write_fitted

    sys.path.insert(0, str(ROOT / "tools"))
    from refit_aim_cost import commit

    rows = measured_counts(Path(args.data))
    index_ref = fitted("aim_cost")[INDEX_REF]
    values = {**fit(rows, index_ref), **fitted_ranges(rows, index_ref)}
    for name, value in values.items():
        print(f"{name} = {value:.3g}")
    cost = {**fitted("aim_cost"), **{k: float(f"{v:.3g}") for k, v in values.items()}}
    print("| case | kind | role | L/λ | rms slope finer than λ | measured (s / p) | planned | error |")
    for r in rows:
        options = AIMOptions(preconditioner="local" if r["local"] else "none", solver="gmres" if r["local"] else "csym")
        predicted = _products(options, r["size_waves"], r["index_modulus"], r["fine_slope"], cost)
        print(f"| {r['case']} | {r['kind']} | {r['role']} | {r['size_waves']:.1f} | {r['fine_slope']:.3f} | "
              f"{r['products_s']} / {r['products_p']} | {int(predicted)} | {predicted / r['products'] - 1:+.0%} |")
    if args.dry_run:
        return 0
    command = "tools/refit_product_counts.py " + " ".join(argv if argv is not None else sys.argv[1:])
    out = fitted_rows("aim_cost")
    for row in out:
        if row["name"] in values:
            row.update(value=f"{values[row['name']]:.3g}", meaning=MEANINGS[row["name"]], command=command.strip(),
                       commit=commit(), machine="any (a least-squares fit of solver/data/aim_products.csv, whose rows "
                                                "name the runs and the 2-core development machine of docs/aim.md)")
    write_fitted(out, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
