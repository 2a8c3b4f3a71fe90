"""Direct position estimation: the ML cost of eqs. (7)–(10) and its divide-and-conquer search.

Eq. (10): p̂ = argmax_p Σ_m ‖S_m(p)^H y_m‖²,  S_m(p) = F D_m Γ_m(τ_m(p)) F_L,

written here in the code's convention (see ``dpe5g.signal``): F is the unitary inverse DFT of eq. (5)
([F]_{n,k} = e^{+j2πnk/N}/√N), D_m = diag(d_{m,k}), Γ_m(τ) = diag(e^{-j2πkΔfτ}), and F_L is the N × L matrix
[F_L]_{k,l} = e^{-j2πkl/N}/√N that turns an L-tap CIR on the sample grid into its frequency response.  Its columns
are orthonormal and D_m^H D_m = I for unit-modulus pilots, so S_m^H S_m = I_L (the identity under the brace of eq. (8)).

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

from . import _checks, correlogram, signal
from .nr import C, PAPER, Numerology

#: Default receiver window L (taps).  First chosen in Chapter 3 on 8 NLoS (TDL-C) links on a 150 m ring with the grid
#: on the truth, where L = 12 gave the smallest RMSE; chosen again on the urban scenario (mixed LoS/NLoS, Figs. 9 and
#: 10 set-ups) with the honest receiver (prior-centred window, certified search; ``paper.urban_window_experiments``,
#: Chapter 5), where the rule of ``studies.choose_window`` picks L = 12 again.  Shorter windows lock onto the strongest
#: cluster of NLoS links; longer ones widen the LoS plateau and flatten the peak (the TDL-C excess delay is 69 samples).
DEFAULT_TAPS = 12
SEARCH_METHODS = ("grid", "bnb")


def ml_cost_literal(y, prs, tau, n_taps: int, scs_hz: float) -> np.ndarray:
    """Eq. (10) evaluated literally: Σ_m ‖S_m(τ_m)^H y_m‖² with S_m = F D_m Γ_m(τ_m) F_L built as matrices, which
    is Σ_m ‖y_m‖² minus the least-squares residual of eq. (7) at the ĥ_m of eq. (8) (eq. (9)).

    y : complex (M, N) received samples per eq. (5); prs : complex (M, N) pilots d_{m,k} in FFT-bin order;
    tau : real (..., M) candidate ToAs in seconds; n_taps : L; scs_hz : Δf in Hz.  Returns real (...).
    F is a dense N × N matrix; D_m and Γ_m are diagonal and applied as row scalings (the same product).
    NumPy, O(N² L) per candidate: for checking ``ml_cost`` on small N.
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


def _ml_cost_terms(g, tau, n_taps, scs_hz, weights=None):
    """Per-BS terms of eq. (10): ‖S_m(τ_m)^H y_m‖², shape (..., M); g = D^H F^H y (M, N), ``ls_spectrum``;
    weights (L,): the taps' weights (``correlogram.tap_weights``), None for eq. (10)'s equal weights."""
    n = g.shape[-1]
    k = jnp.arange(n)
    z = g * jnp.exp(2j * jnp.pi * scs_hz * tau[..., None] * k)  # Γ^H D^H F^H y, (..., M, N)
    h = jnp.fft.ifft(z, axis=-1)[..., :n_taps] * jnp.sqrt(n)  # F_L^H (...): windowed CIR estimate
    e = h.real**2 + h.imag**2
    return jnp.sum(e if weights is None else e * weights, axis=-1)


@partial(jax.jit, static_argnames=("n_taps",))
def _ml_cost(g, tau, n_taps, scs_hz, weights=None):
    return jnp.sum(_ml_cost_terms(g, tau, n_taps, scs_hz, weights), axis=-1)


def ml_cost(y, prs, tau, n_taps: int, scs_hz: float, weights=None) -> jax.Array:
    """Eq. (10), fast: the energy of the delay-compensated LS CIR estimate in an L-tap window, summed over BSs.

    Σ_m Σ_{l<L} |√N · IDFT_l(conj(d_{m,k}) Y_{m,k} e^{+j2πkΔfτ_m})|², Y_m = DFT(y_m) (unitary).

    Same arguments and values as ``ml_cost_literal`` (agreement ≤ 1e-9 relative is tested), one FFT per BS and
    candidate instead of N × N matrices.  Differentiable in ``tau`` (used by the autodiff polish).
    weights : (L,) weights of the window's taps (``correlogram.tap_weights``: the first-path-aware cost, Chapter 8,
    not the paper's), Σ_l w_l |ĥ_l|²; None for eq. (10).
    """
    _checks.require_x64()
    y, prs = correlogram.check_inputs(y, prs, n_taps)
    tau = jnp.asarray(tau, dtype=jnp.float64)
    if tau.shape[-1:] != (y.shape[0],):
        raise ValueError(f"tau must have shape (..., M) with M = {y.shape[0]}, got {tau.shape}")
    if weights is not None:
        weights = jnp.asarray(correlogram.check_weights(weights, n_taps))
    return _ml_cost(correlogram.ls_spectrum(signal.demodulate(y), jnp.asarray(prs)), tau, n_taps, float(scs_hz),
                    weights)


def correlogram_lookup(corr, tau, sample_period_s: float, upsample: int) -> jax.Array:
    """Σ_m corr_m(τ_m) from ``correlogram.correlogram`` output, cubic (Catmull–Rom) interpolation on its T_s/U grid.

    corr : (M, N·U); tau : (..., M) seconds.  Returns (...).  Exact at grid points; between them, on the paper's
    numerology, the error is ≤ 0.2 % of the peak at U = 4 and ≤ 0.02 % at U = 8 (linear interpolation needs U = 16
    for 0.05 %), which the autodiff polish of ``estimate`` removes.
    """
    return _lookup(corr, jnp.asarray(tau) / sample_period_s * upsample)


def _lookup(corr, pos):
    """Catmull–Rom cubic through the four grid values around each position (in grid units), periodic."""
    return jnp.sum(_lookup_terms(corr, pos), axis=-1)


def _lookup_terms(corr, pos):
    """The per-BS terms of ``_lookup``: pos (..., M) → (..., M).  corr : the whole correlograms (M, N·U), read
    periodically, or a window of them, the pair (values (M, W), start (M,)) of ``grid_window`` with
    ``correlogram.energy_window``, whose column i is grid point start + i (the search stays inside it)."""
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
    """τ_m(p) = ‖p_xyz - b_m‖ / c + δt in seconds.  xyz : (..., 3) m; bs_xyz : (M, 3) m → (..., M)."""
    d = jnp.linalg.norm(jnp.asarray(xyz)[..., None, :] - jnp.asarray(bs_xyz), axis=-1)
    return d / C + jnp.asarray(clock_bias_s)[..., None]


