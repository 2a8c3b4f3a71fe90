"""The NLoS-aware OTDoA receiver (``dpe5g.receivers.otdoa_nlos``): its σ model against the spread of the detector's ToAs, its
weighted fit against an independent optimiser and the paper's fit, its fallback flag, its test's false-alarm rate,
and what it can do with 4 and 6 links."""

import jax
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.stats import binom

from dpe5g.phy import nr, signal
from dpe5g.receivers import correlogram, cost, otdoa, otdoa_nlos
from dpe5g.phy.nr import PAPER
from dpe5g.phy.nr import C


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


def runaway_prone(m, rng):
    """m BSs of ``ring`` and ToAs the paper's polish cannot always fit: the UE inside the BSs' hull or 450–900 m
    outside it (half each), each ToA late by up to 150 m with probability 1/2 (inconsistent ToAs), 1 m noise, a clock
    of 30 m."""
    b = ring(m, rng)
    r, a = (rng.uniform(0, 50), rng.uniform(0, 2 * np.pi)) if rng.random() < 0.5 else (rng.uniform(450, 900), 0.0)
    ue = np.array([r * np.cos(a), r * np.sin(a), 2.0])
    late = rng.uniform(0, 150, m) * (rng.random(m) < 0.5)
    return b, (np.linalg.norm(ue - b, axis=1) + rng.normal(0, 1.0, m) + late + 30.0) / C


def test_difference_weights_are_one_to_the_bit_with_equal_sigma():
    """Equal σ: the links in their order and every weight exactly 1 (so the fit is the paper's to the bit); otherwise
    the most trusted link first and w_m = √(2 σ_ref² / (σ_ref² + σ_m²))."""
    for v in (1.0, 0.37, 123.456, 7.3e-3):
        order, w = otdoa_nlos.difference_weights(np.full(5, v))
        assert order.tolist() == list(range(5)) and np.all(w == 1.0)
    order, w = otdoa_nlos.difference_weights(np.array([3.0, 1.0, 2.0, 1.0]))
    assert order.tolist() == [1, 0, 2, 3]
    np.testing.assert_allclose(w, np.sqrt(2 / (1 + np.array([9.0, 4.0, 1.0]))), rtol=1e-15)


@pytest.mark.parametrize("m", [3, 4, 6])
def test_equal_sigma_is_the_papers_fix_to_the_bit(m):
    """With equal σ (any value), ``wls_fix`` and the receiver without exclusion give ``otdoa.Solver.solve``'s fix, to
    the bit, on runaway-prone geometries (inconsistent ToAs, a UE outside the BSs' hull), its flags included: the
    fallback exactly where the paper's polish is rejected, which the sample holds."""
    rng = np.random.default_rng(10 + m)
    base, nlos = otdoa.Solver(m), otdoa_nlos.NlosSolver(exclude=False)
    rejected = 0
    for k in range(60):
        b, t = runaway_prone(m, rng)
        ref = otdoa.solve(b, t, 2.0) if k == 0 else base.solve(b, t, 2.0)
        sigma = np.full(m, rng.uniform(0.3, 30.0))
        _, _, fit = otdoa_nlos.wls_fix(b, t, sigma, 2.0, base)
        f = nlos.fix(b, t, sigma, 2.0)
        np.testing.assert_array_equal(fit.xyz, ref.xyz)
        np.testing.assert_array_equal(f.xyz, ref.xyz)
        assert (fit.ok, fit.reason, fit.polish_rejected) == (ref.ok, ref.reason, ref.polish_rejected)
        assert f.ok and f.fallback == ref.polish_rejected == (not ref.ok)
        rejected += ref.polish_rejected
    assert rejected >= 3, f"only {rejected} of 60 fixes had their polish rejected: the sample tests too little"


