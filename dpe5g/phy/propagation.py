"""The urban propagation models of Section III: UMi street-canyon links (LoS probability of eq. (11), TR 38.901 path
loss, shadow fading), the link budget, and the UE clock bias.  The deployment they act on (base stations, region,
file format) is ``dpe5g.phy.deployment``.

Units: metres, dB / dBm, seconds, Hz.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from . import nr
from .nr import C, PAPER, Numerology

#: TR 38.901 Table 7.4.1-1 shadow-fading standard deviations, UMi street canyon, dB
SIGMA_SF_LOS_DB = 4.0
SIGMA_SF_NLOS_DB = 7.82
#: effective environment height h_E for the UMi breakpoint distance, m
H_E_M = 1.0
#: the largest 2-D distance the models accept, m (TR 38.901 states UMi for d2D up to 5 km)
MAX_D2D_M = 1e5


def los_probability(d2d_m) -> jax.Array:
    """LoS probability of eq. (11) (TR 38.901 Table 7.4.2-1, UMi street canyon).

    Pr_LoS = 1 for D ≤ 18 m, else 18/D + (1 - 18/D) e^{-D/36}.

    Parameters
    ----------
    d2d_m : float (...)
        2-D BS–UE distance D in metres, finite, in [0, ``MAX_D2D_M``].

    Returns
    -------
    jax.Array float (...)
        The probability.

    Raises
    ------
    ValueError
        ``d2d_m`` not finite or outside its range.
    """
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

    Parameters
    ----------
    d2d_m : float (...)
        2-D BS–UE distance in metres, in [0, ``MAX_D2D_M``].
    h_bs_m : float
        BS height in metres, in [1.5, 150] (broadcast against ``d2d_m``).
    h_ut_m : float
        UE height in metres, in [1, 22.5] (the table's UT heights; broadcast).
    fc_hz : float
        Carrier frequency in Hz, in [0.5e9, 100e9] (the table's validity).
    los : bool (...)
        True for a LoS link.

    Returns
    -------
    jax.Array float (...)
        Path loss, dB.

    Raises
    ------
    ValueError
        An argument outside its range.
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

    Attributes
    ----------
    fc_hz : float
        Carrier frequency, Hz, in [0.5e9, 100e9] (the paper's Table I: 3 GHz).
    bandwidth_hz : float
        Noise bandwidth B, Hz, in [1e6, 1e9] (100 MHz, the paper's PRS band).
    noise_psd_dbm_hz : float
        Thermal noise density N0, dBm/Hz, in [-200, -100] (-174 dBm/Hz).
    noise_figure_db : float
        UE noise figure NF, dB, in [0, 30]: 9 dB, our choice, the value TR 38.802 Table A.2.1-1 and TR 38.901
        Table 7.8-1 use for a UE below 6 GHz (the paper does not state one).

    Raises
    ------
    ValueError
        A field outside its range.
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
        """Noise power in the band, dBm (-174 + 80 + 9 = -85 dBm with the defaults)."""
        return self.noise_psd_dbm_hz + 10.0 * math.log10(self.bandwidth_hz) + self.noise_figure_db

    def snr_db(self, power_dbm, path_loss_db, shadow_db=0.0) -> jax.Array:
        """In-band SNR in dB: received power over the noise power in ``bandwidth_hz``.

        Parameters
        ----------
        power_dbm : float (...)
            Transmit power, dBm.
        path_loss_db, shadow_db : float (...)
            Path loss and shadow fading, dB (shadow fading 0 by default); all three broadcast.

        Returns
        -------
        jax.Array float (...)
            SNR over the band, dB.
        """
        return jnp.asarray(power_dbm) - jnp.asarray(path_loss_db) - jnp.asarray(shadow_db) - self.noise_dbm

    def model_snr_db(self, snr_inband_db, num: Numerology = PAPER) -> jax.Array:
        """Convert to the per-sample SNR of ``dpe5g.phy.signal`` (noise over the sampled band N Δf = 122.88 MHz).

        SNR_model = SNR_inband - 10 log10(N Δf / B), i.e. 0.89 dB lower with the defaults.

        Parameters
        ----------
        snr_inband_db : float (...)
            SNR over ``bandwidth_hz``, dB (``snr_db``).
        num : Numerology
            The numerology of the sampled band (``nr.PAPER`` by default).

        Returns
        -------
        jax.Array float (...)
            SNR_model, dB.
        """
        return jnp.asarray(snr_inband_db) - 10.0 * math.log10(num.n_fft * num.scs_hz / self.bandwidth_hz)


def clock_bias(key, sigma_s: float, bound_sigmas: float, shape=()) -> jax.Array:
    """UE clock bias δt: Gaussian of standard deviation ``sigma_s`` truncated at ± ``bound_sigmas`` · ``sigma_s``.

    Parameters
    ----------
    key : jax PRNG key
        The random key.
    sigma_s : float
        σ in seconds, in [0, 1e-6] (a σ above 1 µs is most likely nanoseconds typed as seconds); the paper: σ = 5 ns
        after the coarse random-access synchronization.
    bound_sigmas : float
        The truncation in units of σ, in [0.1, 10]; the bound is ours, 3 σ by default.
    shape : tuple of int
        Shape of the draw (scalar by default).

    Returns
    -------
    jax.Array float (shape)
        δt, seconds.

    Raises
    ------
    ValueError
        ``sigma_s`` or ``bound_sigmas`` outside its range.
    """
    _checks.values_in_range("sigma_s", sigma_s, 0.0, 1e-6, "s (5 ns is 5e-9)")
    _checks.values_in_range("bound_sigmas", bound_sigmas, 0.1, 10.0, "σ")
    return sigma_s * jax.random.truncated_normal(key, -bound_sigmas, bound_sigmas, shape, dtype=jnp.float64)


@dataclass(frozen=True)
class ExcessDelayRow:
    """One row of TR 38.901 (v19.4) Table 7.6.9-1, the NLoS excess delay of §7.6.9's absolute time of arrival.

    lg(Δτ / 1 s) is normal, drawn independently for the links to different BS sites, the same for every cluster of
    an NLoS link (eq. 7.6-43), none on a LoS link.

    Attributes
    ----------
    mu_lg : float
        Mean of lg(Δτ / 1 s), decades.
    sigma_lg : float
        Standard deviation of lg(Δτ / 1 s), decades.
    """

    mu_lg: float
    sigma_lg: float

    @property
    def median_s(self) -> float:
        """The median excess delay 10^mu_lg, s."""
        return 10.0**self.mu_lg

    def quantile_s(self, q: float) -> float:
        """The q-quantile of Δτ, 10^(mu_lg + sigma_lg · Φ⁻¹(q)).

        Parameters
        ----------
        q : float
            The probability, in (0, 1).

        Returns
        -------
        float
            The quantile, seconds.
        """
        return excess_quantile_s(self.median_s, self.sigma_lg, q)


#: TR 38.901 (v19.4) Table 7.6.9-1, its outdoor rows (unbounded; the indoor rows InH and InF are capped at 2L/c and
#: not modelled here).  UMi street canyon is the row of the paper's scenario (``NLOS_EXCESS_ROW``)
TR38901_EXCESS_DELAY = {"UMi": ExcessDelayRow(-7.5, 0.5), "UMa": ExcessDelayRow(-7.4, 0.2),
                        "RMa": ExcessDelayRow(-8.33, 0.26), "SMa": ExcessDelayRow(-7.702, 0.4)}
NLOS_EXCESS_ROW = "UMi"


def excess_quantile_s(median_s: float, sigma_lg: float, q: float) -> float:
    """The q-quantile of the log-normal excess delay of ``nlos_excess_delay``: median_s · 10^(sigma_lg Φ⁻¹(q)).

    Parameters
    ----------
    median_s : float
        Median excess delay, seconds.
    sigma_lg : float
        Standard deviation of lg Δτ, decades.
    q : float
        The probability, strictly between 0 and 1.

    Returns
    -------
    float
        The quantile, seconds.

    Raises
    ------
    ValueError
        ``q`` not strictly between 0 and 1.
    """
    _checks.in_range("q", q, 1e-9, 1 - 1e-9, "(a probability strictly between 0 and 1)")
    return float(median_s * 10.0 ** (sigma_lg * NormalDist().inv_cdf(q)))


def nlos_excess_delay(key, los, median_s: float, sigma_lg: float) -> jax.Array:
    """Excess delay Δτ of each link's paths over the geometric delay: 0 on a LoS link, log-normal on an NLoS one.

    On an NLoS link Δτ = median_s · 10^(sigma_lg · z), z ~ N(0, 1) per link, i.e. lg Δτ normal with mean
    lg median_s and standard deviation sigma_lg: the log-normal of TR 38.901 §7.6.9 (absolute time of arrival),
    whose parameters per scenario are ``TR38901_EXCESS_DELAY``.  Every path of the link arrives Δτ late; the
    receivers do not know it.

    Parameters
    ----------
    key : jax PRNG key
        The random key.
    los : bool (n,)
        True for a LoS link.
    median_s : float
        Median excess delay, seconds, in [0, 1e-6] (100 ns is 1e-7).
    sigma_lg : float
        Standard deviation of lg Δτ, decades, in [0, 1].

    Returns
    -------
    jax.Array float (n,)
        Δτ, seconds.

    Raises
    ------
    ValueError
        ``median_s`` or ``sigma_lg`` outside its range.
    """
    _checks.values_in_range("median_s", median_s, 0.0, 1e-6, "s (30 ns is 3e-8)")
    _checks.values_in_range("sigma_lg", sigma_lg, 0.0, 1.0, "decades")
    z = jax.random.normal(key, jnp.shape(los), dtype=jnp.float64)
    return jnp.where(los, 0.0, median_s * 10.0 ** (sigma_lg * z))


# ---- the PRS frequency reuse plan of a deployment --------------------------------------------------------------

#: PRS sequence IDs n_ID^PRS per resource, 0 … 4095 (TS 38.211 §7.4.1.7.2)
N_PRS_IDS = 4096


def prs_plan(bs_xyz, reuse: int) -> tuple[np.ndarray, np.ndarray]:
    """PRS frequency reuse: each BS gets one of ``reuse`` orthogonal resources and a PRS ID.

    The resources are the comb offsets 0 … reuse − 1 of a comb of size ``reuse`` (``nr.PrsPattern(reuse)``): in the
    fully staggered pattern every offset still covers the whole band, so each link keeps the paper's resolution, and
    the offsets never share an RE.  The assignment colours the BS graph greedily, in the order of the deployment: each
    BS takes the resource whose nearest BS already holding it is farthest away (ties: the lowest resource), so the
    first ``reuse`` BSs take distinct resources and near neighbours differ.  Its PRS ID n_ID is its rank among the
    BSs of its resource (0, 1, …), so co-channel BSs carry different sequences.  Deterministic: a function of the BS
    positions and their order.

    Parameters
    ----------
    bs_xyz : float (B, 3)
        Base-station positions, metres.
    reuse : int
        Number of resources, one of ``nr.PRS_COMB_SIZES``.

    Returns
    -------
    resource : numpy.ndarray int (B,)
        Each BS's resource, 0 … reuse − 1.
    prs_id : numpy.ndarray int (B,)
        Each BS's PRS ID n_ID.

    Raises
    ------
    ValueError
        ``reuse`` not a comb size, or more BSs than reuse × ``N_PRS_IDS``.
    """

    _checks.one_of("reuse", reuse, nr.PRS_COMB_SIZES)
    xy = np.asarray(bs_xyz, dtype=np.float64)[:, :2]
    n_bs = xy.shape[0]
    if n_bs > reuse * N_PRS_IDS:
        raise ValueError(f"n_bs must be at most reuse × PRS IDs = {reuse} × {N_PRS_IDS} = {reuse * N_PRS_IDS} for "
                         f"reuse {reuse}, got {n_bs} base stations")
    res = np.zeros(n_bs, dtype=int)
    nearest = np.full((n_bs, reuse), np.inf)  # nearest[b, r]: distance from b to the closest BS on resource r so far
    for b in range(n_bs):
        score = np.where(np.bincount(res[:b], minlength=reuse) < N_PRS_IDS, nearest[b], -np.inf)
        res[b] = int(np.argmax(score))
        nearest[:, res[b]] = np.minimum(nearest[:, res[b]], np.linalg.norm(xy - xy[b], axis=-1))
    ids = np.array([np.count_nonzero(res[:b] == res[b]) for b in range(n_bs)], dtype=int)
    return res, ids
