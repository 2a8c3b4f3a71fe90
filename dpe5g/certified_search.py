"""The certified search: the global maximum of eq. (10) (its cubic-spline form, ``correlogram.spline_coefficients``)
over the receiver's window by branch and bound, with a certified gap.

The cost is separable, C(p) = Σ_m s_m(u_m(p)) with u_m = (‖p − b_m‖ + c δt) / (c T_s / U) the ToA in knot units.
Over a box every u_m spans an exact interval [lo_m, hi_m] (nearest and farthest point of the box), which gives two
upper bounds over the box: ``piece_max_bound`` (UB1) and ``taylor_bound`` (UB2).  ``certified_search`` tiles the
window (``first_boxes``), then halves the boxes whose bound can still beat the best cost found, level by level
(``refine_level``), and reports the best box centre and the bound left over it (``certified_fix``).

The window's spline cells and their range-maximum tables are built once per search (``SplineCells``).  Positions are
in metres, q = (x, y, z, c δt), at the window centre's height.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from . import _checks, cost
from .nr import C, PAPER, Numerology
from .search_config import WindowFix, SearchConfig


def spline_values(coef, pos) -> jax.Array:
    """Σ_m s_m(pos_m): the spline of ``correlogram.spline_coefficients`` at positions pos (..., M) in knot
    units (periodic)."""
    m, j = coef.shape
    f = jnp.floor(pos)
    i0 = f.astype(jnp.int64)
    c = [coef[jnp.arange(m), jnp.mod(i0 + d, j)] for d in (-1, 0, 1, 2)]
    return jnp.sum(horner(cell_poly(*c), pos - f), axis=-1)


def cell_poly(c0, c1, c2, c3):
    """Power-basis coefficients (a0, a1, a2, a3) of the cubic B-spline on the cell between knots 1 and 2 of c0…c3."""
    return (c0 + 4 * c1 + c2) / 6, (c2 - c0) / 2, (c0 - 2 * c1 + c2) / 2, (-c0 + 3 * c1 - 3 * c2 + c3) / 6


def horner(a, t):
    """a0 + a1 t + a2 t² + a3 t³."""
    return a[0] + t * (a[1] + t * (a[2] + t * a[3]))


def cubic_max(a, lo, hi):
    """max over t ∈ [lo, hi] of a0 + a1 t + a2 t² + a3 t³ (element-wise): the ends and the stationary points."""
    v = jnp.maximum(horner(a, lo), horner(a, hi))
    qa, qb, qc = 3 * a[3], 2 * a[2], a[1]
    disc = qb * qb - 4 * qa * qc
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    lin = jnp.abs(qa) <= 1e-12 * (jnp.abs(qb) + jnp.abs(qc))
    safe_a = jnp.where(lin, 1.0, 2 * qa)
    r_lin = -qc / jnp.where(qb == 0, 1.0, qb)
    for r in ((-qb + sq) / safe_a, (-qb - sq) / safe_a):
        r = jnp.where(lin, r_lin, r)
        ok = (disc >= 0) & (r > lo) & (r < hi)
        v = jnp.where(ok, jnp.maximum(v, horner(a, jnp.clip(r, lo, hi))), v)
    return v


def range_max_table(x, max_len: int):
    """Sparse table for range maxima along the last axis: t[k, ..., j] = max(x[..., j : j + 2^k]), for queries of
    up to ``max_len`` cells (static; ``range_max`` of a longer range would read a level that is not there)."""
    levels = [x]
    n = min(x.shape[-1], max_len)
    while (1 << len(levels)) <= n:
        prev, sh = levels[-1], 1 << (len(levels) - 1)
        tail = jnp.full(prev.shape[:-1] + (sh,), -jnp.inf)
        levels.append(jnp.maximum(prev, jnp.concatenate([prev[..., sh:], tail], axis=-1)))
    return jnp.stack(levels)


def range_max(table, rows, a, b):
    """max over cells a … b (inclusive, b ≥ a) of each row of a ``range_max_table``; -inf where b < a."""
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


#: UB2 (``taylor_bound``) is computed for boxes whose ToA interval spans fewer spline cells than this; larger boxes
#: use UB1 alone.  Either bound is valid and the fix does not depend on the choice (a looser bound only refines more
#: boxes); measured on Fig. 9's urban trials, UB2 prunes almost nothing above this size and UB1 almost nothing below
#: it, so this only saves work.
TAYLOR_MAX_CELLS = 2.5


def taylor_pays(hx: float, hb: float, cell_m: float) -> bool:
    """Whether boxes of half sizes hx (x, y) and hb (c δt) in metres get UB2 as well (``TAYLOR_MAX_CELLS``)."""
    return (2 * np.sqrt(2) * hx + 2 * hb) / cell_m < TAYLOR_MAX_CELLS


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
    dmin, _ = cost.box_distances(center[None, 0:1], center[None, 1:2], half, bs[:, 0, None], bs[:, 1, None], dz2)
    start = jnp.floor((dmin[:, 0] + center[3] - half_b) / cell_m).astype(jnp.int64) - 2
    idx = jnp.mod(start[:, None] + jnp.arange(n_cells + 3)[None], n_knots)
    return jnp.take_along_axis(coef, idx, axis=1), start


@dataclass(frozen=True)
class SplineCells:
    """The window's spline as the bounds read it (built by ``spline_cells``; BSs on the first axis, boxes on the last).

    poly (M, cells, 4) the power-basis coefficients of every cell (``cell_poly``); t_max, t_d2 range-maximum tables
    (``range_max_table``) of each cell's maximum and of s'' at each cell's start; base (M, 1) the knot unit where
    cell 0 starts; bx, by (M, 1) m the BSs' x, y; dz2 (M, 1) m² their squared height difference to the window;
    rows (M, 1) their index; cell_m the knot spacing in metres; n_cells."""

    poly: jax.Array
    t_max: jax.Array
    t_d2: jax.Array
    base: jax.Array
    bx: jax.Array
    by: jax.Array
    dz2: jax.Array
    rows: jax.Array
    cell_m: float
    n_cells: int

    def pieces(self, j):
        """The four coefficients (4, M, K) of cells j (M, K)."""
        return jnp.moveaxis(self.poly[self.rows, j], -1, 0)

    def cell(self, u):
        """The cell (M, K) holding knot position u (M, K), clipped to the window, and u's offset in it."""
        j = jnp.clip(jnp.floor(u).astype(jnp.int64), 0, self.n_cells - 1)
        return j, u - j


