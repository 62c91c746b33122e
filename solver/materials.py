"""Complex refractive indices n − jκ (κ ≥ 0 is loss, e^{+jωt}) by name, constant, or table.

Built-in metals use the Lorentz–Drude fits of Rakić, Djurišić, Elazar & Majewski, Appl. Opt. 37,
5271 (1998), Table 2 (valid well beyond the visible range served here). ``aluminium-bemsim`` is
the aluminium table of the full-wave reference simulator's published examples (0.400–0.688 µm),
for like-with-like comparisons. Constant dielectrics are given by a name or by ``n``/``kappa``.
Tables come as rows (λ, n, κ) or as a file in the reference simulator's ``wvl.txt`` format
(:func:`read_index_file`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from wavebrdf.solver.number_rows import RowError, number_rows
from wavebrdf.solver.options import WAVELENGTH_UM, Limits

__all__ = ["INDEX_COLUMNS", "INDEX_KAPPA", "INDEX_N", "Material", "MaterialError", "BUILTIN", "builtin_names",
           "lorentz_drude_index", "read_index_file"]

HC_EV_UM = 1.239841984  # photon energy (eV) × wavelength (µm)

# The physical range of a complex index n − jκ (a config's [material] n, kappa and table rows)
INDEX_N = Limits(low=0, low_open=True, span=(1e-3, 1e4), note="the real part n of the index n − jκ")
INDEX_KAPPA = Limits(low=0, high=1e4, note="κ of n − jκ; 1e3 is already a perfect conductor")
INDEX_COLUMNS = (("wavelength_um", WAVELENGTH_UM), ("n", INDEX_N), ("kappa", INDEX_KAPPA))  # a table's rows


class MaterialError(ValueError):
    """Invalid material input; the message names the problem."""


# Rakić et al. 1998, Lorentz–Drude parameters: ωp (eV); Drude (f0, Γ0); oscillators (f, Γ, ω) in eV.
_LD_PARAMETERS = {
    "silver": (9.01, (0.845, 0.048), [(0.065, 3.886, 0.816), (0.124, 0.452, 4.481),
                                      (0.011, 0.065, 8.185), (0.840, 0.916, 9.083),
                                      (5.646, 2.419, 20.29)]),
    "gold": (9.03, (0.760, 0.053), [(0.024, 0.241, 0.415), (0.010, 0.345, 0.830),
                                    (0.071, 0.870, 2.969), (0.601, 2.494, 4.304),
                                    (4.384, 2.214, 13.32)]),
    "copper": (10.83, (0.575, 0.030), [(0.061, 0.378, 0.291), (0.104, 1.056, 2.957),
                                       (0.723, 3.213, 5.300), (0.638, 4.305, 11.18)]),
    "aluminium": (14.98, (0.523, 0.047), [(0.227, 0.333, 0.162), (0.050, 0.312, 1.544),
                                          (0.166, 1.351, 1.808), (0.030, 3.382, 3.473)]),
}
_LD_RANGE_UM = (0.2, 2.0)  # range served here (inside every fit's published validity)

_CONSTANT = {"glass": 1.5, "fused-silica": 1.458, "water": 1.333, "vacuum": 1.0}
_ALIASES = {"aluminum": "aluminium", "al": "aluminium", "ag": "silver", "au": "gold", "cu": "copper"}


def lorentz_drude_index(metal: str, wavelength_um) -> np.ndarray:
    """n − jκ of a Rakić Lorentz–Drude metal at vacuum wavelength(s) in µm."""
    wp, (f0, g0), osc = _LD_PARAMETERS[metal]
    w = HC_EV_UM / np.asarray(wavelength_um, dtype=float)
    # ε(ω) in the e^{-iωt} form of the paper, then conjugated to the project's e^{+jωt}
    eps = 1.0 - f0 * wp**2 / (w * (w + 1j * g0))
    for f, g, w0 in osc:
        eps = eps + f * wp**2 / (w0**2 - w**2 - 1j * w * g)
    n_plus_ik = np.sqrt(eps)  # principal root: Im ≥ 0 for a passive medium
    return np.conj(n_plus_ik)


def _reference_table() -> np.ndarray:
    text = resources.files("wavebrdf.solver").joinpath("data/aluminium_bemsim.csv").read_text()
    return np.loadtxt(text.splitlines(), delimiter=",", comments="#")


@dataclass(frozen=True)
class Material:
    """A medium below the surface: :meth:`index` returns n − jκ at vacuum wavelengths (µm)."""

    name: str
    kind: str  # "lorentz-drude" | "table" | "constant"
    table: np.ndarray | None = field(default=None, repr=False)  # rows (λ µm, n, κ)
    constant: complex | None = None

    @classmethod
    def from_name(cls, name: str) -> "Material":
        key = _ALIASES.get(name.lower(), name.lower())
        if key in _LD_PARAMETERS:
            return cls(key, "lorentz-drude")
        if key == "aluminium-bemsim":
            return cls.from_table(_reference_table(), name=key)
        if key in _CONSTANT:
            return cls.from_constant(_CONSTANT[key], 0.0, name=key)
        raise MaterialError(f"material.name {name!r} is unknown; built-in: {', '.join(builtin_names())}")

    @classmethod
    def from_constant(cls, n: float, kappa: float = 0.0, name: str | None = None) -> "Material":
        if not (np.isfinite(n) and n > 0):
            raise MaterialError(f"material.n must be a positive number, got {n!r}")
        if not np.isfinite(kappa) or kappa < 0:
            raise MaterialError(f"material.kappa must be >= 0 (loss, n - j*kappa), got {kappa!r}")
        return cls(name or f"n={n:g}-j{kappa:g}", "constant", constant=complex(n, -kappa))

    @classmethod
    def from_table(cls, rows, name: str = "table") -> "Material":
        try:
            table = np.asarray(rows, dtype=float)
        except (TypeError, ValueError) as exc:
            raise MaterialError(f"material.table must be rows [wavelength_um, n, kappa]: {exc}") from exc
        if table.ndim != 2 or table.shape[1] != 3 or table.shape[0] < 1:
            raise MaterialError(
                f"material.table must be a list of [wavelength_um, n, kappa] rows, got shape {table.shape}"
            )
        if not np.all(np.isfinite(table)):
            raise MaterialError("material.table contains NaN/inf")
        if np.any(table[:, 0] <= 0):
            raise MaterialError(f"material.table wavelengths must be > 0, got {table[:, 0].min()}")
        if np.any(table[:, 1] <= 0):
            raise MaterialError(f"material.table n must be > 0, got {table[:, 1].min()}")
        if np.any(table[:, 2] < 0):
            raise MaterialError(
                f"material.table kappa must be >= 0 (loss, n - j*kappa), got {table[:, 2].min()}"
            )
        order = np.argsort(table[:, 0])
        table = table[order]
        if np.any(np.diff(table[:, 0]) == 0):
            raise MaterialError("material.table has repeated wavelengths")
        return cls(name, "table", table=table)

    @classmethod
    def from_file(cls, path, name: str | None = None) -> "Material":
        """The index table of a text file in the reference simulator's ``wvl.txt`` format
        (:func:`read_index_file`), linearly interpolated over λ like :meth:`from_table`."""
        return cls.from_table(read_index_file(path), name=name or f"file {Path(path).name}")

    @property
    def wavelength_range_um(self) -> tuple[float, float]:
        if self.kind == "table":
            return float(self.table[0, 0]), float(self.table[-1, 0])
        if self.kind == "lorentz-drude":
            return _LD_RANGE_UM
        return 0.0, np.inf

    def index(self, wavelength_um) -> np.ndarray:
        """Complex index n − jκ at vacuum wavelength(s) (µm); errors outside the valid range."""
        lam = np.asarray(wavelength_um, dtype=float)
        lo, hi = self.wavelength_range_um
        if np.any(lam < lo - 1e-12) or np.any(lam > hi + 1e-12):
            raise MaterialError(
                f"material {self.name!r} is defined for {lo:g}–{hi:g} µm; requested wavelength(s) "
                f"{np.atleast_1d(lam)[(np.atleast_1d(lam) < lo) | (np.atleast_1d(lam) > hi)].tolist()}"
            )
        if self.kind == "constant":
            return np.full(lam.shape, self.constant, dtype=complex)
        if self.kind == "lorentz-drude":
            return lorentz_drude_index(self.name, lam)
        n = np.interp(lam, self.table[:, 0], self.table[:, 1])
        k = np.interp(lam, self.table[:, 0], self.table[:, 2])
        return n - 1j * k


INDEX_FILE_MAX_BYTES = 16 * 2**20  # a wvl.txt is a few rows; refuse anything that is clearly not one


def _index_row_error(shown: str, line_no: int, line: str, problem: str) -> MaterialError:
    text = line if len(line) <= 60 else line[:57] + "..."
    return MaterialError(f"material.file = {shown!r}: line {line_no} ({text!r}): {problem}")


def read_index_file(path, label: str | None = None) -> np.ndarray:
    """Rows (λ µm, n, κ) of a ``wvl.txt``-style file, checked: shape (rows, 3), float.

    Format (the reference simulator's ``wvl.txt``, written by MATLAB's ``writematrix``): one row
    per wavelength, ``λ, n, κ`` — vacuum wavelength in µm, then the real part n and the loss κ ≥ 0
    of the index n − jκ (the reference builds its index as n − jκ from the same two numbers for
    e^{+jωt}). Values separated by commas and/or whitespace (``;`` is taken as a comma); blank
    lines and lines starting with ``#`` or ``%`` are ignored; the first remaining line may be a
    header of words (e.g. ``lambda,n,k``). Wavelengths must be > 0 and strictly increasing.
    Every problem is a :class:`MaterialError` naming ``material.file`` (as ``label``, default the
    path), the line and the value.
    """
    path = Path(path)
    shown = str(path) if label is None else label
    if not path.exists():
        raise MaterialError(f"material.file = {shown!r} does not exist")
    if not path.is_file():
        raise MaterialError(f"material.file = {shown!r} is not a regular file")
    if path.stat().st_size > INDEX_FILE_MAX_BYTES:
        raise MaterialError(f"material.file = {shown!r} is {path.stat().st_size / 2**20:.0f} MiB; a table of "
                            "λ, n, κ rows is a small text file")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()  # -sig: a BOM from spreadsheet exports
    except UnicodeDecodeError as exc:
        raise MaterialError(f"material.file = {shown!r} is not UTF-8 text ({exc.reason} at byte "
                            f"{exc.start})") from None
    except OSError as exc:
        raise MaterialError(f"material.file = {shown!r} cannot be read ({exc.strerror})") from None
    rows: list[tuple[float, float, float]] = []
    try:
        numbered = list(number_rows(lines, ("wavelength_um", "n", "kappa")))
    except RowError as exc:
        raise _index_row_error(shown, exc.line_no, exc.line, exc.problem + "; rows are λ (µm), n, κ") from None
    for line_no, line, values in numbered:
        lam, n, kappa = values
        if not all(np.isfinite(values)):
            raise _index_row_error(shown, line_no, line, "values must be finite numbers (not NaN/inf)")
        if lam <= 0:
            raise _index_row_error(shown, line_no, line, f"wavelength {lam:g} µm must be > 0")
        if n <= 0:
            raise _index_row_error(shown, line_no, line, f"n = {n:g} must be > 0")
        if kappa < 0:
            raise _index_row_error(shown, line_no, line, f"kappa = {kappa:g} must be >= 0 (the index is n - j*kappa, "
                                   "kappa > 0 meaning loss; write the magnitude of the imaginary part)")
        if rows and lam <= rows[-1][0]:
            what = "repeats" if lam == rows[-1][0] else "is smaller than"
            raise _index_row_error(shown, line_no, line, f"wavelength {lam:g} µm {what} the previous row's "
                                   f"{rows[-1][0]:g} µm; rows must be in strictly increasing wavelength")
        rows.append((lam, n, kappa))
    if not rows:
        raise MaterialError(f"material.file = {shown!r} holds no rows of λ (µm), n, κ")
    return np.array(rows, dtype=float)


def builtin_names() -> list[str]:
    return sorted(list(_LD_PARAMETERS) + ["aluminium-bemsim"] + list(_CONSTANT))


BUILTIN = tuple(builtin_names())
