"""Jones and Mueller matrices of a coherent far field, in stated s/p frames.

Frames (docs/dataset.md, "Polarization"): every direction d pointing away from the surface (ω_i
toward the light, ω_o toward the viewer) has ŝ(d) = φ̂(d) = (−sin φ, cos φ, 0), perpendicular to
its plane of incidence/exitance (φ = 0 at the pole), and a wave travelling along k̂ has
p̂ = k̂ × ŝ, so (ŝ, p̂, k̂) is right-handed: incident k̂ = −ω_i gives p̂_i = θ̂(ω_i), outgoing
k̂ = ω_o gives p̂_o = −θ̂(ω_o). These are Mitsuba 3's Stokes frames (x axis ŝ, y = k̂ × x), up to
the sign of ŝ, which leaves Stokes vectors unchanged.

Jones matrix J[b, a] (b out, a in, each s|p): the far-field amplitude along b̂_o for a unit
incident field along â_i, normalised so that Σ_b |J[b, a]|² is the BRDF (1/sr) of incident
polarization a: J = (E·b̂_o)·√(n₁ / (2η₀ Φ_a μ_o)) with Φ_a the model's incident power.

Stokes vectors S = (|E_s|² + |E_p|², |E_s|² − |E_p|², 2 Re(E_s E_p*), −2 Im(E_s E_p*)) (e^{+jωt},
the convention of Mitsuba's ``mueller::specular_reflection`` with its n − iκ Fresnel amplitudes),
so M = A (J ⊗ J*) A⁻¹ and M[0, 0] is the unpolarized BRDF. A flat interface gives
J = −diag(r_s, r_p) with r_p in Born & Wolf's (Verdet's) sign convention (r_s = −r_p at normal
incidence); the sign is that of ŝ_o = −ŝ_i at the mirror direction and drops out of M.

Reciprocity (a reciprocal surface): the Jones matrix of the reversed path (light from ω_o,
seen from ω_i) in these frames is D Jᵀ D, D = diag(1, −1), so M_reversed = R Mᵀ R with
R = diag(1, 1, −1, 1) (:func:`reversed_path`; Mᵀ with V negated is the Mueller matrix
of Jᵀ, and D negates U and V).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from wavebrdf.solver.farfield import ETA0, FarField, direction, transverse_basis

__all__ = [
    "POLARIMETRY",
    "STOKES",
    "degree_of_polarization",
    "depolarization_index",
    "in_stated_frame",
    "incident_frame",
    "jones",
    "mueller",
    "outgoing_frames",
    "regular_axis",
    "reversed_path",
    "steered_frame_change",
    "stokes_rotation",
    "to_regular_frames",
]

STOKES = ("I", "Q", "U", "V")
POLARIMETRY = ("intensity", "jones", "mueller")  # what a surface dataset stores per pixel ([output] polarization)

# S = A e with the coherency vector e = (E_s E_s*, E_s E_p*, E_p E_s*, E_p E_p*)
_A = np.array([[1, 0, 0, 1], [1, 0, 0, -1], [0, 1, 1, 0], [0, 1j, -1j, 0]], dtype=complex)
_A_INV = np.linalg.inv(_A)


def incident_frame(theta_i: float, phi_i: float) -> tuple[np.ndarray, np.ndarray]:
    """(ŝ_i, p̂_i) of the incident wave (radians; θ_i, φ_i toward the light, k̂ = −ω_i).

    The models' s and p excitations are E ∥ ŝ_i and E ∥ −p̂_i (solver/footprint.py
    ``incident_basis``, the beams' x_b): :func:`jones` takes care of that sign."""
    st, ct, sp, cp = np.sin(theta_i), np.cos(theta_i), np.sin(phi_i), np.cos(phi_i)
    return np.array([-sp, cp, 0.0]), np.array([ct * cp, ct * sp, -st])


