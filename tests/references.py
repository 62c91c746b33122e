"""Independent reference formulas for the tests, written from the textbooks.

Nothing here imports wavebrdf: a test that compares a model with these formulas compares it with
something the model's own code did not produce. Conventions are those of ARCHITECTURE.md: time
dependence e^{+jωt}, complex index n − jκ with κ ≥ 0 meaning loss, angles in radians.

Sources: Born & Wolf, *Principles of Optics* (7th ed.), §1.5.2 (Fresnel formulas) and §14.2
(absorbing media: Snell's law with a complex index, the transmitted wave must decay);
Hecht, *Optics*, §4.6 (reflectances, Brewster angle, total internal reflection); Bohren &
Huffman, *Absorption and Scattering of Light by Small Particles*, §8.4 (the infinite cylinder
and its small-size limit); Novotny & Hecht, *Principles of Nano-Optics*, §3.2 (the angular
spectrum representation of a beam); treams (an independent T-matrix code, run by the caller);
Beckmann & Spizzichino, *The Scattering of Electromagnetic Waves from Rough Surfaces*, §5.3
(the diffuse lobe of Gaussian-correlated heights as a Poisson series of Gaussians).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ALUMINIUM_400NM",
    "beam_fresnel_reflectance",
    "beckmann_geometric_l2",
    "brewster_angle",
    "coulomb_squares",
    "cylinder_rayleigh_widths",
    "cylinder_widths_treams",
    "fresnel_coefficients",
    "fresnel_mueller",
    "fresnel_reflectance",
    "fresnel_transmittance",
    "gaussian_beam_power_ratio",
    "normal_reflectance",
    "reflected_spectrum_brdf",
    "transmitted_normal_wavenumber",
]

ALUMINIUM_400NM = 0.46582 - 4.7119j  # aluminium at 0.4 µm (the reference simulator's examples)
VACUUM_IMPEDANCE = 376.730313668  # Ω (CODATA 2018, µ₀c)


def beckmann_geometric_l2(g: float, radii: int = 40001) -> float:
    """Relative L2 over the plane of the diffuse Kirchhoff lobe of Gaussian-correlated heights
    against its geometric-optics limit, by radial quadrature. Beckmann's series in v = k(ω_o − ω_i)T:
    Σ_{m≥1} e^{−g} g^m/m! · exp(−|v|²/4m)/m (g = (2kσ cos θ_i)², the m = 0 term is the coherent
    lobe); the limit puts all the power into the m = g Gaussian, exp(−|v|²/4g)/g."""
    from scipy.stats import poisson

    m = np.arange(1, int(g + 15 * np.sqrt(g) + 30))
    r = np.linspace(0.0, 12.0 * np.sqrt(2.0 * (g + 15 * np.sqrt(g) + 30)), radii)
    series = sum(w / n * np.exp(-r**2 / (4 * n)) for w, n in zip(poisson.pmf(m, g), m))
    limit = np.exp(-r**2 / (4 * g)) / g
    return float(np.sqrt(np.trapezoid((series - limit) ** 2 * r, r) / np.trapezoid(series**2 * r, r)))


def transmitted_normal_wavenumber(n1: float, n2: complex, sin_i) -> np.ndarray:
    """q = n₂ cos θ_t = √(n₂² − n₁² sin²θ_i) on the physical branch (in units of k₀).

    Below the interface (z < 0) the transmitted wave varies as e^{+j k₀ q z} (e^{+jωt}, wave
    e^{−j k·r} travelling toward −z), so it decays into medium 2 iff Im q < 0, and carries power
    away from the interface iff Re q > 0. The branch is therefore Im q ≤ 0 and, where Im q = 0
    (a lossless medium without total reflection), Re q ≥ 0. This one rule covers metals
    (Re n₂² < 0), weak absorbers and total internal reflection (q = −j|q|).
    """
    sin_i = np.asarray(sin_i, dtype=float)
    q = np.sqrt(np.asarray(n2, dtype=complex) ** 2 - (n1 * sin_i) ** 2 + 0j)
    flip = (q.imag > 0) | ((q.imag == 0) & (q.real < 0))
    return np.where(flip, -q, q)


def fresnel_coefficients(n1: float, n2: complex, theta_i) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude reflection coefficients (r_s, r_p) from medium n₁ (real) onto n₂ = n − jκ.

    r_s = (n₁ cos θ_i − n₂ cos θ_t) / (n₁ cos θ_i + n₂ cos θ_t)                 (E ⟂ plane)
    r_p = (n₂ cos θ_i − n₁ cos θ_t) / (n₂ cos θ_i + n₁ cos θ_t)                 (E ∥ plane)

    (Born & Wolf's sign convention for r_p; only |r|² is used by the tests.) With
    q = n₂ cos θ_t the p coefficient is written (n₂² cos θ_i − n₁ q)/(n₂² cos θ_i + n₁ q), which
    needs no division by n₂.
    """
    if n1 <= 0 or np.imag(n1) != 0:
        raise ValueError(f"the incident medium must be real and positive, got {n1!r}")
    n2 = complex(n2)
    if n2.imag > 0:
        raise ValueError(f"n2 = n - j*kappa needs kappa >= 0 (loss), got {n2!r}")
    theta_i = np.asarray(theta_i, dtype=float)
    c = np.cos(theta_i)
    q = transmitted_normal_wavenumber(n1, n2, np.sin(theta_i))
    r_s = (n1 * c - q) / (n1 * c + q)
    r_p = (n2 * n2 * c - n1 * q) / (n2 * n2 * c + n1 * q)
    return r_s, r_p


