"""The reference full-wave simulator's inputs taken as they are (issue 18 item 4): its ``wvl.txt``
([material] file), its ``wi.txt`` ([illumination] directions_file), non-square global surfaces for
steering (its ``-x ≠ -y``), and its sub-area workflow as a config that plans.

References are the files' own rows, linear interpolation written out by hand, angles converted by
hand, and the height matrix sliced by hand (bem3d.md §10.2: patch (a, b) starts a·shift/d rows and
b·shift/d columns after the first)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.config import ConfigError, load_config
from wavebrdf.jobs.plan import plan_study
from wavebrdf.jobs.steering import GlobalSurface, PatchLayout
from wavebrdf.solver.materials import Material, MaterialError
from wavebrdf.solver.surface import generate

ROOT = Path(__file__).resolve().parents[1]

# the reference's steerMessy/wvl.txt (aluminium), as MATLAB's writematrix writes it
WVL_ROWS = [(0.4, 0.46582, 4.7119), (0.43, 0.55363, 5.0698), (0.46, 0.65007, 5.4183), (0.49, 0.75329, 5.755)]
WVL_COMMA = "".join(f"{lam:g},{n:g},{k:g}\n" for lam, n, k in WVL_ROWS)

STUDY = """
[study]
output = "{out}"

[surface]
{surface}

[material]
{material}

[illumination]
{illumination}
waist_um = 0.8

[model]
name = "kirchhoff"

