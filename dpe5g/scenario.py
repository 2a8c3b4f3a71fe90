"""The urban propagation models of Section III: UMi street-canyon links (LoS probability of eq. (11), TR 38.901 path
loss, shadow fading), the link budget, and the UE clock bias.  The deployment they act on (base stations, region,
file format) is ``dpe5g.deployment``.

Units: metres, dB / dBm, seconds, Hz.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from . import _checks
from .nr import C, PAPER, Numerology

#: TR 38.901 Table 7.4.1-1 shadow-fading standard deviations, UMi street canyon, dB
SIGMA_SF_LOS_DB = 4.0
SIGMA_SF_NLOS_DB = 7.82
#: effective environment height h_E for the UMi breakpoint distance, m
H_E_M = 1.0
#: the largest 2-D distance the models accept, m (TR 38.901 states UMi for d2D up to 5 km)
MAX_D2D_M = 1e5


def los_probability(d2d_m) -> jax.Array:
    """Eq. (11) (TR 38.901 Table 7.4.2-1, UMi street canyon): Pr_LoS = 1 for D ≤ 18 m, else
    18/D + (1 - 18/D) e^{-D/36}.  d2d_m : (...) 2-D BS–UE distance in metres, finite, in [0, ``MAX_D2D_M``]
    → (...) probability."""
    _checks.values_in_range("d2d_m", d2d_m, 0.0, MAX_D2D_M, "m")
    d = jnp.asarray(d2d_m, dtype=jnp.float64)
    safe = jnp.maximum(d, 18.0)
    return jnp.where(d <= 18.0, 1.0, 18.0 / safe + (1.0 - 18.0 / safe) * jnp.exp(-safe / 36.0))


def path_loss_umi_db(d2d_m, h_bs_m, h_ut_m, fc_hz, los) -> jax.Array:
    """TR 38.901 Table 7.4.1-1 UMi street-canyon path loss in dB (without shadow fading).

    LoS: PL1 = 32.4 + 21 log10(d3D) + 20 log10(fc) for d2D ≤ d'BP, PL2 = 32.4 + 40 log10(d3D) + 20 log10(fc)
    - 9.5 log10(d'BP² + (h_BS - h_UT)²) beyond, with d'BP = 4 (h_BS - 1)(h_UT - 1) fc / c.
    NLoS: max(PL_LoS, 35.3 log10(d3D) + 22.4 + 21.3 log10(fc) - 0.3 (h_UT - 1.5)).  fc in GHz inside the formulas.
    The table states the formulas for 10 m ≤ d2D ≤ 5 km; below 10 m we evaluate them at d2D = 10 m (stated in the
    book, not silent), so a UE at the foot of a mast does not get an unbounded SNR.
    d2d_m, los : (...) arrays; h_bs_m, h_ut_m : metres (broadcast); fc_hz : Hz.  Returns (...).
    Ranges (``ValueError`` outside them): d2d_m in [0, ``MAX_D2D_M``] m, h_bs_m in [1.5, 150] m, h_ut_m in [1, 22.5]
    m (the table's UT heights), fc_hz in [0.5e9, 100e9] Hz (the table's validity).
    """
    _checks.values_in_range("d2d_m", d2d_m, 0.0, MAX_D2D_M, "m")
    _checks.values_in_range("h_bs_m", h_bs_m, 1.5, 150.0, "m")
    _checks.values_in_range("h_ut_m", h_ut_m, 1.0, 22.5, "m")
    _checks.values_in_range("fc_hz", fc_hz, 0.5e9, 100e9, "Hz")
    d2d = jnp.maximum(jnp.asarray(d2d_m, dtype=jnp.float64), 10.0)
    h_bs, h_ut = jnp.asarray(h_bs_m), jnp.asarray(h_ut_m)
    fc = fc_hz / 1e9
    d3d = jnp.sqrt(d2d**2 + (h_bs - h_ut) ** 2)
    d_bp = 4.0 * (h_bs - H_E_M) * (h_ut - H_E_M) * fc_hz / C
    pl1 = 32.4 + 21.0 * jnp.log10(d3d) + 20.0 * jnp.log10(fc)
    pl2 = 32.4 + 40.0 * jnp.log10(d3d) + 20.0 * jnp.log10(fc) - 9.5 * jnp.log10(d_bp**2 + (h_bs - h_ut) ** 2)
    pl_los = jnp.where(d2d <= d_bp, pl1, pl2)
    pl_nlos = jnp.maximum(pl_los, 35.3 * jnp.log10(d3d) + 22.4 + 21.3 * jnp.log10(fc) - 0.3 * (h_ut - 1.5))
    return jnp.where(jnp.asarray(los), pl_los, pl_nlos)


@dataclass(frozen=True)
class LinkBudget:
    """Link budget of the urban study: SNR = P_tx - PL - SF - (N0 + 10 log10 B + NF).

    fc_hz : carrier (the paper's Table I: 3 GHz); bandwidth_hz : 100 MHz (the paper's PRS band);
    noise_psd_dbm_hz : thermal noise density, -174 dBm/Hz; noise_figure_db : UE noise figure, 9 dB (our choice, the
    value TR 38.802 Table A.2.1-1 and TR 38.901 Table 7.8-1 use for a UE below 6 GHz; the paper does not state one).
    """

    fc_hz: float = 3e9
    bandwidth_hz: float = 100e6
    noise_psd_dbm_hz: float = -174.0
    noise_figure_db: float = 9.0

    def __post_init__(self):
        _checks.plain_fields(self)  # NumPy values and ints as the floats they hash as
        _checks.in_range("fc_hz", self.fc_hz, 0.5e9, 100e9, "Hz")
        _checks.in_range("bandwidth_hz", self.bandwidth_hz, 1e6, 1e9, "Hz")
        _checks.in_range("noise_psd_dbm_hz", self.noise_psd_dbm_hz, -200.0, -100.0, "dBm/Hz")
        _checks.in_range("noise_figure_db", self.noise_figure_db, 0.0, 30.0, "dB")

    @property
    def noise_dbm(self) -> float:
        """Noise power in the band: -174 + 80 + 9 = -85 dBm with the defaults."""
        return self.noise_psd_dbm_hz + 10.0 * math.log10(self.bandwidth_hz) + self.noise_figure_db

    def snr_db(self, power_dbm, path_loss_db, shadow_db=0.0) -> jax.Array:
        """In-band SNR in dB: received power over the noise power in ``bandwidth_hz``."""
        return jnp.asarray(power_dbm) - jnp.asarray(path_loss_db) - jnp.asarray(shadow_db) - self.noise_dbm

    def model_snr_db(self, snr_inband_db, num: Numerology = PAPER) -> jax.Array:
        """Convert to the per-sample SNR of ``dpe5g.signal`` (noise over the sampled band N Δf = 122.88 MHz):
        SNR_model = SNR_inband - 10 log10(N Δf / B), i.e. 0.89 dB lower with the defaults."""
        return jnp.asarray(snr_inband_db) - 10.0 * math.log10(num.n_fft * num.scs_hz / self.bandwidth_hz)


def clock_bias(key, sigma_s: float, bound_sigmas: float, shape=()) -> jax.Array:
    """UE clock bias δt in seconds: Gaussian of standard deviation ``sigma_s`` truncated at ± bound_sigmas · sigma_s
    (the paper: σ = 5 ns after the coarse random-access synchronization; the bound is ours, 3 σ by default).
    sigma_s in [0, 1e-6] s (a σ above 1 µs is most likely nanoseconds typed as seconds); bound_sigmas in [0.1, 10]."""
    _checks.values_in_range("sigma_s", sigma_s, 0.0, 1e-6, "s (5 ns is 5e-9)")
    _checks.values_in_range("bound_sigmas", bound_sigmas, 0.1, 10.0, "σ")
    return sigma_s * jax.random.truncated_normal(key, -bound_sigmas, bound_sigmas, shape, dtype=jnp.float64)


@dataclass(frozen=True)
class ExcessDelayRow:
    """One row of TR 38.901 (v19.4) Table 7.6.9-1, the NLoS excess delay of §7.6.9's absolute time of arrival:
    lg(Δτ / 1 s) normal with mean ``mu_lg`` and standard deviation ``sigma_lg`` (decades), drawn independently for the
    links to different BS sites, the same for every cluster of an NLoS link (eq. 7.6-43), none on a LoS link."""

    mu_lg: float
    sigma_lg: float

    @property
    def median_s(self) -> float:
        """The median excess delay 10^mu_lg, s."""
        return 10.0**self.mu_lg

    def quantile_s(self, q: float) -> float:
        """The q-quantile of Δτ (s), q in (0, 1): 10^(mu_lg + sigma_lg · Φ⁻¹(q))."""
        return excess_quantile_s(self.median_s, self.sigma_lg, q)


#: TR 38.901 (v19.4) Table 7.6.9-1, its outdoor rows (unbounded; the indoor rows InH and InF are capped at 2L/c and
#: not modelled here).  UMi street canyon is the row of the paper's scenario (``NLOS_EXCESS_ROW``)
TR38901_EXCESS_DELAY = {"UMi": ExcessDelayRow(-7.5, 0.5), "UMa": ExcessDelayRow(-7.4, 0.2),
                        "RMa": ExcessDelayRow(-8.33, 0.26), "SMa": ExcessDelayRow(-7.702, 0.4)}
NLOS_EXCESS_ROW = "UMi"


def excess_quantile_s(median_s: float, sigma_lg: float, q: float) -> float:
    """The q-quantile (s) of the log-normal excess delay of ``nlos_excess_delay``: median_s · 10^(sigma_lg Φ⁻¹(q)).
    q in (0, 1)."""
    _checks.in_range("q", q, 1e-9, 1 - 1e-9, "(a probability strictly between 0 and 1)")
    return float(median_s * 10.0 ** (sigma_lg * NormalDist().inv_cdf(q)))


def nlos_excess_delay(key, los, median_s: float, sigma_lg: float) -> jax.Array:
    """Excess delay Δτ (s) of each link's paths over the geometric delay: 0 on a LoS link; on an NLoS link
    median_s · 10^(sigma_lg · z), z ~ N(0, 1) per link, i.e. lg Δτ normal with mean lg median_s and standard
    deviation sigma_lg: the log-normal of TR 38.901 §7.6.9 (absolute time of arrival), whose parameters per scenario
    are ``TR38901_EXCESS_DELAY``.  Every path of the link arrives Δτ late; the receivers do not know it.
    los : bool (n,) → (n,) s.  median_s in [0, 1e-6] s (100 ns is 1e-7); sigma_lg in [0, 1]."""
    _checks.values_in_range("median_s", median_s, 0.0, 1e-6, "s (30 ns is 3e-8)")
    _checks.values_in_range("sigma_lg", sigma_lg, 0.0, 1.0, "decades")
    z = jax.random.normal(key, jnp.shape(los), dtype=jnp.float64)
    return jnp.where(los, 0.0, median_s * 10.0 ** (sigma_lg * z))
