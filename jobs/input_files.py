"""Reading the files a config names: the config itself, ``[material] file`` (the reference
simulator's wvl.txt), ``[illumination] directions_file`` (its wi.txt), and the shape of a height
file (``[surface] file``) before it is loaded. Every problem is a one-line
:class:`~wavebrdf.jobs.errors.ConfigError` naming the key (or the config file), the file and,
for a bad row, its line and values.
"""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path

import numpy as np

from wavebrdf.jobs.errors import ConfigError, fail
from wavebrdf.jobs.ranges import direction_identity
from wavebrdf.solver.materials import INDEX_COLUMNS, MaterialError, read_index_file
from wavebrdf.solver.number_rows import RowError, number_rows
from wavebrdf.solver.options import ANGLE_DEG

__all__ = ["height_file_shape", "input_file_problem", "read_config_text", "read_directions_file",
           "read_material_rows", "resolve_input_path"]

MAX_CONFIG_BYTES = 16 * 2**20
DIRECTIONS_FILE_MAX_BYTES = 16 * 2**20


def input_file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be read as an input file ("does not exist", "is a folder, not a file",
    "is not a regular file (a character device)", ...); None for a readable regular file."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "does not exist"
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if stat.S_ISDIR(st.st_mode):
        return "is a folder, not a file"
    if not stat.S_ISREG(st.st_mode):
        kinds = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                 (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"))
        kind = next((name for test, name in kinds if test(st.st_mode)), "not a file")
        return f"is not a regular file ({kind})"
    if not os.access(path, os.R_OK):
        return "is not readable (permission denied)"
    return None


def resolve_input_path(value: str, base_dir: Path) -> Path:
    """An input file path; relative ones are taken from the config file's folder."""
    path = Path(value).expanduser()
    return path if path.is_absolute() else base_dir / path


def read_config_text(path: Path) -> str:
    """The UTF-8 text of config file ``path`` (a one-line ConfigError if it cannot be one)."""
    problem = input_file_problem(path)
    if problem is None and path.stat().st_size > MAX_CONFIG_BYTES:
        problem = f"is {path.stat().st_size / 2**20:.0f} MiB; a config is a small TOML text file"
    if problem is not None:
        raise ConfigError(f"config file {str(path)!r} {problem}")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"config file {str(path)!r} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                          f"{exc.start}); a config is a TOML text file") from None
    return text


def read_material_rows(value: str, path: Path) -> list:
    """The rows (λ µm, n, κ) of ``[material] file = value`` (at ``path``) as plain lists, each
    within the physical ranges of a ``[material] table`` row."""
    problem = input_file_problem(path)
    if problem is not None:
        raise fail("material", "file", value, f"{str(path)!r} {problem}" if str(path) != value else problem)
    try:
        rows = read_index_file(path, label=value).tolist()
    except MaterialError as exc:
        raise ConfigError(f"[material] {exc}") from None
    for number, row in enumerate(rows, start=1):
        for (name, limits), x in zip(INDEX_COLUMNS, row):
            problem = limits.problem(x)
            if problem is not None:
                raise fail("material", "file", value, f"row {number}: {name} {problem} (bad: {x:g} in λ, n, κ = "
                           f"{', '.join(f'{v:g}' for v in row)})")
    return rows


def read_directions_file(value: str, path: Path, angles: str) -> tuple[tuple[float, float], ...]:
    """``[illumination] directions_file`` (the reference simulator's wi.txt): one direction per
    row, θ then φ, in ``angles`` ("rad" as wi.txt, or "deg"), separated by commas and/or
    whitespace; blank lines, ``#``/``%`` comments and a first line of words (a header) are skipped.
    θ from the normal toward the light in [0, 90°); φ any finite azimuth. Returned in degrees;
    every problem is a ConfigError naming the key, the file, the line and the value."""
    problem = input_file_problem(path)
    if problem is None and path.stat().st_size > DIRECTIONS_FILE_MAX_BYTES:
        problem = f"is {path.stat().st_size / 2**20:.0f} MiB; a list of θ, φ rows is a small text file"
    if problem is not None:
        where = f"{str(path)!r} {problem}" if str(path) != value else problem
        raise fail("illumination", "directions_file", value, where)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (UnicodeDecodeError, OSError) as exc:
        raise fail("illumination", "directions_file", value, f"cannot be read as text ({exc})") from None
    unit, to_deg = ("rad", math.degrees) if angles == "rad" else ("deg", float)
    limit = "π/2 rad" if angles == "rad" else "90°"
    out: list[tuple[float, float]] = []
    rows: dict[tuple[float, float], int] = {}

    def bad(line_no, line, problem):
        text = line if len(line) <= 60 else line[:57] + "..."
        return fail("illumination", "directions_file", value, f"line {line_no} ({text!r}): {problem}")

    try:
        for line_no, line, (theta, phi) in number_rows(lines, ("theta", "phi")):
            if not (math.isfinite(theta) and math.isfinite(phi)):
                raise bad(line_no, line, "angles must be finite numbers (not NaN/inf)")
            theta_deg, phi_deg = to_deg(theta), to_deg(phi)
            if not 0.0 <= theta_deg < 90.0:
                hint = (" (the file looks like degrees: set angles = \"deg\")" if angles == "rad"
                        and theta > math.pi / 2 and theta < 90.0 else "")
                raise bad(line_no, line, f"theta = {theta:g} {unit} must be in [0, {limit}){hint}")
            if ANGLE_DEG.problem(phi_deg) is not None:
                raise bad(line_no, line, f"phi = {phi:g} {unit} must lie within ±{'2π rad' if angles == 'rad' else '360°'}")
            identity = direction_identity((theta_deg, phi_deg))
            if identity in rows:
                raise bad(line_no, line, f"repeats the direction of line {rows[identity]} (φ modulo 360°; θ = 0 "
                                         "whatever φ); directions must be distinct")
            rows[identity] = line_no
            out.append((theta_deg, phi_deg))
    except RowError as exc:
        raise bad(exc.line_no, exc.line, f"{exc.problem}; rows are θ, φ in {unit} (angles = \"{angles}\")") from None
    if not out:
        raise fail("illumination", "directions_file", value, "holds no rows of θ, φ")
    return tuple(out)


def height_file_shape(path: Path) -> tuple[int, ...] | None:
    """The shape of a height file without loading it: from a .npy header, or for text the length
    of the first row (the matrix must be square). None when the file has no readable header (the
    loader then says what is wrong)."""
    try:
        with open(path, "rb") as fh:
            if path.suffix == ".npy":
                version = np.lib.format.read_magic(fh)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                return tuple(read(fh)[0])
            for line in iter(lambda: fh.readline(2**26), b""):
                text = line.decode("utf-8", "replace").strip()
                if text and not text.startswith("#"):
                    n = len(text.replace(",", " ").split())  # a lower bound if the row is over 64 MiB
                    return (n, n)
    except (OSError, ValueError):
        return None
    return None