[output]
resolution = 32
{extra}
"""

SURFACE = 'generator = "gaussian"\nsize_um = 4.0\ncells = 40\nrms_height_um = 0.02\ncorrelation_um = 0.5'


def study(tmp_path, *, surface=SURFACE, material='file = "wvl.txt"', illumination="directions_deg = [[0, 0]]",
          extra="", wvl: str | None = WVL_COMMA, wi: str | None = None, name="s"):
    """Write wvl.txt / wi.txt (when given) and a config next to them; load it."""
    if wvl is not None:
        (tmp_path / "wvl.txt").write_text(wvl)
    if wi is not None:
        (tmp_path / "wi.txt").write_text(wi)
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(textwrap.dedent(STUDY.format(out=tmp_path / f"{name}.h5", surface=surface, material=material,
                                                illumination=illumination, extra=extra)))
    return load_config(cfg)


def refused(tmp_path, *patterns, **kwargs) -> str:
    with pytest.raises(ConfigError) as info:
        study(tmp_path, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    for pattern in patterns:
        assert pattern in message, message
    return message


# --- [material] file = "wvl.txt" ---------------------------------------------------------------

WVL_VARIANTS = {
    "comma": WVL_COMMA,
    "whitespace": "".join(f"{lam:g}  {n:g}\t{k:g}\n" for lam, n, k in WVL_ROWS),
    "header and comments": "# aluminium\nlambda_um, n, kappa\n\n" + "".join(
        f"{lam:g}, {n:g}, {k:g}   \n" for lam, n, k in WVL_ROWS) + "% end\n",
    "CRLF": WVL_COMMA.replace("\n", "\r\n"),
}


@pytest.mark.parametrize("variant", list(WVL_VARIANTS))
def test_wvl_file_rows_and_interpolation(tmp_path, variant):
    """Every variant gives n − jκ equal to the row at a tabulated λ and the straight line between
    rows in between; with no wavelengths_um the study runs the file's rows (the reference's default)."""
    cfg = study(tmp_path, wvl=WVL_VARIANTS[variant], illumination="directions_deg = [[0, 0]]")
    case = cfg.cases[0]
    assert case.illumination.wavelengths_um == tuple(r[0] for r in WVL_ROWS)
    material = case.material.build()
    for lam, n, k in WVL_ROWS:
        assert material.index(lam) == complex(n, -k)
    (l0, n0, k0), (l1, n1, k1) = WVL_ROWS[1], WVL_ROWS[2]
    for t in (0.25, 0.5, 0.9):
        lam = l0 + t * (l1 - l0)
        expected = complex(n0 + t * (n1 - n0), -(k0 + t * (k1 - k0)))
        assert abs(material.index(lam) - expected) < 1e-12
    # the plan's index per wavelength is the file's rows (the seam every model reads)
    plan = plan_study(cfg)
    assert np.array_equal(plan.index(0), [complex(n, -k) for _, n, k in WVL_ROWS])


def test_wvl_file_relative_to_config_and_chosen_wavelengths(tmp_path):
    sub = tmp_path / "data"
    sub.mkdir()
    (sub / "al.txt").write_text(WVL_COMMA)
    cfg = study(tmp_path, material='file = "data/al.txt"', wvl=None,
                illumination="wavelengths_um = [0.43, 0.445]\ndirections_deg = [[0, 0]]")
    assert cfg.cases[0].material.file == sub / "al.txt"
    index = plan_study(cfg).index(0)
    assert index[0] == complex(0.55363, -5.0698)
    assert abs(index[1] - complex((0.55363 + 0.65007) / 2, -(5.0698 + 5.4183) / 2)) < 1e-12
    # Material.from_file is the same table
    assert Material.from_file(sub / "al.txt").index(0.49) == complex(0.75329, -5.755)


@pytest.mark.parametrize("text, line, pattern", [
    ("0.4,0.46582,4.7119\n0.43,abc,5.0698\n", 2, "'abc' is not a number"),
    ("0.4,0.46582,4.7119\n0.43,0.55363\n", 2, "needs 3 values"),
    ("0.4,0.46582,4.7119,1\n", 1, "needs 3 values"),
    ("0,0.46582,4.7119\n0.43,0.55363,5.0698\n", 1, "wavelength 0 µm must be > 0"),
    ("-0.4,0.46582,4.7119\n", 1, "wavelength -0.4 µm must be > 0"),
    ("0.4,0.46582,-4.7119\n", 1, "kappa = -4.7119 must be >= 0"),
    ("0.4,0,4.7119\n", 1, "n = 0 must be > 0"),
    ("0.43,0.55363,5.0698\n0.4,0.46582,4.7119\n", 2, "wavelength 0.4 µm is smaller than the previous row's 0.43"),
    ("0.4,0.46582,4.7119\n0.4,0.46582,4.7119\n", 2, "wavelength 0.4 µm repeats the previous row's 0.4"),
    ("0.4,nan,4.7119\n", 1, "finite"),
])
def test_wvl_file_errors_name_the_key_line_and_value(tmp_path, text, line, pattern):
    message = refused(tmp_path, "material.file", "wvl.txt", f"line {line}", pattern, wvl=text)
    # and Material.from_file raises the same as a MaterialError
    with pytest.raises(MaterialError, match="material.file"):
        Material.from_file(tmp_path / "wvl.txt")
    assert message.startswith("[material]")


def test_wvl_file_refusals(tmp_path):
    refused(tmp_path, "[material] file", "missing.txt", "does not exist", material='file = "missing.txt"', wvl=None)
    refused(tmp_path, "material.file", "holds no rows", wvl="# only a comment\n")
    refused(tmp_path, "[material] file and name", material='file = "wvl.txt"\nname = "aluminium"')
    refused(tmp_path, "[material] file and n", material='file = "wvl.txt"\nn = 1.5')
    refused(tmp_path, "[material] file and table", material='file = "wvl.txt"\ntable = [[0.5, 1.5, 0.0]]')
    refused(tmp_path, "[material] file and kappa", material='file = "wvl.txt"\nkappa = 0.1')
    # requested wavelengths outside the file: named with both keys and the file's range
    refused(tmp_path, "[illumination] wavelengths_um", "[0.5]", "material.file", "0.4–0.49 µm",
            illumination="wavelengths_um = [0.45, 0.5]\ndirections_deg = [[0, 0]]")
    refused(tmp_path, "[illumination] wavelengths_um", "[0.39]", "material.file",
            illumination="wavelengths_um = [0.39]\ndirections_deg = [[0, 0]]")
    # without a material file, wavelengths_um stays required
    refused(tmp_path, "[illumination] wavelengths_um: missing required key", material='name = "aluminium"')


# --- [illumination] directions_file = "wi.txt" -------------------------------------------------

DIRECTIONS_DEG = [(0.0, 0.0), (2.4, 0.0), (2.4, 90.0), (30.0, 45.0), (72.0, 270.0)]


@pytest.mark.parametrize("angles, sep", [("rad", ","), ("deg", ","), ("rad", " "), (None, ",")])
def test_wi_file_equals_directions_deg(tmp_path, angles, sep):
    """wi.txt in radians (the reference's default) or degrees gives the directions of the
    equivalent directions_deg, in order; so does the plan's (θ, φ) in radians."""
    convert = (lambda a: a) if angles == "deg" else math.radians
    text = "".join(f"{convert(t)!r}{sep}{convert(p)!r}\n" for t, p in DIRECTIONS_DEG)
    unit = f'\nangles = "{angles}"' if angles else ""
    from_file = study(tmp_path, wi=text, name="file", illumination=f'wavelengths_um = [0.4]\n'
                                                                    f'directions_file = "wi.txt"{unit}')
    listed = study(tmp_path, name="listed", illumination=f"wavelengths_um = [0.4]\n"
                                                        f"directions_deg = {[list(d) for d in DIRECTIONS_DEG]}")
    got = np.array(from_file.cases[0].illumination.directions_deg)
    assert np.allclose(got, DIRECTIONS_DEG, rtol=0, atol=1e-12)
    plans = [plan_study(c) for c in (from_file, listed)]
    rad = [np.array([p.direction_rad(t) for t in p.result_tasks()]) for p in plans]
    assert np.allclose(rad[0], np.radians(DIRECTIONS_DEG), rtol=0, atol=1e-14)
    assert np.allclose(rad[0], rad[1], rtol=0, atol=1e-14)


def test_wi_file_of_the_reference(tmp_path):
    """The reference's steerMessy/wi.txt rows: θ = 0.042 rad, φ = 3° steps in radians."""
    text = "".join(f"0.042,{math.radians(3 * i)!r}\n" for i in range(120))
    cfg = study(tmp_path, wi=text, illumination='wavelengths_um = [0.4]\ndirections_file = "wi.txt"')
    got = np.array(cfg.cases[0].illumination.directions_deg)
    assert got.shape == (120, 2)
    assert np.allclose(got[:, 0], math.degrees(0.042)) and np.allclose(got[:, 1], 3.0 * np.arange(120))


@pytest.mark.parametrize("text, angles, patterns", [
    ("0,0\n1.6,0\n", "rad", ["line 2", "theta = 1.6 rad must be in [0, π/2 rad)"]),
    ("0,0\n30,0\n", "rad", ["line 2", "theta = 30 rad", 'angles = "deg"']),
    ("0,0\n90,0\n", "deg", ["line 2", "theta = 90 deg must be in [0, 90°)"]),
    ("-0.1,0\n", "rad", ["line 1", "theta = -0.1 rad"]),
    ("0,0\n0.1\n", "rad", ["line 2", "needs 2 values"]),
    ("0,0\n0.1,x\n", "rad", ["line 2", "'x' is not a number"]),
    ("0.1,0\n0.2,0\n0.1,0\n", "rad", ["line 3", "repeats the direction of line 1"]),
    ("30,0\n30,360\n", "deg", ["line 2", "repeats the direction of line 1 (φ modulo 360°"]),
    ("0,0\n0,1.5\n", "rad", ["line 2", "repeats the direction of line 1", "θ = 0 whatever φ"]),
    ("0.1,inf\n", "rad", ["line 1", "finite"]),
    ("# nothing\n", "rad", ["holds no rows"]),
])
def test_wi_file_errors_name_the_file_line_and_value(tmp_path, text, angles, patterns):
    refused(tmp_path, "[illumination] directions_file", "wi.txt", *patterns, wi=text,
            illumination=f'wavelengths_um = [0.4]\ndirections_file = "wi.txt"\nangles = "{angles}"')


def test_wi_file_refusals(tmp_path):
    refused(tmp_path, "[illumination] directions_deg and directions_file", wi="0,0\n",
            illumination='wavelengths_um = [0.4]\ndirections_file = "wi.txt"\ndirections_deg = [[0, 0]]')
    refused(tmp_path, "[illumination] angles", "only used with directions_file",
            illumination='wavelengths_um = [0.4]\ndirections_deg = [[0, 0]]\nangles = "deg"')
    refused(tmp_path, "[illumination] angles", "must be one of", wi="0,0\n",
            illumination='wavelengths_um = [0.4]\ndirections_file = "wi.txt"\nangles = "grad"')
    refused(tmp_path, "[illumination] directions_file", "does not exist",
            illumination='wavelengths_um = [0.4]\ndirections_file = "nowhere.txt"')


# --- rectangular global surfaces for steering ---------------------------------------------------

def by_hand(z, layout_counts, patch_cells, shift_cells, patch):
    """The patch's heights sliced from the global matrix: the layout is centred, so patch (0, 0)
    starts half the unused nodes after the first along each axis."""
    span = [patch_cells + (m - 1) * shift_cells for m in layout_counts]
    start = [(z.shape[axis] - 1 - span[axis]) // 2 + patch[axis] * shift_cells for axis in (0, 1)]
    return z[start[0]: start[0] + patch_cells + 1, start[1]: start[1] + patch_cells + 1]


def test_rectangular_surface_cut_into_square_patches(tmp_path):
    """A (N_x+1)×(N_y+1) height file (rows = x) under [steering]: each patch task's surface is the
    hand-sliced square block, centred where the layout says, with the global mean as z reference."""
    rng = np.random.default_rng(5)
    z = rng.normal(0.0, 0.02, (61, 41)) + 0.3  # 6 µm along x, 4 µm along y
    np.savetxt(tmp_path / "zvals.txt", z, delimiter=",")  # the reference's comma-separated zvals.txt
    cfg = study(tmp_path, surface='file = "zvals.txt"\nsize_um = [6.0, 4.0]', material='name = "silver"',
                illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0], [1, 0]]",
                extra='[steering]\npatches = ["auto", 3]\npatch_size_um = 2.0\nshift_um = 0.8')
    plan = plan_study(cfg)
    layout = plan.steering[0].layout
    assert layout.counts == (6, 3)  # "auto" along x: (6 − 2)/0.8 + 1 = 6 patches span the 6 µm exactly
    patches = [t for t in plan.tasks if t.kind == "patch"]
    assert len(patches) == 6 * 3
    for task in patches:
        scene = plan.scene(task)
        expected = by_hand(z, layout.counts, 20, 8, task.patch)
        assert scene.surface.z.shape == (21, 21) and np.array_equal(scene.surface.z, expected)
        assert scene.surface.size_um == pytest.approx(2.0)
        assert np.allclose(scene.surface.origin_um, layout.centre(task.patch)[:2])
        assert scene.z_reference == pytest.approx(z.mean())
    # the layout's centres are 0.8 µm apart and symmetric about the surface centre
    assert np.allclose(layout.centre((0, 0))[:2], [-2.0, -0.8]) and np.allclose(layout.centre((5, 2))[:2], [2.0, 0.8])


