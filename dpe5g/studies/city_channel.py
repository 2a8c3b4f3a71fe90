"""The traced links' large-scale parameters against TR 38.901's UMi-Street Canyon (Table 7.5-6 Part-1): each link's
RMS delay spread and, on a LoS link, its Ricean K-factor, summarised over a population of links.

A traced link (``city_paths.TracedCity``) keeps K paths (``city.spec["n_paths"]``: the first to arrive and the
strongest others), their delays τ_k after d/c and their amplitudes a_k.  Over those kept paths, with P_k the power
of path k (a_k's squared magnitude)::

    DS = sqrt(Σ_k P_k τ_k² / Σ_k P_k − (Σ_k P_k τ_k / Σ_k P_k)²),        K = P_0 / Σ_{k ≥ 1} P_k   (LoS links),

the first the power-weighted second central moment TR 38.901 calibrates (its §7.8; ``channel.rms_delay_spread`` for
one profile), the second the LoS path's power (the first kept path, at τ = 0, on a LoS link) over the rest.  Both are
of the kept paths, the channel a trial's signal carries (``traced_draw``): the paths dropped beyond K hold at most
1.6 dB of a link's power in the Munich trace (``TracedCity.kept_db``), and a link with one path has DS = 0.

TR 38.901 draws lg(DS / 1 s) normal and K (dB) normal per link; its UMi-Street Canyon rows (Table 7.5-6 Part-1),
fc in GHz, the frequency-dependent entries evaluated at fc = 2 GHz below 2 GHz (the table's note for UMi)::

    LoS:  μ_lgDS = −0.24 lg(1 + fc) − 7.14,  σ_lgDS = 0.38;          μ_K = 9 dB, σ_K = 5 dB;
    NLoS: μ_lgDS = −0.24 lg(1 + fc) − 6.83,  σ_lgDS = 0.16 lg(1 + fc) + 0.28.

The numbers are those of independent transcriptions of the table, which agree: ns-3's
``ThreeGppChannelModel::GetThreeGppTable`` ("UMi-StreetCanyon", LoS and NLoS), Sionna's
``tr38901/models/UMi_LoS.json`` and QuaDRiGa's ``3GPP_38.901_UMi_LOS.conf`` (LoS); the 2 GHz floor is Sionna's
``UMiScenario.clip_carrier_frequency_lsp`` (ns-3 does not apply it; at the city's 3 GHz it does not matter).
Units: seconds, dB, GHz where named.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common import _checks
from ..phy import propagation, signal
from ..city import dataset as city_paths
from ..simulation import traced_draw
from . import city as city_study

#: TR 38.901 Table 7.5-6 Part-1, UMi-Street Canyon: lg DS = a lg(1 + fc) + b (fc in GHz), LoS and NLoS
UMI_LGDS_LOS = (-0.24, -7.14)
UMI_LGDS_NLOS = (-0.24, -6.83)
#: its σ_lgDS: 0.38 on LoS links; on NLoS links 0.16 lg(1 + fc) + 0.28
UMI_LGDS_SIGMA_LOS = 0.38
UMI_LGDS_SIGMA_NLOS = (0.16, 0.28)
#: its LoS K-factor, dB: mean and standard deviation
UMI_K_DB = (9.0, 5.0)
#: the table's note for UMi: below 2 GHz the frequency-dependent entries take fc = 2 GHz
UMI_MIN_FC_GHZ = 2.0


@dataclass(frozen=True)
class UmiLsp:
    """TR 38.901 Table 7.5-6 Part-1's UMi-Street Canyon delay spread and K-factor at one carrier (``umi_lsp``).

    Attributes
    ----------
    fc_ghz : float
        The carrier the entries are evaluated at, GHz (at least ``UMI_MIN_FC_GHZ``).
    lgds_mu_los, lgds_sigma_los : float
        Mean and standard deviation of lg(DS / 1 s) on LoS links, decades.
    lgds_mu_nlos, lgds_sigma_nlos : float
        The same on NLoS links.
    k_mu_db, k_sigma_db : float
        Mean and standard deviation of the LoS K-factor, dB.
    """

    fc_ghz: float
    lgds_mu_los: float
    lgds_sigma_los: float
    lgds_mu_nlos: float
    lgds_sigma_nlos: float
    k_mu_db: float
    k_sigma_db: float


def umi_lsp(fc_hz: float) -> UmiLsp:
    """TR 38.901 Table 7.5-6 Part-1's UMi-Street Canyon lg DS and K-factor at the carrier fc (module docstring).

    Parameters
    ----------
    fc_hz : float
        The carrier, Hz, in the table's range 0.5 to 100 GHz (the city's ``city.spec["fc_hz"]``).

    Returns
    -------
    UmiLsp

    Raises
    ------
    ValueError
        When fc_hz is not a number in [0.5e9, 100e9] Hz.
    """
    fc = max(_checks.in_range("fc_hz", fc_hz, 0.5e9, 100e9, "Hz") / 1e9, UMI_MIN_FC_GHZ)
    lg = math.log10(1.0 + fc)
    return UmiLsp(fc_ghz=fc, lgds_mu_los=UMI_LGDS_LOS[0] * lg + UMI_LGDS_LOS[1], lgds_sigma_los=UMI_LGDS_SIGMA_LOS,
                  lgds_mu_nlos=UMI_LGDS_NLOS[0] * lg + UMI_LGDS_NLOS[1],
                  lgds_sigma_nlos=UMI_LGDS_SIGMA_NLOS[0] * lg + UMI_LGDS_SIGMA_NLOS[1], k_mu_db=UMI_K_DB[0],
                  k_sigma_db=UMI_K_DB[1])


def _powers(gains, excess_s=None) -> np.ndarray:
    """|a|² (L, K) of ``gains``, checked: 2-D, finite, every link with power, the shape of ``excess_s`` if given."""
    g = np.asarray(gains)
    if g.ndim != 2 or g.shape[1] < 1 or not np.all(np.isfinite(g)):
        raise ValueError(f"gains must be finite complex amplitudes of shape (L, K), got shape {g.shape}")
    if excess_s is not None and np.shape(excess_s) != g.shape:
        raise ValueError(f"excess_s must have the shape of gains {g.shape}, got {np.shape(excess_s)}")
    p = np.abs(g.astype(np.complex128)) ** 2
    if np.any(p.sum(axis=1) <= 0):
        raise ValueError(f"gains must give every link some power: links {np.nonzero(p.sum(axis=1) <= 0)[0][:5]} "
                         "have none")
    return p


def delay_spread_s(excess_s, gains) -> np.ndarray:
    """Each link's RMS delay spread over its kept paths, DS of the module docstring (TR 38.901's, its §7.8).

    Parameters
    ----------
    excess_s : float (L, K)
        The paths' delays, seconds (after d/c: DS does not depend on a common shift), finite.
    gains : complex (L, K)
        Their amplitudes a_k (0 for a missing path), each link with some power.

    Returns
    -------
    float (L,)
        DS, seconds (0 on a link with one path).

    Raises
    ------
    ValueError
        When the shapes differ or are not (L, K), a delay or amplitude is not finite, or a link has no power.
    """
    p = _powers(gains, excess_s)
    t = np.asarray(excess_s, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise ValueError("excess_s must be finite delays, seconds")
    w = p / p.sum(axis=1, keepdims=True)
    mean = np.sum(w * t, axis=1)
    return np.sqrt(np.maximum(np.sum(w * (t - mean[:, None]) ** 2, axis=1), 0.0))


def k_factor_db(gains, los) -> np.ndarray:
    """Each LoS link's Ricean K-factor over its kept paths, 10 lg(P_0 / Σ_{k ≥ 1} P_k) (module docstring).

    The LoS path is the first kept path of a LoS link (the earliest, at τ = 0 after d/c).

    Parameters
    ----------
    gains : complex (L, K)
        The paths' amplitudes in order of arrival (0 for a missing path), each link with some power.
    los : bool (L,)
        Whether each link is LoS.

    Returns
    -------
    float (L,)
        K, dB; NaN on NLoS links, +inf on a LoS link with no other path.

    Raises
    ------
    ValueError
        When gains is not (L, K) finite with power on every link, or los is not L booleans.
    """
    p = _powers(gains)
    los = np.asarray(los)
    if los.dtype != bool or los.shape != p.shape[:1]:
        raise ValueError(f"los must be a bool array of shape ({p.shape[0]},), one per link, got {los.dtype} "
                         f"{los.shape}")
    rest = p[:, 1:].sum(axis=1)
    with np.errstate(divide="ignore"):
        k = 10.0 * np.log10(p[:, 0]) - 10.0 * np.log10(rest)
    return np.where(los, k, np.nan)


@dataclass(frozen=True)
class Spread:
    """Median, mean and standard deviation of a per-link quantity over a population's finite values.

    Attributes
    ----------
    n : int
        The links counted (finite values).
    n_left_out : int
        The links of the population left out: lg DS of a one-path link (DS = 0), K of a LoS link with one path.
    median, mean, std : float
        Over the n values (NaN when n is 0), in the quantity's unit: decades for lg DS, dB for K.
    """

    n: int
    n_left_out: int
    median: float
    mean: float
    std: float


def spread(values) -> Spread:
    """``Spread`` of ``values``'s finite entries.

    Parameters
    ----------
    values : float (n,)
        The values, ±inf or NaN where a link is left out.

    Returns
    -------
    Spread
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    ok = v[np.isfinite(v)]
    if ok.size == 0:
        return Spread(0, int(v.size), math.nan, math.nan, math.nan)
    return Spread(int(ok.size), int(v.size - ok.size), float(np.median(ok)), float(ok.mean()), float(ok.std()))


