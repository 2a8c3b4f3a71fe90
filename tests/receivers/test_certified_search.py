"""The certified search (``certified_search.certified_search``) against an exhaustive evaluation of the same window."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dpe5g.phy import propagation
from dpe5g.receivers import certified_search, correlogram, cost, dpe_nlos, search_config, spline_boxes
from dpe5g.simulation import experiment, trials
from dpe5g.phy.nr import C, PAPER

N_TRIALS = 16  # each costs an exhaustive evaluation of its window (about 2.5 s)
CFG = search_config.SearchConfig(method="bnb", half_width_m=8.0, bias_half_width_m=3 * 5e-9 * C)


def _exhaustive_max(coef, bs, center, cfg, step=0.1):
    """max of the spline cost over a 0.1 m grid of the whole window (x, y, c δt), by brute force."""
    return float(_exhaustive_fn(cfg, step)(coef, bs, center))


@functools.lru_cache(maxsize=4)
def _exhaustive_fn(cfg, step):
    """The brute-force maximum as one jitted function of (coef, bs, center): compiled once per window, not per trial
    (closing over a trial's arrays would make them constants of a new program each time)."""
    cell_m = C * PAPER.sample_period_s / cfg.spline_upsample
    ax = np.arange(-cfg.half_width_m, cfg.half_width_m + 1e-9, step)
    ab = np.arange(-cfg.bias_half_width_m, cfg.bias_half_width_m + 1e-9, step)

    @jax.jit
    def best(coef, bs, center):
        def row(x):  # one column of the grid: every y and c δt at this x
            xy = jnp.stack([jnp.full(ax.shape, center[0] + x), center[1] + ax], -1)
            d = jnp.sqrt(jnp.sum((xy[:, None, :] - bs[None, :, :2]) ** 2, -1) + (center[2] - bs[None, :, 2]) ** 2)
            pos = (d[:, None, :] + center[3] + ab[None, :, None]) / cell_m  # (XY, B, M)
            return jnp.max(spline_boxes.spline_values(coef, pos))

        return jnp.max(jax.lax.map(row, jnp.asarray(ax)))

    return best


@pytest.fixture(scope="module")
def urban_trials():
    e = experiment.Experiment.build(name="t", n_trials=N_TRIALS, seed=10, snr_mode="link_budget", snrs_db=(), m_values=(4,),
                              centring="prior", search=CFG)
    out = []
    for t in range(N_TRIALS):
        ex = trials.example(e, t)
        rng = np.random.default_rng(t)
        center = np.array([*(ex.ue_xyz[:2] + rng.normal(0, 3.0, 2)), ex.ue_xyz[2], 0.0])
        out.append((ex, center))
    return e, out


def test_certified_search_finds_the_exhaustive_maximum(urban_trials):
    e, items = urban_trials
    search = jax.jit(lambda coef, bs, c: certified_search.certified_search(coef, bs, c, CFG))
    worst, n_cert = np.inf, 0
    for ex, center in items:
        coef = correlogram.spline_correlogram(ex.y, ex.prs, CFG.n_taps, CFG.spline_upsample)
        r, r_cost = search(coef, jnp.asarray(ex.bs_xyz), jnp.asarray(center))
        best = _exhaustive_max(coef, jnp.asarray(ex.bs_xyz), jnp.asarray(center), CFG)
        # the returned cost is the spline at the returned point, and no grid point beats it by more than 1e-4
        q = np.asarray(r.q)
        pos = (np.linalg.norm(q[:3] - ex.bs_xyz, axis=1) + q[3]) / (C * PAPER.sample_period_s / CFG.spline_upsample)
        assert float(spline_boxes.spline_values(coef, jnp.asarray(pos))) == pytest.approx(float(r_cost), rel=1e-12)
        worst = min(worst, float(r_cost) / best)
        n_cert += bool(r.certified)
        if bool(r.certified):  # a certified fix bounds the maximum of the whole window, grid or not
            assert best <= float(r_cost) * (1 + CFG.gap_tol) * (1 + 1e-12)
    assert worst >= 1 - 1e-4, worst
    assert n_cert >= N_TRIALS // 2


def test_certified_search_does_not_depend_on_the_grid_phase(urban_trials):
    """Shifting the window by a fraction of a cell moves the fix by at most the resolution, except between points
    whose costs tie within the certified tolerance (a flat multipath cost: both are maxima).  Fixes on the edge of
    either window are left out: there the two windows hold different points.  Ties are not rare here: with one noise
    floor the nearest link's energy dominates the cost (its SNR is often 20–40 dB above the fourth link's), and its
    L-tap window sum is flat while the window holds its whole channel, so points tens of centimetres apart can tie
    to 1e-7 of the cost; the guard below only asks that the comparison is not vacuous."""
    e, items = urban_trials
    search = jax.jit(lambda coef, bs, c: certified_search.certified_search(coef, bs, c, CFG))
    moved = compared = 0
    for ex, center in items:
        coef = correlogram.spline_correlogram(ex.y, ex.prs, CFG.n_taps, CFG.spline_upsample)
        bs = jnp.asarray(ex.bs_xyz)
        a, a_cost = search(coef, bs, jnp.asarray(center))
        b, b_cost = search(coef, bs, jnp.asarray(center + np.array([0.37, -0.21, 0.0, 0.13])))
        if bool(a.edge) or bool(b.edge):
            continue
        compared += 1
        if np.linalg.norm(np.asarray(a.q) - np.asarray(b.q)) > 2 * CFG.box_final_m:
            moved += 1
            tol = (float(a.gap) + float(b.gap) + 1e-9) * float(a_cost)
            assert abs(float(a_cost) - float(b_cost)) <= tol
    assert compared >= 0.8 * N_TRIALS and moved <= compared // 2, (compared, moved)


def test_chunk_size_and_capacity_do_not_change_an_undropped_fix(urban_trials):
    """The boxes of a level are refined a chunk at a time and a box overtaken by an earlier chunk's best cost is
    skipped: that changes which boxes are refined, never the fix, since every box that holds a better point is still
    refined.  So chunks of 8 boxes in a capacity of 256 give the fix of chunks of 16 in 1024 (the default) wherever
    no box was dropped; a capacity too small for the boxes alive drops boxes and the fix says it is not certified.
    (Each configuration is a compile of its own, the cost of this test.)"""
    e, items = urban_trials
    cfgs = [dataclasses.replace(CFG, capacity=256, chunk_boxes=8), CFG]
    tiny = dataclasses.replace(CFG, capacity=8, chunk_boxes=8)
    runs = [jax.jit(lambda coef, bs, c, cfg=cfg: certified_search.certified_search(coef, bs, c, cfg)) for cfg in cfgs + [tiny]]
    n_tiny_uncertified = 0
    for ex, center in items[:12]:
        coef = correlogram.spline_correlogram(ex.y, ex.prs, CFG.n_taps, CFG.spline_upsample)
        args = (coef, jnp.asarray(ex.bs_xyz), jnp.asarray(center))
        *rs, (small, small_cost) = [run(*args) for run in runs]
        (last, last_cost) = rs[-1]
        for r, r_cost in rs[:-1]:
            if bool(r.certified) and bool(last.certified):
                np.testing.assert_array_equal(np.asarray(r.q), np.asarray(last.q))
                assert float(r_cost) == float(last_cost)
        n_tiny_uncertified += not bool(small.certified)
        assert float(small_cost) <= float(last_cost) * (1 + CFG.gap_tol)
    assert n_tiny_uncertified >= 6


def test_spline_correlogram_is_exact_at_the_knots():
    ex = trials.example(experiment.Experiment.build(n_trials=1, m_values=(6,), snrs_db=(20.0,)), 0)
    coef = correlogram.spline_correlogram(ex.y, ex.prs, 12, 8)
    ref = np.asarray(correlogram.correlogram(ex.y, ex.prs, 12, 8))
    vals = (np.roll(coef, 1, -1) + 4 * np.asarray(coef) + np.roll(coef, -1, -1)) / 6
    assert np.max(np.abs(vals - ref)) <= 1e-10 * ref.max()
    tau = np.asarray(cost.toa(ex.ue_xyz, ex.bs_xyz, float(ex.clock_bias_s)))[None] + np.linspace(-30e-9, 30e-9, 41)[:, None]
    exact = np.asarray(cost.ml_cost(ex.y, ex.prs, tau, 12, PAPER.scs_hz))
    spl = np.asarray(spline_boxes.spline_values(coef, jnp.asarray(tau / PAPER.sample_period_s * 8)))
    assert np.max(np.abs(spl - exact)) <= 1e-4 * exact.max()


def test_bnb_config_rejects_bad_input():
    with pytest.raises(ValueError, match="spline_upsample"):
        search_config.SearchConfig(method="bnb", spline_upsample=3)
    with pytest.raises(ValueError, match="method"):
        search_config.SearchConfig(method="exhaustive")
    with pytest.raises(ValueError, match="chunk_boxes"):
        search_config.SearchConfig(method="bnb", capacity=1024, chunk_boxes=48)
    with pytest.raises(ValueError, match="z_half_width_m"):
        search_config.SearchConfig(method="bnb", z_half_width_m=2.0)
    with pytest.raises(ValueError, match="otdoa"):
        experiment.Experiment.build(centring="otdoa")
    with pytest.raises(ValueError, match="prior_kind"):
        experiment.Experiment.build(centring="prior", prior_kind="cauchy")


FIRST_PATH = dataclasses.replace(CFG, window_decay_s=65e-9, box_final_m=0.0125)


def test_first_path_window_is_the_weighted_cost():
    """The first-path-aware window (tap l weighted by exp(−l T_s / decay)): ``ml_cost`` with weights equals the
    weighted sum of one-tap costs at τ + l T_s (an independent evaluation), and its spline equals ``ml_cost``."""
    ex = trials.example(experiment.Experiment.build(n_trials=1, m_values=(6,), snrs_db=(20.0,)), 0)
    w = FIRST_PATH.tap_weights()
    assert w[0] == 1.0 and np.all(np.diff(w) < 0)
    np.testing.assert_allclose(w[1:] / w[:-1], np.exp(-PAPER.sample_period_s / 65e-9), rtol=1e-12)
    tau = np.asarray(cost.toa(ex.ue_xyz, ex.bs_xyz, float(ex.clock_bias_s)))[None] + np.linspace(-30e-9, 30e-9, 41)[:, None]
    exact = np.asarray(cost.ml_cost(ex.y, ex.prs, tau, 12, PAPER.scs_hz, weights=w))
    one_tap = sum(w[l] * np.asarray(cost.ml_cost(ex.y, ex.prs, tau + l * PAPER.sample_period_s, 1, PAPER.scs_hz))
                  for l in range(12))
    np.testing.assert_allclose(exact, one_tap, rtol=1e-9)
    coef = correlogram.spline_correlogram(ex.y, ex.prs, 12, 8, weights=w)
    spl = np.asarray(spline_boxes.spline_values(coef, jnp.asarray(tau / PAPER.sample_period_s * 8)))
    assert np.max(np.abs(spl - exact)) <= 1e-4 * exact.max()


def test_certified_search_finds_the_exhaustive_maximum_of_the_first_path_cost(urban_trials):
    """The weighted cost is steeper than eq. (10)'s along the plateau, so the certificate (gap ≤ 1e-4) needs finer
    final boxes (1.25 cm here; at the figures' 5 cm most fixes are left uncertified, and counted so); the maximum
    must be found either way."""
    e, items = urban_trials
    search = jax.jit(lambda coef, bs, c: certified_search.certified_search(coef, bs, c, FIRST_PATH))
    w = FIRST_PATH.tap_weights()
    n_cert = 0
    for ex, center in items[:12]:
        coef = correlogram.spline_correlogram(ex.y, ex.prs, FIRST_PATH.n_taps, FIRST_PATH.spline_upsample, w)
        r, r_cost = search(coef, jnp.asarray(ex.bs_xyz), jnp.asarray(center))
        best = _exhaustive_max(coef, jnp.asarray(ex.bs_xyz), jnp.asarray(center), FIRST_PATH)
        assert float(r_cost) >= best * (1 - 1e-4)
        n_cert += bool(r.certified)
        if bool(r.certified):
            assert best <= float(r_cost) * (1 + FIRST_PATH.gap_tol) * (1 + 1e-12)
    assert n_cert >= 6


def test_first_path_window_rejects_bad_input():
    with pytest.raises(ValueError, match="window_decay_s"):
        search_config.SearchConfig(method="bnb", window_decay_s=65.0)  # nanoseconds passed as seconds
    with pytest.raises(ValueError, match="needs method 'bnb'"):
        search_config.SearchConfig(window_decay_s=65e-9)
    with pytest.raises(ValueError, match="weights must be 12"):
        correlogram.window_spectrum(12, 64, np.ones(11))
    with pytest.raises(ValueError, match="weights must be 3"):
        correlogram.window_spectrum(3, 64, [1.0, -0.5, 0.2])
    with pytest.raises(ValueError, match="decay_s"):
        correlogram.tap_weights(12, -1e-9)


def test_certified_search_finds_the_exhaustive_maximum_of_the_nlos_aware_cost(urban_trials):
    """The NLoS-aware DPE's cost (eq. (D1), ``dpe_nlos.marginal_window``, TR 38.901's UMi excess delay) in the same
    windows: the certified search reads only the window's coefficients, and the brute force reads them too (put
    back at their knots of the period, zeros elsewhere, where no ToA of the window reaches)."""
    e, items = urban_trials
    umi = propagation.TR38901_EXCESS_DELAY["UMi"]
    window = jnp.asarray(correlogram.window_spectrum(CFG.n_taps, PAPER.n_fft))
    aware = jax.jit(lambda coef, bs, c: dpe_nlos.marginal_window(coef, bs, c, CFG, window, umi.median_s, umi.sigma_lg,
                                                                 dpe_nlos.CLOCK_NLOS_QUANTILE))
    search = jax.jit(lambda sl, st, bs, c: certified_search.certified_search((sl, st), bs, c, CFG))
    for ex, center in items[:3]:
        coef = correlogram.spline_correlogram(ex.y, ex.prs, CFG.n_taps, CFG.spline_upsample)
        bs, c = jnp.asarray(ex.bs_xyz), jnp.asarray(center)
        sl, st = aware(coef, bs, c)
        r, r_cost = search(sl, st, bs, c)
        idx = np.mod(np.asarray(st)[:, None] + np.arange(sl.shape[1]), coef.shape[1])
        full = np.zeros(coef.shape)
        np.put_along_axis(full, idx, np.asarray(sl), axis=1)
        best = _exhaustive_max(jnp.asarray(full), bs, c, CFG)
        assert float(r_cost) >= best * (1 - 1e-4)
        if bool(r.certified):
            assert best <= float(r_cost) * (1 + CFG.gap_tol) * (1 + 1e-12)
