"""The bounds under the NLoS excess delay (``dpe5g.bounds.misspecified``): the misspecified CRB against the well-specified
one, an independent optimiser and a Monte Carlo of the weighted fit; the prior's Fisher information against a
numerical integral; the NLoS-aware bound against the full Bayesian information matrix."""

import numpy as np
import pytest
from scipy import integrate, optimize, stats

from dpe5g.bounds import crb, misspecified as nlos_bounds
from dpe5g.phy.nr import C

UE = np.array([12.0, -30.0, 1.5])
BS = np.array([[150.0, 20.0, 10.0], [-90.0, 120.0, 10.0], [-60.0, -170.0, 10.0], [110.0, -140.0, 10.0],
               [0.0, 200.0, 10.0]])
J = np.array([4e20, 1e21, 2e20, 6e20, 3e20])  # 1/s²: range σ from 1.5 to 2.1 cm
EXCESS = np.array([0.0, 80e-9, 0.0, 25e-9, 0.0])


def test_without_a_delay_it_is_the_crb_and_no_bias():
    mb = nlos_bounds.misspecified_bound(UE, BS, J, np.zeros(5))
    np.testing.assert_allclose(mb.bias_m, 0.0, atol=1e-9)
    np.testing.assert_allclose(mb.mcrb, crb.position_crb(UE, BS, J), rtol=1e-9)


def test_the_pseudo_true_point_is_the_weighted_fit_of_scipy():
    w = J / C**2
    target = np.linalg.norm(UE - BS, axis=1) + C * EXCESS

    def resid(th):
        return np.sqrt(w) * (target - np.linalg.norm(np.array([th[0], th[1], UE[2]]) - BS, axis=1) - th[2])

    fit = optimize.least_squares(resid, np.array([UE[0], UE[1], 0.0]), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    mb = nlos_bounds.misspecified_bound(UE, BS, J, EXCESS)
    np.testing.assert_allclose(mb.bias_m, fit - np.array([UE[0], UE[1], 0.0]), atol=1e-6)
    assert np.hypot(*mb.bias_m[:2]) > 1.0  # 24 m and 7.5 m late links move the fix by metres


def test_the_misspecified_crb_is_the_spread_of_the_weighted_fit():
    """Noisy ranges about the late ones (σ_m = c / √J_m × 300, 4000 draws, each fitted by plain Gauss–Newton): the
    covariance of the fits is the MCRB within 10 % (its diagonal), not the CRB, and their mean the pseudo-true
    point within 4 of its standard errors."""
    rng = np.random.default_rng(0)
    j = J / 300**2  # decimetre ranges: the curvature term of A is then visible against the noise
    w = j / C**2
    mb = nlos_bounds.misspecified_bound(UE, BS, j, 4 * EXCESS)  # 96 m and 30 m late
    assert np.all(np.isfinite(mb.mcrb))
    r = np.linalg.norm(UE - BS, axis=1) + C * 4 * EXCESS + rng.normal(size=(4000, 5)) / np.sqrt(w)
    th = np.tile(np.array([UE[0], UE[1], 0.0]) + mb.bias_m, (4000, 1))
    for _ in range(10):
        d = np.concatenate([th[:, None, :2] - BS[None, :, :2], np.broadcast_to(UE[2] - BS[:, 2], (4000, 5))[..., None]],
                           axis=-1)
        rng_m = np.linalg.norm(d, axis=-1)
        jac = np.concatenate([d[..., :2] / rng_m[..., None], np.ones((4000, 5, 1))], axis=-1)
        th = th + np.linalg.solve(np.einsum("tmi,m,tmj->tij", jac, w, jac),
                                  np.einsum("tmi,m,tm->ti", jac, w, r - rng_m - th[:, None, 2])[..., None])[..., 0]
    fits = th - np.array([UE[0], UE[1], 0.0])
    np.testing.assert_allclose(np.diag(np.cov(fits.T)), np.diag(mb.mcrb), rtol=0.1)
    assert np.all(np.abs(fits.mean(axis=0) - mb.bias_m) < 4 * np.sqrt(np.diag(mb.mcrb) / 4000))
    assert not np.allclose(np.diag(mb.mcrb), np.diag(crb.position_crb(UE, BS, j)), rtol=0.1)  # A ≠ B here


def test_the_log_normal_fisher_information_is_its_integral():
    """E[(∂ ln f / ∂x)²] by quadrature over z, x = median e^{s z}: ∂ ln f / ∂x = −(1 + z / s) / x."""
    median, sigma_lg = 31.6e-9, 0.5
    s = sigma_lg * np.log(10)
    num = integrate.quad(lambda z: (1 + z / s) ** 2 * np.exp(-2 * s * z) * stats.norm.pdf(z), -12, 12)[0] / median**2
    assert nlos_bounds.excess_fisher_per_m2(median, sigma_lg) == pytest.approx(num / C**2, rel=1e-8)


def test_the_aware_bound_is_the_full_bayesian_information_inverted():
    """The bound of (x, y, c δt) from the (3 + K) × (3 + K) information matrix of the position and the K NLoS links'
    delays, the prior's information on their diagonal: the same as the variance-summing form, and between the CRB
    with every link and the CRB with the LoS links alone."""
    nlos = EXCESS > 0
    j_p = nlos_bounds.excess_fisher_per_m2(31.6e-9, 0.5)
    w = J / C**2
    d = UE - BS
    g = np.column_stack([d[:, 0], d[:, 1], np.linalg.norm(d, axis=1)]) / np.linalg.norm(d, axis=1)[:, None]
    e = np.eye(5)[:, nlos]  # ∂h/∂(c Δτ_k)
    full = np.block([[g.T @ (w[:, None] * g), g.T @ (w[:, None] * e)],
                     [e.T @ (w[:, None] * g), e.T @ (w[:, None] * e) + j_p * np.eye(nlos.sum())]])
    want = np.linalg.inv(full)[:3, :3]
    got = nlos_bounds.aware_crb(UE, BS, J, nlos, 31.6e-9, 0.5)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    h = lambda c: crb.horizontal_rmse_bound_m(c)
    assert h(crb.position_crb(UE, BS, J)) < h(got) < h(crb.position_crb(UE, BS[~nlos], J[~nlos]))


def test_bad_input_names_the_parameter():
    with pytest.raises(ValueError, match="excess_s"):
        nlos_bounds.misspecified_bound(UE, BS, J, -EXCESS)
    with pytest.raises(ValueError, match="bs_xyz"):
        nlos_bounds.misspecified_bound(UE, BS[:2], J[:2], EXCESS[:2])
    with pytest.raises(ValueError, match="median_s"):
        nlos_bounds.excess_fisher_per_m2(0.0, 0.5)