def test_rectangular_generated_surface_and_layout(tmp_path):
    """size_um = [L_x, L_y], cells = [N_x, N_y]: the generator's field on the longer side's square,
    cropped; PatchLayout cuts it as slicing by hand would; an explicit [mx, my] that overflows
    one axis is refused naming that axis."""
    surface = GlobalSurface.generated("gaussian", cells=(60, 36), sides_um=(6.0, 3.6), seed=2,
                                      rms_height_um=0.05, correlation_um=0.5)
    square = generate("gaussian", cells=60, size_um=6.0, seed=2, rms_height_um=0.05, correlation_um=0.5)
    assert surface.z.shape == (61, 37) and np.array_equal(surface.z, square.z[:61, :37])
    assert surface.spacing_um == pytest.approx(0.1) and surface.size_um == 6.0
    assert np.allclose(surface.y, -1.8 + 0.1 * np.arange(37))
    layout = PatchLayout.for_surface(surface, "auto", 2.0, 0.8)
    assert layout.counts == (6, 3)  # (6 − 2)/0.8 + 1 = 6 along x; floor((3.6 − 2)/0.8) + 1 = 3 along y
    layout.check(surface)
    for patch in layout.indices:
        assert np.array_equal(layout.cut(surface, patch).z, by_hand(surface.z, layout.counts, 20, 8, patch))
    with pytest.raises(ValueError, match="along y"):
        PatchLayout((6, 4), 2.0, 0.8).check(surface)
    # a layout leaving half a cell on each side would put patch nodes between the surface's
    with pytest.raises(ValueError, match="not a whole number of cells"):
        PatchLayout((4, 3), 2.0, 0.7).check(surface)  # 4.1 µm of 6: 0.95 µm = 9.5 cells each side
    # placed by for_surface, that layout moves half a cell along x: patch (a, b) is the block from
    # node 9 + 7a (floor of 9.5) and 1 + 7b, and its centre is that block's centre
    shifted = PatchLayout.for_surface(surface, [4, 3], 2.0, 0.7)
    assert shifted.offset_um[0] == pytest.approx(-0.05) and shifted.offset_um[1] == 0.0
    shifted.check(surface)
    for a, b in shifted.indices:
        cut = shifted.cut(surface, (a, b))
        i0, j0 = 9 + 7 * a, 1 + 7 * b
        assert np.array_equal(cut.z, surface.z[i0: i0 + 21, j0: j0 + 21])
        assert np.allclose(shifted.centre((a, b))[:2], [surface.x[i0] + 1.0, surface.y[j0] + 1.0], atol=1e-12)
    stats = surface.statistics()
    assert stats["rms_height_um"] == pytest.approx(np.std(surface.z), rel=1e-12)