def fresnel_mueller(r_s, r_p) -> np.ndarray:
    """Mueller matrix (4, 4, ...) of specular reflection with amplitude coefficients r_s, r_p
    (Collett, *Polarized Light*, §8.2, with the Stokes parameters I = |E_s|² + |E_p|²,
    Q = |E_s|² − |E_p|², U = 2 Re(E_s E_p*), V = −2 Im(E_s E_p*) of an e^{+jωt} field, in frames
    whose first axis is ŝ and second k̂ × ŝ for both waves):

        ½ [[R_s + R_p, R_s − R_p, 0, 0], [R_s − R_p, R_s + R_p, 0, 0],
           [0, 0, 2 Re(r_s r_p*), 2 Im(r_s r_p*)], [0, 0, −2 Im(r_s r_p*), 2 Re(r_s r_p*)]]
    """
    r_s, r_p = np.asarray(r_s, dtype=complex), np.asarray(r_p, dtype=complex)
    R_s, R_p, c = np.abs(r_s) ** 2, np.abs(r_p) ** 2, r_s * np.conj(r_p)
    zero = np.zeros_like(R_s)
    return 0.5 * np.array([[R_s + R_p, R_s - R_p, zero, zero], [R_s - R_p, R_s + R_p, zero, zero],
                           [zero, zero, 2 * c.real, 2 * c.imag], [zero, zero, -2 * c.imag, 2 * c.real]])


def fresnel_reflectance(n1: float, n2: complex, theta_i) -> tuple[np.ndarray, np.ndarray]:
    """Power reflectances (|r_s|², |r_p|²); their mean is the unpolarized reflectance."""
    r_s, r_p = fresnel_coefficients(n1, n2, theta_i)
    return np.abs(r_s) ** 2, np.abs(r_p) ** 2


def fresnel_transmittance(n1: float, n2: float, theta_i) -> tuple[np.ndarray, np.ndarray]:
    """Power transmittances (T_s, T_p) into a *lossless* medium n₂ (real), from the transmission
    coefficients t_s = 2n₁cos θ_i/(n₁cos θ_i + n₂cos θ_t), t_p = 2n₁cos θ_i/(n₂cos θ_i + n₁cos θ_t)
    and the flux ratio Re(n₂ cos θ_t)/(n₁ cos θ_i) (Born & Wolf §1.5.3). Zero beyond the critical
    angle. Used to check R + T = 1, an identity the reflectances alone do not contain."""
    if np.imag(n2) != 0:
        raise ValueError("fresnel_transmittance is for a lossless second medium")
    n2 = float(np.real(n2))
    theta_i = np.asarray(theta_i, dtype=float)
    c = np.cos(theta_i)
    q = transmitted_normal_wavenumber(n1, n2, np.sin(theta_i))
    cos_t = q / n2
    t_s = 2 * n1 * c / (n1 * c + q)
    t_p = 2 * n1 * c / (n2 * c + n1 * cos_t)
    flux = np.real(q) / (n1 * c)
    return flux * np.abs(t_s) ** 2, flux * np.abs(t_p) ** 2


def normal_reflectance(n1: float, n2: complex) -> float:
    """|(n₁ − n₂)/(n₁ + n₂)|², the reflectance at normal incidence (both polarizations)."""
    return float(abs((n1 - n2) / (n1 + n2)) ** 2)


def brewster_angle(n1: float, n2: float) -> float:
    """tan θ_B = n₂/n₁ (real indices): the angle where r_p vanishes."""
    return float(np.arctan2(n2, n1))


