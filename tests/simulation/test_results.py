"""The paired statistics of ``dpe5g.simulation.results``: their intervals cover the true value as often as their level says on
simulated data whose quantiles are known, pairing narrows them, and a claim's verdict follows its interval."""

import numpy as np
import pytest
from scipy import stats

from dpe5g.studies import intervals

Z90 = stats.norm.ppf(0.9)


def correlated_lognormals(rng, n_trials, rho, n_arrays=2):
    """(n_arrays, T) log-normal "errors" exp(s_k z_k) with corr(z_j, z_k) = rho; s = 1, 0.5, 0.8, 0.3."""
    cov = np.full((n_arrays, n_arrays), rho) + (1 - rho) * np.eye(n_arrays)
    z = rng.multivariate_normal(np.zeros(n_arrays), cov, n_trials).T
    return np.exp(np.array([1.0, 0.5, 0.8, 0.3])[:n_arrays, None] * z)


def true_p90(scale):
    return float(np.exp(scale * Z90))


def correlated_gaussian_errors(rng, n_trials, rho, n_arrays=2):
    """(n_arrays, T) horizontal-error-like magnitudes |s_k z_k| with corr(z_j, z_k) = rho; s = 2, 1: RMSE = s."""
    cov = np.full((n_arrays, n_arrays), rho) + (1 - rho) * np.eye(n_arrays)
    z = rng.multivariate_normal(np.zeros(n_arrays), cov, n_trials).T
    return np.abs(np.array([2.0, 1.0])[:n_arrays, None] * z)


def coverage(make_interval, truth, n_rep=200, n_trials=400, rho=0.7, n_arrays=2, seed=11,
             draw=correlated_lognormals):
    rng = np.random.default_rng(seed)
    hits = 0
    for rep in range(n_rep):
        iv = make_interval(*draw(rng, n_trials, rho, n_arrays), rep)
        hits += iv.lo <= truth <= iv.hi
    return hits / n_rep


def test_quantile_difference_covers_the_true_difference_at_its_level():
    """Q90(a) − Q90(b) of two paired receivers: the 95 % interval holds the true difference in about 95 % of 200
    simulated experiments, the 50 % interval in about half (so the level is used, not ignored)."""
    truth = true_p90(1.0) - true_p90(0.5)
    cov95 = coverage(lambda a, b, r: intervals.quantile_difference(a, b, n_boot=400, seed=r), truth)
    cov50 = coverage(lambda a, b, r: intervals.quantile_difference(a, b, n_boot=400, seed=r, level=0.5), truth)
    assert 0.90 <= cov95 <= 0.99, cov95
    assert 0.38 <= cov50 <= 0.62, cov50


def test_quantile_ratio_and_rmse_ratio_cover_their_true_values():
    """Q90(a) / Q90(b) and RMSE(a) / RMSE(b) on paired trials: 95 % intervals cover in 90–99 % of experiments."""
    q_truth = true_p90(1.0) / true_p90(0.5)
    cov_q = coverage(lambda a, b, r: intervals.quantile_ratio(a, b, n_boot=400, seed=r), q_truth)
    cov_r = coverage(lambda a, b, r: intervals.rmse_ratio(a, b, n_boot=400, seed=r), 2.0,
                     draw=correlated_gaussian_errors)
    assert 0.90 <= cov_q <= 0.99, cov_q
    assert 0.90 <= cov_r <= 0.99, cov_r


def test_growth_difference_covers_the_true_difference_of_growths():
    """(Q90(a1) − Q90(a0)) − (Q90(b1) − Q90(b0)), four arrays on the same trials: 95 % coverage within 90–99 %."""
    truth = (true_p90(1.0) - true_p90(0.5)) - (true_p90(0.8) - true_p90(0.3))
    cov = coverage(lambda a1, a0, b1, b0, r: intervals.growth_difference(a1, a0, b1, b0, n_boot=400, seed=r), truth,
                   n_arrays=4)
    assert 0.90 <= cov <= 0.99, cov


def test_best_comparison_names_the_best_and_wins_only_against_every_receiver():
    """Families on the same trials: the best are the lowest 90 % points; a family wins where its best beats every
    receiver of the other (resolved), and a tie with one of them leaves it unresolved."""
    a, b, c, d = correlated_lognormals(np.random.default_rng(0), 2000, 0.9, 4)  # scales 1, 0.5, 0.8, 0.3
    r = intervals.best_comparison({"1": a, "0.3": d}, {"0.5": b, "0.8": c})
    assert (r.best_a, r.best_b, r.a_better, r.b_better) == ("0.3", "0.5", True, False)
    assert r.difference == intervals.quantile_difference(d, b)
    same_law = np.random.default_rng(1).permutation(d)  # d's law, another trial order
    tie = intervals.best_comparison({"1": a, "0.3": d}, {"0.3 again": same_law, "0.8": c})
    assert not tie.a_better and not tie.b_better
    assert intervals.best_comparison({"0.8": c}, {"0.3": d}).b_better
    with pytest.raises(ValueError, match="family"):
        intervals.best_comparison({}, {"u": b})