def spline_cells(sl, start, bs_xyz, center, max_len: int, cfg: SearchConfig, num: Numerology) -> SplineCells:
    """``SplineCells`` of the window (``spline_window``'s coefficients sl (M, cells + 3) and start (M,)), with range
    tables for queries of up to ``max_len`` cells."""
    bs = jnp.asarray(bs_xyz)
    cells = cell_poly(sl[:, :-3], sl[:, 1:-2], sl[:, 2:-1], sl[:, 3:])
    return SplineCells(poly=jnp.stack(cells, axis=-1), t_max=range_max_table(cubic_max(cells, 0.0, 1.0), max_len),
                       t_d2=range_max_table(2 * cells[2], max_len),  # s'' at each cell's start (continuous)
                       base=(start + 1).astype(jnp.float64)[:, None], bx=bs[:, 0, None], by=bs[:, 1, None],
                       dz2=((center[2] - bs[:, 2]) ** 2)[:, None], rows=jnp.arange(sl.shape[0])[:, None],
                       cell_m=C * num.sample_period_s / cfg.spline_upsample, n_cells=slice_cells(cfg, num))


def toa_interval(w: SplineCells, cx, cy, cb, hx, hb):
    """Each BS's ToA interval [lo, hi] (M, K) in the window's knot units over boxes centred on (cx, cy, cb) (1, K)
    m with half sizes hx (x, y) and hb (c δt), and the BSs' nearest distance dmin (M, K) m to them."""
    dmin, dmax = cost.box_distances(cx, cy, hx, w.bx, w.by, w.dz2)
    return (dmin + cb - hb) / w.cell_m - w.base, (dmax + cb + hb) / w.cell_m - w.base, dmin


