"""The certified search: the global maximum of eq. (10) (its cubic-spline form, ``correlogram.spline_coefficients``)
over the receiver's window by branch and bound, with a certified gap.

``certified_search`` tiles the window (``first_boxes``), bounds every box (``spline_bounds.evaluate_boxes``: the
smaller of two upper bounds over the box), then halves the boxes whose bound can still beat the best cost found,
level by level (``refine_level``), and reports the best box centre and the bound left over it (``certified_fix``).
Positions are in metres, q = (x, y, z, c δt), at the window centre's height.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy.nr import C, PAPER, Numerology
from .search_config import WindowFix, SearchConfig
from .spline_boxes import SplineCells, evaluate_boxes, spline_cells, spline_window, taylor_pays


def first_boxes(center, cfg: SearchConfig):
    """Level 0: the window tiled with boxes of ``box_m`` × ``box_m`` × (2 ``bias_half_width_m`` / ``bias_boxes``).

    Parameters
    ----------
    center : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search and its window.

    Returns
    -------
    cx, cy, cb : float (K,)
        The boxes' centres in x, y and c δt, metres.
    hx, hb : float
        Their half sizes in x, y and in c δt, metres (static).
    """
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
    """One level of the branch and bound.

    Keeps the ``capacity`` boxes of highest bound above the best cost and, in that order, chunk by chunk while any is
    left, halves them into 8 children, then bounds and evaluates the children.  A parent whose bound no longer exceeds
    the best cost (raised by an earlier chunk) is skipped: none of its points can beat it.  The loop runs only over the
    parents alive, and stops as soon as none of those left can beat the best cost, so its cost follows them.

    Parameters
    ----------
    w : SplineCells
        The window's spline.
    cfg : SearchConfig
        The search (``capacity``, ``chunk_boxes``).
    state : tuple
        (cx, cy, cb, ub, best, bq, dropped): the boxes' centres (metres) and bounds, each (size,); the best cost found
        and its box centre bq (3,) (x, y, c δt, metres); dropped, the highest bound of a box left for lack of room (the
        fix is then uncertified).
    h : float (3,)
        The children's half sizes (hx, hb), metres, and whether they get UB2 (1.0) or not (0.0).

    Returns
    -------
    tuple
        (the next level's ``state``, None), as a ``lax.scan`` step.
    """
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
    """The half sizes of every level's children, halved from the first boxes' until the x, y side is ≤ ``box_final_m``.

    Parameters
    ----------
    hx, hb : float
        The first boxes' half sizes in x, y and in c δt, metres.
    cell_m : float
        The knot spacing, metres.
    cfg : SearchConfig
        The search.

    Returns
    -------
    list of (float, float, float)
        (hx, hb, whether the level gets UB2: 1.0 or 0.0) per level.
    """
    halves = []
    while 2 * hx > cfg.box_final_m + 1e-12:
        hx, hb = hx / 2, hb / 2
        halves.append((hx, hb, float(taylor_pays(hx, hb, cell_m))))
    return halves


def certified_fix(state, center, hx, hb, cfg: SearchConfig) -> tuple[WindowFix, jax.Array]:
    """The fix of the final level's state: the best box centre found, with its certified gap.

    gap = (largest upper bound left − cost) / cost; certified when gap ≤ ``gap_tol`` and no box was dropped; edge when
    the fix lies within one final box of the window's boundary.

    Parameters
    ----------
    state : tuple
        The final level's state (``refine_level``).
    center : float (4,)
        The window's centre [x, y, z, c δt], metres.
    hx, hb : float
        The final boxes' half sizes in x, y and in c δt, metres.
    cfg : SearchConfig
        The search and its window.

    Returns
    -------
    fix : WindowFix
        The fix, at the centre's height.
    cost : float
        The spline cost at the fix.
    """
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
    height.  Each level keeps the ``capacity`` boxes of highest min(UB1, UB2) that exceed the best cost found at a box
    centre (the others cannot hold the maximum, or are dropped for lack of room and make the result uncertified), and
    halves them in x, y and c δt until the x, y side is ≤ ``box_final_m``.  The gap bounds how far the true maximum of
    the spline cost in the window can lie above the fix's cost.  Traceable (jit, vmap); shapes are static given ``cfg``.

    Parameters
    ----------
    coef : float (M, N·U) or tuple
        ``correlogram.spline_coefficients``, or the pair ``spline_window`` returns for this window (the engine computes
        it beside the coefficients, so that its search reads only that part).
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center : float (4,)
        The window's centre [x, y, z, c δt], in METRES.
    cfg : SearchConfig
        The search and its window.
    num : Numerology
        The numerology.

    Returns
    -------
    fix : WindowFix
        The fix, its certified gap and flags.
    cost : float
        The spline cost at the fix.
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
