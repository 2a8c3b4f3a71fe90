"""Bounds under the NLoS excess delay (ours, beyond the paper): the misspecified Cramér–Rao bound of a receiver that
models no delay, beside the bound of one that models it.

The links' ToA information is ``crb``'s: on the range r_m = c τ_m each link carries w_m = J_τ,m / c² (1/m²), and
the position θ = (x, y, c δt) at a known UE height enters through h_m(θ) = ‖p − b_m‖ + c δt (``bounds.position_fisher``
is Hᵀ W H, H the rows ∂h_m/∂θ).  Under NLoS the true ranges are h_m(θ*) + c Δτ_m.

* A naive receiver (eq. (10) or the OTDoA fit) maximises the likelihood of the model without the delay.  At high SNR
  it converges to the pseudo-true point θ₀ = argmin_θ Σ_m w_m (h_m(θ*) + c Δτ_m − h_m(θ))², and its covariance about
  θ₀ is bounded by the misspecified CRB (Richmond and Horowitz; eq. (B1) of the NLoS chapter)::

      MCRB = A⁻¹ B A⁻¹,   B = Hᵀ W H,   A = Hᵀ W H − Σ_m w_m e_m ∇²h_m,   e_m = h_m(θ*) + c Δτ_m − h_m(θ₀),

  all at θ₀ (``misspecified_bound``).  Its mean-square error is MCRB + (θ₀ − θ*)(θ₀ − θ*)ᵀ: a variance and a bias.
* A receiver that models the delay as a parameter per NLoS link, with TR 38.901's log-normal as its prior and the
  LoS states known (a genie: more than any receiver knows), has the Bayesian information of (θ, c Δτ_NLoS); its
  bound on θ (eq. (B2), ``aware_crb``) is Hᵀ W' H with each NLoS link's range variance grown by the prior's:
  1/w'_m = 1/w_m + 1/J_p, J_p the log-normal's Fisher information (``excess_fisher_per_m2``).  It has no bias.

With one path per link (``bounds.toa_fisher`` without taps) J_τ is the most a link can carry, so both bounds are
lower bounds for the TDL links of the experiments as well.  Units: metres, seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

from ..phy.nr import C
from . import crb

#: Gauss–Newton of the pseudo-true point stops once its step is shorter than this (m)
PSEUDO_TRUE_STOP_M = 1e-9


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class MisspecifiedBound:
    """The naive receiver under the delay (``misspecified_bound``).

    Attributes
    ----------
    bias_m : float (3,)
        θ₀ − θ*, the pseudo-true point's offset in (x, y, c δt), metres.
    mcrb : float (3, 3)
        Eq. (B1), the bound on the covariance about θ₀, m²; NaN where A is not positive definite at θ₀ (the fit's
        minimum is not strict there, and the bound does not exist).
    """

    bias_m: np.ndarray
    mcrb: np.ndarray

    @property
    def horizontal_rmse_m(self) -> np.ndarray:
        """The bound on the RMS horizontal error, √(MCRB_xx + MCRB_yy + bias_x² + bias_y²), metres (leading axes)."""
        return np.sqrt(self.horizontal_variance_m2 + np.sum(self.bias_m[..., :2] ** 2, axis=-1))

    @property
    def horizontal_variance_m2(self) -> np.ndarray:
        """MCRB_xx + MCRB_yy, the variance part, m² (leading axes)."""
        return self.mcrb[..., 0, 0] + self.mcrb[..., 1, 1]


def _ranges(theta, ue_z, bs):
    """h_m(θ) (..., M), the rows ∂h_m/∂θ (..., M, 3) and the horizontal Hessians ∇²h_m (..., M, 2, 2)."""
    d = np.stack([theta[..., None, 0] - bs[..., 0], theta[..., None, 1] - bs[..., 1], ue_z[..., None] - bs[..., 2]],
                 axis=-1)
    r = np.linalg.norm(d, axis=-1)
    u = d[..., :2] / r[..., None]
    hess = (np.eye(2) - u[..., :, None] * u[..., None, :]) / r[..., None, None]
    return r + theta[..., None, 2], np.concatenate([u, np.ones(r.shape + (1,))], axis=-1), hess


def _check(ue_xyz, bs_xyz, toa_fisher_s, excess_s):
    ue, bs, j, ex = (np.asarray(a, dtype=float) for a in (ue_xyz, bs_xyz, toa_fisher_s, excess_s))
    if ue.shape[-1:] != (3,) or bs.shape[:-2] != ue.shape[:-1] or bs.shape[-1] != 3 or bs.shape[-2] < 3 \
            or j.shape != bs.shape[:-1] or ex.shape != j.shape:
        raise ValueError(f"misspecified_bound needs ue_xyz (..., 3), bs_xyz (..., M, 3) with M >= 3, toa_fisher_s and "
                         f"excess_s (..., M); got {ue.shape}, {bs.shape}, {j.shape}, {ex.shape}")
    for name, a in (("ue_xyz", ue), ("bs_xyz", bs), ("toa_fisher_s", j), ("excess_s", ex)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite")
    if np.any(j <= 0) or np.any(ex < 0):
        raise ValueError("toa_fisher_s must be > 0 (1/s²) and excess_s ≥ 0 (s)")
    return ue, bs, j / C**2, ex


def _pseudo_true(theta, ue_z, bs, w, target):
    """Gauss–Newton of the weighted fit Σ_m w_m (target_m − h_m(θ))² from θ (T, 3), each step halved while the cost
    rises, on the trials not yet converged only."""
    theta = theta.copy()
    active = np.arange(len(theta))
    cost = lambda th, a: np.sum(w[a] * (target[a] - _ranges(th, ue_z[a], bs[a])[0]) ** 2, axis=-1)  # noqa: E731
    for _ in range(100):
        th = theta[active]
        h, jac, _ = _ranges(th, ue_z[active], bs[active])
        wj = w[active, :, None] * jac
        step = np.einsum("...ij,...j->...i", np.linalg.pinv(np.swapaxes(jac, -1, -2) @ wj),
                         np.einsum("...mi,...m->...i", wj, target[active] - h))
        base = cost(th, active)
        for _ in range(60):
            worse = (cost(th + step, active) > base) & (np.linalg.norm(step, axis=-1) > PSEUDO_TRUE_STOP_M)
            if not worse.any():
                break
            step = np.where(worse[:, None], step / 2, step)
        theta[active] = th + step
        active = active[np.linalg.norm(step, axis=-1) > PSEUDO_TRUE_STOP_M]
        if active.size == 0:
            break
    return theta


def misspecified_bound(ue_xyz, bs_xyz, toa_fisher_s, excess_s) -> MisspecifiedBound:
    """Eq. (B1): the pseudo-true point and the misspecified CRB of a receiver that models no excess delay.

    Vectorised over leading axes (one geometry per trial).

    Parameters
    ----------
    ue_xyz : float (..., 3)
        The true UE position, metres (its height is known to the receiver).
    bs_xyz : float (..., M, 3)
        Base-station positions, metres, M ≥ 3.
    toa_fisher_s : float (..., M)
        Each link's J_τ, 1/s², > 0 (``bounds.toa_fisher``).
    excess_s : float (..., M)
        Each link's excess delay Δτ_m ≥ 0, seconds (0 on a LoS link); the true clock bias is taken as 0 (it only
        shifts c δt).

    Returns
    -------
    MisspecifiedBound
        Fields with the leading axes.

    Raises
    ------
    ValueError
        Shapes that do not match, values not finite, a J_τ not > 0 or a delay < 0.
    """
    ue, bs, w, ex = _check(ue_xyz, bs_xyz, toa_fisher_s, excess_s)
    truth = np.concatenate([ue[..., :2], np.zeros(ue.shape[:-1] + (1,))], axis=-1)
    target = _ranges(truth, ue[..., 2], bs)[0] + C * ex
    theta = _pseudo_true(truth.reshape(-1, 3), ue[..., 2].reshape(-1), bs.reshape(-1, *bs.shape[-2:]),
                         w.reshape(-1, w.shape[-1]), target.reshape(-1, w.shape[-1])).reshape(truth.shape)
    h, jac, hess = _ranges(theta, ue[..., 2], bs)
    b = np.swapaxes(jac, -1, -2) @ (w[..., None] * jac)
    a = b.copy()
    a[..., :2, :2] -= np.einsum("...m,...mij->...ij", w * (target - h), hess)
    # where A is not positive definite at θ₀ the fit's minimum is not strict, and the bound does not exist (NaN)
    strict = np.linalg.eigvalsh(a)[..., 0] > 1e-9 * np.linalg.eigvalsh(b)[..., -1]
    a_inv = np.linalg.inv(np.where(strict[..., None, None], a, np.eye(3)))
    mcrb = np.where(strict[..., None, None], a_inv @ b @ a_inv, np.nan)
    return MisspecifiedBound(bias_m=theta - truth, mcrb=mcrb)


def excess_fisher_per_m2(median_s: float, sigma_lg: float) -> float:
    """J_p, the Fisher information of a log-normal excess delay about its own value, in 1/m² of c Δτ.

    For ln Δτ ~ N(μ, s²), s = sigma_lg · ln 10: E[(∂ ln f / ∂Δτ)²] = e^{2s² − 2μ} (1 + s²) / s².

    Parameters
    ----------
    median_s : float
        The median e^μ, seconds, > 0.
    sigma_lg : float
        The standard deviation of lg Δτ, decades, > 0.

    Returns
    -------
    float
        J_p, 1/m².

    Raises
    ------
    ValueError
        A median or σ not > 0.
    """
    if not (median_s > 0 and sigma_lg > 0):
        raise ValueError(f"median_s and sigma_lg must be > 0, got {median_s!r}, {sigma_lg!r}")
    s = sigma_lg * np.log(10.0)
    return float(np.exp(2 * s**2) * (1 + s**2) / s**2 / median_s**2 / C**2)


def aware_crb(ue_xyz, bs_xyz, toa_fisher_s, nlos, median_s: float, sigma_lg: float) -> np.ndarray:
    """Eq. (B2): the bound on θ = (x, y, c δt) of a receiver that models each NLoS link's delay under its prior.

    Vectorised over leading axes.

    Parameters
    ----------
    ue_xyz, bs_xyz, toa_fisher_s
        As for ``misspecified_bound``.
    nlos : bool (..., M)
        The links whose delay the receiver models (the NLoS ones; the LoS states known, a genie).
    median_s, sigma_lg : float
        The prior (``excess_fisher_per_m2``).

    Returns
    -------
    float (..., 3, 3)
        The bound, m².

    Raises
    ------
    ValueError
        As ``misspecified_bound``, or a prior not > 0.
    """
    j_p = excess_fisher_per_m2(median_s, sigma_lg)
    ue, bs, w, _ = _check(ue_xyz, bs_xyz, toa_fisher_s, np.zeros(np.shape(toa_fisher_s)))
    w = np.where(np.asarray(nlos, dtype=bool), 1.0 / (1.0 / w + 1.0 / j_p), w)
    truth = np.concatenate([ue[..., :2], np.zeros(ue.shape[:-1] + (1,))], axis=-1)
    jac = _ranges(truth, ue[..., 2], bs)[1]
    return np.linalg.inv(np.swapaxes(jac, -1, -2) @ (w[..., None] * jac))