def piece_max_bound(w: SplineCells, lo, hi):
    """UB1 = Σ_m max_{u ∈ [lo_m, hi_m]} s_m(u) (K,): the maximum of each cubic piece, exact at the two partial
    cells at the ends and read from the range-maximum table of per-cell maxima in between.  Also returns the end
    cells' pieces and offsets, which ``taylor_bound`` reads."""
    (jl, tl), (jh, th) = w.cell(lo), w.cell(hi)
    al, ah = w.pieces(jl), w.pieces(jh)
    same = jl == jh
    ends = jnp.maximum(cubic_max(al, tl, jnp.where(same, th, 1.0)), jnp.where(same, -jnp.inf, cubic_max(ah, 0.0, th)))
    ub1 = jnp.sum(jnp.maximum(ends, range_max(w.t_max, w.rows, jl + 1, jh - 1)), axis=0)
    return ub1, (jl, tl, al), (jh, th, ah)


def taylor_bound(w: SplineCells, cx, cy, cb, hx, hb, lo, hi, dmin, u, d, ac, tc, cost_c, low_end, high_end):
    """UB2 (K,) = C(centre) + |g|·h + Σ_m ½ K_m Δu_m² + Σ_m max(s_m', 0) h_xy² / (d_m c T_s / U), a second-order
    bound: g is the gradient of C at the box centre (d (M, K) its distance to each BS, u its knot position, ac, tc
    its cell's piece and offset, cost_c its cost), h the box's half sizes, K_m ≥ 0 bounds s_m'' on [lo_m, hi_m],
    Δu_m the interval's half width around the centre's ToA, and the last term bounds the curvature of the distance
    (the Hessian of ‖p − b_m‖ has eigenvalues ≤ 1/d_m, d_m = dmin the box's nearest distance)."""
    (jl, tl, al), (jh, th, ah) = low_end, high_end
    d1 = ac[1] + tc * (2 * ac[2] + 3 * ac[3] * tc)  # s_m' per knot unit
    k2 = jnp.maximum(2 * al[2] + 6 * al[3] * tl, 2 * ah[2] + 6 * ah[3] * th)
    k2 = jnp.maximum(jnp.maximum(k2, range_max(w.t_d2, w.rows, jl + 1, jh)), 0.0)
    g = jnp.stack([jnp.sum(d1 * (cx - w.bx) / d, 0), jnp.sum(d1 * (cy - w.by) / d, 0), jnp.sum(d1, 0)]) / w.cell_m
    lin = (jnp.abs(g[0]) + jnp.abs(g[1])) * hx + jnp.abs(g[2]) * hb
    curv = jnp.sum(jnp.maximum(d1, 0.0) * hx**2 / (jnp.maximum(dmin, 1e-3) * w.cell_m), 0)
    quad = jnp.sum(0.5 * k2 * jnp.maximum(hi - u, u - lo) ** 2, 0)
    return cost_c + lin + curv + quad


def evaluate_boxes(w: SplineCells, cx, cy, cb, hx, hb, taylor=True):
    """(upper bound over each box, cost at its centre), (K,) each, for boxes centred on (cx, cy, cb) (K,) m with
    half sizes hx, hb: the bound is min(UB1, UB2), or UB1 alone where ``taylor`` is False (static)."""
    cx, cy, cb = cx[None, :], cy[None, :], cb[None, :]
    lo, hi, dmin = toa_interval(w, cx, cy, cb, hx, hb)
    ub1, low_end, high_end = piece_max_bound(w, lo, hi)
    d = jnp.sqrt((cx - w.bx) ** 2 + (cy - w.by) ** 2 + w.dz2)
    u = (d + cb) / w.cell_m - w.base
    jc, tc = w.cell(u)
    ac = w.pieces(jc)
    cost_c = jnp.sum(horner(ac, tc), 0)
    if not taylor:
        return ub1, cost_c
    return jnp.minimum(ub1, taylor_bound(w, cx, cy, cb, hx, hb, lo, hi, dmin, u, d, ac, tc, cost_c, low_end,
                                         high_end)), cost_c


