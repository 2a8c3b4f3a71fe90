"""The NLoS-aware DPE (``dpe5g.receivers.dpe_nlos``): its prior against the simulator's draws, eq. (D1) against a direct
log-sum-exp, the spline round trip, and the window the certified search reads against an independent computation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import solve_banded
from scipy.special import logsumexp

from dpe5g.phy import nr, propagation, signal
from dpe5g.receivers import correlogram, cost, dpe_nlos
from dpe5g.simulation import experiment
from dpe5g.studies import nlos as nlos_study
from dpe5g.phy.nr import PAPER

UMI = nlos_study.UMI
KNOT_S = PAPER.sample_period_s / 8


def test_prior_masses_are_the_simulators_excess_delays():
    """Eq. (D2) against 200 000 draws of ``scenario.nlos_excess_delay`` (LoS with probability 0.4), rounded to the
    lags: the CDFs over the lags agree within 0.005 (Kolmogorov–Smirnov's 1 % point at this n is 0.0036), and the
    draws past the last lag are (1 − 0.4) × 1 % of all."""
    p_los, n = 0.4, 200_000
    ratio = np.exp(np.asarray(dpe_nlos.excess_log_masses(p_los, UMI.median_s, UMI.sigma_lg, 0.99, KNOT_S)))
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    los = jax.random.uniform(k1, (n,)) < p_los
    lag = np.rint(np.asarray(propagation.nlos_excess_delay(k2, los, UMI.median_s, UMI.sigma_lg)) / KNOT_S)
    kept = lag < len(ratio)
    counts = np.bincount(lag[kept].astype(int), minlength=len(ratio))
    assert np.max(np.abs(np.cumsum(ratio) / ratio.sum() - np.cumsum(counts) / counts.sum())) < 0.005
    assert 1 - kept.mean() == pytest.approx((1 - p_los) * 0.01, abs=0.001)  # the tail past the 99 % point, dropped


def test_marginal_terms_are_a_log_sum_exp_over_the_lags():
    rng = np.random.default_rng(3)
    m, k, j = 3, 50, 20
    values = rng.uniform(0, 40, (m, k + j - 1))
    log_masses = np.concatenate([np.zeros((m, 1)), np.log(rng.uniform(0.001, 0.1, (m, j - 1)))], axis=1)
    noise = rng.uniform(0.5, 3.0, m)
    got = np.asarray(dpe_nlos.marginal_terms(jnp.asarray(values), jnp.asarray(log_masses), jnp.asarray(noise)))
    for a in range(m):
        for t in range(k):
            want = noise[a] * logsumexp(log_masses[a] + values[a, t:t + j] / noise[a])
            assert got[a, t] == pytest.approx(want, rel=1e-12)
    assert np.all(got >= values[:, :k])  # ℓ ≥ c: the lag 0 is one of the terms, its ratio 1


def test_prefilter_inverts_knot_values_inside_the_margin():
    """A stretch of a real spline correlogram: its knot values, put back into coefficients on the stretch alone,
    give the coefficients again, to 1e-12 of the largest, ``PREFILTER_MARGIN`` knots in from either end."""
    prs = nr.prs_matrix(range(2))
    y = signal.received_samples(jax.random.PRNGKey(0), prs, np.ones((2, 1)), np.zeros((2, 1)),
                                np.array([1e-6, 1.3e-6]), 10.0)
    coef = np.asarray(correlogram.spline_correlogram(y, prs, 12, 8))
    a, w, p = 7900, 400, dpe_nlos.PREFILTER_MARGIN
    back = np.asarray(dpe_nlos.spline_prefilter(dpe_nlos.knot_values(jnp.asarray(coef))[:, a - p:a + w + p]))
    np.testing.assert_allclose(back[:, p:p + w], coef[:, a:a + w], atol=1e-12 * np.abs(coef).max())


def test_marginal_window_is_eq_d1_on_the_knots_the_search_reads():
    """``marginal_window`` against an independent computation on four links, two of them late: eq. (D1) by scipy's logsumexp over
    the knot values of the whole period (noise power from the floor, P_m from eq. (11) at the centre), put back into
    spline form by a banded solve of the cubic interpolation on a stretch well wider than the window.  The spline
    values at the window's knots agree to 1e-9 of the largest."""
    rng = np.random.default_rng(4)
    ang = np.sort(rng.uniform(0, 2 * np.pi, 4))
    bs = np.stack([150 * np.cos(ang), 150 * np.sin(ang), np.full(4, 10.0)], -1)
    ue = np.array([3.0, -7.0, 1.5])
    gains = (rng.normal(size=(4, 3)) + 1j * rng.normal(size=(4, 3))) * np.array([1.0, 0.5, 0.3])
    delays = np.array([0.0, 40e-9, 90e-9]) + np.array([0.0, 0.0, 30e-9, 60e-9])[:, None]  # two links late
    y = signal.received_samples(jax.random.PRNGKey(5), nr.prs_matrix(range(4)), gains, delays,
                                np.asarray(cost.toa(ue, bs, 0.0)), 10.0)
    cfg = nlos_study.fig10_clock_nlos()["two_of_four"].receiver_search()
    window = jnp.asarray(correlogram.window_spectrum(cfg.n_taps, PAPER.n_fft))
    coef = correlogram.spline_correlogram(y, nr.prs_matrix(range(4)), cfg.n_taps, cfg.spline_upsample)
    center = jnp.asarray([ue[0] + 6.0, ue[1] + 6.0, ue[2], 0.0])
    got, start = (np.asarray(a) for a in dpe_nlos.marginal_window(
        coef, bs, center, cfg, window, UMI.median_s, UMI.sigma_lg, dpe_nlos.CLOCK_NLOS_QUANTILE))
    c = np.asarray(coef)
    k = c.shape[1]
    v = (np.roll(c, 1, 1) + 4 * c + np.roll(c, -1, 1)) / 6
    far = [np.mod(np.argmax(r) + k // 4 + np.arange(k // 2), k) for r in v]
    noise = np.array([r[f].mean() for r, f in zip(v, far)]) / cfg.n_taps
    d2d = np.linalg.norm(np.asarray(center[:2]) - bs[:, :2], axis=1)
    p = np.asarray(propagation.los_probability(d2d))
    ratio = np.asarray(dpe_nlos.excess_log_masses(p, UMI.median_s, UMI.sigma_lg, 0.99, KNOT_S))
    pad = 200
    for m in range(c.shape[0]):
        knots = np.arange(start[m] - pad, start[m] + got.shape[1] + pad)
        lags = v[m, np.mod(knots[:, None] + np.arange(ratio.shape[1])[None], k)]  # (knots, J)
        ell = noise[m] * logsumexp(ratio[m] + lags / noise[m], axis=1)
        band = np.array([np.full(len(ell), 1 / 6), np.full(len(ell), 4 / 6), np.full(len(ell), 1 / 6)])
        want = solve_banded((1, 1), band, ell)[pad:pad + got.shape[1]]
        vals = lambda a: (a[:-2] + 4 * a[1:-1] + a[2:]) / 6  # the spline at the window's inner knots
        np.testing.assert_allclose(vals(got[m]), vals(want), atol=1e-9 * np.abs(want).max())


def test_dpe_nlos_rejects_what_it_cannot_run():
    e = nlos_study.fig10_clock_nlos()["two_of_four"]
    e.replace(dpe_nlos=True)  # the certified search, "clock_nlos", the UMi delay: fine
    with pytest.raises(ValueError, match="dpe_nlos"):
        e.replace(dpe_nlos=True, clock_window="clock")
    with pytest.raises(ValueError, match="clock_nlos.*nlos_prior 'umi'"):  # no delay assumed: nothing to integrate
        e.replace(dpe_nlos=True, nlos_excess_median_s=0.0)
    with pytest.raises(ValueError, match="nlos_excess_sigma_lg at least 0.001 decades"):  # failed inside the run
        e.replace(dpe_nlos=True, nlos_excess_sigma_lg=0.0)
    umi = e.replace(dpe_nlos=True, nlos_excess_median_s=0.0, nlos_prior="umi")  # the standard's law instead
    assert umi.excess_law() == (nlos_study.UMI.median_s, nlos_study.UMI.sigma_lg) == e.excess_law()
    assert umi.receiver_search() == e.receiver_search()
    with pytest.raises(ValueError, match="nlos_prior"):
        e.replace(nlos_prior="city")
    with pytest.raises(ValueError, match="nlos_prior 'umi' is read by clock_window 'clock_nlos' only"):
        e.replace(nlos_prior="umi", clock_window="clock")
    with pytest.raises(ValueError, match="median_s"):
        dpe_nlos.excess_log_masses(0.5, 2e-6, 0.5, 0.99, KNOT_S)
