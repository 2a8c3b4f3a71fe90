"""Transmitted OFDM symbol (eq. (3)) and received samples (eqs. (5)–(6)) of the paper.

Conventions (used by every module):

* Arrays are in FFT-bin order, k = 0 … N-1, and bin k is the tone at k Δf of eq. (3).
* Time-domain synthesis follows eq. (5): x[n] = (1/√N) Σ_k d_k e^{+j2πkn/N}, i.e. the unitary inverse DFT
  (``jnp.fft.ifft(..., norm="ortho")``).  Eq. (6) writes the same thing as F^H D Γ F_L h with
  [F]_{ι,κ} = e^{+j2πικ/N}/√N, which would make synthesis a *forward* DFT; the code follows eq. (5).
* A delay τ multiplies bin k by e^{-j2πkΔfτ} (the diagonal Γ(τ) of eq. (6)), exactly, for any real τ.
* The ToA of BS m is τ_m = ‖p - b_m‖/c + δt with a clock bias δt common to all BSs.

SNR (``snr_db``) is the per-sample signal-to-noise ratio over the sampled band N Δf: the mean received signal
power per time-domain sample, for a channel of unit mean total power (``E Σ_l |h_l|² = 1``) and the transmitted
pilots' mean power per sample ``mean_k |d_k|²``, divided by the complex noise variance ``σ² = E|η[n]|²``.  With the
paper's full-band unit-modulus PRS, σ² = 10^(-SNR/10).  Because the DFT is unitary it is also the per-subcarrier
SNR.  It is the SNR before correlation: the correlation gain of N = 4096 samples (36 dB) comes on top.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from .channel import frequency_response
from .nr import PAPER, Numerology


def ofdm_symbol(prs) -> jax.Array:
    """Eq. (3) sampled at t = nT_s after CP removal: x[n] = (1/√N) Σ_k d_k e^{j2πkn/N}.

    Parameters
    ----------
    prs : complex (..., N)
        PRS symbols d_{m,k} in FFT-bin order.

    Returns
    -------
    jax.Array complex (..., N)
        The samples x[n].
    """
    _checks.require_x64()
    return jnp.fft.ifft(jnp.asarray(prs), axis=-1, norm="ortho")


def delay_phasor(tau_s, num: Numerology = PAPER) -> jax.Array:
    """Diagonal of Γ(τ) in eq. (6): e^{-j2πkΔfτ}, k = 0 … N-1.

    Parameters
    ----------
    tau_s : float (...)
        Delays τ, seconds.
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    jax.Array complex (..., N)
        The phasors.
    """
    _checks.require_x64()
    k = jnp.arange(num.n_fft)
    return unit_phasor(-2 * jnp.pi * num.scs_hz * jnp.asarray(tau_s)[..., None] * k)


def unit_phasor(phase) -> jax.Array:
    """e^{jφ} = cos φ + j sin φ: the same numbers as ``jnp.exp(1j * φ)``, faster.

    ``jnp.exp`` of a complex argument also evaluates e^0 twice and guards overflow per element (measured 2× slower
    in the Monte Carlo draws).

    Parameters
    ----------
    phase : float (...)
        Real phases φ, radians.

    Returns
    -------
    jax.Array complex (...)
        e^{jφ}.
    """
    return jax.lax.complex(jnp.cos(phase), jnp.sin(phase))


def noise_variance(snr_db, prs) -> jax.Array:
    """σ² of the complex AWGN for a per-sample SNR (the module docstring defines it).

    Parameters
    ----------
    snr_db : float or float (M,)
        Per-sample SNR, dB, in [-50, 100] (not checked when traced).
    prs : complex (..., N)
        The pilots, whose mean power per sample scales σ².

    Returns
    -------
    jax.Array float (...)
        σ², per link.

    Raises
    ------
    ValueError
        ``snr_db`` not real, not finite or outside [-50, 100] dB.
    """
    if not isinstance(snr_db, jax.core.Tracer):  # (traced: the engine checked its SNRs before tracing)
        check_snr_db(snr_db)
    pilot_power = jnp.mean(jnp.abs(jnp.asarray(prs)) ** 2, axis=-1)
    return pilot_power * 10.0 ** (-jnp.asarray(snr_db) / 10.0)


#: what a stated SNR means: "per_sample" — signal power over noise variance per time sample (the SNR of
#: ``noise_variance``, this book's convention); "total" — the SNR after correlating the N samples of the symbol, the
#: energy of the whole pilot over the noise variance, 10 log10 N dB above the per-sample SNR (a reading of the paper's
#: SNR, which it does not define; the reproduction chapter)
SNR_CONVENTIONS = ("per_sample", "total")


def per_sample_snr_db(snr_db, convention: str, num: Numerology = PAPER):
    """The per-sample SNR of an SNR stated in ``convention``: unchanged for "per_sample", 10 log10 N lower for "total".

    10 log10 N is 36.1 dB for the paper's N = 4096.  Traceable in ``snr_db``.

    Parameters
    ----------
    snr_db : float or array
        The stated SNR, dB.
    convention : str
        One of ``SNR_CONVENTIONS``.
    num : Numerology
        The numerology, for N (``nr.PAPER`` by default).

    Returns
    -------
    float or array
        The per-sample SNR, dB.

    Raises
    ------
    ValueError
        An unknown ``convention``.
    """
    _checks.one_of("convention", convention, SNR_CONVENTIONS)
    return snr_db - 10.0 * np.log10(num.n_fft) if convention == "total" else snr_db


def check_snr_db(snr_db) -> np.ndarray:
    """Validate an SNR in dB: real numbers (not text or True/False), finite and within [-50, 100] dB.

    Parameters
    ----------
    snr_db : float or array
        The SNR, dB.

    Returns
    -------
    numpy.ndarray float
        ``snr_db`` as float64.

    Raises
    ------
    ValueError
        ``snr_db`` not real, not finite or outside [-50, 100] dB.
    """
    if isinstance(snr_db, (str, bytes)) or np.asarray(snr_db).dtype.kind not in "iuf":
        raise ValueError(f"snr_db must be real numbers (dB, in [-50, 100]), got {snr_db!r}")
    s = np.asarray(snr_db, dtype=np.float64)
    if not np.all(np.isfinite(s)):
        raise ValueError(f"snr_db must be finite (dB, in [-50, 100]), got {snr_db!r}")
    if np.any(s < -50) or np.any(s > 100):
        raise ValueError(f"snr_db must be in [-50, 100] dB, got {snr_db!r}")
    return s


def demodulate(y) -> jax.Array:
    """The receiver's OFDM demodulation, the inverse of ``ofdm_symbol``: Y_k = (1/√N) Σ_n y[n] e^{-j2πkn/N}.

    This is the unitary DFT, F^H y in eq. (6).

    Parameters
    ----------
    y : complex (..., N)
        Received samples.

    Returns
    -------
    jax.Array complex (..., N)
        Y_k, bins in FFT order.
    """
    _checks.require_x64()
    return jnp.fft.fft(jnp.asarray(y), axis=-1, norm="ortho")


def received_spectrum(prs, freq_response, toa_s, clock_bias_s=0.0, num: Numerology = PAPER) -> jax.Array:
    """Noise-free received signal of eq. (5) in the frequency domain, the unitary DFT of its samples (eq. (6)).

    Y_{m,k} = d_{m,k} H_{m,k} e^{-j2πkΔf(τ_m + δt)}.

    This is the one signal path of the package: ``received_noiseless`` is its inverse DFT, and the Monte Carlo
    engine (``dpe5g.receivers.receiver.spectrum_at``) adds its noise here, in the frequency domain, where the receivers start
    (the DFT is unitary, so CN(0, σ²) per bin is exactly the time-domain AWGN of the same variance).

    Parameters
    ----------
    prs : complex (..., M, N)
        PRS symbols d_{m,k}.
    freq_response : complex (..., M, N)
        Channel responses H_{m,k} (``channel.frequency_response``).
    toa_s : float (..., M)
        ToA τ_m of the first path, seconds.
    clock_bias_s : float or float (...)
        Clock bias δt, seconds, common to the M base stations (0 by default).
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    jax.Array complex (..., M, N)
        Y_{m,k}.
    """
    _checks.require_x64()
    tau = jnp.asarray(toa_s) + jnp.asarray(clock_bias_s)[..., None]
    return jnp.asarray(prs) * jnp.asarray(freq_response) * delay_phasor(tau, num)


def received_noiseless(prs, gains, tap_delays_s, toa_s, clock_bias_s=0.0, num: Numerology = PAPER) -> jax.Array:
    """Noise-free received samples of eq. (5): the inverse DFT of ``received_spectrum``.

    y_m[n] = (1/√N) Σ_k d_{m,k} H_{m,k} e^{-j2πkΔf(τ_m + δt)} e^{j2πkn/N},
    H_{m,k} = Σ_l h_{m,l} e^{-j2πkΔf τ_l}.

    Parameters
    ----------
    prs : complex (M, N)
        PRS symbols d_{m,k}.
    gains : complex (M, L)
        Tap gains h_{m,l}.
    tap_delays_s : float (M, L)
        Excess delays τ_l, seconds (first arrival at 0).
    toa_s : float (M,)
        ToA τ_m of the first path, seconds.
    clock_bias_s : float
        UE clock bias δt, seconds, common to all BSs (0 by default).
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    jax.Array complex (M, N)
        y_m[n].
    """
    H = frequency_response(gains, tap_delays_s, num)
    return ofdm_symbol(received_spectrum(prs, H, toa_s, clock_bias_s, num))


def awgn(key: jax.Array, shape, variance) -> jax.Array:
    """Circular complex Gaussian noise CN(0, variance).

    The real and imaginary parts are the two halves of one standard normal draw of shape ``(*shape, 2)``, paired by
    ``lax.complex``.  Precision: the normals are drawn in float32 and widened (float64 normals took 2.8× as long,
    most of the Monte Carlo draws' time on this CPU): each is a Gaussian sample to float32 round-off (~6e-8
    relative), with the tails cut where float32 uniforms end, ``|x| ≲ 5.4`` (a probability of ~7e-8 per sample),
    far below what any figure of the book resolves.

    Parameters
    ----------
    key : jax PRNG key
        The random key.
    shape : tuple of int
        Shape of the noise.
    variance : float (...)
        ``σ² = E|η|²``, non-negative, broadcast against ``shape[:-1]``.

    Returns
    -------
    jax.Array complex (shape)
        The noise.

    Raises
    ------
    ValueError
        A negative or non-finite ``variance``.
    """
    _checks.values_in_range("variance", variance, 0.0, np.inf)
    x = jax.random.normal(key, (*shape, 2), jnp.float32).astype(jnp.float64)
    z = jax.lax.complex(x[..., 0], x[..., 1])
    return jnp.sqrt(jnp.asarray(variance) / 2.0)[..., None] * z


def received_samples(
    key: jax.Array,
    prs,
    gains,
    tap_delays_s,
    toa_s,
    snr_db,
    clock_bias_s: float = 0.0,
    num: Numerology = PAPER,
) -> jax.Array:
    """Received samples y_m = F D_m Γ_m(p) H_m + η_m of eqs. (5)–(6) with AWGN at ``snr_db``.

    F is the unitary inverse DFT (the synthesis of eq. (5); the module docstring says how this reads eq. (6)).

    Parameters
    ----------
    key : jax PRNG key
        The random key for the noise.
    prs, gains, tap_delays_s, toa_s, num
        As ``received_noiseless``.
    snr_db : float or float (M,)
        Per-sample SNR as defined in the module docstring, dB, in [-50, 100].
    clock_bias_s : float
        UE clock bias δt, seconds, in [-1e-3, 1e-3] (0 by default).

    Returns
    -------
    jax.Array complex (M, N)
        y_m[n].

    Raises
    ------
    ValueError
        ``snr_db`` or ``clock_bias_s`` invalid or outside its range.
    """
    check_snr_db(snr_db)
    _checks.in_range("clock_bias_s", clock_bias_s, -1e-3, 1e-3, "s")
    s = received_noiseless(prs, gains, tap_delays_s, toa_s, clock_bias_s, num)
    return s + awgn(key, s.shape, noise_variance(snr_db, prs))


def received_noiseless_direct(prs, gains, tap_delays_s, toa_s, clock_bias_s=0.0, num: Numerology = PAPER):
    """Eq. (4) sampled at t = nT_s, i.e. eq. (5), evaluated term by term in the time domain, for verification.

    y_m[n] = (1/√N) Σ_k exp(j2πk n/N) d_{m,k} Σ_l h_{m,l} exp(-j2πkΔf(τ_m + δt + τ_l)).

    For small N only (O(N² + L N) time, memory N²); uses NumPy, no FFT.

    Parameters
    ----------
    prs, gains, tap_delays_s, toa_s, clock_bias_s, num
        As ``received_noiseless``.

    Returns
    -------
    numpy.ndarray complex (M, N)
        y_m[n], as ``received_noiseless``.
    """
    d = np.asarray(prs)
    g = np.asarray(gains)
    tl = np.asarray(tap_delays_s)
    tau = np.asarray(toa_s) + clock_bias_s
    n_fft = num.n_fft
    k = np.arange(n_fft)
    synthesis = np.exp(2j * np.pi * np.outer(k, k) / n_fft)  # [n, k] = exp(j2πkn/N)
    out = np.zeros(d.shape, dtype=np.complex128)
    for m in range(d.shape[0]):
        paths = sum(g[m, l] * np.exp(-2j * np.pi * k * num.scs_hz * (tau[m] + tl[m, l])) for l in range(g.shape[1]))
        out[m] = synthesis @ (d[m] * paths)
    return out / np.sqrt(n_fft)
