"""Bounds of eq. (10) over boxes of the receiver's window, for the certified search (``certified_search``).

The cost is separable, C(p) = Σ_m s_m(u_m(p)) with s_m the cubic spline of link m's correlogram
(``correlogram.spline_coefficients``) and u_m = (‖p − b_m‖ + c δt) / (c T_s / U) the ToA in knot units.  Over a box
every u_m spans an exact interval [lo_m, hi_m] (``toa_interval``: nearest and farthest point of the box), which gives
two upper bounds over the box: ``piece_max_bound`` (UB1, the maximum of each link's spline pieces over its interval)
and ``taylor_bound`` (UB2, a first-order bound around the box centre); ``evaluate_boxes`` takes the smaller.  The
window's spline cells and their range-maximum tables are built once per search (``SplineCells``).  Positions are in
metres, q = (x, y, z, c δt), at the window centre's height.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..phy.nr import C, PAPER, Numerology
from . import cost
from .search_config import SearchConfig

def spline_values(coef, pos) -> jax.Array:
    """The spline cost Σ_m s_m(pos_m) of ``correlogram.spline_coefficients`` (periodic).

    Parameters
    ----------
    coef : float (M, J)
        Spline coefficients of the M BSs on J = N·U knots.
    pos : float (..., M)
        Positions, knot units.

    Returns
    -------
    float (...)
        The sum over the BSs.
    """
    m, j = coef.shape
    f = jnp.floor(pos)
    i0 = f.astype(jnp.int64)
    c = [coef[jnp.arange(m), jnp.mod(i0 + d, j)] for d in (-1, 0, 1, 2)]
    return jnp.sum(horner(cell_poly(*c), pos - f), axis=-1)


def cell_poly(c0, c1, c2, c3):
    """Power-basis coefficients of the cubic B-spline on the cell between knots 1 and 2 of c0 … c3.

    Parameters
    ----------
    c0, c1, c2, c3 : float (...)
        Four consecutive spline coefficients.

    Returns
    -------
    tuple of 4 float (...)
        (a0, a1, a2, a3) of a0 + a1 t + a2 t² + a3 t³, t the offset from knot 1 (0 to 1).
    """
    return (c0 + 4 * c1 + c2) / 6, (c2 - c0) / 2, (c0 - 2 * c1 + c2) / 2, (-c0 + 3 * c1 - 3 * c2 + c3) / 6


def horner(a, t):
    """The cubic a0 + a1 t + a2 t² + a3 t³.

    Parameters
    ----------
    a : sequence of 4 float (...)
        Power-basis coefficients (a0, a1, a2, a3) (``cell_poly``).
    t : float (...)
        Where to evaluate it.

    Returns
    -------
    float (...)
        Its value.
    """
    return a[0] + t * (a[1] + t * (a[2] + t * a[3]))


def cubic_max(a, lo, hi):
    """Maximum over t ∈ [lo, hi] of a0 + a1 t + a2 t² + a3 t³ (element-wise): the ends and the stationary points.

    Parameters
    ----------
    a : sequence of 4 float (...)
        Power-basis coefficients (``cell_poly``).
    lo, hi : float (...)
        The interval, lo ≤ hi.

    Returns
    -------
    float (...)
        The exact maximum.
    """
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
    """Sparse table for range maxima along the last axis: t[k, ..., j] = max(x[..., j : j + 2^k]).

    Parameters
    ----------
    x : float (..., n)
        The values.
    max_len : int
        The longest query, in cells (static): ``range_max`` of a longer range would read a level that is not there.

    Returns
    -------
    float (K, ..., n)
        The table, K = ⌊log2 min(n, max_len)⌋ + 1 levels, -inf past the last cell.
    """
    levels = [x]
    n = min(x.shape[-1], max_len)
    while (1 << len(levels)) <= n:
        prev, sh = levels[-1], 1 << (len(levels) - 1)
        tail = jnp.full(prev.shape[:-1] + (sh,), -jnp.inf)
        levels.append(jnp.maximum(prev, jnp.concatenate([prev[..., sh:], tail], axis=-1)))
    return jnp.stack(levels)


def range_max(table, rows, a, b):
    """Maximum over cells a … b (inclusive) of each row of a ``range_max_table``; -inf where b < a.

    Parameters
    ----------
    table : float (K, R, n)
        A ``range_max_table`` of R rows.
    rows : int (...)
        The row of each query.
    a, b : int (...)
        First and last cell of each query, b − a + 1 at most the table's ``max_len``.

    Returns
    -------
    float (...)
        The maxima.
    """
    w = b - a + 1
    k = jnp.floor(jnp.log2(jnp.maximum(w, 1).astype(jnp.float64))).astype(jnp.int64)
    n = table.shape[-1]
    v = jnp.maximum(table[k, rows, jnp.clip(a, 0, n - 1)], table[k, rows, jnp.clip(b - (1 << k) + 1, 0, n - 1)])
    return jnp.where(w > 0, v, -jnp.inf)


def slice_cells(cfg: SearchConfig, num: Numerology = PAPER) -> int:
    """Static number of spline cells per BS that any ToA inside the search window can reach (a power of two).

    Parameters
    ----------
    cfg : SearchConfig
        The search: its window and ``spline_upsample`` U.
    num : Numerology
        The numerology (its sample period T_s; a cell is c T_s / U).

    Returns
    -------
    int
        The number of cells.
    """
    cell_m = C * num.sample_period_s / cfg.spline_upsample
    span = 2 * np.sqrt(2) * cfg.half_width_m + 2 * cfg.bias_half_width_m
    return int(2 ** np.ceil(np.log2(span / cell_m + 8)))


#: UB2 (``taylor_bound``) is computed for boxes whose ToA interval spans fewer spline cells than this; larger boxes
#: use UB1 alone.  Either bound is valid and the fix does not depend on the choice (a looser bound only refines more
#: boxes); measured on Fig. 9's urban trials, UB2 prunes almost nothing above this size and UB1 almost nothing below
#: it, so this only saves work.
TAYLOR_MAX_CELLS = 2.5


def taylor_pays(hx: float, hb: float, cell_m: float) -> bool:
    """Whether boxes of these half sizes get UB2 as well (``TAYLOR_MAX_CELLS``).

    Parameters
    ----------
    hx, hb : float
        The boxes' half sizes in x, y and in c δt, metres.
    cell_m : float
        The knot spacing c T_s / U, metres.

    Returns
    -------
    bool
        True where UB2 pays.
    """
    return (2 * np.sqrt(2) * hx + 2 * hb) / cell_m < TAYLOR_MAX_CELLS


def spline_window(coef, bs_xyz, center, cfg: SearchConfig, num: Numerology = PAPER):
    """The part of each BS's spline (``correlogram.spline_coefficients``) that a ToA inside ``certified_search``'s
    window can reach.

    ``slice_cells(cfg)`` cells from the nearest point of the window's x, y square and its lowest c δt, with the knots
    either side that the cubic pieces read.  Rows are per BS, so the first M' rows are the window of the M' nearest.
    Traceable.

    Parameters
    ----------
    coef : float (M, N·U)
        The spline coefficients.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search and its window.
    num : Numerology
        The numerology.

    Returns
    -------
    coefficients : float (M, cells + 3)
        The window's coefficients: cell r of BS m spans knot units [start_m + 1 + r, start_m + 2 + r).
    start : int (M,)
        The knot index of each row's first coefficient, modulo N·U.
    """
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

    Attributes
    ----------
    poly : float (M, cells, 4)
        The power-basis coefficients of every cell (``cell_poly``).
    t_max, t_d2 : float (K, M, cells)
        Range-maximum tables (``range_max_table``) of each cell's maximum and of s'' at each cell's start.
    base : float (M, 1)
        The knot unit where cell 0 starts.
    bx, by : float (M, 1)
        The BSs' x and y, metres.
    dz2 : float (M, 1)
        Their squared height difference to the window, m².
    rows : int (M, 1)
        Their index.
    cell_m : float
        The knot spacing, metres.
    n_cells : int
        Cells per BS (``slice_cells``).
    """

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
        """The four coefficients of cells j.

        Parameters
        ----------
        j : int (M, K)
            A cell per BS and box.

        Returns
        -------
        float (4, M, K)
            (a0, a1, a2, a3) of each cell.
        """
        return jnp.moveaxis(self.poly[self.rows, j], -1, 0)

    def cell(self, u):
        """The cell holding knot position u, clipped to the window, and u's offset in it.

        Parameters
        ----------
        u : float (M, K)
            Knot positions, the window's knot units.

        Returns
        -------
        j : int (M, K)
            The cell.
        t : float (M, K)
            u − j.
        """
        j = jnp.clip(jnp.floor(u).astype(jnp.int64), 0, self.n_cells - 1)
        return j, u - j


