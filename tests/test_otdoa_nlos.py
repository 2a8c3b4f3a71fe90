"""The NLoS-aware OTDoA receiver (``dpe5g.otdoa_nlos``): its σ model against the spread of the detector's ToAs, its
weighted fit against an independent optimiser, its test's false-alarm rate, and what it can do with 4 and 6 links."""

import jax
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.stats import binom

from dpe5g import correlogram, cost, nr, otdoa, otdoa_nlos, signal
from dpe5g.nr import PAPER
from dpe5g.nr import C


#: eq. (O1)'s resolution term, c / (B √12) with the paper's full band B = N Δf
RESOLUTION_M = C / (PAPER.n_fft * PAPER.scs_hz) / np.sqrt(12)


def ring(m, rng):
    """m BSs at random azimuths and ranges 100–400 m around the origin, 10 m high."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, m))
    r = rng.uniform(100, 400, m)
    return np.stack([r * np.cos(ang), r * np.sin(ang), np.full(m, 10.0)], -1)


@pytest.mark.parametrize("snr_db", [-10.0, 0.0])
def test_sigma_is_the_spread_of_the_first_path_toas(snr_db):
    """One path per link, AWGN: eq. (O1)'s CRB term, estimated from each received signal, is the standard deviation
    of the first-path ToAs over 30 noise draws: the median of |error| / CRB is a normal's 0.67 within 20 % (the
    detector reaches the bound at the estimated SNR); σ is at least the resolution term."""
    m, draws = 6, 30
    prs = nr.prs_matrix(range(m))
    bs = ring(m, np.random.default_rng(1))
    tau = np.asarray(cost.toa(np.array([10.0, -20.0, 2.0]), bs, 0.0))
    err, sig = [], []
    for k in range(draws):
        y = signal.received_samples(jax.random.PRNGKey(k), prs, np.ones((m, 1)), np.zeros((m, 1)), tau, snr_db)
        t, s = otdoa_nlos.link_sigma_m(y, prs)
        if k == 0:  # the first-path ToAs are otdoa.toa's, to the bit
            np.testing.assert_array_equal(t, np.asarray(otdoa.toa(y, prs)))
        assert np.all(s >= RESOLUTION_M)
        err.append(C * (t - tau))
        sig.append(otdoa_nlos.crb_m(correlogram.energy_grid(correlogram.ls_spectrum(signal.demodulate(y), prs), 1, 8),
                                    nr.PAPER.n_fft * nr.PAPER.scs_hz))
    err, sig = np.array(err), np.array(sig)
    z = (err - np.median(err, axis=0)) / sig  # each link has its own interpolation bias, of centimetres
    mad = np.median(np.abs(z))  # 0.674 for a standard normal; robust to the detector's rare outliers
    assert 0.55 < mad < 0.8, f"median |error| / σ is {mad:.2f} at {snr_db} dB (0.67 if σ were the spread)"


def test_a_late_peak_widens_sigma():
    """A second path 10 samples after a weaker first one: σ covers the span between the two detectors' ToAs (and the
    resolution cell; the CRB is negligible at 0 dB over 4096 samples)."""
    prs = nr.prs_matrix(range(1))
    ts = nr.PAPER.sample_period_s
    y = signal.received_samples(jax.random.PRNGKey(0), prs, np.array([[0.5, 1.0]]), np.array([[0.0, 10 * ts]]),
                                np.array([1e-6]), 0.0)
    _, s = otdoa_nlos.link_sigma_m(y, prs)
    span = C * 10 * ts / np.sqrt(12)
    assert span <= s[0] < np.hypot(span, RESOLUTION_M) * 1.05


def test_wls_fix_keeps_its_start_where_the_weighted_cost_has_no_minimum_near_the_links():
    """Three of four links late by 22–132 m, each trusted to 0.7 m: no point near the links fits them, and the
    weighted cost keeps falling as the fix runs away (scipy's least_squares ends hundreds of kilometres out, at a
    lower cost).  wls_fix then keeps its start.  Other delays put the minimum just outside the BSs' circle,
    farther from the start than every BS: that fit converges and is kept."""
    ang = np.array([0.528, 1.504, 4.945, 5.232])
    b = np.stack([100 * np.cos(ang), 100 * np.sin(ang), np.full(4, 10.0)], axis=-1)
    t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + np.array([131.5, 0.0, 50.4, 22.5])) / C
    s, xy0 = np.full(4, 0.7), np.array([5.0, -5.0])
    q, stat = otdoa_nlos.wls_fix(b, t, s, 2.0, xy0)
    start = otdoa_nlos.wls_fix(b, t, s, 2.0, xy0, iters=0)
    np.testing.assert_array_equal(q, start[0])
    assert stat == start[1]

    def res(v):
        return (C * t - np.linalg.norm(np.array([v[0], v[1], 2.0]) - b, axis=1) - v[2]) / s

    away = least_squares(res, start[0], xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100_000)
    assert np.linalg.norm(away.x[:2] - xy0) > 1000.0 and np.sum(away.fun**2) < stat
    ang = np.array([2.248, 3.053, 5.589, 5.869])
    b = np.stack([100 * np.cos(ang), 100 * np.sin(ang), np.full(4, 10.0)], axis=-1)
    t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + np.array([85.7, 0.0, 89.1, 50.7])) / C
    q, _ = otdoa_nlos.wls_fix(b, t, s, 2.0, xy0)
    ref = least_squares(res, q, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert np.linalg.norm(q[:2] - xy0) > np.max(np.linalg.norm(b[:, :2] - xy0, axis=1))
    np.testing.assert_allclose(q, ref.x, atol=1e-4)


def test_wls_fix_is_the_weighted_least_squares_minimum():
    """Equal to scipy's least_squares on the same weighted residuals, started at the truth."""
    rng = np.random.default_rng(2)
    for _ in range(20):
        b = ring(6, rng)
        ue = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), 2.0])
        s = rng.uniform(0.5, 5.0, 6)
        t = (np.linalg.norm(ue - b, axis=1) + rng.normal(0, s) + 40.0) / C
        q, stat = otdoa_nlos.wls_fix(b, t, s, 2.0, ue[:2] + 20.0)

        def res(v):
            return (C * t - np.linalg.norm(np.array([v[0], v[1], 2.0]) - b, axis=1) - v[2]) / s

        ref = least_squares(res, np.array([ue[0], ue[1], 40.0]), xtol=1e-14, ftol=1e-14, gtol=1e-14)
        np.testing.assert_allclose(q, ref.x, atol=1e-5)
        assert stat == pytest.approx(np.sum(ref.fun**2), rel=1e-8)


