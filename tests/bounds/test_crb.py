"""Cramér–Rao bounds (``dpe5g.bounds.crb``) against independent NumPy evaluations, the closed forms, and a Monte Carlo of
the ML ToA."""

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dpe5g.phy import channel
from dpe5g.simulation import engine, experiment, trials
from dpe5g.bounds import crb as bounds
from dpe5g.studies import paper
from dpe5g.phy.nr import C, PAPER


def _fisher_by_jacobian(freqs, gains, delays, noise_var):
    """CRB of τ written out the long way: the real Fisher matrix of (τ, Re a_1…a_L, Im a_1…a_L) from the Jacobian of
    μ_k = Σ_l a_l e^{-j2π f_k (τ + δ_l)} at τ = 0, (2/σ²) Re(JᴴJ), inverted whole; returns 1 / CRB_ττ."""
    e = np.exp(-2j * np.pi * np.outer(freqs, delays))  # (K, L)
    d_tau = (-2j * np.pi * freqs[:, None] * e) @ gains
    jac = np.column_stack([d_tau, e, 1j * e])  # ∂μ/∂τ, ∂μ/∂Re a_l, ∂μ/∂Im a_l
    fim = 2.0 / noise_var * np.real(jac.conj().T @ jac)
    return 1.0 / np.linalg.inv(fim)[0, 0]


@pytest.mark.parametrize("subcarriers,comb", [("full", 4), ("active", 4), ("comb", 4), ("comb", 12)])
def test_single_link_fisher_matches_the_full_fisher_matrix(subcarriers, comb):
    f = bounds.subcarrier_frequencies_hz(subcarriers, comb=comb)
    prof = channel.tdl_profile("C", 100e-9)
    gains = np.asarray(channel.draw_gains(prof, jax.random.PRNGKey(3)))
    for g, dl in ((np.ones(1), np.zeros(1)), (gains, prof.delays_s)):
        ref = _fisher_by_jacobian(f, g, dl, 10 ** (-1.5))
        assert bounds.toa_fisher(f, 15.0, g, dl) == pytest.approx(ref, rel=1e-6)


def test_single_path_closed_forms():
    n, df = PAPER.n_fft, PAPER.scs_hz
    f = bounds.subcarrier_frequencies_hz("full")
    beta = bounds.rms_bandwidth_hz(f)
    assert beta == pytest.approx(df * np.sqrt((n**2 - 1) / 12), rel=1e-12)
    rho = 10 ** (7.0 / 10)
    assert bounds.toa_crb_s(f, 7.0) == pytest.approx(1 / (2 * np.pi * beta * np.sqrt(2 * rho * n)), rel=1e-9)
    # a comb of K keeps 1/K of the subcarriers and (nearly) the same β: the variance grows K-fold
    full = bounds.toa_fisher(bounds.subcarrier_frequencies_hz("active"), 7.0)
    for k in (2, 4, 6, 12):
        ratio = full / bounds.toa_fisher(bounds.subcarrier_frequencies_hz("comb", comb=k), 7.0)
        assert ratio == pytest.approx(k, rel=2e-2)


def test_window_model_keeps_about_half_the_information():
    """Eq. (8)'s L free taps on the sample grid: the information about τ falls with L (nested models) towards half
    the one-path value (the window is one-sided: it absorbs the derivative's components at later delays only)."""
    f = bounds.subcarrier_frequencies_hz("full")
    one = bounds.toa_fisher(f, 10.0)
    ratios = [bounds.window_model_toa_fisher(f, 10.0, n) / one for n in (1, 2, 4, 8, 12, 24, 64)]
    assert ratios[0] == pytest.approx(1.0, rel=1e-9)
    assert all(b < a for a, b in zip(ratios, ratios[1:]))
    assert 0.5 < ratios[-1] < 0.52 and 0.5 < ratios[4] < 0.55


@settings(max_examples=25, deadline=None)
@given(m=st.integers(3, 12), seed=st.integers(0, 2**31 - 1), ref=st.integers(0, 11))
def test_dpe_and_two_step_bounds_coincide(m, seed, ref):
    """With independent per-link gains, the DPE bound on (x, y) equals the two-step TDoA bound, whatever the
    reference link (the clock bias is a nuisance parameter either way)."""
    rng = np.random.default_rng(seed)
    bs = np.column_stack([rng.uniform(-300, 300, (m, 2)), rng.uniform(5, 40, m)])
    ue = np.array([*rng.uniform(-100, 100, 2), 1.5])
    j = rng.uniform(0.5, 2.0, m) / (1e-10) ** 2
    dpe_xy = bounds.position_crb(ue, bs, j)[:2, :2]
    tdoa = bounds.tdoa_position_crb(ue, bs, j, reference=ref % m)
    np.testing.assert_allclose(tdoa, dpe_xy, rtol=1e-7, atol=1e-12 * np.abs(dpe_xy).max())


