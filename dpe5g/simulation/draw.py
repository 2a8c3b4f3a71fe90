"""One trial's draws (Section IV): the UE, its nearest BSs, their LoS states, channels and SNRs, the clock bias, the
noise-free received spectra and one unit noise spectrum, as a typed pytree (``TrialDraw``).

One trial = one UE position uniform over the deployment's region at the UE height, the ``max(m_values)`` nearest
BSs, a LoS/NLoS draw per link (eq. (11)), TDL-D (K = 13.3 dB) for LoS and TDL-C for NLoS links at 65 ns, a truncated
Gaussian clock bias and a unit noise spectrum, which the receiver scales to each SNR's variance (``receiver``: one
noise draw serves every SNR, and every M reads the nearest of the same links — common random numbers).  The signal
is simulated in the frequency domain, where both receivers start (``signal.received_spectrum``).  Every draw of
trial t comes from ``trial_key(seed, t)`` = fold_in(PRNGKey(seed), t), so results do not depend on the batch size,
the chunk size, the thread or the machine.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..phy import channel, deployment, nr, propagation, signal
from ..receivers import cost
from . import traced_draw
from .experiment import Experiment
from .trial_draw import CoChannelDraw, ReuseDraw, TrialDraw, link_snr_db, sinr_db, trial_keys

#: folded into a trial's key, the key of its links' NLoS excess delays (``excess_delay``)
EXCESS_KEY_FOLD = 3000


def profiles(e: Experiment) -> tuple[channel.TDLProfile, channel.TDLProfile]:
    """The NLoS (TDL-C) and LoS (TDL-D) profiles of the experiment.

    Parameters
    ----------
    e : Experiment
        The experiment (its scenario's delay spread, K-factor and delay-spread definition).

    Returns
    -------
    nlos, los : channel.TDLProfile
        The TDL-C and TDL-D profiles.
    """
    return (channel.tdl_profile("C", e.scenario.delay_spread_s, definition=e.scenario.delay_spread_def),
            channel.tdl_profile("D", e.scenario.delay_spread_s, e.scenario.k_factor_db, definition=e.scenario.delay_spread_def))


def draw_fn(e: Experiment, dep: deployment.Deployment):
    """Build the traceable (trial key, trial index t) → ``TrialDraw`` of trial t, whose key is ``trial_key(seed, t)``.

    Shared by the engine, ``trials.example`` and ``draw_links``.  The seed is not read (it enters through the key), so
    one compiled engine serves every seed.  Each link's channel is TDL-D if LoS and TDL-C if not; its frequency response
    is ``channel.frequency_response`` of the profile it belongs to, and the received spectrum
    ``signal.received_spectrum`` (the one signal path; ``signal.received_noiseless`` is its inverse DFT, which a test
    checks against the engine).  With PRS reuse the co-channel BSs' draws come from fold_in(key, 2000), so the links'
    draws are those of the same experiment without reuse; with an NLoS excess delay (``Scenario.nlos_excess_median_s``)
    the links' Δτ come from fold_in(key, 3000), so every other draw is that of the same experiment without it.

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.

    Returns
    -------
    callable
        (key, t) → ``TrialDraw``.  The TDL source reads only the key; a traced source (``Scenario.channel``) reads
        trial t's UE from its dataset.
    """
    if e.scenario.channel == "traced":
        return traced_draw.draw_fn(e, dep)
    links = _LinkModel(e, dep)
    m_max = max(e.receiver.m_values)

    def draw(key, t):
        k_ue, k_los, k_c, k_d, k_b, k_sf, k_n = jax.random.split(key, 7)
        ue, d2d, order = links.place_ue(k_ue)
        idx = order[:m_max]  # nearest first
        bs = links.bs_all[idx]
        if e.scenario.los_mode == "pr_los":
            los = jax.random.uniform(k_los, (m_max,)) < propagation.los_probability(d2d[idx])
        elif e.scenario.los_mode in ("all_los", "free_space"):
            los = jnp.ones(m_max, dtype=bool)
        elif e.scenario.los_mode == "all_nlos":
            los = jnp.zeros(m_max, dtype=bool)
        elif e.scenario.los_mode == "nearest_two_los":  # the two nearest LoS, the two farther NLoS
            los = jnp.array([True, True, False, False])
        else:  # two of the four nearest LoS, which two at random
            los = jax.random.permutation(k_los, jnp.array([True, True, False, False]))
        bias = propagation.clock_bias(k_b, e.scenario.clock_sigma_s, e.scenario.clock_bound_sigmas)
        h, gains = links.channels(los, k_c, k_d, m_max)
        delays = jnp.where(los[:, None], links.delays_d, links.delays_c)
        if e.scenario.nlos_excess_median_s:  # every path of an NLoS link Δτ late, from a key of its own
            excess = excess_delay(e, key, los)
            h = h * signal.delay_phasor(excess)
            delays = delays + excess[:, None]
        prs = links.prs_all[idx]
        y_clean = signal.received_spectrum(prs, h, cost.toa(ue, bs), bias)
        if e.links.snr_mode == "fixed":
            rx = None
            snr = signal.per_sample_snr_db(jnp.broadcast_to(links.snrs[:, None], (links.snrs.size, m_max)),
                                           e.links.snr_convention)
        else:
            rx = links.received_dbm(d2d[idx], bs, los, k_sf, idx)
            snr = link_snr_db(e, rx, rx[0], links.snrs)
        reuse = None
        if e.scenario.prs_reuse:
            x = links.co_channel(key, ue, d2d, order[m_max:], rx, bias, snr.shape[0]) if e.scenario.co_channel else None
            reuse = ReuseDraw(res=links.res_all[idx], co_channel=x, n_res=e.scenario.prs_reuse)
        noise = signal.awgn(k_n, y_clean.shape, 1.0)  # CN(0, 1) per bin, scaled per SNR by ``receiver.spectrum_at``
        return TrialDraw(ue_xyz=ue, clock_bias_s=bias, bs_index=idx, bs_xyz=bs, los=los, prs=prs, gains=gains,
                         delays_s=delays, y0=y_clean,
                         link_snr_db=snr, link_sinr_db=sinr_db(snr, reuse), noise=noise, reuse=reuse,
                         per_link_power=e.links.snr_mode != "fixed")

    return draw


class _LinkModel:
    """The deployment and channel model of an experiment, as the traceable pieces ``draw_fn`` composes."""

    def __init__(self, e: Experiment, dep: deployment.Deployment):
        self.e, self.dep = e, dep
        self.nlos, self.los_prof = profiles(e)
        self.n_taps = max(self.nlos.n_taps, self.los_prof.n_taps)
        pad = lambda a: np.pad(np.asarray(a), (0, self.n_taps - len(a)))
        self.delays_c, self.delays_d = pad(self.nlos.delays_s), pad(self.los_prof.delays_s)
        if e.scenario.prs_reuse:  # TS 38.211's pattern; each BS on its resource (comb offset) with its PRS ID
            res_np, ids_np = dep.prs_plan(e.scenario.prs_reuse)
            pattern = nr.PrsPattern(e.scenario.prs_reuse)
            self.prs_all = jnp.asarray(np.stack([nr.prs_per_subcarrier(int(i), pattern, int(r))
                                                 for i, r in zip(ids_np, res_np)]))
            self.res_all = jnp.asarray(res_np)
        else:
            self.prs_all = jnp.asarray(nr.prs_matrix(range(dep.n_bs)))  # PRS ID = deployment index
        self.bs_all = jnp.asarray(dep.bs_xyz)
        self.pw_all = jnp.asarray(dep.power_dbm)
        self.snrs = jnp.asarray(e.links.snrs_db if e.links.snr_mode != "link_budget" else (0.0,), dtype=jnp.float64)

    def place_ue(self, k_ue):
        """The UE (3,) m uniform over the UE's area (``Deployment.ue_bounds``) at the UE height, its 2-D distance
        (B,) m to every BS and the BSs ordered nearest first (B,)."""
        x0, y0, x1, y1 = self.dep.ue_bounds
        xy = jax.random.uniform(k_ue, (2,), minval=jnp.array([x0, y0]), maxval=jnp.array([x1, y1]))
        ue = jnp.concatenate([xy, jnp.array([self.dep.ue_height_m])])
        d2d = jnp.linalg.norm(self.bs_all[:, :2] - xy, axis=-1)
        return ue, d2d, jnp.argsort(d2d)

    def channels(self, los, k_c, k_d, n):
        """(n, N) frequency responses and (n, L) gains of n links with LoS flags ``los``; los_mode "free_space": one
        path of unit power and phase uniform on [0, 2π) from k_d, at the first tap (delay 0)."""
        nlos, los_prof, n_taps = self.nlos, self.los_prof, self.n_taps
        if self.e.scenario.los_mode == "free_space":
            g = jnp.exp(2j * jnp.pi * jax.random.uniform(k_d, (n,)))
            h = jnp.broadcast_to(g[:, None], (n, self.prs_all.shape[1]))
            return h, jnp.pad(g[:, None], ((0, 0), (0, n_taps - 1)))
        g_c = jax.vmap(lambda kk: channel.draw_gains(nlos, kk))(jax.random.split(k_c, n))
        g_d = jax.vmap(lambda kk: channel.draw_gains(los_prof, kk))(jax.random.split(k_d, n))
        h = jnp.where(los[:, None], channel.frequency_response(g_d, los_prof.delays_s),
                      channel.frequency_response(g_c, nlos.delays_s))  # (n, N), eq. (5)
        gains = jnp.where(los[:, None], jnp.pad(g_d, ((0, 0), (0, n_taps - g_d.shape[1]))),
                          jnp.pad(g_c, ((0, 0), (0, n_taps - g_c.shape[1]))))
        return h, gains

    def received_dbm(self, d2d, bs, los, k_sf, sel):
        """Received power P_tx - PL - SF (dBm) of the links to the BSs ``sel`` (deployment indices), the in-band
        SNR's numerator."""
        e = self.e
        pl = propagation.path_loss_umi_db(d2d, bs[:, 2], self.dep.ue_height_m, e.links.budget.fc_hz, los)
        sf = jax.random.normal(k_sf, (sel.shape[0],)) * jnp.where(los, propagation.SIGMA_SF_LOS_DB,
                                                                   propagation.SIGMA_SF_NLOS_DB)
        return self.pw_all[sel] - pl - sf

    def co_channel(self, key, ue, d2d, idx_x, rx, bias, n_snr) -> CoChannelDraw:
        """The other BSs idx_x (X,) of the deployment, keyed from fold_in(key, 2000); rx (I,) dBm the links'
        received powers (the nearest link's sets the SNR scale)."""
        e, n_x = self.e, idx_x.shape[0]
        if not n_x:
            return CoChannelDraw(res=self.res_all[idx_x], prs=self.prs_all[idx_x],
                                 y0=jnp.zeros((0, self.prs_all.shape[1]), self.prs_all.dtype),
                                 snr_db=jnp.zeros((n_snr, 0)))
        k_xl, k_xc, k_xd, k_xs = jax.random.split(jax.random.fold_in(key, 2000), 4)
        bs_x = self.bs_all[idx_x]
        if e.scenario.los_mode in ("all_los", "free_space", "all_nlos"):  # the same state as the links
            los_x = jnp.full(n_x, e.scenario.los_mode != "all_nlos")
        else:
            los_x = jax.random.uniform(k_xl, (n_x,)) < propagation.los_probability(d2d[idx_x])
        h_x, _ = self.channels(los_x, k_xc, k_xd, n_x)
        y_x = signal.received_spectrum(self.prs_all[idx_x], h_x, cost.toa(ue, bs_x), bias)
        snr_x = link_snr_db(e, self.received_dbm(d2d[idx_x], bs_x, los_x, k_xs, idx_x), rx[0], self.snrs)
        return CoChannelDraw(res=self.res_all[idx_x], prs=self.prs_all[idx_x], y0=y_x, snr_db=snr_x)


def excess_delay(e: Experiment, key, los) -> jax.Array:
    """The links' NLoS excess delays Δτ of the trial whose key is ``key`` (``scenario.nlos_excess_delay``, from a key
    of their own: ``EXCESS_KEY_FOLD`` folded into the trial's), as ``draw_fn``'s trial draws them.

    Parameters
    ----------
    e : Experiment
        The experiment; its scenario's ``nlos_excess_median_s`` > 0.
    key : jax PRNG key
        The trial's key (``trial_draw.trial_key``).
    los : bool (I,)
        The trial's LoS states.

    Returns
    -------
    float (I,)
        Δτ, seconds, 0 on a LoS link.
    """
    return propagation.nlos_excess_delay(jax.random.fold_in(key, EXCESS_KEY_FOLD), los, e.scenario.nlos_excess_median_s,
                                      e.scenario.nlos_excess_sigma_lg)


def prior_center(e: Experiment, ue, key) -> jax.Array:
    """Centring "prior": the window centre at the truth plus a horizontal error drawn from the stated prior.

    Keyed by fold_in(trial key, 1000), so the trial's other draws are unchanged; the height is the known UE height and
    c δt is 0.

    Parameters
    ----------
    e : Experiment
        The experiment (``prior_kind``, ``prior_scale_m``).
    ue : float (3,)
        The true UE position, metres.
    key : jax PRNG key
        The trial's key.

    Returns
    -------
    float (4,)
        The centre [x, y, z, c δt], metres.
    """
    key = jax.random.fold_in(key, 1000)
    if e.receiver.prior_kind == "gaussian":
        err = e.receiver.prior_scale_m * jax.random.normal(key, (2,))
    else:
        k_r, k_a = jax.random.split(key)
        r = e.receiver.prior_scale_m * jnp.sqrt(jax.random.uniform(k_r))
        a = 2 * jnp.pi * jax.random.uniform(k_a)
        err = r * jnp.stack([jnp.cos(a), jnp.sin(a)])
    return jnp.concatenate([ue[:2] + err, ue[2:3], jnp.zeros(1)])


def draw_links(e: Experiment, n_trials: int) -> dict:
    """Link draws only (no DPE) for trials 0 … n_trials − 1, from the same keys as the engine.

    They are the statistics the urban-scenario chapter shows.

    Parameters
    ----------
    e : Experiment
        The experiment.
    n_trials : int
        The number of trials T.

    Returns
    -------
    dict
        "los" (T, I) LoS flags, "link_snr_db" and "link_sinr_db" (T, S, I) per-sample link SNR and SINR in dB,
        "d2d_m" (T, I) 2-D distances in metres; "ue_xyz" (T, 3) and "bs_xyz" (T, I, 3), metres; "gains" (T, I, P)
        complex and "delays_s" (T, I, P), seconds, each link's channel taps.
    """
    draw = draw_fn(e, e.load_deployment())

    @jax.jit
    def one(a):
        d = draw(*a)
        return {"los": d.los, "link_snr_db": d.link_snr_db, "link_sinr_db": d.link_sinr_db,
                "d2d_m": jnp.linalg.norm(d.bs_xyz[:, :2] - d.ue_xyz[:2], axis=-1), "ue_xyz": d.ue_xyz,
                "bs_xyz": d.bs_xyz, "gains": d.gains, "delays_s": d.delays_s}

    out = jax.lax.map(one, (trial_keys(e.run.seed, 0, n_trials), jnp.arange(n_trials)), batch_size=64)
    return {k: np.asarray(v) for k, v in out.items()}