def test_false_alarm_rate_is_the_stated_one():
    """Unbiased ToAs with the modelled σ: the share of fixes flagged is the false-alarm rate (within the binomial
    99.9 % range of 400 fixes), for 4 and 6 links."""
    rng = np.random.default_rng(3)
    solver = otdoa_nlos.NlosSolver(false_alarm=0.05)
    n = 400
    lo, hi = binom.ppf([0.0005, 0.9995], n, 0.05)
    for m in (4, 6):
        flagged = 0
        for _ in range(n):
            b = ring(m, rng)
            ue = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), 2.0])
            s = rng.uniform(0.5, 3.0, m)
            f = solver.fix(b, (np.linalg.norm(ue - b, axis=1) + rng.normal(0, s) + 7.0) / C, s, 2.0)
            flagged += f.detected
        assert lo <= flagged <= hi, f"M = {m}: {flagged} of {n} flagged at a 5 % false-alarm rate"


def test_one_nlos_link_is_excluded_with_six_links_and_only_detected_with_four():
    """A link 30 m late (σ 1 m): with 6 links it is identified and excluded and the fix is back within metres; with
    the 4 nearest (one redundancy) it is detected, nothing is excluded and the fix is not called consistent."""
    rng = np.random.default_rng(4)
    solver = otdoa_nlos.NlosSolver()
    right, n = 0, 40
    for _ in range(n):
        b = ring(6, rng)
        bias = np.zeros(6)
        bias[2] = 30.0
        t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + rng.normal(0, 1.0, 6) + bias) / C
        f = solver.fix(b, t, np.ones(6), 2.0)
        if f.excluded == (2,):
            right += 1
            assert np.hypot(*f.xyz[:2]) < 5.0 and f.consistent and f.dof == 2
    assert right >= 0.8 * n, f"the late link was excluded in {right} of {n} fixes"
    b = ring(4, rng)
    t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + np.array([0.0, 60.0, 0.0, 0.0])) / C
    f = solver.fix(b, t, np.ones(4), 2.0)
    assert f.detected and f.excluded == () and not f.consistent and f.dof == 1
    assert not otdoa_nlos.NlosSolver(exclude=False).fix(ring(6, rng), np.r_[t, t[:2]], np.ones(6), 2.0).excluded


