"""Chirp-z (Bluestein) evaluation of Fourier sums on arbitrary uniform output grids.

Along one axis: inputs g_a at positions x_a = x₀ + a·Δ (a < Na), outputs at wave-vector
samples s_j = s₀ + j·δ (j < M, dimensionless direction cosines), wavenumber k:

    X_j = Σ_a g_a · exp(+j k s_j x_a)

With β = kΔδ and j·a = (j² + a² − (j−a)²)/2 this is a convolution with the chirp e^{−jβm²/2}:
X_j = post_j · Σ_a (pre_a g_a) h_{j−a}, evaluated exactly (to FFT round-off) with FFTs of
length L ≥ Na + M − 1. Used by the Kirchhoff model to land far fields exactly on the
projected-hemisphere pixels at any wavelength (no interpolation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft

__all__ = ["ChirpZAxis", "fast_length"]


def fast_length(n: int) -> int:
    """Smallest 2·3·5-smooth length ≥ n (fast for pocketfft, FFTW and VkFFT)."""
    return scipy.fft.next_fast_len(int(n), real=False)


@dataclass
class ChirpZAxis:
    """Precomputed chirps and filter spectrum for one axis (see module docstring)."""

    pre: np.ndarray  # (Na,) complex: multiplies the input samples
    post: np.ndarray  # (M,) complex: multiplies the outputs
    filter_spectrum: np.ndarray  # (L,) complex: FFT of the chirp filter
    n_in: int
    n_out: int

    @classmethod
    def plan(cls, k: float, x0: float, dx: float, n_in: int, s0: float, ds: float, n_out: int):
        beta = k * dx * ds
        a = np.arange(n_in, dtype=float)
        j = np.arange(n_out, dtype=float)
        pre = np.exp(1j * (k * dx * s0 * a + 0.5 * beta * a * a))
        post = np.exp(1j * (k * (s0 + ds * j) * x0 + 0.5 * beta * j * j))
        length = fast_length(n_in + n_out - 1)
        h = np.zeros(length, dtype=complex)
        m_pos = np.arange(n_out, dtype=float)
        h[:n_out] = np.exp(-0.5j * beta * m_pos * m_pos)
        m_neg = np.arange(1, n_in, dtype=float)
        h[length - (n_in - 1):] = np.exp(-0.5j * beta * m_neg[::-1] ** 2)
        return cls(pre, post, np.fft.fft(h), n_in, n_out)

    @property
    def length(self) -> int:
        return self.filter_spectrum.size

    def convolve(
        self, pre_multiplied: np.ndarray, axis: int, fft=None, workers: int | None = None, trim: bool = True
    ):
        """Σ_a p_a h_{j−a} along ``axis`` for inputs already multiplied by :attr:`pre`.

        ``fft`` is a module with fft/ifft (numpy.fft or scipy.fft); scipy.fft also takes
        ``workers``. The result still lacks the :attr:`post` factor. With ``trim=False`` the
        padded length L is kept along ``axis`` (outputs are its first M entries), saving a copy.
        """
        fft = scipy.fft if fft is None else fft
        kw = {"workers": workers} if (fft is scipy.fft and workers) else {}
        spec = fft.fft(pre_multiplied, n=self.length, axis=axis, **kw)
        shape = [1] * spec.ndim
        shape[axis] = self.length
        spec *= self.filter_spectrum.astype(spec.dtype, copy=False).reshape(shape)
        out = fft.ifft(spec, axis=axis, **kw)
        if not trim:
            return out
        index = [slice(None)] * out.ndim
        index[axis] = slice(0, self.n_out)
        return out[tuple(index)]

    def __call__(self, g: np.ndarray, axis: int, fft=None, workers: int | None = None) -> np.ndarray:
        """The full transform X_j of ``g`` along ``axis``."""
        shape = [1] * g.ndim
        shape[axis] = self.n_in
        conv = self.convolve(g * self.pre.reshape(shape), axis, fft, workers)
        shape[axis] = self.n_out
        return conv * self.post.reshape(shape)