def test_the_fallback_is_flagged_exactly_where_the_weighted_polish_is_rejected():
    """Unequal σ on runaway-prone geometries: ``NlosFix.fallback`` is set exactly where the weighted polish, run here
    from the weighted SOCP's solution, moves farther than ``otdoa.MAX_POLISH_MOVE_M``; the fix is then that solution,
    else the polished one.  Both occur.  And three of four links late by 22–132 m, each trusted to 0.7 m: the
    weighted cost keeps falling as the fix runs away (scipy's least_squares ends kilometres out, at a lower cost);
    the receiver falls back, as the paper's fit does."""
    rng = np.random.default_rng(11)
    solver, convex_solver = otdoa_nlos.NlosSolver(exclude=False), otdoa.Solver(4)
    seen = []
    for _ in range(80):
        b, t = runaway_prone(4, rng)
        s = rng.uniform(0.5, 20.0, 4)
        order, w = otdoa_nlos.difference_weights(s)
        convex = convex_solver.solve(b[order], t[order], 2.0, polish=False, weights=w).xyz[:2]
        polished = otdoa.gauss_newton(b[order], t[order], 2.0, convex, weights=w)
        fires = bool(np.linalg.norm(polished - convex) > otdoa.MAX_POLISH_MOVE_M)
        f = solver.fix(b, t, s, 2.0)
        assert f.fallback == fires
        np.testing.assert_array_equal(f.xyz[:2], convex if fires else polished)
        seen.append(fires)
    assert 3 <= sum(seen) <= len(seen) - 3, f"the rule fired on {sum(seen)} of {len(seen)} fixes"
    ang = np.array([0.528, 1.504, 4.945, 5.232])
    b = np.stack([100 * np.cos(ang), 100 * np.sin(ang), np.full(4, 10.0)], axis=-1)
    t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + np.array([131.5, 0.0, 50.4, 22.5])) / C
    s = np.full(4, 0.7)
    q, stat, fit = otdoa_nlos.wls_fix(b, t, s, 2.0)
    assert fit.polish_rejected and solver.fix(b, t, s, 2.0).fallback and otdoa.solve(b, t, 2.0).polish_rejected

    def res(v):
        return (C * t - np.linalg.norm(np.array([v[0], v[1], 2.0]) - b, axis=1) - v[2]) / s

    away = least_squares(res, q, xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100_000)
    assert np.linalg.norm(away.x[:2] - q[:2]) > 1000.0 and np.sum(away.fun**2) < np.sum(res(q) ** 2)


def test_unequal_sigma_moves_the_fix_toward_the_trusted_links():
    """Five links, one 40 m late (the reference BS, the nearest, in a fifth of the geometries), the others unbiased.
    Distrusting it more (σ of 1, 10 and 1e4 m, the others 1 m) moves the fix toward the paper's fix on the four
    others, which it reaches within 1 mm; with σ 10 m the fix is nearer the UE than with equal σ in ≥ 90 % of 30
    geometries."""
    rng = np.random.default_rng(7)
    nearer, four, five = 0, otdoa.Solver(4), otdoa.Solver(5)
    for k in range(30):
        b = ring(5, rng)
        ue = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), 2.0])
        late = k % 5
        t = (np.linalg.norm(ue - b, axis=1) + rng.normal(0, 1.0, 5) + 40.0 * (np.arange(5) == late) + 20.0) / C
        without = four.solve(np.delete(b, late, 0), np.delete(t, late), 2.0).xyz[:2]
        fixes = [otdoa_nlos.wls_fix(b, t, np.where(np.arange(5) == late, s_k, 1.0), 2.0, five)[0][:2]
                 for s_k in (1, 10, 1e4)]
        d = [np.linalg.norm(x - without) for x in fixes]
        assert d[0] > d[1] > d[2] and d[2] < 1e-3, d
        nearer += np.linalg.norm(fixes[1] - ue[:2]) < np.linalg.norm(fixes[0] - ue[:2])
    assert nearer >= 27, f"the weighted fix was nearer the UE in {nearer} of 30 geometries"


def test_wls_fix_is_the_weighted_range_difference_minimum_and_its_t_the_tdoa_fit_s():
    """Equal to scipy's least_squares on the weighted range differences to the most trusted link, started at the
    truth; T equals the minimum of the ToAs' weighted least squares over (x, y, c δt) (scipy's) to 1e-3, since
    ``gls_residuals`` linearises that fit at the fix."""
    rng, six = np.random.default_rng(2), otdoa.Solver(6)
    for _ in range(20):
        b = ring(6, rng)
        ue = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), 2.0])
        s = rng.uniform(0.5, 5.0, 6)
        t = (np.linalg.norm(ue - b, axis=1) + rng.normal(0, s) + 40.0) / C
        q, stat, fit = otdoa_nlos.wls_fix(b, t, s, 2.0, six)
        order, w = otdoa_nlos.difference_weights(s)
        bo, to = b[order], t[order]

        def rd(v):
            d = np.linalg.norm(np.array([v[0], v[1], 2.0]) - bo, axis=1)
            return w * (d[1:] - d[0] - C * (to[1:] - to[0]))

        def toa(v):
            return (C * t - np.linalg.norm(np.array([v[0], v[1], 2.0]) - b, axis=1) - v[2]) / s

        ref = least_squares(rd, ue[:2], xtol=1e-14, ftol=1e-14, gtol=1e-14)
        np.testing.assert_allclose(q[:2], ref.x, atol=1e-5)
        assert fit.ok and not fit.polish_rejected
        gls = least_squares(toa, np.array([ue[0], ue[1], 40.0]), xtol=1e-14, ftol=1e-14, gtol=1e-14)
        assert stat == pytest.approx(np.sum(gls.fun**2), rel=1e-3)


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
    """A link 30 m late (σ 1 m): with 6 links it is identified and excluded and the fix is back within metres (a
    median under 2 m; 5 m where the five BSs left lie near a line); with the 4 nearest (one redundancy) it is
    detected, nothing is excluded and the fix is not called consistent."""
    rng = np.random.default_rng(4)
    solver = otdoa_nlos.NlosSolver()
    right, n, err, five = 0, 40, [], otdoa.Solver(5)
    for _ in range(n):
        b = ring(6, rng)
        bias = np.zeros(6)
        bias[2] = 30.0
        t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + rng.normal(0, 1.0, 6) + bias) / C
        f = solver.fix(b, t, np.ones(6), 2.0)
        if f.excluded == (2,):
            right += 1
            assert f.consistent and f.dof == 2
            # equal σ: the paper's fix on the links left
            np.testing.assert_array_equal(f.xyz, five.solve(np.delete(b, 2, 0), np.delete(t, 2), 2.0).xyz)
            err.append(np.hypot(*f.xyz[:2]))
    assert right >= 0.8 * n, f"the late link was excluded in {right} of {n} fixes"
    assert np.median(err) < 2.0 and max(err) < 10.0, err
    b = ring(4, rng)
    t = (np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + np.array([0.0, 60.0, 0.0, 0.0])) / C
    f = solver.fix(b, t, np.ones(4), 2.0)
    assert f.detected and f.excluded == () and not f.consistent and f.dof == 1
    assert not otdoa_nlos.NlosSolver(exclude=False).fix(ring(6, rng), np.r_[t, t[:2]], np.ones(6), 2.0).excluded