@dataclass(frozen=True)
class SearchConfig:
    """Divide-and-conquer grid search of eq. (10) over (x, y, c δt) at known UE height (the paper's set-up), or over
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
    method : "grid" — the coarse-to-fine grid above (the paper's divide-and-conquer search; no guarantee);
        "bnb" — ``certified_search``: branch-and-bound over (x, y, c δt) boxes that returns the global maximum of
        eq. (10) (cubic-spline form) inside the window with a certified gap.  The fields below apply to "bnb" only,
        which searches (x, y, c δt) at the known UE height (``z_half_width_m`` must be 0).
    spline_upsample : T_s / spline_upsample is the knot spacing of the spline form of eq. (10) (8 → 0.305 m).
    box_m : side of the first boxes in x and y (the c δt window is split into ``bias_boxes`` boxes).
    box_final_m : boxes are halved until their x, y side is ≤ this (m).
    capacity : boxes kept per level (the highest bounds); a box dropped for lack of room makes the fix uncertified
        (counted, not hidden).  A level's work follows the boxes alive, not the capacity: they are refined
        ``chunk_boxes`` at a time, in order of bound, while any is left.
    chunk_boxes : boxes refined together (a divisor of ``capacity``).  A level's loop evaluates all 8 × chunk_boxes
        children of a chunk, live or not, and the levels of Fig. 9's fixes keep a few tens of boxes alive, so small
        chunks waste less: measured on the 2-core CI machine (interleaved runs), 16 took 0.85 of the time of 64 on
        Fig. 9's honest receiver and 0.82 on Fig. 10's; 8 was within 5 % of 16, and keeps more loop steps where
        many boxes stay alive (wide windows, low SNR).  Where no box is dropped the fix does not depend on it: every
        box holding a point better than the best cost found is refined, whatever the order (ties aside); its gap,
        the bound left over the final boxes, does.
    gap_tol : a fix is certified when its upper bound exceeds its cost by at most gap_tol × cost.
    window_decay_s : 0 (default) — eq. (10)'s window, its L taps weighted equally; > 0 (seconds, "bnb" only) — the
        first-path-aware window, our extension and not the paper's (Chapter 8): tap l weighted by
        exp(−l T_s / window_decay_s) (``correlogram.tap_weights``).
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
    method: str = "grid"
    spline_upsample: int = 8
    box_m: float = 4.0
    bias_boxes: int = 3
    box_final_m: float = 0.05
    capacity: int = 1024
    chunk_boxes: int = 16
    gap_tol: float = 1e-4
    window_decay_s: float = 0.0

    def __post_init__(self):
        _checks.integer("n_taps", self.n_taps, 1, 4096)
        _checks.integer("upsample", self.upsample, 1, 256)
        _checks.in_range("half_width_m", self.half_width_m, 0.1, 1000.0, "m")
        _checks.in_range("bias_half_width_m", self.bias_half_width_m, 0.0, 1000.0, "m")
        _checks.in_range("z_half_width_m", self.z_half_width_m, 0.0, 1000.0, "m")
        _checks.in_range("coarse_step_m", self.coarse_step_m, 0.01, 100.0, "m")
        _checks.in_range("final_step_m", self.final_step_m, 1e-4, self.coarse_step_m, "m")
        _checks.integer("polish_iters", self.polish_iters, 0, 20)
        _checks.one_of("method", self.method, SEARCH_METHODS)
        _checks.integer("spline_upsample", self.spline_upsample, 2, 64)
        if self.spline_upsample % 2:
            raise ValueError(f"spline_upsample must be an even integer in [2, 64], got {self.spline_upsample!r}")
        _checks.in_range("box_m", self.box_m, 0.1, 100.0, "m")
        _checks.integer("bias_boxes", self.bias_boxes, 1, 64)
        _checks.in_range("box_final_m", self.box_final_m, 1e-3, self.box_m, "m")
        _checks.integer("capacity", self.capacity, 8, 1 << 16)
        _checks.integer("chunk_boxes", self.chunk_boxes, 1, self.capacity)
        if self.capacity % self.chunk_boxes:
            raise ValueError(f"chunk_boxes must divide capacity ({self.capacity}), got {self.chunk_boxes!r}")
        _checks.in_range("gap_tol", self.gap_tol, 0.0, 1.0)
        _checks.in_range("window_decay_s", self.window_decay_s, 0.0, correlogram.MAX_WINDOW_DECAY_S, "s")
        if self.window_decay_s > 0 and self.method != "bnb":
            raise ValueError(f"window_decay_s > 0 (the first-path-aware window) needs method 'bnb', got "
                             f"method {self.method!r}")
        if self.method == "bnb" and self.z_half_width_m > 0:
            raise ValueError("z_half_width_m must be 0 with method 'bnb' (it searches x, y, c δt at the known height)")

    def tap_weights(self, num: Numerology = PAPER) -> np.ndarray:
        """The weights (L,) of the window's taps (``correlogram.tap_weights``)."""
        return correlogram.tap_weights(self.n_taps, self.window_decay_s, num.sample_period_s)

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


def _newton_step(g, bs_xyz, q, mask, n_taps, scs_hz, max_step_m):
    """One Newton step on the exact eq. (10) in q = (x, y, z, c δt), derivatives by JAX autodiff.

    The cost is separable, C(q) = Σ_m c_m(τ_m(q)), so one nested forward-mode pass over the M ToAs gives every
    c_m, c_m' and c_m'' at once; the chain rule then gives ∇C = Jᵀc' and ∇²C = Jᵀ diag(c'') J + Σ_m c_m' ∇²τ_m with
    J = ∂τ/∂q (both of the small geometric map also by autodiff).  The step is taken only if it is finite, shorter
    than ``max_step_m`` and raises the exact cost; ``mask`` (4,) freezes coordinates that are not searched.
    Returns the step (4,).
    """

    def terms(t):
        return _ml_cost_terms(g, t, n_taps, scs_hz)

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


def _grid_reach(cfg: SearchConfig) -> tuple[float, float, float]:
    """How far the grid search's candidates can lie from its centre in x and y, in z and in c δt (metres): the first
    level's half widths, plus 2 steps per further level (each is ±2 steps around the best point)."""
    extra = 2 * sum(cfg.steps()[1:])
    return (cfg.half_width_m + extra, cfg.z_half_width_m + extra * (cfg.z_half_width_m > 0),
            cfg.bias_half_width_m + extra * (cfg.bias_half_width_m > 0))


