"""The NLoS-aware DPE (ours, beyond the paper): eq. (10) with each link's NLoS excess delay integrated out under
TR 38.901's law of it.

Eq. (10) scores a position p by Σ_m c_m(τ_m(p)), the energy c_m of link m's CIR estimate in an L-tap window that
starts at the geometric ToA τ_m(p).  It is the log-likelihood of the received signals, concentrated over the CIRs
(eq. (9)), times the noise power σ²: log p(y_m | p) = c_m(τ_m(p)) / σ² + const.  On an NLoS link every path comes
late by an unknown excess delay β_m ≥ 0, so the window should start at τ_m(p) + β_m.  The receiver knows the law
of β_m, not its value: 0 with the link's LoS probability P_m (eq. (11), at the window centre's distance), else
TR 38.901 §7.6.9's log-normal (``scenario.ExcessDelayRow``).  Integrating β_m out on the knots Δ = T_s / U of the
spline correlogram (eq. (D1) of the NLoS chapter)::

    ℓ_m(τ) = σ̂_m² · log Σ_{j=0}^{J-1} (π_{m,j} / π_{m,0}) · exp(c_m(τ + jΔ) / σ̂_m²),     p̂ = argmax_p Σ_m ℓ_m(τ_m(p)),

where π_{m,j} is the prior probability that β_m rounds to jΔ (eq. (D2): π_{m,0} = P_m + (1 − P_m) F(Δ/2),
π_{m,j} = (1 − P_m)(F((j + ½)Δ) − F((j − ½)Δ)), F the log-normal's CDF, J − 1 the lags up to its
``CLOCK_NLOS_QUANTILE`` point, the tail beyond dropped), and σ̂_m² the noise power estimated from the
link's own correlogram (its floor, ``otdoa_nlos.noise_floor``, over the window's weight Σ_l w_l, the floor of an
L-tap window of noise).  The ratio to π_{m,0} subtracts a constant per link: ℓ_m ≥ c_m, and where P_m = 1, ℓ_m = c_m
(eq. (10)).  Each ℓ_m is computed on the knots that the certified search reads and put back into cubic-spline form
(``marginal_window``), so that ``certified_search`` runs on it unchanged: what it certifies is the global maximum in
its window of Σ_m of the cubic splines through ℓ_m's knot values (the naive receiver's is the same statement with
c_m).  The window's clock range must cover the law of β too (the experiment's "clock_nlos" clock window): a delay
common to every link looks like a clock bias.

No truth enters: neither the LoS states, nor the drawn delays, nor the position (P_m is read at the window's
centre, a receiver quantity).  Units: seconds, metres.
"""

from __future__ import annotations

from statistics import NormalDist

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy import propagation
from ..phy.nr import PAPER, Numerology
from . import otdoa_nlos
from .search_config import SearchConfig
from .spline_boxes import slice_cells, spline_window

#: the narrowest log-normal the NLoS-aware DPE integrates over: its median (s) and σ of lg Δτ (decades)
MIN_MEDIAN_S, MIN_SIGMA_LG = 1e-12, 1e-3

#: the percentile of c·Δτ that the "clock_nlos" window adds to the clock model's support (``Experiment.receiver_search``)
CLOCK_NLOS_QUANTILE = 0.99

#: knots either side of the searched cells whose values are profiled too, so that the local spline prefilter's edge
#: error (it decays by 2 − √3 ≈ 0.27 per knot) is below 1e-13 of the values where the search reads them
PREFILTER_MARGIN = 24


def excess_log_masses(p_los, median_s: float, sigma_lg: float, quantile: float, knot_s: float) -> jax.Array:
    """Eq. (D2): log(π_j / π_0), the prior of a link's excess delay on the lags jΔ, relative to the lag 0.

    Parameters
    ----------
    p_los : float (...)
        Each link's LoS probability, in [0, 1].
    median_s, sigma_lg : float
        The log-normal's median (seconds, > 0) and the standard deviation of lg Δτ (decades, > 0).
    quantile : float
        The lags reach the log-normal's ``quantile`` point; the tail beyond is dropped.
    knot_s : float
        Δ, the lag step, seconds.

    Returns
    -------
    float (..., J)
        log(π_j / π_0), 0 at j = 0 (−inf where P_m = 1 and j > 0).
    """
    _checks.in_range("median_s", median_s, MIN_MEDIAN_S, 1e-6, "s (31.6 ns is 3.16e-8)")
    _checks.in_range("sigma_lg", sigma_lg, MIN_SIGMA_LG, 1.0, "decades")
    _checks.in_range("knot_s", knot_s, 1e-12, 1e-6, "s")
    _checks.values_in_range("p_los", p_los, 0.0, 1.0)
    n_lags = int(np.ceil(propagation.excess_quantile_s(median_s, sigma_lg, quantile) / knot_s)) + 1
    edges = (np.arange(n_lags) + 0.5) * knot_s  # the upper edge of each lag's cell
    cdf = np.array([NormalDist(np.log10(median_s), sigma_lg).cdf(np.log10(x)) for x in edges])
    nlos = np.diff(cdf, prepend=0.0)  # F((j + ½)Δ) − F((j − ½)Δ), F(−Δ/2) = 0
    p = jnp.asarray(p_los, dtype=jnp.float64)[..., None]
    mass = jnp.where(np.arange(n_lags) == 0, p + (1.0 - p) * nlos[0], (1.0 - p) * nlos)
    return jnp.log(mass) - jnp.log(mass[..., :1])