def test_position_bound_scales_with_the_toa_bound():
    bs = np.array([[0.0, 0, 10], [200, 0, 10], [0, 200, 10], [200, 200, 10]])
    ue = np.array([80.0, 60.0, 1.5])
    j = np.full(4, 1 / (1e-9) ** 2)  # 1 ns per link
    b1 = bounds.horizontal_rmse_bound_m(bounds.position_crb(ue, bs, j))
    b4 = bounds.horizontal_rmse_bound_m(bounds.position_crb(ue, bs, 4 * j))
    assert b4 == pytest.approx(b1 / 2, rel=1e-12)
    assert 0.5 * C * 1e-9 < b1 < 5 * C * 1e-9


def test_ml_toa_reaches_the_bound_at_high_snr():
    """The ML ToA of one LoS path (``bounds.ml_toa_errors_s`` of ``paper.ml_toa_experiment``, the OTDoA peak
    detector on free-space links) at −10 dB per sample, well above the threshold after the correlation over
    N = 4096: its mean square over 1000 trials × 4 links is the CRB's within the Monte Carlo error (relative standard
    error of a mean square over n draws ≈ √(2/n) = 2.2 %), its bias below a tenth of √CRB.  The results come from
    the store (its sampled verification checks them against today's code)."""
    e = paper.ml_toa_experiment()
    crb = bounds.toa_crb_s(bounds.subcarrier_frequencies_hz("full"), paper.ML_TOA_SNR_DB)
    err = bounds.ml_toa_errors_s(engine.run(e, progress=False))
    assert err.size == e.run.n_trials * paper.ML_TOA_LINKS
    ratio = np.mean(err**2) / crb**2
    assert 0.93 < ratio < 1.07, ratio
    assert abs(np.mean(err)) < 0.1 * crb


def test_ml_toa_errors_need_a_free_space_experiment():
    e = paper.fig9_truth(2)
    with pytest.raises(ValueError, match="free_space"):
        bounds.ml_toa_errors_s(engine.run(e, progress=False))


def test_bounds_reject_bad_input():
    f = bounds.subcarrier_frequencies_hz("full")
    with pytest.raises(ValueError, match="subcarriers"):
        bounds.subcarrier_frequencies_hz("dense")
    with pytest.raises(ValueError, match="comb"):
        bounds.subcarrier_frequencies_hz("comb", comb=3)
    with pytest.raises(ValueError, match="snr_db"):
        bounds.toa_fisher(f, float("nan"))
    with pytest.raises(ValueError, match="tap_delays_s"):
        bounds.toa_fisher(f, 10.0, [1.0, 0.5], [0.0, 300.0])  # 300 ns passed as seconds
    with pytest.raises(ValueError, match="freqs_hz"):
        bounds.toa_fisher(np.full(10, 3e4), 10.0)
    with pytest.raises(ValueError, match="at least 3 base stations"):
        bounds.position_crb(np.zeros(3), np.ones((2, 3)), np.ones(2))
    with pytest.raises(ValueError, match="n_taps"):
        bounds.window_model_toa_fisher(f, 10.0, 2, gains=[1.0, 0.5, 0.2])


def test_experiment_bound_is_the_mean_of_its_trials_bounds():
    """``rmse_bound_m`` over an experiment: the RMS over trials of each trial's bound, which scales as 1/√SNR."""

    e = experiment.Experiment.build(n_trials=2, snrs_db=(10.0, 30.0), m_values=(3, 6), los_mode="all_los")
    got = bounds.rmse_bound_m(e, 2)
    assert got.shape == (2, 2)
    f = bounds.subcarrier_frequencies_hz("full")
    var = []
    for t in range(2):
        ex = trials.example(e, t)
        assert ex.los.all()
        j = np.array([bounds.toa_fisher(f, 10.0, ex.gains[i], ex.delays_s[i]) for i in range(6)])
        var.append([np.trace(bounds.position_crb(ex.ue_xyz, ex.bs_xyz[:m], j[:m])[:2, :2]) for m in (3, 6)])
    np.testing.assert_allclose(got[0], np.sqrt(np.mean(var, axis=0)), rtol=1e-9)
    np.testing.assert_allclose(got[1], got[0] / 10, rtol=1e-9)
    np.testing.assert_allclose(bounds.rmse_bound_m(e, 2, snrs_db=[0.0, 30.0]), [got[0] * 10 ** 0.5, got[1]], rtol=1e-9)
    with pytest.raises(ValueError, match="snrs_db"):
        bounds.rmse_bound_m(experiment.Experiment.build(n_trials=2, snr_mode="link_budget", snrs_db=()), 2, snrs_db=[0.0])