def beam_fresnel_reflectance(kvec: np.ndarray, E: np.ndarray, n1: float, n2: complex) -> np.ndarray:
    """Reflectance (s, p) of a beam given as a sum of propagating plane waves on the flat interface
    z = 0 between n₁ (above) and n₂ (below): Σ_m |k_z,m| (|E_m·ŝ_m|² R_s(θ_m) + |E_m·p̂_m|² R_p(θ_m))
    / Σ_m |k_z,m| |E_m|².

    kvec: (M, 3) wave vectors (k_z < 0, travelling down); E: (2, M, 3) amplitudes of the beam's
    two polarizations. Each plane wave is reflected with the Fresnel coefficients of its own angle
    θ_m (cos θ_m = |k_z|/|k|), ŝ = ẑ × k̂ normalised (any transverse pair at normal incidence,
    where R_s = R_p), p̂ = ŝ × k̂; the power a wave carries through a plane z = const is
    proportional to |E|²|k_z| (plane waves are orthogonal over the period cell of a lattice
    spectrum). The plane waves are the model's input, the Fresnel factors are this module's.
    """
    kvec = np.asarray(kvec, dtype=float)
    E = np.asarray(E, dtype=complex)
    k = np.linalg.norm(kvec, axis=1)
    khat = kvec / k[:, None]
    if np.any(khat[:, 2] >= 0):
        raise ValueError("beam_fresnel_reflectance: every plane wave must travel toward -z")
    s_hat = np.cross([0.0, 0.0, 1.0], khat)
    norm = np.linalg.norm(s_hat, axis=1)
    s_hat = np.where(norm[:, None] > 1e-12, s_hat / np.where(norm > 0, norm, 1.0)[:, None], [0.0, 1.0, 0.0])
    p_hat = np.cross(s_hat, khat)
    weight = np.abs(khat[:, 2])
    R_s, R_p = fresnel_reflectance(n1, n2, np.arccos(np.clip(weight, 0.0, 1.0)))
    e_s = np.abs(np.einsum("pmc,mc->pm", E, s_hat)) ** 2
    e_p = np.abs(np.einsum("pmc,mc->pm", E, p_hat)) ** 2
    reflected = np.sum(weight * (e_s * R_s + e_p * R_p), axis=1)
    incident = np.sum(weight * np.sum(np.abs(E) ** 2, axis=2), axis=1)
    return reflected / incident


def gaussian_beam_power_ratio(wavelength_um: float, waist_um: float, theta_i: float, n1: float = 1.0,
                              samples: int = 1601) -> float:
    """P_p / P_s of the angular-spectrum Gaussian beam of waist w toward θ_i (in the plane φ = 0).

    The beam (Novotny & Hecht §3.2): a vector potential A = U ŷ_b (s) or U x̂_b (p), x̂_b in the
    plane of incidence and ŷ_b normal to it, both ⟂ the central direction; U a superposition of
    the propagating plane waves k = (κ, −k_z) with amplitudes ∝ exp(−w²|κ − κ_c|²/4), κ_c = −k sinθ_i x̂
    (the beam travels along −ω_i).
    A plane wave of potential Â carries E ∝ k²Â − k(k·Â), so |E|² ∝ 1 − (k̂·â)², and its flux
    through the plane z = const ∝ |E|² |k̂_z|. Both polarizations share U and so their central
    amplitude; their powers differ where the spectrum is wide against cos θ_i (toward grazing):
    a BRDF normalized per polarization by the beam's power sees r_p/r_s scaled by √(P_s/P_p).
    Midpoint sums over ±8/w about κ_c, clipped to the propagating disk (:func:`gaussian_beam_powers`).
    """
    power = gaussian_beam_powers(wavelength_um, waist_um, theta_i, n1, samples)
    return float(power[1] / power[0])


