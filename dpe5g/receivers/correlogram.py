"""The least-squares CIR estimate and its correlograms: what the DPE cost of eq. (10) and the OTDoA ToA share.

Both receivers start from the demodulated received symbol Y_m = F^H y_m (``signal.demodulate``) and the known
pilots d_m.  The least-squares CIR estimate of BS m in the frequency domain (eq. (8) with D_m^H D_m = I,
``ls_spectrum``) is ``G_{m,k} = conj(d_{m,k}) Y_{m,k}``, and ``ĥ_m(τ) = (1/√N) Σ_k G_{m,k} e^{+j2πkΔfτ}`` the CIR
estimate delayed by τ.  The BS-m term of eq. (10) at ToA τ is its energy in an L-tap window,
``c_m(τ) = N Σ_{l<L} |ĥ_m(τ + l T_s) / √N|²`` (the DPE chapter derives it), and the correlograms below tabulate it:

* ``energy_grid`` — c_m on a grid of T_s/U, read by the grid search (cubic interpolation) and the OTDoA ToA (L = 1);
* ``spline_coefficients`` — cubic B-spline coefficients of c_m on knots T_s/U apart, read by the certified search.

Precision: ``energy_grid`` follows its input's dtype.  ``benchmarks/bench_engine.py`` times it in complex64 and
complex128 on the same signals and measures the ToA error complex64 adds to the detector's peak (the engine table of
book/running.md): twice as fast, far below a millimetre, so the receivers' grid correlograms (``GRID_DTYPE``: grid
search, OTDoA detector) use it.  The certified search's spline coefficients stay float64 (its certificate compares
costs to 1e-4 relative, and its bounds must hold), as do the book's exactness checks (complex128 ``correlogram``).

``correlogram`` and ``spline_correlogram`` are the validated entry points for time-domain samples y (the book's
checks); the engine calls the traceable ``energy_grid`` / ``spline_coefficients`` on ``ls_spectrum`` directly.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy import signal
from ..phy.nr import PAPER, Numerology


#: precision of the grid correlograms the receivers read (``receiver.receiver_correlogram`` for the grid search,
#: ``otdoa.toa_from_spectrum``), chosen from the measurement in the module docstring
GRID_DTYPE = jnp.complex64


def check_inputs(y, prs, n_taps: int):
    """Validate received samples and pilots for a correlogram or the cost.

    Parameters
    ----------
    y, prs : complex (M, N)
        Received samples and pilots, of equal shape.
    n_taps : int
        L, the window's taps, 1 ≤ L ≤ N.

    Returns
    -------
    y : numpy.ndarray, complex (M, N)
        The samples, as NumPy.
    prs : numpy.ndarray, complex (M, N)
        The pilots, as NumPy.

    Raises
    ------
    ValueError
        When y and prs are not (M, N) arrays of equal shape, or n_taps is out of range.
    """
    _checks.require_x64()
    y = np.asarray(y)
    prs = np.asarray(prs)
    if y.ndim != 2 or prs.shape != y.shape:
        raise ValueError(f"y and prs must both be complex (M, N) arrays of equal shape, got {y.shape} and {prs.shape}")
    _checks.integer("n_taps", n_taps, 1, y.shape[1])
    return y, prs


def ls_spectrum(spectrum, prs) -> jax.Array:
    """G = conj(d) ⊙ Y: the LS CIR estimate in the frequency domain (D^H F^H y of eq. (8)).

    Parameters
    ----------
    spectrum : complex (..., M, N)
        Demodulated symbols Y (``signal.demodulate`` of y, or the engine's ``signal.received_spectrum`` plus noise).
    prs : complex (..., M, N)
        Pilots d.

    Returns
    -------
    complex (..., M, N)
    """
    _checks.require_x64()
    return jnp.conj(prs) * spectrum


def window_sum(e, n_taps: int) -> jax.Array:
    """Circular L-tap window sum along the last axis, w[j] = e[j] + e[j+1] + … + e[j+L-1] (indices mod N).

    By prefix doubling: blocks of 1, 2, 4, … taps, b_{2s}[j] = b_s[j] + b_s[j+s], and w the sum of the blocks of the
    binary digits of L placed end to end (4 + 8 for L = 12): about 2 log2 L additions per entry, no FFT and no
    cancellation (a running-sum difference S[j+L] − S[j] does the same with one subtraction but was measured 1.7×
    slower on this CPU).

    Parameters
    ----------
    e : real (..., N)
        The values summed (energies).
    n_taps : int
        L, the window's taps.

    Returns
    -------
    real (..., N)
    """
    out, off, block, size, rest = None, 0, e, 1, n_taps
    while rest:
        if rest & 1:
            part = jnp.roll(block, -off, axis=-1)
            out = part if out is None else out + part
            off += size
        rest >>= 1
        if rest:
            block = block + jnp.roll(block, -size, axis=-1)
            size *= 2
    return out


@partial(jax.jit, static_argnames=("n_taps", "upsample"))
def energy_grid(g, n_taps: int, upsample: int) -> jax.Array:
    """Per-BS correlograms from the LS spectrum: the BS-m terms of eq. (10), L-tap window, on a T_s/U grid, exactly.

    The CIR estimate on T_s/U by one zero-padded inverse FFT of length U·N (``cir_grid``), the energy, then the L-tap
    window sum by ``window_sum`` (no FFT; ``energy_from_cir``).  Periodic in τ with period N T_s = 1/Δf; traceable.

    Parameters
    ----------
    g : complex (..., M, N)
        The LS spectrum (``ls_spectrum``).
    n_taps, upsample : int
        L, the window's taps, and U, grid points per sample T_s.

    Returns
    -------
    real (..., M, N·U)
        Entry j of row m is c_m(j T_s / U).
    """
    return energy_from_cir(cir_grid(g, upsample), n_taps, upsample)


def cir_grid(g, upsample: int) -> jax.Array:
    """The CIR estimate on a grid of T_s/U from the LS spectrum, by one zero-padded inverse FFT of length U·N.

    The bins k < N carry the spectrum, the rest are empty, so the transform interpolates ĥ exactly between samples.
    Traceable and linear in g: the engine forms the CIR of every SNR of a trial from those of its noise-free spectrum
    and its unit noise (``receiver.noise_scales``).  (U phase-ramped transforms of length N give the same numbers, but
    XLA fuses g's producers, such as the noise draw, into each of the U products and repeats them U times.)

    Parameters
    ----------
    g : complex (..., M, N)
        The LS spectrum (``ls_spectrum``).
    upsample : int
        U, grid points per sample T_s.

    Returns
    -------
    complex (..., M, N·U)
        In g's dtype; entry j of row m is ĥ_m(j T_s / U) / √N = (1/N) Σ_k g_k e^{j2πkj/(UN)}.
    """
    _checks.require_x64()
    n = g.shape[-1]
    return jnp.fft.ifft(g, n=n * upsample, axis=-1) * upsample


def energy_from_cir(h, n_taps: int, upsample: int) -> jax.Array:
    """``energy_grid`` from ``cir_grid``'s output: the energy ``N |ĥ/√N|²`` and its L-tap window sum (``window_sum``).

    Parameters
    ----------
    h : complex (..., M, N·U)
        ``cir_grid``'s output.
    n_taps, upsample : int
        L, the window's taps (T_s = U grid points apart), and U, grid points per sample T_s.

    Returns
    -------
    real (..., M, N·U)
    """
    n = h.shape[-1] // upsample
    e = (h.real**2 + h.imag**2) * n
    e = jnp.swapaxes(e.reshape(e.shape[:-1] + (n, upsample)), -1, -2)  # (..., M, U, N): offsets, samples
    w = jnp.swapaxes(window_sum(e, n_taps), -1, -2)  # (..., M, N, U)
    return w.reshape(w.shape[:-2] + (n * upsample,))


#: longest decay of the first-path-aware window's tap weights, seconds (``tap_weights``): a microsecond is longer than
#: any TR 38.901 delay spread; a larger value is most likely nanoseconds passed as seconds
MAX_WINDOW_DECAY_S = 1e-6


def tap_weights(n_taps: int, decay_s: float = 0.0, sample_period_s: float = PAPER.sample_period_s) -> np.ndarray:
    """Weights w_l of the receiver window's L taps.

    decay_s = 0: all 1, eq. (8)'s window (the ML cost of eq. (10), L free taps).  decay_s > 0: the first-path-aware
    window (ours, not the paper's; the bounds chapter), w_l = exp(−l T_s / decay_s), the low-SNR limit of the MAP cost
    when the taps are independent CN(0, p_l) with an exponential power-delay profile p_l ∝ exp(−l T_s / decay_s).

    Parameters
    ----------
    n_taps : int
        L, 1 to 2^20.
    decay_s : float
        The weights' decay, seconds, 0 to ``MAX_WINDOW_DECAY_S``; 0 (the default): all weights 1.
    sample_period_s : float
        T_s, seconds (the paper's by default).

    Returns
    -------
    float (L,)

    Raises
    ------
    ValueError
        When an argument is out of range.
    """
    _checks.integer("n_taps", n_taps, 1, 1 << 20)
    _checks.in_range("decay_s", decay_s, 0.0, MAX_WINDOW_DECAY_S, "s")
    _checks.in_range("sample_period_s", sample_period_s, 1e-12, 1e-3, "s")
    if decay_s == 0:
        return np.ones(n_taps)
    return np.exp(-np.arange(n_taps) * sample_period_s / decay_s)


def check_weights(weights, n_taps: int) -> np.ndarray:
    """Validate window tap weights: L finite, non-negative numbers, not all zero.

    Parameters
    ----------
    weights : float (L,)
        The taps' weights.
    n_taps : int
        L.

    Returns
    -------
    float (L,)
        The weights, as a NumPy array.

    Raises
    ------
    ValueError
        When they are not L finite non-negative numbers, not all zero.
    """
    w = np.asarray(weights, dtype=float)
    if w.shape != (n_taps,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
        raise ValueError(f"weights must be {n_taps} finite non-negative numbers, not all 0 (one per window tap), "
                         f"got shape {w.shape}")
    return w


def window_spectrum(n_taps: int, n_fft: int, weights=None, tap_spacing: float = 1.0) -> np.ndarray:
    """The weighted L-tap window sum as a multiplier on the harmonics q = 0 … N of Δf of the energy e(τ).

    The window sum w_0 e(τ) + w_1 e(τ + s T_s) + … + w_{L−1} e(τ + (L−1) s T_s) multiplies harmonic q by
    Σ_{l<L} w_l e^{j2πqls/N}; the Nyquist harmonic q = N is set to 0.  ``spline_coefficients`` takes it as an input, so
    one compiled Monte Carlo serves every L, weighting and spacing.

    Parameters
    ----------
    n_taps, n_fft : int
        L (1 to N) and N.
    weights : float (L,) or None
        w, from ``tap_weights``; None: all 1 (eq. (8)'s window).
    tap_spacing : float
        s, the taps' spacing in samples, 1 to N: the spacing at which taps are orthogonal over the pilots, so that the
        window's energy is the ML cost of L free taps: 1 when they fill all N bins (eq. (8)), N / K on one contiguous
        band of K bins (``nr.band_bins``, ``band_tap_spacing``).

    Returns
    -------
    complex (N + 1,)

    Raises
    ------
    ValueError
        When n_taps, tap_spacing or the weights are out of range.
    """
    _checks.integer("n_taps", n_taps, 1, n_fft)
    _checks.in_range("tap_spacing", tap_spacing, 1.0, float(n_fft), "samples")
    w = np.ones(n_taps) if weights is None else check_weights(weights, n_taps)
    q = np.arange(n_fft + 1)
    taps = np.arange(n_taps) if tap_spacing == 1.0 else np.arange(n_taps) * float(tap_spacing)
    window = (np.exp(2j * np.pi * np.outer(q, taps) / n_fft) * w).sum(axis=1)
    window[n_fft] = 0.0  # no harmonic N: the Nyquist bin of the 2N samples is zero
    return window


def band_tap_spacing(num: Numerology = PAPER) -> float:
    """N / K samples: the tap spacing orthogonal over pilots on one contiguous band of K = n_active subcarriers.

    On the carrier's band (``nr.band_bins``), Σ_{k in band} e^{j2πk(l − l')/K} = K δ_{ll'}; T_s itself is the spacing
    for pilots on all N bins (eq. (8)).  With K < N and taps T_s apart, the taps' pulses overlap, eq. (10)'s window
    energy is no longer the ML cost of L free taps, and its maximum moves off the first path toward the middle of the
    pulse's energy (the Fig. 9 chapter measures it).

    Parameters
    ----------
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    float
        N / K, samples.
    """
    return num.n_fft / num.n_active


def spline_coefficients(g, window, upsample: int) -> jax.Array:
    """Cubic B-spline coefficients of the per-BS terms of eq. (10) on knots T_s/U apart, from the LS spectrum.

    c_m(τ) is a real trigonometric polynomial with harmonics of Δf up to N − 1 (``|Σ_k g_k e^{j2πkΔfτ}|²`` summed over
    L shifts), so its 2N samples at T_s/2 determine it: the energies at n T_s and (n + ½) T_s (``half_sample_cir``),
    their real FFT, times the window and the inverse of the cubic B-spline's sampled kernel (1/6, 4/6, 1/6) at the knot
    spacing (the interpolation prefilter), then one zero-padded real inverse FFT of length N·U gives coefficients c_j
    such that Σ_j c_j β³(τ/(T_s/U) − j) equals c_m(τ) at every knot exactly (to round-off).  Between knots the spline
    differs from eq. (10) by ≤ 2e-5 of the peak at U = 8 (the DPE chapter measures it).  (U/2 complex length-N
    transforms for the U knot phases instead of the long one were measured slower on this CPU, 0.39 against 0.30 ms per
    BS, and dropped.)  Traceable (U static).

    Parameters
    ----------
    g : complex (..., M, N)
        The LS spectrum (``ls_spectrum``).
    window : complex (N + 1,)
        ``window_spectrum(L, N)``.
    upsample : int
        U, knots per sample T_s, even.

    Returns
    -------
    real (..., M, N·U)
        The coefficients c_j.
    """
    h = half_sample_cir(g)
    return spline_from_energy((h.real**2 + h.imag**2) * g.shape[-1], window, upsample)


def half_sample_cir(g) -> jax.Array:
    """The CIR estimate at T_s/2 from the LS spectrum: ``cir_grid`` with U = 2; traceable and linear in g.

    Parameters
    ----------
    g : complex (..., M, N)
        The LS spectrum (``ls_spectrum``).

    Returns
    -------
    complex (..., M, 2N)
        Entry j of row m is ĥ_m(j T_s / 2) / √N (one zero-padded inverse FFT of length 2N).
    """
    return cir_grid(g, 2)


def spline_from_energy(e2, window, upsample: int) -> jax.Array:
    """``spline_coefficients`` from the energies at T_s/2, or from any real function sampled there (the map is linear).

    Parameters
    ----------
    e2 : real (..., M, 2N)
        The energies at T_s/2, ``N |half_sample_cir|²`` (the engine maps the three parts of the energy of a·G + b·G_n
        once per trial, ``receiver.spline_noise_basis``).
    window : complex (N + 1,)
        ``window_spectrum(L, N)``.
    upsample : int
        U, knots per sample T_s, even.

    Returns
    -------
    real (..., M, N·U)
    """
    n = e2.shape[-1] // 2
    q = np.arange(n + 1)
    prefilter = 6.0 / (4.0 + 2.0 * np.cos(2 * np.pi * q / (n * upsample)))  # 1 / DFT of (1/6, 4/6, 1/6)
    spec = jnp.fft.rfft(e2, axis=-1) * (window * prefilter)
    pad = jnp.zeros(spec.shape[:-1] + (n * upsample // 2 + 1,), dtype=spec.dtype).at[..., : n + 1].set(spec)
    return jnp.fft.irfft(pad, n=n * upsample, axis=-1) * (upsample / 2)


def cir_window(h, start, width: int, n_taps: int, upsample: int) -> jax.Array:
    """The samples of ``cir_grid``'s h that the windowed energies of grid points start … start + W − 1 read.

    Parameters
    ----------
    h : complex (..., M, N·U)
        ``cir_grid``'s output.
    start : int (..., M)
        The window's first grid point, a multiple of U (``grid_search.grid_window``), not reduced modulo N·U.
    width : int
        W, a multiple of U.
    n_taps, upsample : int
        L, the window's taps, and U, grid points per sample T_s.

    Returns
    -------
    complex (..., M, U, W/U + L − 1)
        Offsets u, samples: W/U + L − 1 whole samples from start on, at every offset.
    """
    n_rows = width // upsample + n_taps - 1
    idx = jnp.mod(start[..., None] + jnp.arange(n_rows * upsample), h.shape[-1])
    hw = jnp.take_along_axis(h, idx, axis=-1)
    return jnp.swapaxes(hw.reshape(hw.shape[:-1] + (n_rows, upsample)), -1, -2)


def energy_window(hw, n_taps: int, n_fft: int) -> jax.Array:
    """``energy_from_cir`` on the samples of a window (``cir_window``): the correlogram at its W grid points.

    Parameters
    ----------
    hw : complex (..., M, U, W/U + L − 1)
        ``cir_window``'s output.
    n_taps, n_fft : int
        L, the window's taps, and N.

    Returns
    -------
    real (..., M, W)
        The same numbers as ``energy_grid`` there, bit for bit (the same sums, in the same order).
    """
    return window_sums((hw.real**2 + hw.imag**2) * n_fft, n_taps)


def window_sums(e, n_taps: int) -> jax.Array:
    """The L-tap window sums of the energies of a window (``cir_window``), the offsets interleaved; linear in e.

    Parameters
    ----------
    e : real (..., M, U, W/U + L − 1)
        The energies of the window's samples.
    n_taps : int
        L, the window's taps.

    Returns
    -------
    real (..., M, W)
    """
    n_rows = e.shape[-1] - n_taps + 1
    w = window_sum(e, n_taps)[..., :n_rows]  # the first W/U sums do not wrap
    return jnp.swapaxes(w, -1, -2).reshape(w.shape[:-2] + (n_rows * w.shape[-2],))


def correlogram(y, prs, n_taps: int, upsample: int) -> jax.Array:
    """Per-BS correlograms of time-domain samples: ``energy_grid`` of ``ls_spectrum(signal.demodulate(y), prs)``.

    Entry j of row m is the BS-m term of ``cost.ml_cost`` at τ = j T_s / U, exactly (one FFT per BS instead of one per
    candidate).  The cost is periodic in τ with period N T_s = 1/Δf, so the grid covers every τ modulo that period.

    Parameters
    ----------
    y, prs : complex (M, N)
        Received samples (eq. (5)) and pilots.
    n_taps, upsample : int
        L, the window's taps (1 to N), and U, grid points per sample T_s (1 to 256).

    Returns
    -------
    real (M, N·U)

    Raises
    ------
    ValueError
        When the shapes do not match or n_taps or upsample is out of range.
    """
    y, prs = check_inputs(y, prs, n_taps)
    _checks.integer("upsample", upsample, 1, 256)
    return energy_grid(ls_spectrum(signal.demodulate(y), prs), n_taps, upsample)


def spline_correlogram(y, prs, n_taps: int, upsample: int = 8, weights=None) -> jax.Array:
    """Cubic B-spline coefficients of the per-BS terms of eq. (10) (``spline_coefficients``) from time-domain samples.

    Parameters
    ----------
    y, prs : complex (M, N)
        Received samples (eq. (5)) and pilots.
    n_taps, upsample : int
        L, the window's taps (1 to N), and U, knots per sample T_s (even, 2 to 64).
    weights : float (L,) or None
        The L taps' weights (``tap_weights``); None for eq. (10)'s equal weights.

    Returns
    -------
    real (M, N·U)

    Raises
    ------
    ValueError
        When the shapes do not match, n_taps or upsample is out of range or odd, or the weights are invalid.
    """
    y, prs = check_inputs(y, prs, n_taps)
    _checks.integer("upsample", upsample, 2, 64)
    if upsample % 2:
        raise ValueError(f"upsample must be an even integer in [2, 64], got {upsample!r}")
    g = ls_spectrum(signal.demodulate(y), prs)
    return _spline_jit(g, jnp.asarray(window_spectrum(n_taps, y.shape[1], weights)), upsample)


_spline_jit = jax.jit(spline_coefficients, static_argnames=("upsample",))