def first_boxes(center, cfg: SearchConfig):
    """Level 0: the window tiled with boxes of ``box_m`` × ``box_m`` × (2 ``bias_half_width_m`` / ``bias_boxes``).
    Returns their centres cx, cy, cb (K,) m and half sizes hx, hb (m, static)."""
    half, half_b = cfg.half_width_m, cfg.bias_half_width_m
    n0 = max(int(np.ceil(2 * half / cfg.box_m - 1e-9)), 1)
    nb0 = cfg.bias_boxes if half_b > 0 else 1
    hx, hb = half / n0, half_b / nb0
    ax = -half + hx * (2 * np.arange(n0) + 1)
    ab = -half_b + hb * (2 * np.arange(nb0) + 1)
    gx, gy, gb = (a.ravel() for a in np.meshgrid(ax, ax, ab, indexing="ij"))
    return center[0] + gx, center[1] + gy, center[3] + gb, hx, hb


#: the signs of the 8 children's centre offsets (x, y, c δt) when a box is halved
_CHILD_SIGNS = (np.array([-1.0, 1, -1, 1, -1, 1, -1, 1]), np.array([-1.0, -1, 1, 1, -1, -1, 1, 1]),
                np.array([-1.0, -1, -1, -1, 1, 1, 1, 1]))


def refine_level(w: SplineCells, cfg: SearchConfig, state, h):
    """One level: keep the ``capacity`` boxes of highest bound above the best cost and, in that order, chunk by
    chunk while any is left, halve them into 8 children (half sizes h = (hx, hb, taylor)), bound and evaluate the
    children.  A parent whose bound no longer exceeds the best cost (raised by an earlier chunk) is skipped: none of
    its points can beat it.  The loop runs only over the parents alive, and stops as soon as none of those left can
    beat the best cost, so its cost follows them.  state = (cx, cy, cb, ub (size,), best, bq (3,), dropped), where
    dropped is the highest bound of a box left for lack of room (the fix is then uncertified)."""
    cx, cy, cb, ub, best, bq, dropped = state
    cap, size = cfg.capacity, ub.shape[0]
    chunk = min(cfg.chunk_boxes, cap)
    hx, hb, taylor = h[0], h[1], h[2] > 0
    alive = ub > best
    # ranked by the bound rounded to float32 (XLA's float64 top_k was measured 10x slower on this CPU); the
    # ranking only orders the work and picks whom to drop, every comparison with the best cost stays float64
    _, ix = jax.lax.top_k(jnp.where(alive, ub.astype(jnp.float32), -jnp.inf), cap)
    vals = jnp.where(alive[ix], ub[ix], -jnp.inf)
    left = alive & ~jnp.zeros(size, bool).at[ix].set(True)
    dropped = jnp.maximum(dropped, jnp.max(jnp.where(left, ub, -jnp.inf)))
    pxyb = jnp.stack([cx[ix], cy[ix], cb[ix]])
    n_live = jnp.sum(vals > -jnp.inf)
    # rest[i]: the highest bound among the parents from i on (any order): once it no longer exceeds the best
    # cost, no parent left is refined, and the loop stops (the chunks it skips would only produce dead children)
    rest = jax.lax.cummax(vals, reverse=True)
    out = jnp.full((3, size), 0.0), jnp.full(size, -jnp.inf)
    sx, sy, sb = _CHILD_SIGNS

    def body(carry):
        k, best, bq, (oxyb, oub) = carry
        pv = jax.lax.dynamic_slice(vals, (k * chunk,), (chunk,))
        p = jax.lax.dynamic_slice(pxyb, (0, k * chunk), (3, chunk))
        ccx = (p[0][:, None] + sx * hx).ravel()
        ccy = (p[1][:, None] + sy * hx).ravel()
        ccb = (p[2][:, None] + sb * hb).ravel()
        cub, clb = jax.lax.cond(taylor, lambda: evaluate_boxes(w, ccx, ccy, ccb, hx, hb, True),
                                lambda: evaluate_boxes(w, ccx, ccy, ccb, hx, hb, False))
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


def level_halves(hx: float, hb: float, cell_m: float, cfg: SearchConfig) -> list[tuple[float, float, float]]:
    """The half sizes (hx, hb) of every level's children, halved from the first boxes' until the x, y side is
    ≤ ``box_final_m``, each with whether it gets UB2 (1.0) or not (0.0)."""
    halves = []
    while 2 * hx > cfg.box_final_m + 1e-12:
        hx, hb = hx / 2, hb / 2
        halves.append((hx, hb, float(taylor_pays(hx, hb, cell_m))))
    return halves


