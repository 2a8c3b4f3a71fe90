"""Direct position estimation: the ML cost of eqs. (5)–(8) and its divide-and-conquer search.

Eq. (8): p̂ = argmax_p Σ_m ‖S_m(p)^H y_m‖²,  S_m(p) = F D_m Γ_m(τ_m(p)) F_L,

written here in the code's convention (see ``dpe5g.signal``): F is the unitary inverse DFT of eq. (3)
([F]_{n,k} = e^{+j2πnk/N}/√N), D_m = diag(d_{m,k}), Γ_m(τ) = diag(e^{-j2πkΔfτ}), and F_L is the N × L matrix
[F_L]_{k,l} = e^{-j2πkl/N}/√N that turns an L-tap CIR on the sample grid into its frequency response.  Its columns
are orthonormal and D_m^H D_m = I for unit-modulus pilots, so S_m^H S_m = I_L (the identity under the brace of eq. (6)).

Two evaluations of the same number:

* ``ml_cost_literal`` builds the matrices and multiplies them out (for verification on small N);
* ``ml_cost`` uses the identity derived in Chapter 3: S_m^H y_m = √N · IDFT(conj(d_m) ⊙ DFT(y_m) ⊙ e^{+j2πkΔfτ_m})[0:L],
  the delay-compensated least-squares CIR estimate, so the cost is the energy of that estimate in an L-tap window.

Position model: p = [x, y, z, δt] with τ_m(p) = ‖(x, y, z) - b_m‖ / c + δt.  The search works in metres, with the
clock bias as b = c δt.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import _checks
from .nr import C, PAPER, Numerology

#: Default receiver window L (taps), chosen from the study in Chapter 3 (8 BSs on a 150 m ring, every link TDL-C at
#: 65 ns, 20 dB, 5 ns clock bias, 200 trials, grid centred on the truth): L = 12 gave the smallest RMSE, 1.03 m,
#: against 2.20 m for L = 8, 3.40 m for L = 16 and 5.85 m for L = 32.  Shorter windows lock onto the strongest
#: cluster of some links; longer ones flatten the peak (the TDL-C excess delay is 69 samples).
DEFAULT_TAPS = 12


def _check_inputs(y, prs, n_taps):
    y = np.asarray(y)
    prs = np.asarray(prs)
    if y.ndim != 2 or prs.shape != y.shape:
        raise ValueError(f"y and prs must both be complex (M, N) arrays of equal shape, got {y.shape} and {prs.shape}")
    _checks.integer("n_taps", n_taps, 1, y.shape[1])
    return y, prs


def ml_cost_literal(y, prs, tau, n_taps: int, scs_hz: float) -> np.ndarray:
    """Eq. (8) evaluated literally: Σ_m ‖S_m(τ_m)^H y_m‖² with S_m = F D_m Γ_m(τ_m) F_L built as matrices.

    y : complex (M, N) received samples per eq. (3); prs : complex (M, N) pilots d_{m,k} in FFT-bin order;
    tau : real (..., M) candidate ToAs in seconds; n_taps : L; scs_hz : Δf in Hz.  Returns real (...).
    F is a dense N × N matrix; D_m and Γ_m are diagonal and applied as row scalings (the same product).
    NumPy, O(N² L) per candidate: for checking ``ml_cost`` on small N.
    """
    y, prs = _check_inputs(y, prs, n_taps)
    n_bs, n = y.shape
    tau = np.asarray(tau, dtype=np.float64)
    if tau.shape[-1:] != (n_bs,):
        raise ValueError(f"tau must have shape (..., M) with M = {n_bs}, got {tau.shape}")
    k = np.arange(n)
    f = np.exp(2j * np.pi * np.outer(k, k) / n) / np.sqrt(n)  # synthesis, eq. (3)
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


def _ml_cost_terms(y, prs, tau, n_taps, scs_hz):
    """Per-BS terms of eq. (8): ‖S_m(τ_m)^H y_m‖², shape (..., M)."""
    n = y.shape[-1]
    g = jnp.conj(prs) * jnp.fft.fft(y, axis=-1, norm="ortho")  # D^H F^H y, (M, N)
    k = jnp.arange(n)
    z = g * jnp.exp(2j * jnp.pi * scs_hz * tau[..., None] * k)  # Γ^H D^H F^H y, (..., M, N)
    h = jnp.fft.ifft(z, axis=-1)[..., :n_taps] * jnp.sqrt(n)  # F_L^H (...): windowed CIR estimate
    return jnp.sum(h.real**2 + h.imag**2, axis=-1)


@partial(jax.jit, static_argnames=("n_taps",))
def _ml_cost(y, prs, tau, n_taps, scs_hz):
    return jnp.sum(_ml_cost_terms(y, prs, tau, n_taps, scs_hz), axis=-1)


def ml_cost(y, prs, tau, n_taps: int, scs_hz: float) -> jax.Array:
    """Eq. (8), fast: the energy of the delay-compensated LS CIR estimate in an L-tap window, summed over BSs.

    Σ_m Σ_{l<L} |√N · IDFT_l(conj(d_{m,k}) Y_{m,k} e^{+j2πkΔfτ_m})|², Y_m = DFT(y_m) (unitary).

    Same arguments and values as ``ml_cost_literal`` (agreement ≤ 1e-9 relative is tested), one FFT per BS and
    candidate instead of N × N matrices.  Differentiable in ``tau`` (used by the autodiff polish).
    """
    y, prs = _check_inputs(y, prs, n_taps)
    tau = jnp.asarray(tau, dtype=jnp.float64)
    if tau.shape[-1:] != (y.shape[0],):
        raise ValueError(f"tau must have shape (..., M) with M = {y.shape[0]}, got {tau.shape}")
    return _ml_cost(jnp.asarray(y), jnp.asarray(prs), tau, n_taps, float(scs_hz))


def correlogram(y, prs, n_taps: int, upsample: int) -> jax.Array:
    """Per-BS correlograms: the windowed energy of eq. (8) for every candidate ToA on a grid of T_s/upsample.

    Returns real (M, N·upsample); entry j of row m is the BS-m term of ``ml_cost`` at τ = j T_s / upsample,
    exactly (one FFT per fractional offset, U per BS, instead of one per candidate).  The cost is periodic in τ
    with period N T_s = 1/Δf, so the grid covers every τ modulo that period.
    """
    y, prs = _check_inputs(y, prs, n_taps)
    _checks.integer("upsample", upsample, 1, 256)
    return _correlogram(jnp.asarray(y), jnp.asarray(prs), n_taps, upsample)


@partial(jax.jit, static_argnames=("n_taps", "upsample"))
def _correlogram(y, prs, n_taps, upsample):
    m, n = y.shape
    g = jnp.conj(prs) * jnp.fft.fft(y, axis=-1, norm="ortho")
    k = np.arange(n)
    shifts = np.exp(2j * np.pi * np.outer(np.arange(upsample) / upsample, k) / n)  # (U, N), a compile-time constant
    h = jnp.fft.ifft(g[:, None, :] * shifts[None], axis=-1)  # (M, U, N): ĥ(n + u/U) / √N
    e = (h.real**2 + h.imag**2) * n
    if n_taps == 1:
        w = e
    else:  # circular window sum over l = 0 … L-1 as a product of spectra (real FFTs of length N)
        box = np.fft.rfft(((k == 0) | (k > n - n_taps)).astype(np.float64))  # e[j] + e[j+1] + … + e[j+L-1]
        w = jnp.fft.irfft(jnp.fft.rfft(e, axis=-1) * box, n=n, axis=-1)
    return jnp.transpose(w, (0, 2, 1)).reshape(m, n * upsample)


def correlogram_lookup(corr, tau, sample_period_s: float, upsample: int) -> jax.Array:
    """Σ_m corr_m(τ_m) from ``correlogram`` output, cubic (Catmull–Rom) interpolation on its T_s/U grid.

    corr : (M, N·U); tau : (..., M) seconds.  Returns (...).  Exact at grid points; between them, on the paper's
    numerology, the error is ≤ 0.2 % of the peak at U = 4 and ≤ 0.02 % at U = 8 (linear interpolation needs U = 16
    for 0.05 %), which the autodiff polish of ``estimate`` removes.
    """
    return _lookup(corr, jnp.asarray(tau) / sample_period_s * upsample)


def _lookup(corr, pos):
    """Catmull–Rom cubic through the four grid values around each position (in grid units), periodic."""
    m, j = corr.shape
    f = jnp.floor(pos)
    t = pos - f
    i0 = jnp.mod(f.astype(jnp.int64), j)
    rows = jnp.arange(m)
    vm, v0, v1, v2 = (corr[rows, jnp.mod(i0 + d, j)] for d in (-1, 0, 1, 2))
    v = v0 + t * (0.5 * (v1 - vm) + t * ((vm - 2.5 * v0 + 2.0 * v1 - 0.5 * v2) + t * (1.5 * (v0 - v1) + 0.5 * (v2 - vm))))
    return jnp.sum(v, axis=-1)


def toa(xyz, bs_xyz, clock_bias_s=0.0) -> jax.Array:
    """τ_m(p) = ‖p_xyz - b_m‖ / c + δt in seconds.  xyz : (..., 3) m; bs_xyz : (M, 3) m → (..., M)."""
    d = jnp.linalg.norm(jnp.asarray(xyz)[..., None, :] - jnp.asarray(bs_xyz), axis=-1)
    return d / C + jnp.asarray(clock_bias_s)[..., None]


@dataclass(frozen=True)
class SearchConfig:
    """Divide-and-conquer grid search of eq. (8) over (x, y, c δt) at known UE height (the paper's set-up), or over
    (x, y, z, c δt) with ``z_half_width_m`` > 0.

    n_taps : receiver window L in taps (default ``DEFAULT_TAPS``; Chapter 3 shows the bias-vs-L study behind it).
    upsample : correlogram grid T_s / upsample (4 → 0.61 m of range; cubic interpolation between grid points).
    half_width_m : the grid spans centre ± half_width_m in x and y.
    bias_half_width_m : and centre ± this in c δt (the paper's clock bias: σ = 5 ns = 1.5 m); 0 fixes δt.
    z_half_width_m : 0 (default, the paper's set-up) keeps the UE height at the centre's z; > 0 searches z too,
        over centre ± this (the 3-D option).
    coarse_step_m : step of the first grid; each further level is a 5-point-per-axis grid around the best point,
        with the step divided by 2.5, until the step is ≤ final_step_m.
    final_step_m : resolution reached by the grid (0.1 m by default).
    polish : after the grid, Newton steps on the exact ``ml_cost`` with JAX autodiff (accepted only if the cost rises).
        Off by default, as in the paper, whose search ends on the grid: on Chapter 3's ring study it moves fixes by
        4 cm (median, 13 cm at most) and costs about as much as the grid search.
    """

    n_taps: int = DEFAULT_TAPS
    upsample: int = 4
    half_width_m: float = 10.0
    bias_half_width_m: float = 6.0
    z_half_width_m: float = 0.0
    coarse_step_m: float = 1.0
    final_step_m: float = 0.1
    polish: bool = False
    polish_iters: int = 2

    def __post_init__(self):
        _checks.integer("n_taps", self.n_taps, 1, 4096)
        _checks.integer("upsample", self.upsample, 1, 256)
        _checks.in_range("half_width_m", self.half_width_m, 0.1, 1000.0, "m")
        _checks.in_range("bias_half_width_m", self.bias_half_width_m, 0.0, 1000.0, "m")
        _checks.in_range("z_half_width_m", self.z_half_width_m, 0.0, 1000.0, "m")
        _checks.in_range("coarse_step_m", self.coarse_step_m, 0.01, 100.0, "m")
        _checks.in_range("final_step_m", self.final_step_m, 1e-4, self.coarse_step_m, "m")
        _checks.integer("polish_iters", self.polish_iters, 0, 20)

    def steps(self) -> tuple[float, ...]:
        """Grid step of each level in metres."""
        s = [self.coarse_step_m]
        while s[-1] > self.final_step_m + 1e-12:
            s.append(s[-1] / 2.5)
        return tuple(s)


def _axis(half_width, step):
    if half_width <= 0:
        return np.zeros(1)
    n = int(np.floor(half_width / step + 1e-9))
    return np.arange(-n, n + 1) * step


def _grid_offsets(half_xy, half_z, half_b, step):
    ax = _axis(half_xy, step)
    g = np.meshgrid(ax, ax, _axis(half_z, step), _axis(half_b, step), indexing="ij")
    return np.stack([a.ravel() for a in g], axis=-1)  # (K, 4): dx, dy, dz, d(c δt)


def _tau_of(q, bs_xyz):
    """q : (..., 4) = (x, y, z, c δt) in metres → τ (..., M) seconds."""
    return toa(q[..., :3], bs_xyz, q[..., 3] / C)


def _newton_step(y, prs, bs_xyz, q, mask, n_taps, scs_hz, max_step_m):
    """One Newton step on the exact eq. (8) in q = (x, y, z, c δt), derivatives by JAX autodiff.

    The cost is separable, C(q) = Σ_m c_m(τ_m(q)), so one nested forward-mode pass over the M ToAs gives every
    c_m, c_m' and c_m'' at once; the chain rule then gives ∇C = Jᵀc' and ∇²C = Jᵀ diag(c'') J + Σ_m c_m' ∇²τ_m with
    J = ∂τ/∂q (both of the small geometric map also by autodiff).  The step is taken only if it is finite, shorter
    than ``max_step_m`` and raises the exact cost; ``mask`` (4,) freezes coordinates that are not searched.
    Returns the step (4,).
    """

    def terms(t):
        return _ml_cost_terms(y, prs, t, n_taps, scs_hz)

    tau = _tau_of(q, bs_xyz)
    ones = jnp.ones_like(tau)
    (c, c1), (_, c2) = jax.jvp(lambda t: jax.jvp(terms, (t,), (ones,)), (tau,), (ones,))
    tau_of = partial(_tau_of, bs_xyz=bs_xyz)
    jac = jax.jacfwd(tau_of)(q)  # (M, 4)
    hess_tau = jax.hessian(tau_of)(q)  # (M, 4, 4)
    g = (jac.T @ c1) * mask
    h = jac.T @ (c2[:, None] * jac) + jnp.einsum("m,mij->ij", c1, hess_tau)
    h = h * mask[:, None] * mask[None, :] + jnp.diag(1.0 - mask)
    step = -jnp.linalg.solve(h, g)
    ok = jnp.all(jnp.isfinite(step)) & (jnp.linalg.norm(step) < max_step_m)
    step = jnp.where(ok, step, 0.0)
    better = jnp.sum(terms(_tau_of(q + step, bs_xyz))) > jnp.sum(c)
    return jnp.where(better, step, 0.0)


def search(corr, y, prs, bs_xyz, center, cfg: SearchConfig, n_fft: int, scs_hz: float, with_cost: bool = True):
    """The divide-and-conquer search on precomputed correlograms (traceable; used inside jit by ``estimate`` and
    by ``dpe5g.montecarlo``, which reuses one set of correlograms for several M).

    corr : (M, N·U) from ``correlogram``; y, prs : (M, N) (read only by the polish); bs_xyz : (M, 3) m;
    center : (4,) = [x, y, z, δt].  Returns q (4,) = (x, y, z, c δt) in metres and the exact cost there (or only q
    when ``with_cost`` is False).
    """
    ts = 1.0 / (n_fft * scs_hz)
    q = jnp.array([center[0], center[1], center[2], center[3] * C])
    search_b, search_z = cfg.bias_half_width_m > 0, cfg.z_half_width_m > 0
    steps = cfg.steps()
    for level, step in enumerate(steps):
        if level == 0:
            off = _grid_offsets(cfg.half_width_m, cfg.z_half_width_m, cfg.bias_half_width_m, step)
        else:
            off = _grid_offsets(2 * step, 2 * step * search_z, 2 * step * search_b, step)
        cand = q + jnp.asarray(off)
        vals = _lookup(corr, _tau_of(cand, bs_xyz) / ts * cfg.upsample)
        q = cand[jnp.argmax(vals)]
    if cfg.polish:
        mask = jnp.array([1.0, 1.0, float(search_z), float(search_b)])
        for _ in range(cfg.polish_iters):
            q = q + _newton_step(y, prs, bs_xyz, q, mask, cfg.n_taps, scs_hz, 2 * steps[-1])
    if not with_cost:
        return q
    return q, _ml_cost(y, prs, _tau_of(q, bs_xyz), cfg.n_taps, scs_hz)


@partial(jax.jit, static_argnames=("cfg", "n_fft"))
def _estimate_one(y, prs, bs_xyz, center, cfg: SearchConfig, n_fft: int, scs_hz: float):
    corr = _correlogram(y, prs, cfg.n_taps, cfg.upsample)
    return search(corr, y, prs, bs_xyz, center, cfg, n_fft, scs_hz)


@dataclass(frozen=True)
class Estimate:
    """Result of ``estimate``: xyz (..., 3) metres, clock_bias_s (...), cost (...) = eq. (8) at the estimate."""

    xyz: np.ndarray
    clock_bias_s: np.ndarray
    cost: np.ndarray


def estimate(
    y, prs, bs_xyz, center, cfg: SearchConfig = SearchConfig(), num: Numerology = PAPER, batch_size: int = 8
) -> Estimate:
    """DPE fix by divide-and-conquer search of eq. (8) around ``center``, batched over trials with vmap.

    y, prs : complex (..., M, N); bs_xyz : (..., M, 3) metres; center : (..., 4) = [x, y, z, δt] (m, m, m, s), the
    grid centre — the true position in the paper's set-up, or a prior from a coarse fix; z is the known UE height
    (or the centre of the z search when ``cfg.z_half_width_m`` > 0).
    batch_size : trials evaluated together (vmap) inside a sequential ``lax.map``; results do not depend on it.
    Returns an ``Estimate`` with leading shape (...).
    """
    y = jnp.asarray(y)
    prs = jnp.asarray(prs)
    bs_xyz = jnp.asarray(bs_xyz, dtype=jnp.float64)
    center = jnp.asarray(center, dtype=jnp.float64)
    if y.shape[-1] != num.n_fft or prs.shape != y.shape:
        raise ValueError(f"y and prs must be (..., M, {num.n_fft}) of equal shape, got {y.shape} and {prs.shape}")
    if bs_xyz.shape[-2:] != (y.shape[-2], 3) or center.shape[-1] != 4:
        raise ValueError(f"bs_xyz must be (..., M, 3) and center (..., 4); got {bs_xyz.shape} and {center.shape}")
    if not bool(jnp.all(jnp.isfinite(center))) or not bool(jnp.all(jnp.isfinite(bs_xyz))):
        raise ValueError("center and bs_xyz must be finite")
    batch_size = _checks.integer("batch_size", batch_size, 1, 1 << 16)
    fn = partial(_estimate_one, cfg=cfg, n_fft=num.n_fft, scs_hz=num.scs_hz)
    lead = y.shape[:-2]
    if lead:
        # trials in vmapped chunks of `batch_size` (bounded memory); each trial's result is independent of chunking
        flat = [a.reshape((-1,) + a.shape[len(lead):]) for a in (y, prs, bs_xyz, center)]
        q, cost = jax.lax.map(lambda a: fn(*a), tuple(flat), batch_size=batch_size)
        q, cost = q.reshape(lead + (4,)), cost.reshape(lead)
    else:
        q, cost = fn(y, prs, bs_xyz, center)
    q = np.asarray(q)
    q = np.asarray(q)
    return Estimate(q[..., :3], q[..., 3] / C, np.asarray(cost))