@pytest.mark.parametrize("kwargs, match", [
    ({"toa_s": np.full(5, 1e-6)}, "toa_s and sigma_m must be"),
    ({"sigma_m": np.array([1.0, 1.0, 0.0, 1.0])}, "sigma_m finite and > 0"),
    ({"toa_s": np.array([1e-6, np.nan, 1e-6, 1e-6])}, "toa_s must be finite"),
    ({"ue_z": np.inf}, "ue_z"),
    ({"bs_xyz": np.zeros((2, 3))}, "at least 3 base stations"),
])
def test_bad_input_is_a_value_error_naming_it(kwargs, match):
    rng = np.random.default_rng(5)
    args = {"bs_xyz": ring(4, rng), "toa_s": np.full(4, 1e-6), "sigma_m": np.ones(4), "ue_z": 2.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        otdoa_nlos.NlosSolver().fix(**args)
    with pytest.raises(ValueError, match="false_alarm"):
        otdoa_nlos.NlosSolver(false_alarm=0.9)


def test_link_sigma_bad_input_names_the_parameter():
    prs = nr.prs_matrix(range(2))
    y = np.zeros_like(prs)
    with pytest.raises(ValueError, match="upsample"):
        otdoa_nlos.link_sigma_m(y, prs, upsample=0)
    with pytest.raises(ValueError, match="threshold_db"):
        otdoa_nlos.link_sigma_m(y, prs, threshold_db=3.0)


def test_the_engine_runs_the_receiver_on_each_trials_own_signals(tmp_path):
    """``otdoa_nlos``: the engine's σ of each link is ``link_sigma_m`` on the trial's received signals (its grid in
    the engine's precision), its fix the receiver's on them; every other field as computed without it, to the bit."""
    from dpe5g import engine, experiment, results, search_config, trials

    kw = dict(name="s", n_trials=2, seed=1, snrs_db=(0.0, 20.0), m_values=(5,), otdoa=True, centring="truth",
              nlos_excess_median_s=31.6e-9, nlos_excess_sigma_lg=0.5,
              search=search_config.SearchConfig(half_width_m=3.0, bias_half_width_m=3.0))
    e = experiment.Experiment.build(otdoa_nlos=True, **kw)
    res = engine.run(e, cache=tmp_path / "a", progress=False, use_store=False)
    plain = engine.run(experiment.Experiment.build(**kw), cache=tmp_path / "b", progress=False, use_store=False)
    assert plain.otdoa_sigma_m is None and res.otdoa_sigma_m.shape == res.link_snr_db.shape
    for f in results.Results.FIELDS + results.Results.OTDOA_FIELDS:
        np.testing.assert_array_equal(getattr(res, f), getattr(plain, f), err_msg=f)
    solver = otdoa_nlos.NlosSolver()
    for t in range(e.run.n_trials):
        for s in range(e.n_snr):
            ex = trials.example(e, t, s)
            toa, sig = otdoa_nlos.link_sigma_m(ex.y, ex.prs)
            np.testing.assert_allclose(res.otdoa_sigma_m[t, s], sig, rtol=1e-4)
            f = solver.fix(ex.bs_xyz[:5], toa[:5], sig[:5], ex.ue_xyz[2])  # the receiver on the trial's signals
            np.testing.assert_allclose(res.otdoa_nlos_xyz[t, s, 0], f.xyz, atol=1e-3)
            assert res.otdoa_nlos_detected[t, s, 0] == f.detected
            assert np.flatnonzero(res.otdoa_nlos_excluded[t, s, 0]).tolist() == sorted(f.excluded)
    assert res.otdoa_nlos_error_m.shape == res.error_m.shape
    with pytest.raises(ValueError, match="otdoa_nlos"):
        experiment.Experiment.build(**{**kw, "otdoa": False}, otdoa_nlos=True)