def gaussian_beam_powers(wavelength_um: float, waist_um: float, theta_i: float, n1: float = 1.0,
                         samples: int = 4001) -> np.ndarray:
    """(P_s, P_p) of the angular-spectrum Gaussian beam of :func:`gaussian_beam_power_ratio`,
    normalised like wavebrdf's beams (the x_b component of the p field at the focus is 1 V/µm):
    with a(κ) = exp(−w²|κ − κ_c|²/4), a plane wave of potential â carries |E|² ∝ k⁴(1 − (k̂·â)²)
    and E·x̂_b ∝ k²(1 − (k̂·x̂_b)²) for â = x̂_b, so

        P_a = (2π)² ∫ a² (1 − (k̂·â)²) k_z d²κ / (2 η₀ k₀ |∫ a (1 − (k̂·x̂_b)²) d²κ|²)

    (the flux of a plane wave through z = const is |E|² k_z / (2 η₀ k₀); the field's common
    factors cancel). Midpoint sums over ±8/w
    about κ_c, clipped to the propagating disk (the flux integrand vanishes at the cut, the
    amplitude's does not: ~5e-4 relative at 80° for a waist of 6λ)."""
    eta0 = 376.730313412
    k0 = 2 * np.pi / wavelength_um
    k = k0 * n1
    x_b = np.array([-np.cos(theta_i), 0.0, np.sin(theta_i)])
    y_b = np.array([0.0, 1.0, 0.0])
    half = 8.0 / waist_um
    step = 2 * half / samples
    axis = -half + step * (np.arange(samples) + 0.5)
    kx, ky = np.meshgrid(-k * np.sin(theta_i) + axis, axis, indexing="ij")
    kz2 = k**2 - kx**2 - ky**2
    inside = kz2 > 0
    kx, ky, kz = kx[inside], ky[inside], np.sqrt(kz2[inside])
    khat = np.stack([kx, ky, -kz], axis=-1) / k
    a = np.exp(-0.25 * waist_um**2 * ((kx + k * np.sin(theta_i)) ** 2 + ky**2))
    centre = np.sum(a * (1.0 - (khat @ x_b) ** 2)) * step**2
    powers = [(2 * np.pi) ** 2 * np.sum(a**2 * (1.0 - (khat @ v) ** 2) * kz) * step**2 / (2 * eta0 * k0)
              for v in (y_b, x_b)]
    return np.array(powers) / centre**2


def coulomb_squares(a: tuple, b: tuple) -> float:
    """∫_A ∫_B dA dA'/|r − r'| for coplanar axis-aligned rectangles A, B = ((x0, x1), (y0, y1)).

    Closed form: Σ ± F(x_i − x'_k, y_j − y'_l) with ∂²_X∂²_Y F = 1/√(X² + Y²),
    F = X²Y/2 asinh(Y/X) + XY²/2 asinh(X/Y) − r³/6 (even in X and Y).
    """

    def F(X, Y):
        X, Y = abs(X), abs(Y)
        r = np.hypot(X, Y)
        t1 = 0.5 * X * X * Y * np.arcsinh(Y / X) if X > 0 else 0.0
        t2 = 0.5 * X * Y * Y * np.arcsinh(X / Y) if Y > 0 else 0.0
        return t1 + t2 - r**3 / 6.0

    total = 0.0
    for i, xa in enumerate(a[0]):
        for k, xb in enumerate(b[0]):
            for j, ya in enumerate(a[1]):
                for m, yb in enumerate(b[1]):
                    sign = (-(-1) ** (i + k)) * (-(-1) ** (j + m))
                    total += sign * F(xa - xb, ya - yb)
    return total


def cylinder_rayleigh_widths(wavelength_um: float, radius_um: float, index: complex) -> tuple[np.ndarray, np.ndarray]:
    """(C_ext, C_sca) per unit length (µm), cases (I, II), of a thin cylinder (x = k a ≪ 1) at
    normal incidence: the leading terms of the series (Bohren & Huffman §8.4), b₀ ≈ −iπx²(ε−1)/4
    (case I, E ∥ axis) and a₁ ≈ −iπx²/4 (ε−1)/(ε+1) (case II), with ε = m² and the loss taken
    as −Im ε ≥ 0 for m = n − jκ:

        Q_sca,I = π²x³/8 |ε−1|²,        Q_sca,II = π²x³/4 |(ε−1)/(ε+1)|²,
        Q_abs,I = (πx/2)(−Im ε),         Q_abs,II = 2πx (−Im ε)/|ε+1|²,

    C = 2a Q, C_ext = C_sca + C_abs; relative error O(x²).
    """
    index = complex(index)
    if index.imag > 0:
        raise ValueError(f"index must be n - j*kappa with kappa >= 0, got {index!r}")
    x = 2 * np.pi * radius_um / wavelength_um
    eps = index * index
    loss = -eps.imag
    q_sca = np.array([np.pi**2 * x**3 / 8 * abs(eps - 1) ** 2, np.pi**2 * x**3 / 4 * abs((eps - 1) / (eps + 1)) ** 2])
    q_abs = np.array([0.5 * np.pi * x * loss, 2 * np.pi * x * loss / abs(eps + 1) ** 2])
    width = 2 * radius_um
    return width * (q_sca + q_abs), width * q_sca