def test_rectangular_generated_surface_plans_in_a_steering_study(tmp_path):
    surface = ('generator = "gaussian"\nsize_um = [6.0, 3.6]\ncells = [60, 36]\nrms_height_um = 0.05\n'
               'correlation_um = 0.5\nseed = 2')
    cfg = study(tmp_path, surface=surface, material='name = "silver"',
                illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0]]",
                extra='[steering]\npatches = "auto"\npatch_size_um = 2.0\nshift_um = 0.8')
    plan = plan_study(cfg)
    assert plan.steering[0].layout.counts == (6, 3)
    z = plan.surface(0).z
    for task in (t for t in plan.tasks if t.kind == "patch"):
        assert np.array_equal(plan.scene(task).surface.z, by_hand(z, (6, 3), 20, 8, task.patch))
    refused(tmp_path, "[surface] size_um = [6.0, 3.5], cells = [60, 36]", "cells must be square",
            surface=surface.replace("3.6]", "3.5]"), material='name = "silver"',
            illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0]]",
            extra='[steering]\npatches = "auto"\npatch_size_um = 2.0')


def test_rectangular_surface_refused_outside_steering(tmp_path):
    rect = 'generator = "gaussian"\nsize_um = [6.0, 4.0]\ncells = [60, 40]\nrms_height_um = 0.05\ncorrelation_um = 0.5'
    refused(tmp_path, "[surface] size_um = [6.0, 4.0], cells = [60, 40]", "only accepted as the global surface of a "
            "[steering] study", surface=rect, material='name = "silver"',
            illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0]]")
    np.savetxt(tmp_path / "zvals.txt", np.zeros((61, 41)), delimiter=",")
    refused(tmp_path, "[surface] file", "zvals.txt", "holds 61x41 heights", "[steering]",
            surface='file = "zvals.txt"\nsize_um = [6.0, 4.0]', material='name = "silver"',
            illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0]]")
    # a non-square file with a single size: the x side alone cannot say L_y
    refused(tmp_path, "[surface]", "must be square", "61x41", "size_um = [L_x, L_y]",
            surface='file = "zvals.txt"\nsize_um = 6.0',
            material='name = "silver"', illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0]]",
            extra='[steering]\npatches = "auto"\npatch_size_um = 2.0')
    # square pairs are plain square surfaces, accepted anywhere
    square = study(tmp_path, surface=rect.replace("[6.0, 4.0]", "[4.0, 4.0]").replace("[60, 40]", "[40, 40]"),
                   material='name = "silver"', illumination="wavelengths_um = [0.5]\ndirections_deg = [[0, 0]]")
    assert square.cases[0].surface.build().z.shape == (41, 41)


