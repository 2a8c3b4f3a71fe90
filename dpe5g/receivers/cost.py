"""The ML cost of DPE, eqs. (7)–(10), its correlogram lookup and its exact Newton step.

Eq. (10)::

    p̂ = argmax_p Σ_m ‖S_m(p)^H y_m‖²,   S_m(p) = F D_m Γ_m(τ_m(p)) F_L

is written here in the code's convention (see ``dpe5g.phy.signal``): F is the unitary inverse DFT of eq. (5)
([F]_{n,k} = e^{+j2πnk/N}/√N), D_m = diag(d_{m,k}), Γ_m(τ) = diag(e^{-j2πkΔfτ}), and F_L is the N × L matrix
[F_L]_{k,l} = e^{-j2πkl/N}/√N that turns an L-tap CIR on the sample grid into its frequency response.  Its columns
are orthonormal and D_m^H D_m = I for unit-modulus pilots, so S_m^H S_m = I_L (the identity under the brace of
eq. (8)).

Two evaluations of the same number:

* ``ml_cost_literal`` builds the matrices and multiplies them out (for verification on small N);
* ``ml_cost`` uses the identity derived in the DPE chapter,
  ``S_m^H y_m = √N · IDFT(conj(d_m) ⊙ DFT(y_m) ⊙ e^{+j2πkΔfτ_m})[0:L]``, the delay-compensated least-squares CIR
  estimate, so the cost is the energy of that estimate in an L-tap window.

Position model: p = [x, y, z, δt] with τ_m(p) = ‖(x, y, z) - b_m‖ / c + δt.  The searches (``grid_search``,
``certified_search``) work in metres, with the clock bias as b = c δt.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy import signal
from ..phy.nr import C
from . import correlogram

def ml_cost_literal(y, prs, tau, n_taps: int, scs_hz: float) -> np.ndarray:
    """Eq. (10) evaluated literally: Σ_m ‖S_m(τ_m)^H y_m‖² with S_m = F D_m Γ_m(τ_m) F_L built as matrices.

    This is Σ_m ‖y_m‖² minus the least-squares residual of eq. (7) at the ĥ_m of eq. (8) (eq. (9)).  F is a dense N × N
    matrix; D_m and Γ_m are diagonal and applied as row scalings (the same product).  NumPy, O(N² L) per candidate: for
    checking ``ml_cost`` on small N.

    Parameters
    ----------
    y : complex (M, N)
        Received samples per eq. (5).
    prs : complex (M, N)
        Pilots d_{m,k} in FFT-bin order.
    tau : float (..., M)
        Candidate ToAs, seconds.
    n_taps : int
        L, the window's taps, 1 to N.
    scs_hz : float
        Δf, Hz.

    Returns
    -------
    float (...)
        The cost of each candidate.

    Raises
    ------
    ValueError
        When y and prs are not (M, N) of equal shape, n_taps is out of range, or tau is not (..., M).
    """
    _checks.require_x64()
    y, prs = correlogram.check_inputs(y, prs, n_taps)
    n_bs, n = y.shape
    tau = np.asarray(tau, dtype=np.float64)
    if tau.shape[-1:] != (n_bs,):
        raise ValueError(f"tau must have shape (..., M) with M = {n_bs}, got {tau.shape}")
    k = np.arange(n)
    f = np.exp(2j * np.pi * np.outer(k, k) / n) / np.sqrt(n)  # synthesis, eq. (5)
    f_l = np.exp(-2j * np.pi * np.outer(k, np.arange(n_taps)) / n) / np.sqrt(n)  # (N, L)
    out = np.zeros(tau.shape[:-1])
    for idx in np.ndindex(*tau.shape[:-1]):
        total = 0.0
        for m in range(n_bs):
            gamma = np.exp(-2j * np.pi * k * scs_hz * tau[idx + (m,)])
            s = f @ ((prs[m] * gamma)[:, None] * f_l)  # F D_m Γ_m F_L, (N, L)
            total += float(np.sum(np.abs(s.conj().T @ y[m]) ** 2))
        out[idx] = total
    return out


def ml_cost_terms(g, tau, n_taps, scs_hz, weights=None):
    """Per-BS terms of eq. (10), ‖S_m(τ_m)^H y_m‖², from the LS spectrum.

    Parameters
    ----------
    g : complex (M, N)
        D^H F^H y, the LS spectrum (``correlogram.ls_spectrum``).
    tau : float (..., M)
        ToAs, seconds.
    n_taps : int
        L, the window's taps.
    scs_hz : float
        Δf, Hz.
    weights : float (L,) or None
        The taps' weights (``correlogram.tap_weights``); None for eq. (10)'s equal weights.

    Returns
    -------
    float (..., M)
    """
    n = g.shape[-1]
    k = jnp.arange(n)
    z = g * jnp.exp(2j * jnp.pi * scs_hz * tau[..., None] * k)  # Γ^H D^H F^H y, (..., M, N)
    h = jnp.fft.ifft(z, axis=-1)[..., :n_taps] * jnp.sqrt(n)  # F_L^H (...): windowed CIR estimate
    e = h.real**2 + h.imag**2
    return jnp.sum(e if weights is None else e * weights, axis=-1)


@partial(jax.jit, static_argnames=("n_taps",))
def ml_cost_of_spectrum(g, tau, n_taps, scs_hz, weights=None):
    """Eq. (10) from the LS spectrum: the sum of ``ml_cost_terms`` over the BSs.  Jitted, traceable.

    Parameters
    ----------
    g : complex (M, N)
        The LS spectrum (``correlogram.ls_spectrum``).
    tau : float (..., M)
        ToAs, seconds.
    n_taps : int
        L, the window's taps.
    scs_hz : float
        Δf, Hz.
    weights : float (L,) or None
        The taps' weights (``correlogram.tap_weights``); None for eq. (10)'s equal weights.

    Returns
    -------
    float (...)
    """
    return jnp.sum(ml_cost_terms(g, tau, n_taps, scs_hz, weights), axis=-1)


def ml_cost(y, prs, tau, n_taps: int, scs_hz: float, weights=None) -> jax.Array:
    """Eq. (10), fast: the energy of the delay-compensated LS CIR estimate in an L-tap window, summed over BSs.

    ``Σ_m Σ_{l<L} |√N · IDFT_l(conj(d_{m,k}) Y_{m,k} e^{+j2πkΔfτ_m})|²``, Y_m = DFT(y_m) (unitary).  Same arguments and
    values as ``ml_cost_literal`` (agreement ≤ 1e-9 relative is tested), one FFT per BS and candidate instead of N × N
    matrices.  Differentiable in ``tau`` (used by the autodiff polish).

    Parameters
    ----------
    y : complex (M, N)
        Received samples per eq. (5).
    prs : complex (M, N)
        Pilots d_{m,k} in FFT-bin order.
    tau : float (..., M)
        Candidate ToAs, seconds.
    n_taps : int
        L, the window's taps, 1 to N.
    scs_hz : float
        Δf, Hz.
    weights : float (L,) or None
        Weights w_l of the window's taps, ``Σ_l w_l |ĥ_l|²`` (``correlogram.tap_weights``: the first-path-aware cost,
        the bounds chapter, not the paper's); None for eq. (10).

    Returns
    -------
    float (...)
        The cost of each candidate.

    Raises
    ------
    ValueError
        When y and prs are not (M, N) of equal shape, n_taps is out of range, tau is not (..., M), or the weights are
        not L finite non-negative numbers, not all zero.
    """
    _checks.require_x64()
    y, prs = correlogram.check_inputs(y, prs, n_taps)
    tau = jnp.asarray(tau, dtype=jnp.float64)
    if tau.shape[-1:] != (y.shape[0],):
        raise ValueError(f"tau must have shape (..., M) with M = {y.shape[0]}, got {tau.shape}")
    if weights is not None:
        weights = jnp.asarray(correlogram.check_weights(weights, n_taps))
    g = correlogram.ls_spectrum(signal.demodulate(y), jnp.asarray(prs))
    return ml_cost_of_spectrum(g, tau, n_taps, float(scs_hz), weights)


def correlogram_lookup(corr, tau, sample_period_s: float, upsample: int) -> jax.Array:
    """Σ_m corr_m(τ_m) from ``correlogram.correlogram`` output, cubic (Catmull–Rom) interpolation on its T_s/U grid.

    Exact at grid points; between them, on the paper's numerology, the error is ≤ 0.2 % of the peak at U = 4 and
    ≤ 0.02 % at U = 8 (linear interpolation needs U = 16 for 0.05 %), which the autodiff polish (``newton_step``)
    removes.

    Parameters
    ----------
    corr : float (M, N·U)
        The correlograms.
    tau : float (..., M)
        ToAs, seconds.
    sample_period_s : float
        T_s, seconds.
    upsample : int
        U, grid points per sample T_s.

    Returns
    -------
    float (...)
    """
    return lookup(corr, jnp.asarray(tau) / sample_period_s * upsample)


def lookup(corr, pos):
    """Catmull–Rom cubic through the four grid values around each position (in grid units), periodic, summed over BSs.

    Parameters
    ----------
    corr : float (M, N·U) or tuple
        The correlograms, or a window of them, as in ``lookup_terms``.
    pos : float (..., M)
        Positions, grid units.

    Returns
    -------
    float (...)
    """
    return jnp.sum(lookup_terms(corr, pos), axis=-1)


def lookup_terms(corr, pos):
    """The per-BS terms of ``lookup``.

    Parameters
    ----------
    corr : float (M, N·U) or (float (M, W), int (M,))
        The whole correlograms, read periodically, or a window of them: the pair (values, start) of
        ``grid_search.grid_window`` with ``correlogram.energy_window``, whose column i is grid point start + i (the
        search stays inside it).
    pos : float (..., M)
        Positions, grid units.

    Returns
    -------
    float (..., M)
    """
    f = jnp.floor(pos)
    t = pos - f
    if isinstance(corr, tuple):  # the four values as one slice per lookup (a quarter of the gathers)
        corr, start = corr
        first = f.astype(jnp.int64) - start - 1
        rows = jnp.broadcast_to(jnp.arange(corr.shape[0]), first.shape)
        dims = jax.lax.GatherDimensionNumbers(offset_dims=(first.ndim,), collapsed_slice_dims=(0,),
                                              start_index_map=(0, 1))
        v = jax.lax.gather(corr, jnp.stack([rows, first], axis=-1), dims, slice_sizes=(1, 4),
                           mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS)
        vm, v0, v1, v2 = (v[..., d] for d in range(4))
    else:
        m, j = corr.shape
        i0 = jnp.mod(f.astype(jnp.int64), j)
        rows = jnp.arange(m)
        vm, v0, v1, v2 = (corr[rows, jnp.mod(i0 + d, j)] for d in (-1, 0, 1, 2))
    return v0 + t * (0.5 * (v1 - vm) + t * ((vm - 2.5 * v0 + 2.0 * v1 - 0.5 * v2) + t * (1.5 * (v0 - v1) + 0.5 * (v2 - vm))))


def toa(xyz, bs_xyz, clock_bias_s=0.0) -> jax.Array:
    """τ_m(p) = ‖p_xyz - b_m‖ / c + δt, seconds.

    Parameters
    ----------
    xyz : float (..., 3)
        Positions, metres.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    clock_bias_s : float (...)
        Clock bias δt, seconds (0 by default).

    Returns
    -------
    float (..., M)
        ToAs, seconds.
    """
    d = jnp.linalg.norm(jnp.asarray(xyz)[..., None, :] - jnp.asarray(bs_xyz), axis=-1)
    return d / C + jnp.asarray(clock_bias_s)[..., None]


def tau_of(q, bs_xyz):
    """ToAs of points q = (x, y, z, c δt) in metres.

    Parameters
    ----------
    q : float (..., 4)
        Position and clock bias times c, metres.
    bs_xyz : float (M, 3)
        Base-station positions, metres.

    Returns
    -------
    float (..., M)
        τ, seconds.
    """
    return toa(q[..., :3], bs_xyz, q[..., 3] / C)


def newton_step(g, bs_xyz, q, mask, n_taps, scs_hz, max_step_m):
    """One Newton step on the exact eq. (10) in q = (x, y, z, c δt), derivatives by JAX autodiff.

    The cost is separable, C(q) = Σ_m c_m(τ_m(q)), so one nested forward-mode pass over the M ToAs gives every
    c_m, c_m' and c_m'' at once; the chain rule then gives ∇C = Jᵀc' and ∇²C = Jᵀ diag(c'') J + Σ_m c_m' ∇²τ_m with
    J = ∂τ/∂q (both of the small geometric map also by autodiff).  The step is taken only if it is finite, shorter
    than ``max_step_m`` and raises the exact cost.

    Parameters
    ----------
    g : complex (M, N)
        The LS spectrum (``correlogram.ls_spectrum``).
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    q : float (4,)
        The point the step starts from, metres.
    mask : float (4,)
        1 for a searched coordinate, 0 freezes it.
    n_taps : int
        L, the window's taps.
    scs_hz : float
        Δf, Hz.
    max_step_m : float
        Longest step taken, metres.

    Returns
    -------
    float (4,)
        The step, metres; zero where it is not taken.
    """

    def terms(t):
        return ml_cost_terms(g, t, n_taps, scs_hz)

    tau = tau_of(q, bs_xyz)
    ones = jnp.ones_like(tau)
    (c, c1), (_, c2) = jax.jvp(lambda t: jax.jvp(terms, (t,), (ones,)), (tau,), (ones,))
    geometry = partial(tau_of, bs_xyz=bs_xyz)
    jac = jax.jacfwd(geometry)(q)  # (M, 4)
    hess_tau = jax.hessian(geometry)(q)  # (M, 4, 4)
    g = (jac.T @ c1) * mask
    h = jac.T @ (c2[:, None] * jac) + jnp.einsum("m,mij->ij", c1, hess_tau)
    h = h * mask[:, None] * mask[None, :] + jnp.diag(1.0 - mask)
    step = -jnp.linalg.solve(h, g)
    ok = jnp.all(jnp.isfinite(step)) & (jnp.linalg.norm(step) < max_step_m)
    step = jnp.where(ok, step, 0.0)
    better = jnp.sum(terms(tau_of(q + step, bs_xyz))) > jnp.sum(c)
    return jnp.where(better, step, 0.0)


def catmull_rom_weights(t):
    """The weights of the four grid values around a position in ``lookup``'s cubic (the same polynomial, nested there).

    Parameters
    ----------
    t : float (...)
        The position's fractional part.

    Returns
    -------
    float (..., 4)
    """
    return jnp.stack([t * (-0.5 + t * (1.0 - 0.5 * t)), 1.0 + t * t * (-2.5 + 1.5 * t),
                      t * (0.5 + t * (2.0 - 1.5 * t)), t * t * (-0.5 + 0.5 * t)], axis=-1)


def box_distances(cx, cy, hx, bx, by, dz2):
    """Nearest and farthest distance from each BS to horizontal squares, metres.

    Parameters
    ----------
    cx, cy : float (1, K)
        The squares' centres, metres.
    hx : float
        The squares' half side, metres.
    bx, by : float (M, 1)
        The BSs' coordinates, metres.
    dz2 : float (M, 1)
        Each BS's squared height difference, m².

    Returns
    -------
    nearest : float (M, K)
        Nearest distances, metres.
    farthest : float (M, K)
        Farthest distances, metres.
    """
    xl, xh, yl, yh = cx - hx, cx + hx, cy - hx, cy + hx
    dxn = jnp.maximum(jnp.maximum(xl - bx, bx - xh), 0.0)
    dyn = jnp.maximum(jnp.maximum(yl - by, by - yh), 0.0)
    dxx = jnp.maximum(jnp.abs(xl - bx), jnp.abs(xh - bx))
    dyx = jnp.maximum(jnp.abs(yl - by), jnp.abs(yh - by))
    return jnp.sqrt(dxn**2 + dyn**2 + dz2), jnp.sqrt(dxx**2 + dyx**2 + dz2)