@pytest.mark.parametrize("kwargs, match", [
    ({"toa_s": np.full(5, 1e-6)}, "toa_s and sigma_m must be"),
    ({"sigma_m": np.array([1.0, 1.0, 0.0, 1.0])}, "sigma_m must be .* finite and > 0"),
    ({"sigma_m": np.array([1.0, np.nan, 1.0, 1.0])}, "sigma_m must be .* finite and > 0"),
    ({"toa_s": np.array([1e-6, np.nan, 1e-6, 1e-6])}, "toa_s must be finite"),
    ({"ue_z": np.inf}, "ue_z"),
    ({"bs_xyz": np.zeros((2, 3))}, "at least 3 base stations"),
])
def test_bad_input_is_a_value_error_naming_it(kwargs, match):
    rng = np.random.default_rng(5)
    args = {"bs_xyz": ring(4, rng), "toa_s": np.full(4, 1e-6), "sigma_m": np.ones(4), "ue_z": 2.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        otdoa_nlos.NlosSolver().fix(**args)
    for public in (otdoa_nlos.wls_fix, otdoa_nlos.check_links):  # the fit and the residuals check alike
        with pytest.raises(ValueError, match=match):
            public(**args)
    with pytest.raises(ValueError, match=match):
        otdoa_nlos.normalised_residuals(**args, q=np.zeros(3))
    if "sigma_m" in kwargs:
        with pytest.raises(ValueError, match=match):
            otdoa_nlos.difference_weights(kwargs["sigma_m"])
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
    from dpe5g.receivers import search_config
    from dpe5g.simulation import engine, experiment, results, trials

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
            assert res.otdoa_nlos_detected[t, s, 0] == f.detected and res.otdoa_nlos_fallback[t, s, 0] == f.fallback
            assert np.flatnonzero(res.otdoa_nlos_excluded[t, s, 0]).tolist() == sorted(f.excluded)
    assert res.otdoa_nlos_error_m.shape == res.error_m.shape
    with pytest.raises(ValueError, match="otdoa_nlos"):
        experiment.Experiment.build(**{**kw, "otdoa": False}, otdoa_nlos=True)


def test_the_nlos_receivers_refuse_what_they_cannot_mean():
    """Two BSs at one place (their TDoA is 0 wherever the UE is: a fix 348 m off was reported consistent), a
    false-alarm rate outside its range, a switch that is not True or False, and a LoS prior outside [0, 1] are
    ValueErrors naming the parameter."""
    from dpe5g.receivers import dpe_nlos

    bs = np.array([[0.0, 0.0, 10.0], [200.0, 0.0, 10.0], [0.0, 200.0, 10.0], [0.0, 200.0, 10.0]])
    toa = np.linalg.norm(bs - [50.0, 50.0, 1.5], axis=1) / C
    with pytest.raises(ValueError, match="base stations 2 and 3 are at one place"):
        otdoa_nlos.NlosSolver().fix(bs, toa, np.ones(4), 1.5)
    for rate in (0.0, 1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="false_alarm must"):
            otdoa_nlos.threshold(2, rate)
    with pytest.raises(ValueError, match="exclude must be True or False"):
        otdoa_nlos.NlosSolver(exclude="False")
    for p in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="p_los must be finite and in"):
            dpe_nlos.excess_log_masses(np.array([0.5, p]), 3e-8, 0.3, 0.99, 1e-9)
