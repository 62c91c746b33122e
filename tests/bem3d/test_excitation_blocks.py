"""The excitation and the surface power over blocks of elements equal the whole-patch sums."""

from __future__ import annotations

import numpy as np

from wavebrdf.solver.beams import make_beam
from wavebrdf.solver.bem3d import excitation
from wavebrdf.solver.bem3d.excitation import (SurfaceRule, beam_right_hand_side, power_into_material,
                                              right_hand_side, surface_currents)
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.farfield import ETA0
from wavebrdf.solver.surface import generate


def test_blocks_give_the_whole_patch_sums(monkeypatch, rng):
    mesh = BEMMesh(generate("gaussian", cells=13, size_um=1.3, seed=4, rms_height_um=0.05, correlation_um=0.3))
    beam = make_beam("exact", 0.5, 0.3, 0.2, 0.4, patch_size_um=1.3)
    rule = SurfaceRule.build(mesh, 3)
    whole = right_hand_side(mesh, beam.fields(rule.r), rule)
    x = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
    j, m = surface_currents(mesh, x, rule)
    normal = np.cross(rule.ru, rule.rv)
    integrand = np.einsum("eqc,...eqc->...eq", normal, np.cross(m, np.conj(j))) / np.linalg.norm(normal, axis=-1) ** 2
    power = 0.5 * ETA0 * np.real(np.einsum("...eq,q->...", integrand, rule.weights))
    monkeypatch.setattr(excitation, "ELEMENT_BLOCK", 7)  # 169 elements: 25 blocks, the last one short
    monkeypatch.setattr(excitation.element_blocks, "__defaults__", (7,))
    assert sum(1 for _ in excitation.element_blocks(mesh)) == 25
    np.testing.assert_allclose(beam_right_hand_side(mesh, beam, 3), whole, rtol=1e-12, atol=1e-12 * np.abs(whole).max())
    np.testing.assert_allclose(power_into_material(mesh, x, 3), power, rtol=1e-12)
