"""The traced channel source: one trial's draws (``TrialDraw``) from a ray-traced city's paths (``city_paths``),
beside the TDL source of ``draw``; ``draw.draw_fn`` picks one by ``Scenario.channel``.

Trial t is the t-th UE of the population: the traced UEs that hear at least max(m_values) BSs, in the order they
were drawn.  A UE hears a BS when the link's per-sample SNR from the link budget (the BS's power, the traced path
gain, ``Links.budget``) is at least ``DETECTION_SNR_DB``, as a UE detects a PRS by its own measurement.  Its links are
the max(m_values) BSs it hears strongest (what its RSRP ranks, strongest first; every M reads the strongest M).  LoS is the geometry's: whether the straight line is clear.  Each
link's kept paths (excess delays after d/c, complex amplitudes) replace the TDL taps in the same signal model
(``channel.frequency_response``, ``signal.received_spectrum``), normalised to unit power as the TDL taps are; its
received power is the BS's transmit power plus the traced path gain (snr_mode "link_budget"), or every link is at
each SNR (snr_mode "fixed").  The clock bias and the noise come from the trial's key, as in the TDL source.

Units: metres, seconds, dB.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..phy import channel, deployment, nr, propagation, signal
from ..receivers import cost
from ..city import dataset as city_paths
from .experiment import Experiment
from .trial_draw import TrialDraw, link_snr_db, sinr_db

#: the per-sample SNR (dB) at which a UE hears a BS: ours, not the paper's or a standard's.  Correlated over the
#: PRS's N = 4096 bins it is 36 dB higher (23 dB), where a PRS is detected without doubt; the traced links below it
#: (most of them: multi-bounce paths 130 dB and more below the transmit power) are left out, as a UE would
DETECTION_SNR_DB = -13.0


@dataclass(frozen=True)
class TracedLinks:
    """The population of a traced city that hears at least I BSs, and each UE's I strongest links.

    Attributes
    ----------
    ue_index : int (T,)
        The UEs (indices into the city's), in the order traced.
    bs_index : int (T, I)
        Their BSs, strongest first.
    los : bool (T, I)
        The links' geometric LoS states.
    power_db : float (T, I)
        The links' traced path gains, dB.
    excess_s : float (T, I, K)
        The kept paths' delays after d/c, seconds.
    gains : complex (T, I, K)
        The kept paths' amplitudes, scaled to unit power per link.
    """

    ue_index: np.ndarray
    bs_index: np.ndarray
    los: np.ndarray
    power_db: np.ndarray
    excess_s: np.ndarray
    gains: np.ndarray


def traced_links(city: city_paths.TracedCity, n_links: int, heard) -> TracedLinks:
    """The UEs of ``city`` that hear at least ``n_links`` BSs, with their ``n_links`` strongest links.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    n_links : int
        I, the links per UE (max(m_values)).
    heard : bool (L,)
        Which of the city's links the UE hears (``heard_links``).

    Returns
    -------
    TracedLinks
    """
    table = np.where(heard[city.link_table()] & (city.link_table() >= 0), city.link_table(), -1)
    ues = np.nonzero((table >= 0).sum(axis=1) >= n_links)[0]
    power = np.where(table[ues] >= 0, city.power_db[table[ues]], -np.inf)
    bs = np.argsort(-power, axis=1, kind="stable")[:, :n_links]
    k = np.take_along_axis(table[ues], bs, 1)  # (T, I) link indices, all heard
    g = city.gains[k].astype(np.complex128)
    g = g / np.sqrt((np.abs(g) ** 2).sum(axis=-1, keepdims=True))
    return TracedLinks(ue_index=ues, bs_index=bs, los=city.los[k], power_db=city.power_db[k].astype(float),
                       excess_s=city.excess_s[k].astype(float), gains=g)


def heard_links(e: Experiment, city: city_paths.TracedCity, dep: deployment.Deployment) -> np.ndarray:
    """Which links a UE hears: their per-sample SNR from the link budget at least ``DETECTION_SNR_DB``.

    Parameters
    ----------
    e : Experiment
        The experiment (its ``Links.budget`` and ``snr_convention``).
    city : city_paths.TracedCity
        The traced city.
    dep : deployment.Deployment
        Its deployment (the BSs' powers).

    Returns
    -------
    bool (L,)
    """
    rx = np.asarray(dep.power_dbm)[city.link_bs] + city.power_db.astype(float)
    snr = e.links.budget.model_snr_db(rx - e.links.budget.noise_dbm)
    return np.asarray(signal.per_sample_snr_db(snr, e.links.snr_convention)) >= DETECTION_SNR_DB


def population(e: Experiment) -> tuple[city_paths.TracedCity, TracedLinks]:
    """The traced city of ``e`` (its deployment: a name or a city's deployment file, ``city_paths.city_at``) and its
    population for ``max(m_values)`` links.

    Parameters
    ----------
    e : Experiment
        An experiment with ``Scenario.channel`` "traced".

    Returns
    -------
    city : city_paths.TracedCity
    links : TracedLinks

    Raises
    ------
    ValueError
        When the experiment asks for more trials than the population has UEs.
    """
    city = city_paths.load_city(*city_paths.city_at(e.scenario.deployment))
    links = traced_links(city, max(e.receiver.m_values), heard_links(e, city, e.load_deployment()))
    if e.run.n_trials > len(links.ue_index):
        raise ValueError(f"n_trials must be at most {len(links.ue_index)} on the traced city "
                         f"'{e.scenario.deployment}' with M = {max(e.receiver.m_values)} (the UEs that hear "
                         f"{max(e.receiver.m_values)} BSs at {DETECTION_SNR_DB:g} dB), got {e.run.n_trials}")
    return city, links


def draw_fn(e: Experiment, dep: deployment.Deployment):
    """Build the traceable (trial key, trial index t) → ``TrialDraw`` of the traced city's UE t.

    Parameters
    ----------
    e : Experiment
        An experiment with ``Scenario.channel`` "traced".
    dep : deployment.Deployment
        Its deployment (the city's BSs and their powers).

    Returns
    -------
    callable
        (key, t) → ``TrialDraw``.
    """
    city, links = population(e)
    ue_all = jnp.asarray(city.ue_xyz[links.ue_index])
    bs_idx, los_all = jnp.asarray(links.bs_index), jnp.asarray(links.los)
    gains_all, excess_all = jnp.asarray(links.gains), jnp.asarray(links.excess_s)
    rx_all = jnp.asarray(np.asarray(dep.power_dbm)[links.bs_index] + links.power_db)  # (T, I) dBm
    bs_xyz, prs_all = jnp.asarray(dep.bs_xyz), jnp.asarray(nr.prs_matrix(range(dep.n_bs)))
    snrs = jnp.asarray(e.links.snrs_db if e.links.snr_mode != "link_budget" else (0.0,), dtype=jnp.float64)
    m_max = bs_idx.shape[1]

    def draw(key, t):
        k_b, k_n = jax.random.split(key)
        ue, idx = ue_all[t], bs_idx[t]
        bs, prs = bs_xyz[idx], prs_all[idx]
        bias = propagation.clock_bias(k_b, e.scenario.clock_sigma_s, e.scenario.clock_bound_sigmas)
        h = channel.frequency_response(gains_all[t], excess_all[t])  # (I, N), eq. (5) with the traced paths
        y_clean = signal.received_spectrum(prs, h, cost.toa(ue, bs), bias)
        if e.links.snr_mode == "fixed":
            snr = signal.per_sample_snr_db(jnp.broadcast_to(snrs[:, None], (snrs.size, m_max)),
                                           e.links.snr_convention)
        else:
            snr = link_snr_db(e, rx_all[t], rx_all[t, 0], snrs)
        noise = signal.awgn(k_n, y_clean.shape, 1.0)
        return TrialDraw(ue_xyz=ue, clock_bias_s=bias, bs_index=idx, bs_xyz=bs, los=los_all[t], prs=prs,
                         gains=gains_all[t], delays_s=excess_all[t], y0=y_clean, link_snr_db=snr,
                         link_sinr_db=sinr_db(snr, None), noise=noise, reuse=None,
                         per_link_power=e.links.snr_mode != "fixed")

    return draw