@dataclass(frozen=True)
class LspSummary:
    """A population of traced links' delay spread and K-factor beside TR 38.901's UMi-Street Canyon (``lsp_summary``).

    Attributes
    ----------
    n_links : int
        The links of the population (LoS and NLoS).
    lgds_los, lgds_nlos : Spread
        lg(DS / 1 s) over its LoS and its NLoS links, decades (a one-path link, DS = 0, left out).
    k_db : Spread
        The K-factor over its LoS links, dB.
    umi : UmiLsp
        TR 38.901's values at the city's carrier.
    """

    n_links: int
    lgds_los: Spread
    lgds_nlos: Spread
    k_db: Spread
    umi: UmiLsp


def lsp_summary(city: city_paths.TracedCity, links=None) -> LspSummary:
    """The delay spread (``delay_spread_s``) and LoS K-factor (``k_factor_db``) of ``city``'s links ``links``,
    beside TR 38.901 Table 7.5-6 Part-1's UMi-Street Canyon at the city's carrier (``umi_lsp``).

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    links : bool (L,), int (n,) or None
        The population: a mask or link indices (``city_study.link_mask``); None: every traced link.

    Returns
    -------
    LspSummary

    Raises
    ------
    ValueError
        When ``links`` is not a mask or indices of the city's links.
    """

    m = city_study.link_mask(city, links)
    ds = delay_spread_s(city.excess_s[m], city.gains[m])
    los = city.los[m]
    with np.errstate(divide="ignore"):
        lg = np.log10(ds)
    return LspSummary(n_links=int(m.sum()), lgds_los=spread(lg[los]), lgds_nlos=spread(lg[~los]),
                      k_db=spread(k_factor_db(city.gains[m], los)[los]), umi=umi_lsp(city.spec["fc_hz"]))