def spline_cells(sl, start, bs_xyz, center, max_len: int, cfg: SearchConfig, num: Numerology) -> SplineCells:
    """``SplineCells`` of the window, with range tables for queries of up to ``max_len`` cells.

    Parameters
    ----------
    sl : float (M, cells + 3)
        ``spline_window``'s coefficients.
    start : int (M,)
        ``spline_window``'s first knot indices.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center : float (4,)
        The window's centre [x, y, z, c δt], metres.
    max_len : int
        The longest range query, in cells (static).
    cfg : SearchConfig
        The search and its window.
    num : Numerology
        The numerology.

    Returns
    -------
    SplineCells
        The window's spline.
    """
    bs = jnp.asarray(bs_xyz)
    cells = cell_poly(sl[:, :-3], sl[:, 1:-2], sl[:, 2:-1], sl[:, 3:])
    return SplineCells(poly=jnp.stack(cells, axis=-1), t_max=range_max_table(cubic_max(cells, 0.0, 1.0), max_len),
                       t_d2=range_max_table(2 * cells[2], max_len),  # s'' at each cell's start (continuous)
                       base=(start + 1).astype(jnp.float64)[:, None], bx=bs[:, 0, None], by=bs[:, 1, None],
                       dz2=((center[2] - bs[:, 2]) ** 2)[:, None], rows=jnp.arange(sl.shape[0])[:, None],
                       cell_m=C * num.sample_period_s / cfg.spline_upsample, n_cells=slice_cells(cfg, num))