def grid_window_cells(cfg: SearchConfig, num: Numerology = PAPER) -> int:
    """Static width W (grid points of T_s/U, a multiple of U) of ``grid_window``: the ToA span of the search's
    reach (``_grid_reach``: its x, y, z box's diameter plus twice the c δt reach), the 2 + 1 grid points either side
    that the cubic reads, the alignment of the start to a multiple of U, and a margin."""
    r_xy, r_z, r_b = _grid_reach(cfg)
    cell_m = C * num.sample_period_s / cfg.upsample
    span = 2 * np.sqrt(2 * r_xy**2 + r_z**2) + 2 * r_b
    u = cfg.upsample
    return int(u * np.ceil((np.ceil(span / cell_m) + u + 6) / u))


def grid_window(bs_xyz, center_m, cfg: SearchConfig, num: Numerology = PAPER) -> jax.Array:
    """The first grid point (M,) of the part of each BS's correlogram that the grid search (``search``) around
    center_m can read: ``grid_window_cells(cfg)`` points from there hold every ToA of its candidates and the
    cubic's neighbours.  The start is the nearest distance from the BS to the search's reach box plus its lowest
    c δt, less 2 points, rounded down to a multiple of U (``correlogram.energy_window`` computes whole samples).

    bs_xyz : (M, 3) m; center_m : (4,) = [x, y, z, c δt] m.  Returns int (M,), in grid points of T_s/U, not reduced
    modulo N·U.  Traceable."""
    r_xy, r_z, r_b = _grid_reach(cfg)
    cell_m = C * num.sample_period_s / cfg.upsample
    bs = jnp.asarray(bs_xyz)
    dz2 = (jnp.maximum(jnp.abs(center_m[2] - bs[:, 2]) - r_z, 0.0) ** 2)[:, None]
    dmin, _ = _box_distances(center_m[None, 0:1], center_m[None, 1:2], r_xy, bs[:, 0, None], bs[:, 1, None], dz2)
    first = jnp.floor((dmin[:, 0] + center_m[3] - r_b) / cell_m).astype(jnp.int64) - 2
    return (first // cfg.upsample) * cfg.upsample


def first_rows(corr, m: int):
    """The correlograms of the m nearest BSs: the first m rows of the whole correlograms or of both parts of a
    window pair (``_lookup_terms``)."""
    return (corr[0][:m], corr[1][:m]) if isinstance(corr, tuple) else corr[:m]


def _level_candidates(q, cfg: SearchConfig, level: int):
    """The candidates (K, 4) of ``search``'s level ``level`` around q (4,) and the number of c δt offsets per
    (x, y, z) point (they vary fastest)."""
    step = cfg.steps()[level]
    search_b, search_z = cfg.bias_half_width_m > 0, cfg.z_half_width_m > 0
    half_b = cfg.bias_half_width_m if level == 0 else 2 * step * search_b
    if level == 0:
        off = _grid_offsets(cfg.half_width_m, cfg.z_half_width_m, half_b, step)
    else:
        off = _grid_offsets(2 * step, 2 * step * search_z, half_b, step)
    return q + jnp.asarray(off), _axis(half_b, step).size


def _candidate_terms(corr, bs_xyz, cand, n_b, cfg: SearchConfig, ts: float):
    """Per-BS terms (K, M) of the cost at candidates cand (K, 4) whose c δt offsets vary fastest (n_b per point):
    the distances of each (x, y, z) point are computed once for all of its c δt offsets."""
    grid = cand.reshape(-1, n_b, 4)
    dist = jnp.linalg.norm(grid[:, 0, None, :3] - bs_xyz, axis=-1) / C  # (K / n_b, M)
    tau = dist[:, None, :] + (grid[..., 3] / C)[..., None]  # = _tau_of(cand), (K / n_b, n_b, M)
    return _lookup_terms(corr, tau.reshape(cand.shape[0], -1) / ts * cfg.upsample)


def search(corr, g, bs_xyz, center, cfg: SearchConfig, n_fft: int, scs_hz: float, with_cost: bool = True,
           first_level=None):
    """The divide-and-conquer search on precomputed correlograms (traceable; used inside jit by ``estimate`` and
    by ``dpe5g.montecarlo``, which reuses one set of correlograms for several M).

    corr : (M, N·U) from ``correlogram.energy_grid``, or the window of it around ``center`` (``grid_window``,
    ``correlogram.energy_window``: a pair (values (M, W), start (M,))); g : (M, N) the LS spectrum (``correlogram.ls_spectrum``,
    read only by the polish and for the cost); bs_xyz : (M, 3) m;
    center : (4,) = [x, y, z, δt].  first_level : the best candidate (4,) of the first level in metres, when the
    caller has found it (``nested_grid_fixes``); None searches it.  Returns q (4,) = (x, y, z, c δt) in metres and
    the exact cost there (or only q when ``with_cost`` is False).
    """
    _checks.require_x64()
    ts = 1.0 / (n_fft * scs_hz)
    q = jnp.array([center[0], center[1], center[2], center[3] * C])
    steps = cfg.steps()
    for level in range(len(steps)):
        if level == 0 and first_level is not None:
            q = first_level
            continue
        cand, n_b = _level_candidates(q, cfg, level)
        q = cand[jnp.argmax(jnp.sum(_candidate_terms(corr, bs_xyz, cand, n_b, cfg, ts), axis=-1))]
    if cfg.polish:
        mask = jnp.array([1.0, 1.0, float(cfg.z_half_width_m > 0), float(cfg.bias_half_width_m > 0)])
        for _ in range(cfg.polish_iters):
            q = q + _newton_step(g, bs_xyz, q, mask, cfg.n_taps, scs_hz, 2 * steps[-1])
    if not with_cost:
        return q
    return q, _ml_cost(g, _tau_of(q, bs_xyz), cfg.n_taps, scs_hz)


def nested_grid_fixes(corr, g, bs_xyz, center_m, cfg: SearchConfig, m_values, num: Numerology = PAPER) -> dict:
    """``fix`` with the grid search for each M of ``m_values`` (the M nearest BSs, rows nearest first) around one
    shared centre (traceable).  The first level's candidates are then the same for every M: their per-BS terms are
    looked up once, for the largest M, and the cost of each M is a running sum over the BSs — on Fig. 9's grid this
    level is 94 % of the candidates, looked up for 24 BSs instead of 6 + 12 + 18 + 24.  The finer levels run per M.
    Equal to ``fix`` per M up to the order of the sum (a tie of two candidates within round-off could differ; a
    test checks the fixes agree).

    corr : (I, N·U) ``receiver_correlogram`` of the I ≥ max(m_values) nearest BSs (or its window around center_m,
    as ``search`` reads it); g : (I, N); bs_xyz : (I, 3) m;
    center_m : (4,) = [x, y, z, c δt] m.  Returns ``fix``'s dict with a leading axis over m_values."""
    _checks.require_x64()
    if cfg.method != "grid":
        raise ValueError(f"nested_grid_fixes runs the grid search; cfg.method must be 'grid', got {cfg.method!r}")
    ts = num.sample_period_s
    cand, n_b = _level_candidates(center_m, cfg, 0)
    m_max = max(m_values)
    running = jnp.cumsum(_candidate_terms(first_rows(corr, m_max), bs_xyz[:m_max], cand, n_b, cfg, ts), axis=-1)
    center = center_m.at[3].divide(C)
    fixes = []
    for m in m_values:
        q = search(first_rows(corr, m), g[:m], bs_xyz[:m], center, cfg, num.n_fft, num.scs_hz, with_cost=False,
                   first_level=cand[jnp.argmax(running[:, m - 1])])
        fixes.append({"q": q, "gap": jnp.asarray(jnp.nan), "certified": jnp.asarray(False),
                      "edge": grid_edge(q, center_m, cfg)})
    return {k: jnp.stack([f[k] for f in fixes]) for k in fixes[0]}


def _catmull_rom_weights(t):
    """The weights (..., 4) of the four grid values around a position with fractional part t (...) in
    ``_lookup``'s cubic, written as weights: the same polynomial as its nested form."""
    return jnp.stack([t * (-0.5 + t * (1.0 - 0.5 * t)), 1.0 + t * t * (-2.5 + 1.5 * t),
                      t * (0.5 + t * (2.0 - 1.5 * t)), t * t * (-0.5 + 0.5 * t)], axis=-1)


def _parts_terms(parts, start, pos):
    """The per-BS terms of ``_lookup`` for the three parts (3, M, W) of a correlogram window starting at grid
    points start (M,) (``correlogram.energy_window_parts``), at positions pos (..., M) in grid units: one gather of
    the 3 × 4 values and one set of cubic weights per lookup, for all parts.  Returns (3, ..., M)."""
    f = jnp.floor(pos)
    first = f.astype(jnp.int64) - start - 1
    rows = jnp.broadcast_to(jnp.arange(parts.shape[1]), first.shape)
    dims = jax.lax.GatherDimensionNumbers(offset_dims=(first.ndim, first.ndim + 1), collapsed_slice_dims=(1,),
                                          start_index_map=(1, 2))
    v = jax.lax.gather(parts, jnp.stack([rows, first], axis=-1), dims, slice_sizes=(3, 1, 4),
                       mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS)  # (..., M, 3, 4)
    terms = jnp.einsum("...q,...pq->...p", _catmull_rom_weights(pos - f), v)  # (..., M, 3)
    return jnp.moveaxis(terms, -1, 0)


def mixed_grid_fixes(parts, start, a, b, bs_xyz, center_m, cfg: SearchConfig, m_values,
                     num: Numerology = PAPER) -> dict:
    """``nested_grid_fixes`` for S received spectra a_s·g0 + b_s·gn at once (the engine's SNRs of one trial, its
    noise-free spectrum g0 and unit noise gn), from the three parts of their correlograms' windows around one
    centre: the correlogram of spectrum s is ``correlogram.mix_parts(parts, a_s, b_s)``, and so is its cubic
    lookup, which is linear in the grid values.  The first level — 94 % of Fig. 9's candidates — is looked up once
    for the three parts instead of once per spectrum, and the cost of every (s, M) is one matrix product over the
    BSs; the finer levels run per (s, M) on the mixed window, as ``nested_grid_fixes``.  Equal to it up to
    round-off (the weights form of the cubic and the order of the sums; a test checks the fixes agree).

    parts : (3, I, W) ``correlogram.energy_window_parts`` of the I ≥ max(m_values) nearest BSs, starting at grid
    points start (I,) (``grid_window`` of center_m); a, b : (S, I); bs_xyz : (I, 3) m; center_m : (4,) =
    [x, y, z, c δt] m.  Needs cfg.polish False (the polish reads each spectrum).  Returns ``fix``'s dict with
    leading axes (S, len(m_values))."""
    _checks.require_x64()
    if cfg.method != "grid" or cfg.polish:
        raise ValueError(f"mixed_grid_fixes runs the grid search without polish; got method {cfg.method!r}, "
                         f"polish {cfg.polish!r}")
    ts = num.sample_period_s
    cand, n_b = _level_candidates(center_m, cfg, 0)
    m_max = max(m_values)
    grid = cand.reshape(-1, n_b, 4)
    dist = jnp.linalg.norm(grid[:, 0, None, :3] - bs_xyz[:m_max], axis=-1) / C  # as ``_candidate_terms``
    # cost of (s, M) at each candidate: Σ_{m < M} (a² T_0 + 2ab T_1 + b² T_2), one product over (part, BS)
    mix = jnp.stack([a * a, 2.0 * a * b, b * b], axis=1)[..., :m_max]  # (S, 3, m_max)
    upto = (np.arange(m_max)[:, None] < np.asarray(m_values)[None, :]).astype(float)  # (m_max, J)
    weights = jnp.einsum("spm,mj->pmsj", mix, upto).reshape(3 * m_max, -1)  # (3 m_max, S J)

    def per_bias(bias_s):  # one c δt offset: the ToAs of every (x, y) point shift by it
        terms = _parts_terms(parts[:, :m_max], start[:m_max], (dist + bias_s) / ts * cfg.upsample)  # (3, XY, M)
        return jnp.moveaxis(terms, 0, 1).reshape(dist.shape[0], -1) @ weights  # (XY, S J)

    # a loop over the offsets, so that the distances (and the window's start) are computed once, not again inside
    # each lookup (XLA on the CPU fuses such small producers into the large loops that read them)
    costs = jax.lax.map(per_bias, grid[0, :, 3] / C)  # (n_b, XY, S J)
    costs = jnp.swapaxes(costs, 0, 1).reshape(cand.shape[0], -1)  # (K, S J), candidates in ``cand``'s order
    first = cand[jnp.argmax(costs, axis=0)].reshape(a.shape[0], len(m_values), 4)  # (S, J, 4)
    center = center_m.at[3].divide(C)

    def per_spectrum(x):
        a_s, b_s, first_s = x
        corr = (correlogram.mix_parts(parts, a_s, b_s), start)
        qs = [search(first_rows(corr, m), None, bs_xyz[:m], center, cfg, num.n_fft, num.scs_hz, with_cost=False,
                     first_level=first_s[j]) for j, m in enumerate(m_values)]
        return jnp.stack(qs)

    q = jax.lax.map(per_spectrum, (a, b, first))  # (S, J, 4)
    nan = jnp.full(q.shape[:2], jnp.nan)
    return {"q": q, "gap": nan, "certified": jnp.zeros(q.shape[:2], bool), "edge": grid_edge(q, center_m, cfg)}


# ---- the certified search ------------------------------------------------------------------------------------------

def spline_values(coef, pos) -> jax.Array:
    """Σ_m s_m(pos_m): the spline of ``correlogram.spline_coefficients`` at positions pos (..., M) in knot
    units (periodic)."""
    m, j = coef.shape
    f = jnp.floor(pos)
    i0 = f.astype(jnp.int64)
    c = [coef[jnp.arange(m), jnp.mod(i0 + d, j)] for d in (-1, 0, 1, 2)]
    return jnp.sum(_horner(_cell_poly(*c), pos - f), axis=-1)


def _cell_poly(c0, c1, c2, c3):
    """Power-basis coefficients (a0, a1, a2, a3) of the cubic B-spline on the cell between knots 1 and 2 of c0…c3."""
    return (c0 + 4 * c1 + c2) / 6, (c2 - c0) / 2, (c0 - 2 * c1 + c2) / 2, (-c0 + 3 * c1 - 3 * c2 + c3) / 6


def _horner(a, t):
    return a[0] + t * (a[1] + t * (a[2] + t * a[3]))


def _cubic_max(a, lo, hi):
    """max over t ∈ [lo, hi] of a0 + a1 t + a2 t² + a3 t³ (element-wise): the ends and the stationary points."""
    v = jnp.maximum(_horner(a, lo), _horner(a, hi))
    qa, qb, qc = 3 * a[3], 2 * a[2], a[1]
    disc = qb * qb - 4 * qa * qc
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    lin = jnp.abs(qa) <= 1e-12 * (jnp.abs(qb) + jnp.abs(qc))
    safe_a = jnp.where(lin, 1.0, 2 * qa)
    r_lin = -qc / jnp.where(qb == 0, 1.0, qb)
    for r in ((-qb + sq) / safe_a, (-qb - sq) / safe_a):
        r = jnp.where(lin, r_lin, r)
        ok = (disc >= 0) & (r > lo) & (r < hi)
        v = jnp.where(ok, jnp.maximum(v, _horner(a, jnp.clip(r, lo, hi))), v)
    return v


def _range_max_table(x, max_len: int):
    """Sparse table for range maxima along the last axis: t[k, ..., j] = max(x[..., j : j + 2^k]), for queries of
    up to ``max_len`` cells (static; ``_range_max`` of a longer range would read a level that is not there)."""
    levels = [x]
    n = min(x.shape[-1], max_len)
    while (1 << len(levels)) <= n:
        prev, sh = levels[-1], 1 << (len(levels) - 1)
        tail = jnp.full(prev.shape[:-1] + (sh,), -jnp.inf)
        levels.append(jnp.maximum(prev, jnp.concatenate([prev[..., sh:], tail], axis=-1)))
    return jnp.stack(levels)


def _range_max(table, rows, a, b):
    """max over cells a … b (inclusive, b ≥ a) of each row; -inf where b < a."""
    w = b - a + 1
    k = jnp.floor(jnp.log2(jnp.maximum(w, 1).astype(jnp.float64))).astype(jnp.int64)
    n = table.shape[-1]
    v = jnp.maximum(table[k, rows, jnp.clip(a, 0, n - 1)], table[k, rows, jnp.clip(b - (1 << k) + 1, 0, n - 1)])
    return jnp.where(w > 0, v, -jnp.inf)


def slice_cells(cfg: SearchConfig, num: Numerology = PAPER) -> int:
    """Static number of spline cells per BS that any ToA inside the search window can reach (a power of two)."""
    cell_m = C * num.sample_period_s / cfg.spline_upsample
    span = 2 * np.sqrt(2) * cfg.half_width_m + 2 * cfg.bias_half_width_m
    return int(2 ** np.ceil(np.log2(span / cell_m + 8)))


#: UB2 (the second-order bound of ``certified_search``) is computed for boxes whose ToA interval spans fewer spline
#: cells than this; larger boxes use UB1 alone.  Either bound is valid and the fix does not depend on the choice (a
#: looser bound only refines more boxes); measured on Fig. 9's urban trials, UB2 prunes almost nothing above this size
#: and UB1 almost nothing below it, so this only saves work.
TAYLOR_MAX_CELLS = 2.5


def _taylor_pays(hx: float, hb: float, cell_m: float) -> bool:
    """Whether boxes of half sizes hx (x, y) and hb (c δt) in metres get UB2 as well (``TAYLOR_MAX_CELLS``)."""
    return (2 * np.sqrt(2) * hx + 2 * hb) / cell_m < TAYLOR_MAX_CELLS


def _box_distances(cx, cy, hx, bx, by, dz2):
    """Nearest and farthest distance from each BS (bx, by (M, 1) m; dz2 (M, 1) its squared height difference) to
    the squares centred on (cx, cy) (1, K) m with half side hx: (M, K) each."""
    xl, xh, yl, yh = cx - hx, cx + hx, cy - hx, cy + hx
    dxn = jnp.maximum(jnp.maximum(xl - bx, bx - xh), 0.0)
    dyn = jnp.maximum(jnp.maximum(yl - by, by - yh), 0.0)
    dxx = jnp.maximum(jnp.abs(xl - bx), jnp.abs(xh - bx))
    dyx = jnp.maximum(jnp.abs(yl - by), jnp.abs(yh - by))
    return jnp.sqrt(dxn**2 + dyn**2 + dz2), jnp.sqrt(dxx**2 + dyx**2 + dz2)


def spline_window(coef, bs_xyz, center, cfg: SearchConfig, num: Numerology = PAPER):
    """The part of each BS's spline (``correlogram.spline_coefficients``) that a ToA inside ``certified_search``'s
    window can reach: ``slice_cells(cfg)`` cells from the nearest point of the window's x, y square and its lowest
    c δt, with the knots either side that the cubic pieces read.

    coef : (M, N·U); bs_xyz : (M, 3) m; center : (4,) = [x, y, z, c δt] m.  Returns (coefficients (M, cells + 3),
    start (M,) the knot index of the first, modulo N·U); cell r of BS m spans knot units [start_m + 1 + r,
    start_m + 2 + r).  Rows are per BS, so the first M' rows are the window of the M' nearest.  Traceable."""
    n_knots = coef.shape[1]
    cell_m = C * num.sample_period_s / cfg.spline_upsample
    n_cells = slice_cells(cfg, num)
    half, half_b = cfg.half_width_m, cfg.bias_half_width_m
    bs = jnp.asarray(bs_xyz)
    dz2 = ((center[2] - bs[:, 2]) ** 2)[:, None]
    dmin, _ = _box_distances(center[None, 0:1], center[None, 1:2], half, bs[:, 0, None], bs[:, 1, None], dz2)
    start = jnp.floor((dmin[:, 0] + center[3] - half_b) / cell_m).astype(jnp.int64) - 2
    idx = jnp.mod(start[:, None] + jnp.arange(n_cells + 3)[None], n_knots)
    return jnp.take_along_axis(coef, idx, axis=1), start


def certified_search(coef, bs_xyz, center, cfg: SearchConfig, num: Numerology = PAPER) -> dict:
    """Global maximum of eq. (10) (its spline form, ``correlogram.spline_coefficients``) over the window by branch and
    bound.

    The window is centre ± ``half_width_m`` in x and y and centre ± ``bias_half_width_m`` in c δt, at the centre's
    height.  The cost is separable, C(p) = Σ_m s_m(u_m(p)) with u_m = (‖p − b_m‖ + c δt) / (c T_s / U) the ToA in
    knot units.  Over a box every u_m spans an exact interval [lo_m, hi_m] (nearest and farthest point of the box),
    so two upper bounds hold for every point of the box:

    * UB1 = Σ_m max_{u ∈ [lo_m, hi_m]} s_m(u) — the maximum of each cubic piece, exact at the two partial cells at
      the ends and read from a range-maximum table of per-cell maxima in between;
    * UB2 = C(centre) + |g|·h + Σ_m ½ K_m Δu_m² + Σ_m max(s_m', 0) h_xy² / (d_m c T_s / U), a second-order bound:
      g is the gradient of C at the centre, h the box's half sizes, K_m ≥ 0 bounds s_m'' on [lo_m, hi_m], Δu_m the
      interval's half width around the centre's ToA, and the last term bounds the curvature of the distance
      (the Hessian of ‖p − b_m‖ has eigenvalues ≤ 1/d_m, d_m the box's nearest distance).

    Level 0 tiles the window with boxes of ``box_m`` × ``box_m`` × (2 ``bias_half_width_m`` / ``bias_boxes``); each
    level keeps the ``capacity`` boxes of highest min(UB1, UB2) that exceed the best cost found at a box centre
    (the others cannot hold the maximum, or are dropped for lack of room and make the result uncertified), and
    halves them in x, y and c δt — ``chunk_boxes`` at a time in order of bound, skipping a box whose bound an earlier
    chunk's best cost has overtaken —, until the x, y side is ≤ ``box_final_m``.  The result is the best box centre
    found; ``gap`` = (largest upper bound left − cost) / cost bounds how far the true maximum of the spline cost in
    the window can lie above it.

    coef : (M, N·U) from ``correlogram.spline_coefficients``, or the pair ``spline_window`` returns for this window
    (the Monte Carlo engine computes it beside the coefficients, so that its search reads only that part); bs_xyz :
    (M, 3) m; center : (4,) = [x, y, z, c δt] in METRES.
    Returns a dict: q (4,) = (x, y, z, c δt) m, cost (spline), gap (relative), certified (gap ≤ gap_tol, no
    box dropped), edge (the fix lies within one final box of the window's boundary in x, y or c δt).
    Traceable (jit, vmap); shapes are static given ``cfg``.
    """
    _checks.require_x64()
    sl, start = coef if isinstance(coef, tuple) else spline_window(coef, bs_xyz, center, cfg, num)
    m = sl.shape[0]
    u_scale = cfg.spline_upsample
    cell_m = C * num.sample_period_s / u_scale
    n_cells = slice_cells(cfg, num)
    half, half_b = cfg.half_width_m, cfg.bias_half_width_m
    bs = jnp.asarray(bs_xyz)
    dz2 = ((center[2] - bs[:, 2]) ** 2)[:, None]
    bx, by = bs[:, 0, None], bs[:, 1, None]
    rows = jnp.arange(m)[:, None]  # BSs on the first axis, boxes on the last (12 % faster than boxes first here)

    def dist_bounds(cx, cy, hx):
        return _box_distances(cx, cy, hx, bx, by, dz2)

    base = (start + 1).astype(jnp.float64)[:, None]  # cell r of the window spans knot units [base + r, base + r + 1)
    cells = _cell_poly(sl[:, :-3], sl[:, 1:-2], sl[:, 2:-1], sl[:, 3:])
    poly = jnp.stack(cells, axis=-1)  # (M, n_cells, 4)
    # the longest range a box can query: the ToA interval of a level-0 box spans ≤ (2√2 hx + 2 hb) / cell cells
    # (the box's diagonal in x, y and its c δt side), plus the partial cells at both ends
    n0 = max(int(np.ceil(2 * half / cfg.box_m - 1e-9)), 1)
    nb0 = cfg.bias_boxes if half_b > 0 else 1
    hx, hb = half / n0, half_b / nb0
    max_len = int(np.ceil((2 * np.sqrt(2) * hx + 2 * hb) / cell_m)) + 3
    t_max = _range_max_table(_cubic_max(cells, 0.0, 1.0), max_len)
    t_d2 = _range_max_table(2 * cells[2], max_len)  # s'' at the start of each cell (continuous for a cubic B-spline)

    def evaluate(cx, cy, cb, hx, hb, taylor=True):
        """(upper bound over each box, cost at its centre); the bound is min(UB1, UB2), or UB1 alone where
        ``taylor`` is False (static)."""
        cx, cy, cb = cx[None, :], cy[None, :], cb[None, :]
        dmin, dmax = dist_bounds(cx, cy, hx)
        lo = (dmin + cb - hb) / cell_m - base
        hi = (dmax + cb + hb) / cell_m - base
        jl = jnp.clip(jnp.floor(lo).astype(jnp.int64), 0, n_cells - 1)
        jh = jnp.clip(jnp.floor(hi).astype(jnp.int64), 0, n_cells - 1)
        tl, th = lo - jl, hi - jh
        al, ah = jnp.moveaxis(poly[rows, jl], -1, 0), jnp.moveaxis(poly[rows, jh], -1, 0)
        same = jl == jh
        ends = jnp.maximum(_cubic_max(al, tl, jnp.where(same, th, 1.0)), jnp.where(same, -jnp.inf, _cubic_max(ah, 0.0, th)))
        ub1 = jnp.sum(jnp.maximum(ends, _range_max(t_max, rows, jl + 1, jh - 1)), axis=0)
        d = jnp.sqrt((cx - bx) ** 2 + (cy - by) ** 2 + dz2)
        u = (d + cb) / cell_m - base
        jc = jnp.clip(jnp.floor(u).astype(jnp.int64), 0, n_cells - 1)
        ac = jnp.moveaxis(poly[rows, jc], -1, 0)
        tc = u - jc
        val = _horner(ac, tc)
        cost = jnp.sum(val, 0)
        if not taylor:
            return ub1, cost
        d1 = ac[1] + tc * (2 * ac[2] + 3 * ac[3] * tc)  # s_m' per knot unit
        k2 = jnp.maximum(2 * al[2] + 6 * al[3] * tl, 2 * ah[2] + 6 * ah[3] * th)
        k2 = jnp.maximum(jnp.maximum(k2, _range_max(t_d2, rows, jl + 1, jh)), 0.0)
        g = jnp.stack([jnp.sum(d1 * (cx - bx) / d, 0), jnp.sum(d1 * (cy - by) / d, 0), jnp.sum(d1, 0)]) / cell_m
        lin = (jnp.abs(g[0]) + jnp.abs(g[1])) * hx + jnp.abs(g[2]) * hb
        curv = jnp.sum(jnp.maximum(d1, 0.0) * hx**2 / (jnp.maximum(dmin, 1e-3) * cell_m), 0)
        quad = jnp.sum(0.5 * k2 * jnp.maximum(hi - u, u - lo) ** 2, 0)
        return jnp.minimum(ub1, cost + lin + curv + quad), cost

    ax = -half + hx * (2 * np.arange(n0) + 1)
    ab = -half_b + hb * (2 * np.arange(nb0) + 1)
    gx, gy, gb = (a.ravel() for a in np.meshgrid(ax, ax, ab, indexing="ij"))
    cx, cy, cb = center[0] + gx, center[1] + gy, center[3] + gb
    ub, lb = evaluate(cx, cy, cb, hx, hb, taylor=_taylor_pays(hx, hb, cell_m))
    i = jnp.argmax(lb)
    best, bq = lb[i], jnp.stack([cx[i], cy[i], cb[i]])
    sx = np.array([-1.0, 1, -1, 1, -1, 1, -1, 1])
    sy = np.array([-1.0, -1, 1, 1, -1, -1, 1, 1])
    sb = np.array([-1.0, -1, -1, -1, 1, 1, 1, 1])
    cap = cfg.capacity
    chunk = min(cfg.chunk_boxes, cap)
    size = max(8 * cap, int(ub.shape[0]))  # every level's boxes live in buffers of this static size
    pad = lambda a, fill: jnp.concatenate([a, jnp.full(size - a.shape[0], fill, a.dtype)])

    def refine(state, h):
        """One level: keep the ``capacity`` boxes of highest bound above the best cost and, in that order, chunk by
        chunk while any is left, halve them into 8 children (half sizes h = (hx, hb)), bound and evaluate the
        children.  A parent whose bound no longer exceeds the best cost (raised by an earlier chunk) is skipped:
        none of its points can beat it.  The loop runs only over the parents alive, and stops as soon as none of those
        left can beat the best cost, so its cost follows them."""
        cx, cy, cb, ub, best, bq, dropped = state
        hx, hb, taylor = h[0], h[1], h[2] > 0
        alive = ub > best
        # ranked by the bound rounded to float32 (XLA's float64 top_k was measured 10x slower on this CPU); the
        # ranking only orders the work and picks whom to drop, every comparison with the best cost stays float64
        _, ix = jax.lax.top_k(jnp.where(alive, ub.astype(jnp.float32), -jnp.inf), cap)
        vals = jnp.where(alive[ix], ub[ix], -jnp.inf)
        left = alive & ~jnp.zeros(size, bool).at[ix].set(True)
        dropped = jnp.maximum(dropped, jnp.max(jnp.where(left, ub, -jnp.inf)))  # highest bound left for lack of room
        pxyb = jnp.stack([cx[ix], cy[ix], cb[ix]])
        n_live = jnp.sum(vals > -jnp.inf)
        # rest[i]: the highest bound among the parents from i on (any order): once it no longer exceeds the best
        # cost, no parent left is refined, and the loop stops (the chunks it skips would only produce dead children)
        rest = jax.lax.cummax(vals, reverse=True)
        out = jnp.full((3, size), 0.0), jnp.full(size, -jnp.inf)

        def body(carry):
            k, best, bq, (oxyb, oub) = carry
            pv = jax.lax.dynamic_slice(vals, (k * chunk,), (chunk,))
            p = jax.lax.dynamic_slice(pxyb, (0, k * chunk), (3, chunk))
            ccx = (p[0][:, None] + sx * hx).ravel()
            ccy = (p[1][:, None] + sy * hx).ravel()
            ccb = (p[2][:, None] + sb * hb).ravel()
            cub, clb = jax.lax.cond(taylor, lambda: evaluate(ccx, ccy, ccb, hx, hb, True),
                                    lambda: evaluate(ccx, ccy, ccb, hx, hb, False))
            live = jnp.repeat(pv > best, 8)
            cub, clb = jnp.where(live, cub, -jnp.inf), jnp.where(live, clb, -jnp.inf)
            j = jnp.argmax(clb)
            bq = jnp.where(clb[j] > best, jnp.stack([ccx[j], ccy[j], ccb[j]]), bq)
            oxyb = jax.lax.dynamic_update_slice(oxyb, jnp.stack([ccx, ccy, ccb]), (0, 8 * chunk * k))
            oub = jax.lax.dynamic_update_slice(oub, cub, (8 * chunk * k,))
            return k + 1, jnp.maximum(best, clb[j]), bq, (oxyb, oub)

        go = lambda c: (c[0] * chunk < n_live) & (rest[jnp.minimum(c[0] * chunk, cap - 1)] > c[1])
        _, best, bq, (oxyb, oub) = jax.lax.while_loop(go, body, (0, best, bq, out))
        return (oxyb[0], oxyb[1], oxyb[2], oub, best, bq, dropped), None

    halves = []  # the half sizes of every level's children
    while 2 * hx > cfg.box_final_m + 1e-12:
        hx, hb = hx / 2, hb / 2
        halves.append((hx, hb, float(_taylor_pays(hx, hb, cell_m))))
    state = (pad(cx, 0.0), pad(cy, 0.0), pad(cb, 0.0), pad(ub, -jnp.inf), best, bq, jnp.asarray(-jnp.inf))
    if halves:  # every level has the same shapes: one scan, compiled once
        state, _ = jax.lax.scan(refine, state, jnp.asarray(halves))
    cx, cy, cb, ub, best, bq, dropped = state
    top = jnp.maximum(jnp.max(ub), dropped)
    gap = jnp.maximum(top - best, 0.0) / best
    off = bq - jnp.stack([center[0], center[1], center[3]])
    edge = (jnp.abs(off[0]) >= half - 2 * hx) | (jnp.abs(off[1]) >= half - 2 * hx)
    if half_b > 0:
        edge = edge | (jnp.abs(off[2]) >= half_b - 2 * hb)
    q = jnp.stack([bq[0], bq[1], center[2], bq[2]])
    return {"q": q, "cost": best, "gap": gap, "certified": (gap <= cfg.gap_tol) & ~(dropped > best), "edge": edge}


def grid_edge(q, center_m, cfg: SearchConfig):
    """Whether a ``search`` fix q (..., 4) lies on the boundary of its grid window (centre (4,) in metres)."""
    tol = 1.5 * cfg.final_step_m
    off = jnp.abs(q - center_m)
    edge = (off[..., 0] >= cfg.half_width_m - tol) | (off[..., 1] >= cfg.half_width_m - tol)
    if cfg.bias_half_width_m > 0:
        edge = edge | (off[..., 3] >= cfg.bias_half_width_m - tol)
    return edge


def fix(g, bs_xyz, center_m, cfg: SearchConfig, num: Numerology = PAPER, corr=None) -> dict:
    """One DPE fix with either search (traceable): g (M, N) the LS spectrum (``correlogram.ls_spectrum``);
    bs_xyz (M, 3) m; center_m (4,) = [x, y, z, c δt] in metres.  corr : ``receiver_correlogram`` of g (or of more
    BSs, of which the first M rows are read), or None to compute it.
    Returns a dict: q (4,) m, gap (relative; NaN for the grid, which certifies nothing), certified, edge."""
    _checks.require_x64()
    corr = receiver_correlogram(g, cfg) if corr is None else corr
    if cfg.method == "bnb":
        r = certified_search(corr, bs_xyz, center_m, cfg, num)
        return {"q": r["q"], "gap": r["gap"], "certified": r["certified"], "edge": r["edge"]}
    center = center_m.at[3].divide(C)
    q = search(corr, g, bs_xyz, center, cfg, num.n_fft, num.scs_hz, with_cost=False)
    return {"q": q, "gap": jnp.asarray(jnp.nan), "certified": jnp.asarray(False), "edge": grid_edge(q, center_m, cfg)}


def receiver_correlogram(g, cfg: SearchConfig, window=None):
    """The per-BS correlograms the chosen search reads (traceable), from the LS spectrum g (M, N):
    ``correlogram.energy_grid`` on T_s/upsample (in ``correlogram.GRID_DTYPE``) for "grid",
    ``correlogram.spline_coefficients`` (float64) for "bnb".  Rows are
    per BS, so the M nearest of them serve any M.  window : for "bnb", ``correlogram.window_spectrum(cfg.n_taps, N)``
    passed as an array (then ``cfg.n_taps`` and ``cfg.window_decay_s`` are not read, and a compiled caller serves
    every window); None computes it from them."""
    if cfg.method == "bnb":
        if window is None:
            window = jnp.asarray(correlogram.window_spectrum(cfg.n_taps, g.shape[-1], cfg.tap_weights()))
        return correlogram.spline_coefficients(g, window, cfg.spline_upsample)
    return correlogram.energy_grid(g.astype(correlogram.GRID_DTYPE), cfg.n_taps, cfg.upsample)


@partial(jax.jit, static_argnames=("cfg", "num"))
def _estimate_one(y, prs, bs_xyz, center, cfg: SearchConfig, num: Numerology):
    g = correlogram.ls_spectrum(signal.demodulate(y), prs)
    r = fix(g, bs_xyz, center.at[3].multiply(C), cfg, num)
    cost = _ml_cost(g, _tau_of(r["q"], bs_xyz), cfg.n_taps, num.scs_hz, jnp.asarray(cfg.tap_weights(num)))
    return r["q"], cost, r["gap"], r["certified"], r["edge"]


@dataclass(frozen=True)
class Estimate:
    """Result of ``estimate``: xyz (..., 3) metres, clock_bias_s (...), cost (...) = eq. (10) at the estimate;
    gap (...) relative certified gap (NaN for the grid search), certified (...), edge (...) fix on the window's
    boundary."""

    xyz: np.ndarray
    clock_bias_s: np.ndarray
    cost: np.ndarray
    gap: np.ndarray
    certified: np.ndarray
    edge: np.ndarray


def estimate(
    y, prs, bs_xyz, center, cfg: SearchConfig = SearchConfig(), num: Numerology = PAPER, batch_size: int = 8
) -> Estimate:
    """DPE fix by divide-and-conquer search of eq. (10) around ``center``, batched over trials with vmap.

    y, prs : complex (..., M, N); bs_xyz : (..., M, 3) metres; center : (..., 4) = [x, y, z, δt] (m, m, m, s), the
    grid centre — the true position in the paper's set-up, or a prior from a coarse fix; z is the known UE height
    (or the centre of the z search when ``cfg.z_half_width_m`` > 0).
    batch_size : trials evaluated together (vmap) inside a sequential ``lax.map``; results do not depend on it.
    Returns an ``Estimate`` with leading shape (...).
    """
    _checks.require_x64()
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
    fn = partial(_estimate_one, cfg=cfg, num=num)
    lead = y.shape[:-2]
    if lead:
        # trials in vmapped chunks of `batch_size` (bounded memory); each trial's result is independent of chunking
        flat = [a.reshape((-1,) + a.shape[len(lead):]) for a in (y, prs, bs_xyz, center)]
        out = jax.lax.map(lambda a: fn(*a), tuple(flat), batch_size=batch_size)
        out = [o.reshape(lead + o.shape[1:]) for o in out]
    else:
        out = fn(y, prs, bs_xyz, center)
    q, cost, gap, certified, edge = (np.asarray(o) for o in out)
    return Estimate(q[..., :3], q[..., 3] / C, cost, gap, certified, edge)