def certified_fix(state, center, hx, hb, cfg: SearchConfig) -> tuple[WindowFix, jax.Array]:
    """The fix of the final level's state (``refine_level``) with the final half sizes hx, hb: the best box
    centre found, gap = (largest upper bound left − cost) / cost, certified when gap ≤ ``gap_tol`` and no box was
    dropped, edge when the fix lies within one final box of the window's boundary.  Returns (WindowFix, cost)."""
    cx, cy, cb, ub, best, bq, dropped = state
    top = jnp.maximum(jnp.max(ub), dropped)
    gap = jnp.maximum(top - best, 0.0) / best
    off = bq - jnp.stack([center[0], center[1], center[3]])
    half, half_b = cfg.half_width_m, cfg.bias_half_width_m
    edge = (jnp.abs(off[0]) >= half - 2 * hx) | (jnp.abs(off[1]) >= half - 2 * hx)
    if half_b > 0:
        edge = edge | (jnp.abs(off[2]) >= half_b - 2 * hb)
    q = jnp.stack([bq[0], bq[1], center[2], bq[2]])
    return WindowFix(q=q, gap=gap, certified=(gap <= cfg.gap_tol) & ~(dropped > best), edge=edge), best


def certified_search(coef, bs_xyz, center, cfg: SearchConfig, num: Numerology = PAPER) -> tuple[WindowFix, jax.Array]:
    """Global maximum of eq. (10) (its spline form) over the window by branch and bound (see the module docstring).

    The window is centre ± ``half_width_m`` in x and y and centre ± ``bias_half_width_m`` in c δt, at the centre's
    height.  Each level keeps the ``capacity`` boxes of highest min(UB1, UB2) that exceed the best cost found at a
    box centre (the others cannot hold the maximum, or are dropped for lack of room and make the result
    uncertified), and halves them in x, y and c δt until the x, y side is ≤ ``box_final_m``.  The gap bounds how far
    the true maximum of the spline cost in the window can lie above the fix's cost.

    coef : (M, N·U) from ``correlogram.spline_coefficients``, or the pair ``spline_window`` returns for this window
    (the engine computes it beside the coefficients, so that its search reads only that part); bs_xyz : (M, 3) m;
    center : (4,) = [x, y, z, c δt] in METRES.  Returns (``WindowFix``, the spline cost at the fix).  Traceable (jit,
    vmap); shapes are static given ``cfg``.
    """
    _checks.require_x64()
    sl, start = coef if isinstance(coef, tuple) else spline_window(coef, bs_xyz, center, cfg, num)
    cx, cy, cb, hx, hb = first_boxes(center, cfg)
    cell_m = C * num.sample_period_s / cfg.spline_upsample
    # the longest range a box can query: the ToA interval of a level-0 box spans ≤ (2√2 hx + 2 hb) / cell cells
    # (the box's diagonal in x, y and its c δt side), plus the partial cells at both ends
    max_len = int(np.ceil((2 * np.sqrt(2) * hx + 2 * hb) / cell_m)) + 3
    w = spline_cells(sl, start, bs_xyz, center, max_len, cfg, num)
    ub, lb = evaluate_boxes(w, cx, cy, cb, hx, hb, taylor=taylor_pays(hx, hb, cell_m))
    i = jnp.argmax(lb)
    size = max(8 * cfg.capacity, int(ub.shape[0]))  # every level's boxes live in buffers of this static size
    pad = lambda a, fill: jnp.concatenate([a, jnp.full(size - a.shape[0], fill, a.dtype)])
    state = (pad(cx, 0.0), pad(cy, 0.0), pad(cb, 0.0), pad(ub, -jnp.inf), lb[i], jnp.stack([cx[i], cy[i], cb[i]]),
             jnp.asarray(-jnp.inf))
    halves = level_halves(hx, hb, cell_m, cfg)
    if halves:  # every level has the same shapes: one scan, compiled once
        state, _ = jax.lax.scan(lambda s, h: refine_level(w, cfg, s, h), state, jnp.asarray(halves))
        hx, hb = halves[-1][0], halves[-1][1]
    return certified_fix(state, center, hx, hb, cfg)