def population_lsps(city: city_paths.TracedCity, e, res) -> dict:
    """``lsp_summary`` on each of the city's link populations (``city_study.link_populations``).

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    e : Experiment
        A city experiment (``city_study.city_fig10``).
    res : results.Results
        Its run (``engine.run(e)``).

    Returns
    -------
    dict
        {"all", "heard", "trial": LspSummary}.

    Raises
    ------
    ValueError
        When ``res`` is not a run of ``e`` on the city (``city_study.link_populations``).
    """

    return {name: lsp_summary(city, mask) for name, mask in city_study.link_populations(city, e, res).items()}


@dataclass(frozen=True)
class Hearability:
    """Who hears whom, by distance, in the traced city and under TR 38.901's UMi path loss (``hearability``).

    Attributes
    ----------
    edges_m : float (n + 1,)
        The 2-D distance bins, metres.
    n_pairs : int (2, n)
        (UE, BS) pairs per bin, [0] LoS (a traced straight line), [1] NLoS (every other pair, with a path or not).
    traced : float (2, n)
        The share of those pairs heard in the traced city (``city_draw.heard_links``).
    umi : float (2, n)
        The probability that a pair at those distances is heard under TR 38.901 Table 7.4.1-1's UMi-Street Canyon path
        loss with its log-normal shadow fading (σ 4 dB LoS, 7.82 dB NLoS), the same link budget and threshold, averaged
        over the bin's pairs.
    gain_db : float (2, n)
        The traced path gain of the bin's pairs with a path, median, dB (NaN where none).
    umi_gain_db : float (2, n)
        −PL of TR 38.901's model at the bin's median distance, dB.
    """

    edges_m: np.ndarray
    n_pairs: np.ndarray
    traced: np.ndarray
    umi: np.ndarray
    gain_db: np.ndarray
    umi_gain_db: np.ndarray