def marginal_terms(values, log_masses, noise_power) -> jax.Array:
    """Eq. (D1) on the knots: ℓ(τ_k) = σ² log Σ_j (π_j / π_0) exp(c(τ_{k+j}) / σ²), per link.

    Parameters
    ----------
    values : float (M, K + J − 1)
        Each link's correlogram c_m at consecutive knots.
    log_masses : float (M, J)
        ``excess_log_masses``.
    noise_power : float (M,)
        σ̂_m², in the units of the correlogram.

    Returns
    -------
    float (M, K)
        ℓ_m at the first K knots (≥ ``values`` there).
    """
    values, log_masses, noise_power = (jnp.asarray(a, dtype=jnp.float64) for a in (values, log_masses, noise_power))
    n_lags = log_masses.shape[-1]
    k = values.shape[-1] - n_lags + 1
    z = values / noise_power[:, None]

    def lag(j, acc):
        return jnp.logaddexp(acc, log_masses[:, j, None] + jax.lax.dynamic_slice_in_dim(z, j, k, axis=1))

    return noise_power[:, None] * jax.lax.fori_loop(1, n_lags, lag, z[:, :k])


def knot_values(coef) -> jax.Array:
    """The cubic B-spline's values at its knots, (c_{k−1} + 4 c_k + c_{k+1}) / 6, on the whole (cyclic) period.

    Parameters
    ----------
    coef : float (..., K)
        Spline coefficients (``correlogram.spline_coefficients``).

    Returns
    -------
    float (..., K)
    """
    return (jnp.roll(coef, 1, axis=-1) + 4.0 * coef + jnp.roll(coef, -1, axis=-1)) / 6.0


def spline_prefilter(values) -> jax.Array:
    """Cubic B-spline coefficients through values on consecutive knots, the row taken as periodic (one real FFT).

    On a stretch cut from a longer function the wrap-around is wrong at both ends; its error decays by 2 − √3 per
    knot inward (``PREFILTER_MARGIN``).

    Parameters
    ----------
    values : float (..., K)

    Returns
    -------
    float (..., K)
        Coefficients c with (c_{k−1} + 4 c_k + c_{k+1}) / 6 = values_k (cyclically).
    """
    k = values.shape[-1]
    kernel = (4.0 + 2.0 * np.cos(2 * np.pi * np.arange(k // 2 + 1) / k)) / 6.0
    return jnp.fft.irfft(jnp.fft.rfft(values, axis=-1) / kernel, n=k, axis=-1)


def marginal_window(coef, bs_xyz, center, cfg: SearchConfig, window, median_s: float, sigma_lg: float,
                    quantile: float, num: Numerology = PAPER):
    """``spline_window`` of eq. (D1)'s per-link terms instead of eq. (10)'s: the NLoS-aware DPE's input to
    ``certified_search``.  Traceable.

    Parameters
    ----------
    coef : float (M, N·U)
        Each link's spline correlogram (``correlogram.spline_coefficients``) over the whole period.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center : float (4,)
        The window's centre [x, y, z, c δt], metres; eq. (11)'s P_m is read at its 2-D distance to each BS.
    cfg : SearchConfig
        The certified search and its window.
    window : complex (N + 1,)
        The receiver window (``correlogram.window_spectrum``); its harmonic 0 is Σ_l w_l.
    median_s, sigma_lg, quantile : float
        The law of β (TR 38.901's row) and the quantile where its lags stop (``excess_log_masses``).
    num : Numerology
        The numerology.

    Returns
    -------
    coefficients : float (M, cells + 3)
        As ``spline_window``'s, of ℓ_m.
    start : int (M,)
        As ``spline_window``'s.
    """
    bs = jnp.asarray(bs_xyz)
    values = knot_values(coef)
    noise = otdoa_nlos.noise_floor(values) / jnp.real(window[0])
    _, start = spline_window(coef, bs, center, cfg, num)
    d2d = jnp.linalg.norm(center[None, :2] - bs[:, :2], axis=-1)
    log_masses = excess_log_masses(propagation.los_probability(d2d), median_s, sigma_lg, quantile,
                                   num.sample_period_s / cfg.spline_upsample)
    n_out = slice_cells(cfg, num) + 3  # as spline_window's
    width = n_out + 2 * PREFILTER_MARGIN
    idx = jnp.mod(start[:, None] - PREFILTER_MARGIN + jnp.arange(width + log_masses.shape[-1] - 1)[None],
                  values.shape[-1])
    ell = marginal_terms(jnp.take_along_axis(values, idx, axis=1), log_masses, noise)
    return spline_prefilter(ell)[:, PREFILTER_MARGIN:PREFILTER_MARGIN + n_out], start