def cylinder_widths_treams(wavelength_um: float, radius_um: float, index: complex, theta_i: float,
                           orders: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(C_ext, C_sca) per unit length (µm), cases (I, II), of an infinite circular cylinder from
    treams' T-matrix (e^{-iωt}: ε = conj(m)²), normalised like the fiber models (by S₀ cos θ_i:
    treams' widths divided by cos θ_i). Case I: E in the plane of the axis and k; case II: E ⟂ to
    it. ``theta_i`` (radians) from the plane normal to the axis; ``orders``: the T-matrix's
    largest |m| (default x + 4x^{1/3} + 10, Wiscombe's rule)."""
    import warnings

    import treams  # independent reference (dev dependency): a missing one fails, never skips

    k0 = 2 * np.pi / wavelength_um
    x = k0 * radius_um * max(1.0, abs(complex(index)))
    orders = orders or int(x + 4 * x ** (1 / 3) + 10)
    kz = k0 * np.sin(theta_i)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the plane wave stores its unit vector; the T-matrix's kz must equal k0·q_z bit for bit,
        # else treams' expansion finds no matching kz and returns 0 (e.g. at λ = 0.55 µm, θ_i = 30°)
        probe = treams.plane_wave([k0 * np.cos(theta_i), 0.0, kz], [0.0, 1.0, 0.0], k0=k0,
                                  material=treams.Material(), poltype="parity")
        tm = treams.TMatrixC.cylinder(k0 * float(probe.basis.qz[0]), orders, k0, radius_um,
                                      [treams.Material(np.conj(complex(index)) ** 2), treams.Material()])
        tm = tm.changepoltype("parity")
        widths = []
        for pol in ([-np.sin(theta_i), 0.0, np.cos(theta_i)], [0.0, 1.0, 0.0]):
            wave = treams.plane_wave([k0 * np.cos(theta_i), 0.0, kz], pol, k0=k0, material=treams.Material(),
                                     poltype="parity")
            widths.append(tm.xw(wave))
    sca, ext = np.array(widths, dtype=float).T / np.cos(theta_i)
    if not np.all(ext > 0):  # e.g. θ_i = 80°, 89°: treams' plane wave misses the T-matrix's k_z
        raise ValueError(f"treams gave no extinction at θ_i = {np.rad2deg(theta_i):g}° ({ext}): not a reference here")
    return ext, sca


def reflected_spectrum_brdf(E: np.ndarray, u: np.ndarray, v: np.ndarray, n2: complex, k: float,
                            power: np.ndarray) -> np.ndarray:
    """BRDF (2, n) of a beam of angular spectrum E reflected by the flat interface z = 0 from vacuum
    onto n₂, each plane wave in its own plane of incidence (Novotny & Hecht §3.2, Born & Wolf
    §1.5.2): at ω_o = (u, v, μ) the far field of the reflected spectrum is |E| = 2πk μ |Ê_r(κ)| at
    κ = k(u, v) (stationary phase), Ê_r = r_s (Ê·ŝ) ŝ + r_p (Ê·p̂) p̂_r with ŝ = ẑ × k̂ normalised
    and θ the wave's angle, so f = |E|²/(2 η₀ Φ_i μ) = (2πk)² μ (|r_s Ê·ŝ|² + |r_p Ê·p̂|²)/(2 η₀ Φ_i).

    E: (2 pol, n, 3) incident spectral densities (per unit κ area) at those κ, travelling down;
    u, v: (n,) direction cosines (u² + v² < 1); power: (2,) Φ_i per polarization (W)."""
    mu = np.sqrt(1.0 - u * u - v * v)
    k_in = np.stack([u, v, -mu], axis=-1)
    s_hat = np.cross([0.0, 0.0, 1.0], k_in)
    norm = np.linalg.norm(s_hat, axis=1)
    s_hat = np.where(norm[:, None] > 1e-12, s_hat / np.where(norm > 0, norm, 1.0)[:, None], [0.0, 1.0, 0.0])  # any at 0°
    p_hat = np.cross(s_hat, k_in)
    r_s, r_p = fresnel_coefficients(1.0, n2, np.arccos(mu))
    out = np.empty((2, len(u)))
    for pol in range(2):
        reflected = (np.abs(r_s * np.einsum("nc,nc->n", E[pol], s_hat)) ** 2
                     + np.abs(r_p * np.einsum("nc,nc->n", E[pol], p_hat)) ** 2)
        out[pol] = (2 * np.pi * k) ** 2 * mu * reflected / (2 * VACUUM_IMPEDANCE * power[pol])
    return out