# --- the reference's sub-area workflow ---------------------------------------------------------

def test_reference_subareas_config_loads_and_plans():
    """configs/reference_subareas.toml: 32 µm global surface at d = 0.025 µm (1281² heights), 9 × 9
    patches of 12 µm (481²) shifted by 2.5 µm, 25 aluminium wavelengths from its wvl.txt, 5
    directions from its wi.txt in one basic direction: 2025 patch tasks + 125 syntheses."""
    cfg = load_config(ROOT / "configs" / "reference_subareas.toml")
    case = cfg.cases[0]
    lams = np.round(0.4 + 0.012 * np.arange(25), 12)
    assert np.allclose(case.illumination.wavelengths_um, lams, rtol=0, atol=1e-12)
    assert case.material.file.name == "aluminium_wvl.txt"
    assert case.model.name == "bem" and case.model.options.method == "aim"
    plan = plan_study(cfg)
    # the reference simulator's own aluminium rows (its wvl.txt), at every wavelength
    table = np.loadtxt(ROOT / "solver" / "data" / "aluminium_bemsim.csv", delimiter=",", comments="#")
    assert np.array_equal(plan.index(0), table[:, 1] - 1j * table[:, 2])
    surface = plan.surface(0)
    assert surface.z.shape == (1281, 1281) and surface.spacing_um == pytest.approx(0.025)
    st = plan.steering[0]
    assert st.layout.counts == (9, 9) and len(st.basics_rad) == 1 and np.allclose(st.basics_rad[0], 0.0)
    kinds = [t.kind for t in plan.tasks]
    assert kinds.count("patch") == 25 * 81 and kinds.count("synth") == 25 * 5
    first = plan.scene(next(t for t in plan.tasks if t.kind == "patch"))
    assert first.surface.z.shape == (481, 481) and first.waist_um == 2.5 and first.beam == "exact"
    assert np.array_equal(first.surface.z, surface.z[:481, :481])


