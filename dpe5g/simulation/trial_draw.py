"""What one trial's draws are, whatever the channel source: the typed draw (``TrialDraw``), its PRS-reuse parts, the
trial's key, and the links' SNR and SINR from their received powers.

The sources that fill a ``TrialDraw`` are ``draw`` (the TDL model of Section IV, and the entry point ``draw.draw_fn``)
and ``city_draw`` (a ray-traced city's paths).  Every draw of trial t comes from ``trial_key(seed, t)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from ..phy import signal
from .experiment import Experiment


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CoChannelDraw:
    """With PRS reuse and ``co_channel``: every other BS of the deployment (X of them, nearest first).

    Each transmits on its resource too.

    Attributes
    ----------
    res : int (X,)
        Resource index.
    prs : complex (X, N)
        Pilots.
    y0 : complex (X, N)
        Noise-free received spectra (unit power).
    snr_db : float (S, X)
        Per-sample SNR at each SNR index, dB.
    """

    res: jax.Array
    prs: jax.Array
    y0: jax.Array
    snr_db: jax.Array


@dataclass(frozen=True)
class ReuseDraw:
    """With PRS reuse (``Experiment.prs_reuse`` = n_res > 0): every link's resource and the other BSs.

    Attributes
    ----------
    res : int (I,)
        The resource (comb offset) of every link.
    co_channel : CoChannelDraw or None
        The other BSs; None without ``co_channel``.
    n_res : int
        The number of resources (static).
    """

    res: jax.Array
    co_channel: CoChannelDraw | None
    n_res: int


jax.tree_util.register_dataclass(ReuseDraw, data_fields=["res", "co_channel"], meta_fields=["n_res"])


@dataclass(frozen=True)
class TrialDraw:
    """The draws of one trial (``draw_fn``), arrays over the I = max(m_values) nearest links, nearest first.

    Attributes
    ----------
    ue_xyz : float (3,)
        The UE position, metres.
    clock_bias_s : float ()
        The clock bias δt, seconds.
    bs_index : int (I,)
        The BSs' deployment indices.
    bs_xyz : float (I, 3)
        The BSs' positions, metres.
    los : bool (I,)
        The links' LoS states.
    prs : complex (I, N)
        Pilots.
    gains : complex (I, L)
        Tap gains, padded with zero-gain taps to the longer profile.
    delays_s : float (I, L)
        Tap delays, seconds.
    y0 : complex (I, N)
        Noise-free received spectrum (unit power).
    link_snr_db : float (S, I)
        Per-sample SNR of each link at each SNR index, dB.
    link_sinr_db : float (S, I)
        Its SINR, dB (equal to the SNR without co-channel interference).
    noise : complex (I, N)
        The trial's unit noise spectrum, CN(0, 1) per bin.
    reuse : ReuseDraw or None
        With PRS reuse, else None.
    per_link_power : bool
        Whether the links' received powers differ (snr_mode "link_budget" or "nearest"), static: it sets how the
        receiver scales signal and noise (``receiver.spectrum_at``).
    """

    ue_xyz: jax.Array
    clock_bias_s: jax.Array
    bs_index: jax.Array
    bs_xyz: jax.Array
    los: jax.Array
    prs: jax.Array
    gains: jax.Array
    delays_s: jax.Array
    y0: jax.Array
    link_snr_db: jax.Array
    link_sinr_db: jax.Array
    noise: jax.Array
    reuse: ReuseDraw | None
    per_link_power: bool

    @property
    def n_snr(self) -> int:
        """The number S of SNR indices."""
        return self.link_snr_db.shape[0]


jax.tree_util.register_dataclass(
    TrialDraw, data_fields=["ue_xyz", "clock_bias_s", "bs_index", "bs_xyz", "los", "prs", "gains", "delays_s", "y0",
                            "link_snr_db", "link_sinr_db", "noise", "reuse"], meta_fields=["per_link_power"])


def trial_key(seed: int, t) -> jax.Array:
    """The key every draw of trial t comes from: fold_in(PRNGKey(seed), t).

    Parameters
    ----------
    seed : int
        The run's seed.
    t : int
        The trial index (may be traced).

    Returns
    -------
    jax PRNG key
        The trial's key.
    """
    return jax.random.fold_in(jax.random.PRNGKey(seed), t)


def trial_keys(seed: int, start: int, stop: int) -> jax.Array:
    """``trial_key`` of trials start … stop − 1.

    Parameters
    ----------
    seed : int
        The run's seed.
    start, stop : int
        The first trial and one past the last.

    Returns
    -------
    uint32 (T, 2)
        The T = stop − start keys.
    """
    return jax.vmap(lambda t: trial_key(seed, t))(jnp.arange(start, stop))


def link_snr_db(e: Experiment, rx_dbm, rx_nearest_dbm, snrs) -> jax.Array:
    """Per-sample SNR of links from their received powers, in the experiment's ``snr_convention``.

    From the link budget (snr_mode "link_budget", S = 1), or the nearest link's SNR ``snrs`` plus the power difference
    (snr_mode "nearest"); then read in the experiment's ``snr_convention``.

    Parameters
    ----------
    e : Experiment
        The experiment.
    rx_dbm : float (n,)
        The links' received powers, dBm.
    rx_nearest_dbm : float
        The nearest link's received power, dBm.
    snrs : float (S,)
        The nearest link's SNRs, dB (snr_mode "nearest").

    Returns
    -------
    float (S, n)
        Per-sample SNR of every link, dB.
    """
    if e.links.snr_mode == "link_budget":
        snr = e.links.budget.model_snr_db(rx_dbm - e.links.budget.noise_dbm)[None, :]
        if e.links.snr_offset_db:
            snr = snr + e.links.snr_offset_db
    else:
        snr = snrs[:, None] + (rx_dbm - rx_nearest_dbm)[None, :]
    return signal.per_sample_snr_db(snr, e.links.snr_convention)


def sinr_db(link_snr, reuse: ReuseDraw | None) -> jax.Array:
    """SINR of every link: its SNR over 1 + the SNRs (linear) of the BSs on its resource.

    The BSs on its resource are the other links and the co-channel BSs of ``reuse``, all per sample, so the pilots'
    equal power cancels; without co-channel interference the SINR is the SNR itself.

    Parameters
    ----------
    link_snr : float (S, I)
        Per-sample SNR of the links, dB.
    reuse : ReuseDraw or None
        The trial's PRS reuse draw.

    Returns
    -------
    float (S, I)
        The SINR, dB.
    """
    if reuse is None or reuse.co_channel is None:
        return link_snr
    x = reuse.co_channel
    p_link, p_x = 10.0 ** (link_snr / 10.0), 10.0 ** (x.snr_db / 10.0)
    res = jnp.concatenate([reuse.res, x.res])
    per_res = jax.vmap(lambda p: jax.ops.segment_sum(p, res, num_segments=reuse.n_res))(
        jnp.concatenate([p_link, p_x], axis=1))  # (S, R) total received power per resource, in noise units
    interference = per_res[:, reuse.res] - p_link
    return 10.0 * jnp.log10(p_link / (1.0 + interference))