def test_pairing_narrows_the_interval_of_a_difference_of_correlated_receivers():
    """Two receivers whose errors move together (rho 0.98, the same law): the paired interval of their 90 % point
    difference is less than half as wide as one that resamples each receiver on its own trials."""
    rng = np.random.default_rng(3)
    z = rng.multivariate_normal([0, 0], [[1, 0.98], [0.98, 1]], 1000).T
    a, b = np.exp(z)
    paired = intervals.quantile_difference(a, b, seed=1)
    lo_a, hi_a = intervals.bootstrap_interval(a, seed=1)
    lo_b, hi_b = intervals.bootstrap_interval(b, seed=2)
    unpaired_width = np.hypot(hi_a - lo_a, hi_b - lo_b)  # independent resamples: the widths add in quadrature
    assert paired.hi - paired.lo < 0.5 * unpaired_width, (paired, unpaired_width)


def test_paired_interval_is_the_same_for_any_block_of_draws_and_reproduces_from_its_seed():
    """The draws are made once from the seed, so the interval does not depend on how many are evaluated at once;
    the value is the statistic on all trials."""
    rng = np.random.default_rng(5)
    a, b = correlated_lognormals(rng, 300, 0.5)
    one = intervals.quantile_difference(a, b, seed=9)
    again = intervals.quantile_difference(a, b, seed=9)
    assert one == again
    assert one.value == pytest.approx(np.quantile(a, 0.9) - np.quantile(b, 0.9), abs=1e-12)
    big = intervals.paired_interval(lambda x, y: np.quantile(x, 0.9, axis=1) - np.quantile(y, 0.9, axis=1),
                                  np.repeat(a[:, None], 5000, axis=1)[:, 0], b, seed=9)  # a (T,) again, another path
    assert big == one
    assert one.n_trials == 300 and one.lo < one.value < one.hi


def test_bootstrap_interval_is_unchanged_by_the_shared_draws():
    """intervals.bootstrap_interval draws its resamples with bootstrap_draws: the same stream as drawing one
    resample at a time from default_rng(seed)."""
    err = np.random.default_rng(1).exponential(size=250)
    rng = np.random.default_rng(4)
    draws = [np.quantile(err[rng.integers(0, err.size, err.size)], 0.9) for _ in range(500)]
    assert intervals.bootstrap_interval(err, n_boot=500, seed=4) == (float(np.quantile(draws, 0.025)),
                                                                    float(np.quantile(draws, 0.975)))


@pytest.mark.parametrize("lo, hi, low, high, verdict", [
    (1.0, 1.5, 0.0, 2.0, "reproduces"), (1.0, 2.5, 0.0, 2.0, "unresolved"), (2.1, 3.0, 0.0, 2.0, "fails"),
    (1.1, 1.3, 1.0, np.inf, "reproduces"), (0.9, 1.3, 1.0, np.inf, "unresolved"), (0.5, 0.9, 1.0, np.inf, "fails"),
    (30.0, 40.0, 33.6, 50.4, "unresolved"), (35.0, 40.0, 33.6, 50.4, "reproduces"), (51.0, 60.0, 33.6, 50.4, "fails"),
])
def test_verdict_follows_the_interval_against_the_claims_range(lo, hi, low, high, verdict):
    iv = intervals.Interval(value=(lo + hi) / 2, lo=lo, hi=hi, n_trials=100)
    assert iv.verdict(low, high) == verdict


def test_bad_input_is_refused_with_the_parameter_named():
    a = np.ones(10)
    with pytest.raises(ValueError, match="same trials"):
        intervals.quantile_difference(a, np.ones(11))
    with pytest.raises(ValueError, match="level must be in"):
        intervals.quantile_difference(a, a, level=1.5)
    with pytest.raises(ValueError, match="n_boot must be"):
        intervals.quantile_difference(a, a, n_boot=1)
    with pytest.raises(ValueError, match="low <= high"):
        intervals.Interval(1.0, 0.5, 1.5, 10).verdict(2.0, 1.0)