def test_docs_worked_example_loads(tmp_path):
    """docs/from_reference.md's example config, with a folder data/brushedRough/ of the reference's
    three files (flat heights: only the reading is tested), loads as its flags say."""
    text = (ROOT / "docs" / "from_reference.md").read_text()
    example = text.split("```toml\n", 1)[1].split("```", 1)[0]
    folder = tmp_path / "data" / "brushedRough"
    folder.mkdir(parents=True)
    np.savetxt(folder / "zvals.txt", np.zeros((961, 961)), delimiter=",", fmt="%g")
    table = np.loadtxt(ROOT / "configs" / "data" / "aluminium_wvl.txt", delimiter=",")
    (folder / "wvl.txt").write_text((ROOT / "configs" / "data" / "aluminium_wvl.txt").read_text())
    wi = [(0.0, 0.0), (math.radians(18), 0.0), (math.radians(36), math.radians(90)),
          (math.radians(54), math.radians(180)), (math.radians(72), math.radians(270))]
    (folder / "wi.txt").write_text("".join(f"{t!r},{p!r}\n" for t, p in wi))
    cfg_path = tmp_path / "brushedRough.toml"
    cfg_path.write_text(example.replace('output = "out/brushedRough.h5"', f'output = "{tmp_path / "b.h5"}"'))
    case = load_config(cfg_path).cases[0]
    assert case.illumination.wavelengths_um == tuple(table[:, 0])  # every row: no -c
    assert np.allclose(case.illumination.directions_deg, [(0, 0), (18, 0), (36, 90), (54, 180), (72, 270)])
    assert case.illumination.waist_um == 5.5 and case.output_options.resolution == 1024
    assert case.material.exterior_index == 1.0 and case.surface.size_um == 24.0
    assert case.surface.build().spacing_um == pytest.approx(0.025)