def hearability(city: city_paths.TracedCity, e, dep, edges_m) -> Hearability:
    """The share of (UE, BS) pairs a UE hears by 2-D distance, LoS and NLoS, traced against TR 38.901 UMi's.

    A pair is heard when its per-sample SNR from the link budget reaches ``city_draw.DETECTION_SNR_DB``
    (``city_draw.heard_links``); under the standard's model its received power is P − PL(d) − SF with SF normal of
    σ ``scenario.SIGMA_SF_LOS_DB`` or ``SIGMA_SF_NLOS_DB``, so a pair is heard with probability Φ((P − PL − P*) / σ),
    P* the least received power heard.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    e : Experiment
        A city experiment: its link budget.
    dep : deployment.Deployment
        The city's deployment: the BSs' powers, dBm.
    edges_m : float (n + 1,)
        Distance bins, metres, increasing.

    Returns
    -------
    Hearability
    """
    from scipy import stats  # (scipy.stats: 0.8 s to import, only for the fits)


    edges = np.asarray(edges_m, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"edges_m must be at least two increasing distances, got {edges_m!r}")
    b = e.links.budget
    rx = np.linspace(-200.0, 0.0, 200_001)  # the least received power heard, dBm, on a 1 mdB grid
    snr = np.asarray(signal.per_sample_snr_db(b.model_snr_db(rx - b.noise_dbm), e.links.snr_convention))
    p_min = rx[np.argmax(snr >= traced_draw.DETECTION_SNR_DB)]
    d = np.linalg.norm(city.ue_xyz[:, None, :2] - city.bs_xyz[None, :, :2], axis=-1)  # (U, B)
    los = np.zeros(d.shape, bool)
    los[city.link_ue, city.link_bs] = city.los
    heard, gain = np.zeros(d.shape, bool), np.full(d.shape, np.nan)
    heard[city.link_ue, city.link_bs] = traced_draw.heard_links(e, city, dep)
    gain[city.link_ue, city.link_bs] = city.power_db
    power = np.broadcast_to(np.asarray(dep.power_dbm, dtype=float)[None, :], d.shape)
    n = len(edges) - 1
    out = {k: np.full((2, n), np.nan) for k in ("traced", "umi", "gain_db", "umi_gain_db")}
    n_pairs = np.zeros((2, n), int)
    for i, is_los in enumerate((True, False)):
        sigma = propagation.SIGMA_SF_LOS_DB if is_los else propagation.SIGMA_SF_NLOS_DB
        for k in range(n):
            sel = (los == is_los) & (d >= edges[k]) & (d < edges[k + 1])
            n_pairs[i, k] = sel.sum()
            if not sel.any():
                continue
            pl = np.asarray(propagation.path_loss_umi_db(d[sel], city.spec["bs_height_m"], city.spec["ue_height_m"],
                                                      b.fc_hz, is_los))
            out["traced"][i, k] = heard[sel].mean()
            out["umi"][i, k] = stats.norm.cdf((power[sel] - pl - p_min) / sigma).mean()
            g = gain[sel][np.isfinite(gain[sel])]
            out["gain_db"][i, k] = np.median(g) if g.size else np.nan
            out["umi_gain_db"][i, k] = -float(np.asarray(propagation.path_loss_umi_db(
                np.median(d[sel]), city.spec["bs_height_m"], city.spec["ue_height_m"], b.fc_hz, is_los)))
    return Hearability(edges_m=edges, n_pairs=n_pairs, **out)