def toa_interval(w: SplineCells, cx, cy, cb, hx, hb):
    """Each BS's ToA interval [lo, hi] over boxes, in the window's knot units, and its nearest distance to them.

    Parameters
    ----------
    w : SplineCells
        The window's spline.
    cx, cy, cb : float (1, K)
        The boxes' centres in x, y and c δt, metres.
    hx, hb : float
        Their half sizes in x, y and in c δt, metres.

    Returns
    -------
    lo, hi : float (M, K)
        The intervals' ends, knot units.
    dmin : float (M, K)
        Each BS's nearest distance to each box, metres.
    """
    dmin, dmax = cost.box_distances(cx, cy, hx, w.bx, w.by, w.dz2)
    return (dmin + cb - hb) / w.cell_m - w.base, (dmax + cb + hb) / w.cell_m - w.base, dmin


def piece_max_bound(w: SplineCells, lo, hi):
    """UB1 = Σ_m max_{u ∈ [lo_m, hi_m]} s_m(u): the maximum of each cubic piece over each BS's ToA interval.

    Exact at the two partial cells at the ends, read from the range-maximum table of per-cell maxima in between.

    Parameters
    ----------
    w : SplineCells
        The window's spline.
    lo, hi : float (M, K)
        The ToA intervals (``toa_interval``), knot units.

    Returns
    -------
    ub1 : float (K,)
        The bound over each box.
    low_end, high_end : tuple
        The end cells' (cell, offset, piece), which ``taylor_bound`` reads.
    """
    (jl, tl), (jh, th) = w.cell(lo), w.cell(hi)
    al, ah = w.pieces(jl), w.pieces(jh)
    same = jl == jh
    ends = jnp.maximum(cubic_max(al, tl, jnp.where(same, th, 1.0)), jnp.where(same, -jnp.inf, cubic_max(ah, 0.0, th)))
    ub1 = jnp.sum(jnp.maximum(ends, range_max(w.t_max, w.rows, jl + 1, jh - 1)), axis=0)
    return ub1, (jl, tl, al), (jh, th, ah)


def taylor_bound(w: SplineCells, cx, cy, cb, hx, hb, lo, hi, dmin, u, d, ac, tc, cost_c, low_end, high_end):
    """UB2, a second-order bound of the cost over each box around its centre.

    UB2 = ``C(centre) + |g|·h + Σ_m ½ K_m Δu_m² + Σ_m max(s_m', 0) h_xy² / (d_m c T_s / U)``: g is the gradient of C
    at the box centre, h the box's half sizes, K_m ≥ 0 bounds s_m'' on [lo_m, hi_m], Δu_m is the interval's half width
    around the centre's ToA, and the last term bounds the curvature of the distance (the Hessian of ‖p − b_m‖ has
    eigenvalues ≤ 1/d_m, d_m = dmin the box's nearest distance).

    Parameters
    ----------
    w : SplineCells
        The window's spline.
    cx, cy, cb : float (1, K)
        The boxes' centres in x, y and c δt, metres.
    hx, hb : float
        Their half sizes in x, y and in c δt, metres.
    lo, hi, dmin : float (M, K)
        ``toa_interval``'s ToA intervals (knot units) and nearest distances (metres).
    u : float (M, K)
        The centre's ToA, knot units.
    d : float (M, K)
        The centre's distance to each BS, metres.
    ac : float (4, M, K)
        The piece of the centre's cell (``SplineCells.pieces``).
    tc : float (M, K)
        The centre's offset in that cell.
    cost_c : float (K,)
        The cost at the centre.
    low_end, high_end : tuple
        ``piece_max_bound``'s end cells.

    Returns
    -------
    float (K,)
        UB2 of each box.
    """
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
    """The upper bound over each box and the cost at its centre.

    The bound is min(UB1, UB2), or UB1 alone where ``taylor`` is False.

    Parameters
    ----------
    w : SplineCells
        The window's spline.
    cx, cy, cb : float (K,)
        The boxes' centres in x, y and c δt, metres.
    hx, hb : float
        Their half sizes in x, y and in c δt, metres.
    taylor : bool
        Whether UB2 is computed too (static).

    Returns
    -------
    ub : float (K,)
        The bound of the spline cost over each box.
    cost : float (K,)
        The spline cost at each box's centre.
    """
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
