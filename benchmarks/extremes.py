"""The extremes table: every case of tests/extremes.py on every registered model it applies to,
in double and single precision → docs/extremes.md (case × model: value, reference, error,
warning; |single − double|).

    nice -n 10 .venv/bin/python -m benchmarks.extremes --out docs/extremes.md

``--cases`` / ``--models``: comma-separated prefixes of case ids / model names (default: all);
``--no-single``: double precision only; ``--update``: rerun only the selected cases and replace
their rows in the existing ``--out`` (the rest of the table is kept). Progress lines go to stderr.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parent.parent / "tests"
sys.path.insert(0, str(TESTS))  # the case library and the references live beside the tests
os.environ.setdefault("POCL_CACHE_DIR", str(TESTS.parent / ".cache" / "pocl"))

from extremes import CASES, MAX_BYTES, MAX_SECONDS, Outcome, models_for, run_case  # noqa: E402

COMMAND = "nice -n 10 .venv/bin/python -m benchmarks.extremes --out docs/extremes.md"
VERDICTS = ("ok", "warned", "refused", "skipped", "FAIL")

INTRO = f"""# Numerical stability at the extremes

Every case of the extremes suite (VALIDATION.md "Numerical stability at the extremes", issue 17)
on every registered model it applies to. The cases are defined once, in `tests/extremes.py`, and
used both by `tests/test_extremes.py` (a CI subset; the whole grid is `-m slow`) and by the
generator of this page. A model registered later is run on the same cases.

Regenerate this page (about 20 minutes on 2 cores; `--update --cases <prefix>` reruns some cases):

    {COMMAND}

**Verdicts.** `ok`: within the tolerance of an independent reference (`tests/references.py`:
textbook Fresnel; the Rayleigh limit of a thin cylinder, Bohren & Huffman §8.4; treams' T-matrix
for cylinders; or a bound such as albedo ≤ 1). `warned`: outside it, and the run said so — a
Python warning, which the batch layer stores in the dataset's `tasks/diagnostics`, or the
dataset's own EnergyWarning (albedo > 1 + 1e-3, jobs/tasks.py). `refused`: a one-line
ValueError naming the field, no number. `skipped`: beyond {MAX_BYTES / 2**30:.1f} GiB or
{MAX_SECONDS:g} s by the model's own estimate (not run on this 2-core machine). `FAIL`: a silent
wrong number, which the suite forbids.

**Columns.** *value*: the unpolarized albedo (bounds: the larger of s and p; fibers: C_ext of
case I and II averaged, µm); *reference*: the reference value or bound; *error*: relative to the
reference (bounds: the distance outside it); *tol*: the case's tolerance (the model's flat-Fresnel
bar of tests/test_models.py: 0.5% approximate wave rungs, 1% BEM and ray rungs; rough bounds
add it as slack; 1% for fibers); *single*: |value(single) − value(double)| / |value(double)| with
float32 kernels and FFTs (`[model] precision = "single"`; 0 for dense BEM and the fiber models,
which assemble and factor in complex128 whatever the precision); *warning*: the first warning, shortened.

**Cases** (λ = 0.4 µm for surfaces, 0.5 µm for fibers; scenes sized per model as in the conformance
suite: "flat" scenes for the Fresnel family, "gain" scenes (10 µm, 160 cells, waist 1.8 µm; BEM
0.6 µm, 12 cells) for rough patches):

"""


def _fmt(x) -> str:
    if isinstance(x, str):
        return x
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    return f"{x:.4g}"


def _short(text: str, n: int = 140) -> str:
    text = text.replace("|", "/").replace("\n", " ")
    return text if len(text) <= n else text[: n - 1] + "…"


def _row(o: Outcome, single: Outcome | None) -> str:
    diff = "—"
    if single is not None and single.verdict not in ("n/a", "skipped") and not single.refused:
        if math.isfinite(o.value) and o.value != 0 and math.isfinite(single.value):
            diff = f"{abs(single.value - o.value) / abs(o.value):.2g}"
        elif single.verdict == "FAIL":
            diff = "FAIL"
    warning = o.refused or (o.warnings[0] if o.warnings else "") or (o.note if o.verdict == "skipped" else "")
    more = f" (+{len(o.warnings) - 1})" if len(o.warnings) > 1 else ""
    return (f"| {o.case} | {o.model} | **{o.verdict}** | {_fmt(o.value)} | {_fmt(o.reference)} | {_fmt(o.error)} | "
            f"{_fmt(o.tolerance)} | {diff} | {_short(warning)}{more} | {o.seconds:.1f} |")


def _merged(path: Path, new_rows: list, rerun: set) -> tuple[list, Counter, list]:
    """The table of ``path`` with the rows of the ``rerun`` cases replaced by ``new_rows`` (in case
    order), the verdict counts of the result, and every case."""
    old = [line for line in path.read_text().splitlines() if line.startswith("| ") and not line.startswith("| case")]
    by_case: dict = {}
    for line in [line for line in old if line.split("|")[1].strip() not in rerun] + new_rows:
        by_case.setdefault(line.split("|")[1].strip(), []).append(line)
    rows = [line for c in CASES for line in by_case.get(c.id, [])]
    counts = Counter(line.split("|")[3].strip().strip("*") for line in rows)
    return rows, counts, CASES


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/extremes.md"))
    parser.add_argument("--cases", default="", help="comma-separated prefixes of case ids")
    parser.add_argument("--models", default="", help="comma-separated model names")
    parser.add_argument("--no-single", action="store_true", help="double precision only")
    parser.add_argument("--update", action="store_true", help="replace the selected cases' rows in --out")
    args = parser.parse_args(argv)
    from wavebrdf.solver.opencl import create_context

    ctx = create_context()
    prefixes = [p for p in args.cases.split(",") if p]
    only = [m for m in args.models.split(",") if m]
    cases = [c for c in CASES if not prefixes or any(c.id.startswith(p) for p in prefixes)]
    rows, counts, t0 = [], Counter(), time.perf_counter()
    for case in cases:
        kept: dict = {}
        for name in models_for(case):
            if only and name not in only:
                continue
            o = run_case(ctx, case, name, "double", kept)
            single = None
            if not args.no_single and o.verdict in ("ok", "warned", "FAIL"):
                single = run_case(ctx, case, name, "single", kept)
            counts[o.verdict] += 1
            rows.append(_row(o, single))
            print(f"{case.id:18s} {name:9s} {o.verdict:8s} {_fmt(o.value):>10s} err {_fmt(o.error):>9s} "
                  f"{o.seconds:6.1f} s {_short(o.refused or '; '.join(o.warnings), 100)}", file=sys.stderr, flush=True)
    if args.update:
        rows, counts, cases = _merged(args.out, rows, {c.id for c in cases})
    lines = [INTRO.rstrip(), ""]
    lines += [f"* `{c.id}` ({c.group}): {c.checks}" for c in cases]
    total = sum(counts.values())
    lines += ["", f"**Summary**: {total} (case, model) pairs — " + ", ".join(f"{counts[v]} {v}" for v in VERDICTS)
              + f" ({'rows of ' + ', '.join(prefixes) + ' updated' if args.update else 'generated'} in "
              f"{(time.perf_counter() - t0) / 60:.0f} min).", "",
              "| case | model | verdict | value | reference | error | tol | single | warning / refusal | s |",
              "|---|---|---|---|---|---|---|---|---|---|", *rows, ""]
    args.out.parent.mkdir(exist_ok=True)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}: {dict(counts)}", file=sys.stderr)
    return 1 if counts["FAIL"] else 0


if __name__ == "__main__":
    sys.exit(main())