def outgoing_frames(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ŝ_o, p̂_o) of the directions with projected coordinates (u, v), shape (..., 3) each."""
    theta_hat, phi_hat = transverse_basis(u, v)
    return phi_hat, -theta_hat


_EXCITATION_SIGN = np.array([1.0, -1.0])  # the models' s and p excitations are ŝ_i and −p̂_i


def jones(field: FarField) -> np.ndarray:
    """J[b, a, i, j] (complex, √(1/sr)) of a FarField on its grid; 0 outside the unit disk."""
    grid = field.grid
    U, V = grid.uv
    s_out, p_out = outgoing_frames(U, V)
    mu = grid.mu
    inside = grid.inside
    scale = np.zeros((2,) + mu.shape)
    for a in range(2):
        scale[a][inside] = np.sqrt(field.exterior_index / (2.0 * ETA0 * field.incident_power[a] * mu[inside]))
    E = field.E * _EXCITATION_SIGN[:, None, None, None]  # (a, xyz, i, j)
    out = np.empty((2, 2) + mu.shape, dtype=complex)
    for b, basis in enumerate((s_out, p_out)):
        out[b] = np.einsum("axij,ijx->aij", E, basis) * scale
    return out


def steered_frame_change(excited_rad: tuple[float, float], stated_rad: tuple[float, float],
                         beam: bool) -> np.ndarray:
    """T[a, a'] (2×2, real, s|p of :func:`incident_frame`): the response per unit incident power
    to the stated direction's polarization a' is Σ_a T[a, a'] times the response to the excited
    direction's a (θ, φ in radians toward the light; a steered synthesis excites its patches with
    the basic direction's polarizations).

    ``beam`` True: exact beams (transverse plane waves: bem, po lit by the beam). The plane wave
    along ω_i in the summed beams carries â_exc projected on the plane normal to ω_i, with stated
    components P[a, a'] = â_exc · â'_i; the synthesis normalizes by that wave's power, so the
    responses are J V̂ᵀ (V̂: P with unit rows) and T = (V̂ᵀ)⁻¹.
    ``beam`` False: locally plane footprints keep â_exc, and their rungs answer in the excited
    frame (Fresnel factors included): T is that frame carried to ω_i by the rotation about
    ω_exc × ω_i that turns ω_exc into ω_i, dotted with the stated frame (orthogonal, so Σ|J|² and
    M[0, 0] are kept)."""
    excited = np.array(incident_frame(*excited_rad))
    stated = np.array(incident_frame(*stated_rad))
    if beam:
        projected = excited @ stated.T
        lengths = np.linalg.norm(projected, axis=1, keepdims=True)
        if np.min(lengths) < 1e-6:
            raise ValueError(f"steered_frame_change: a polarization of {excited_rad} (rad) has no component "
                             f"normal to {stated_rad}")
        return np.linalg.inv((projected / lengths).T)
    w_exc, w_i = direction(*excited_rad), direction(*stated_rad)
    axis, cos = np.cross(w_exc, w_i), float(np.dot(w_exc, w_i))
    if cos <= -1.0 + 1e-12:
        raise ValueError(f"steered_frame_change: directions {excited_rad} and {stated_rad} (rad) are opposite")
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    rotation = np.eye(3) + cross + cross @ cross / (1.0 + cos)  # Rodrigues: R ω_exc = ω_i
    return (excited @ rotation.T) @ stated.T


def in_stated_frame(field: FarField, excited_rad: tuple[float, float], beam: bool) -> FarField:
    """``field`` (excited with the polarizations of ``excited_rad``, radians) as the response to
    its own direction's s and p (:func:`steered_frame_change`), with the mean incident power of
    the two excitations for both."""
    T = _EXCITATION_SIGN[:, None] * steered_frame_change(excited_rad, (field.theta_i, field.phi_i), beam) \
        * _EXCITATION_SIGN[None, :]  # in the models' excitations ŝ, −p̂
    power = np.asarray(field.incident_power, dtype=float)
    weights = T * np.sqrt(np.mean(power) / power)[:, None]

    def changed(X):
        return None if X is None else np.einsum("a...,ab->b...", X, weights)

    return dataclasses.replace(field, E=changed(field.E), H=changed(field.H),
                               incident_power=np.full(2, np.mean(power)), diagnostics=dict(field.diagnostics))


def mueller(J: np.ndarray) -> np.ndarray:
    """M[m, n, ...] (real, 1/sr) of Jones matrices J[b, a, ...]; averages of M over pixels,
    realizations or wavelengths are the incoherent averages."""
    J = np.asarray(J)
    kron = np.einsum("bc...,de...->bdce...", J, np.conj(J)).reshape((4, 4) + J.shape[2:])
    M = np.einsum("mk,kl...,ln->mn...", _A, kron, _A_INV)
    return np.real(M)


def regular_axis(d: np.ndarray) -> np.ndarray:
    """A first Stokes axis for direction d (..., 3) that varies smoothly over the whole upper
    hemisphere (Ludwig's third definition: x̂ carried to d, singular only at −ẑ):
    (1 − u²/(1 + w), −uv/(1 + w), −u), ⟂ d; x̂ at the pole. Frames built on it (second axis k̂ × x)
    suit interpolation across the pole, where the s/p frames turn with φ."""
    d = np.asarray(d, dtype=float)
    u, v, w = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([1.0 - u * u / (1.0 + w), -u * v / (1.0 + w), -u], axis=-1)


def stokes_rotation(two_chi: np.ndarray) -> np.ndarray:
    """(4, 4, ...) Mueller matrix taking Stokes vectors to a basis turned by χ (new first axis
    cos χ x + sin χ y): Q' = cos 2χ Q + sin 2χ U, U' = −sin 2χ Q + cos 2χ U."""
    two_chi = np.asarray(two_chi, dtype=float)
    c, s = np.cos(two_chi), np.sin(two_chi)
    one, zero = np.ones_like(c), np.zeros_like(c)
    return np.array([[one, zero, zero, zero], [zero, c, s, zero], [zero, -s, c, zero], [zero, zero, zero, one]])


def to_regular_frames(M: np.ndarray, u: np.ndarray, v: np.ndarray, phi_i: float,
                      reference_phi: float = 0.0) -> np.ndarray:
    """M (4, 4, ..., res, res) from the s/p frames to frames whose first axes are
    :func:`regular_axis` of ω_i (incident, azimuth ``phi_i``) and of each ω_o = (u, v) (the pixel
    grid, (res, res) each), taken in the frame turned by ``reference_phi`` about z (radians). In the
    s/p frames (x = φ̂, second axis k̂ × x) the regular axis is turned by 2χ = π + 2(φ_i − φ_ref)
    (incident, k̂ = −ω_i) and π − 2(φ_o − φ_ref) (outgoing); so the frames of two references a and
    b differ by the same turn everywhere: M_b = S(2(b − a)) M_a S(2(b − a)), S = :func:`stokes_rotation`.
    With φ_ref = φ_i they turn with the incidence, as the s/p frames do, and stay smooth at ω_o's pole."""
    phi_o = np.where(np.hypot(u, v) > 0, np.arctan2(v, u), 0.0)
    out = stokes_rotation(np.pi - 2.0 * (phi_o - reference_phi))
    back = stokes_rotation(-(np.pi + 2.0 * (phi_i - reference_phi)))
    return np.einsum("mk...ij,kl...ij,ln->mn...ij", out, M, back)


def reversed_path(M: np.ndarray) -> np.ndarray:
    """The Mueller matrix of the reversed path of a reciprocal surface: R Mᵀ R, R = diag(1, 1, −1, 1)
    (module docstring)."""
    M = np.asarray(M)
    R = np.array([1.0, 1.0, -1.0, 1.0]).reshape((4,) + (1,) * (M.ndim - 2))
    return R[:, None] * np.swapaxes(M, 0, 1) * R[None, :]


def degree_of_polarization(M: np.ndarray) -> np.ndarray:
    """Degree of polarization of the light scattered from unpolarized incidence: |M[1:, 0]| / M[0, 0]."""
    M = np.asarray(M)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.sum(M[1:, 0] ** 2, axis=0)) / M[0, 0]


def depolarization_index(M: np.ndarray) -> np.ndarray:
    """Gil–Bernabeu depolarization index √(Σ M² − M₀₀²)/(√3 M₀₀): 1 for a pure (non-depolarizing)
    Mueller matrix, 0 for an ideal depolarizer."""
    M = np.asarray(M)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.clip(np.sum(M**2, axis=(0, 1)) - M[0, 0] ** 2, 0.0, None)) / (np.sqrt(3.0) * M[0, 0])
