"""The AIM solver through the product: ``[model] name = "bem", method = "aim"`` in a config.

Reference: the same study with ``method = "dense"`` (the LU ground truth of issue 3), run through
the same planner, scheduler and HDF5 writer. A solve that misses its tolerance must be recorded
as a failed task (never written as a result) and make the run exit non-zero.
"""

from __future__ import annotations

import textwrap

import h5py
import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import ConfigError, load_config
from wavebrdf.jobs.plan import plan_study

STUDY = """
[study]
name = "{name}"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 1.6
cells = 16
rms_height_um = 0.03
correlation_um = 0.4
seed = 2

[material]
n = 1.5

[illumination]
wavelengths_um = [0.5]
directions_deg = [[0, 0], [25, 30]]
waist_um = 0.32

[model]
name = "bem"
method = "{method}"
{aim}

[output]
resolution = 64
"""


def write(tmp_path, name, method, aim=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(textwrap.dedent(STUDY.format(name=name, out=tmp_path / f"{name}.h5", method=method, aim=aim)))
    return path


@pytest.mark.parametrize("aim_table", ["", "[model.aim]\nfit_speed = false\n"],
                         ids=["planner_choice", "near_lu_as_given"])
def test_aim_study_matches_the_dense_study(tmp_path, aim_table):
    """Through the config, with the settings the planner picks (the flat patch here) and with the
    defaults kept as given (the near LU)."""
    results = {}
    for method in ("dense", "aim"):
        cfg = write(tmp_path, method, method, aim_table if method == "aim" else "")
        if method == "aim":
            plan = plan_study(load_config(cfg))
            chosen = plan.model_spec(plan.tasks[0]).build().aim_options(plan.scene(plan.tasks[0]))
            assert chosen.preconditioner == ("near" if aim_table else "flat-patch")
        assert main(["run", str(cfg), "-q", "--no-render"]) == 0
        with h5py.File(tmp_path / f"{method}.h5", "r") as h5:
            results[method] = (np.nan_to_num(h5["brdf"][()].astype(float)), h5["albedo"][()])  # NaN: u²+v² > 1
            if method == "aim":
                assert set(h5["tasks/status"][()].astype(str)) == {"done"}
                assert "gmres" in set(h5["tasks/krylov_method"][()].astype(str))
    (dense, dense_albedo), (aim, aim_albedo) = results["dense"], results["aim"]
    lobe = dense > 1e-3 * dense.max()
    rel_l2 = np.linalg.norm((aim - dense)[lobe]) / np.linalg.norm(dense[lobe])
    print(f"AIM vs dense through the config: BRDF rel L2 {rel_l2:.2e}, albedo {aim_albedo} vs {dense_albedo}")
    assert rel_l2 < 0.01
    assert np.allclose(aim_albedo, dense_albedo, rtol=0.01)


def test_unconverged_aim_solve_is_a_failed_task(tmp_path):
    aim = "[model.aim]\nmax_iterations = 3\npreconditioner = \"none\"\nfit_speed = false\n[run]\nretries = 0\n"
    assert main(["run", str(write(tmp_path, "stuck", "aim", aim)), "-q", "--no-render"]) == 1
    with h5py.File(tmp_path / "stuck.h5", "r") as h5:
        status = h5["tasks/status"][()].astype(str)
        assert set(status) == {"failed"}
        assert "KrylovNotConverged" in h5["tasks/error"][0].decode()
        assert np.all(np.isnan(h5["brdf"][()]))


@pytest.mark.parametrize("aim, message", [
    ("[model.aim]\nnear_cell = 4\n", "near_cell"),
    ("[model.aim]\nsolver = \"cg\"\n", r'\[model.aim\] solver = "cg": must be one of "gmres", "csym", "bicgstab"'),
    ("aim = 3\n", "must be a table"),
])
def test_bad_aim_options_name_the_key(tmp_path, aim, message):
    with pytest.raises(ConfigError, match=message):
        load_config(write(tmp_path, "bad", "aim", aim))


def test_aim_options_need_the_aim_method(tmp_path):
    with pytest.raises(ConfigError, match="method = \"aim\""):
        load_config(write(tmp_path, "bad", "dense", "[model.aim]\nnear_cells = 4\n"))


def test_plan_estimates_an_aim_study(tmp_path, capsys):
    assert main(["plan", str(write(tmp_path, "plan", "aim"))]) == 0
    assert "aim 960 unknowns" in capsys.readouterr().out
