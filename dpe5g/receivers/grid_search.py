"""The divide-and-conquer grid search of eq. (10) (the paper's search), and the part of each correlogram it reads.

A coarse grid around the window's centre, then finer 5-point grids around the best point, on precomputed
correlograms (``cost.lookup``); ``grid_window`` is the part of each correlogram (its window) that a search can read.
The search config is ``search_config.SearchConfig``; the public fix is ``dpe.fix``.  Positions are
q = (x, y, z, c δt) in metres.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy.nr import C, PAPER, Numerology
from . import cost
from .search_config import WindowFix, SearchConfig

def _axis(half_width, step):
    if half_width <= 0:
        return np.zeros(1)
    n = int(np.floor(half_width / step + 1e-9))
    return np.arange(-n, n + 1) * step


def _grid_offsets(half_xy, half_z, half_b, step):
    ax = _axis(half_xy, step)
    g = np.meshgrid(ax, ax, _axis(half_z, step), _axis(half_b, step), indexing="ij")
    return np.stack([a.ravel() for a in g], axis=-1)  # (K, 4): dx, dy, dz, d(c δt)


def grid_reach(cfg: SearchConfig) -> tuple[float, float, float]:
    """How far the grid search's candidates can lie from its centre, in metres.

    Each is the first level's half width plus 2 steps per further level (each is ±2 steps around the best point).

    Parameters
    ----------
    cfg : SearchConfig
        The search.

    Returns
    -------
    r_xy : float
        The reach in x and in y, metres.
    r_z : float
        The reach in z, metres (0 when z is not searched).
    r_b : float
        The reach in c δt, metres (0 when it is not searched).
    """
    extra = 2 * sum(cfg.steps()[1:])
    return (cfg.half_width_m + extra, cfg.z_half_width_m + extra * (cfg.z_half_width_m > 0),
            cfg.bias_half_width_m + extra * (cfg.bias_half_width_m > 0))


def grid_window_cells(cfg: SearchConfig, num: Numerology = PAPER) -> int:
    """Static width W of ``grid_window``, in grid points of T_s/U (a multiple of U).

    It covers the ToA span of the search's reach (``grid_reach``: its x, y, z box's diameter plus twice the c δt
    reach), the 2 + 1 grid points either side that the cubic reads, the alignment of the start to a multiple of U, and
    a margin.

    Parameters
    ----------
    cfg : SearchConfig
        The search (its reach and upsampling U).
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    int
        W.
    """
    r_xy, r_z, r_b = grid_reach(cfg)
    cell_m = C * num.sample_period_s / cfg.upsample
    span = 2 * np.sqrt(2 * r_xy**2 + r_z**2) + 2 * r_b
    u = cfg.upsample
    return int(u * np.ceil((np.ceil(span / cell_m) + u + 6) / u))


def grid_window(bs_xyz, center_m, cfg: SearchConfig, num: Numerology = PAPER) -> jax.Array:
    """The first grid point of the part of each BS's correlogram that the grid search (``search``) can read.

    ``grid_window_cells(cfg)`` points from there hold every ToA of its candidates and the cubic's neighbours.  The
    start is the nearest distance from the BS to the search's reach box plus its lowest c δt, less 2 points, rounded
    down to a multiple of U (``correlogram.energy_window`` computes whole samples).  Traceable.

    Parameters
    ----------
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search.
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    int (M,)
        The first grid point of each BS, in grid points of T_s/U, not reduced modulo N·U.
    """
    r_xy, r_z, r_b = grid_reach(cfg)
    cell_m = C * num.sample_period_s / cfg.upsample
    bs = jnp.asarray(bs_xyz)
    dz2 = (jnp.maximum(jnp.abs(center_m[2] - bs[:, 2]) - r_z, 0.0) ** 2)[:, None]
    dmin, _ = cost.box_distances(center_m[None, 0:1], center_m[None, 1:2], r_xy, bs[:, 0, None], bs[:, 1, None], dz2)
    first = jnp.floor((dmin[:, 0] + center_m[3] - r_b) / cell_m).astype(jnp.int64) - 2
    return (first // cfg.upsample) * cfg.upsample


def first_rows(corr, m: int):
    """The correlograms of the m nearest BSs.

    Parameters
    ----------
    corr : float (M, N·U) or (values (M, W), start (M,))
        The whole correlograms, rows nearest first, or a window pair (``cost.lookup_terms``).
    m : int
        The number of rows.

    Returns
    -------
    float (m, N·U) or (values (m, W), start (m,))
        The first m rows (of both parts of a pair).
    """
    return (corr[0][:m], corr[1][:m]) if isinstance(corr, tuple) else corr[:m]


def level_candidates(q, cfg: SearchConfig, level: int):
    """The candidates of ``search``'s level ``level`` around a point.

    Parameters
    ----------
    q : float (4,)
        The point [x, y, z, c δt], metres: the window's centre for level 0, else the previous level's best.
    cfg : SearchConfig
        The search.
    level : int
        The level, 0 the coarse grid.

    Returns
    -------
    cand : float (K, 4)
        The candidates, metres, their c δt offsets varying fastest.
    n_b : int
        The number of c δt offsets per (x, y, z) point.
    """
    step = cfg.steps()[level]
    search_b, search_z = cfg.bias_half_width_m > 0, cfg.z_half_width_m > 0
    half_b = cfg.bias_half_width_m if level == 0 else 2 * step * search_b
    if level == 0:
        off = _grid_offsets(cfg.half_width_m, cfg.z_half_width_m, half_b, step)
    else:
        off = _grid_offsets(2 * step, 2 * step * search_z, half_b, step)
    return q + jnp.asarray(off), _axis(half_b, step).size


def candidate_terms(corr, bs_xyz, cand, n_b, cfg: SearchConfig, ts: float):
    """Per-BS terms of the cost at candidates whose c δt offsets vary fastest.

    The distances of each (x, y, z) point are computed once for all of its c δt offsets.

    Parameters
    ----------
    corr : float (M, N·U) or (values (M, W), start (M,))
        The correlograms, as ``search`` reads them.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    cand : float (K, 4)
        The candidates [x, y, z, c δt], metres (``level_candidates``).
    n_b : int
        The number of c δt offsets per (x, y, z) point.
    cfg : SearchConfig
        The search (its upsampling U).
    ts : float
        The sample period T_s, seconds.

    Returns
    -------
    float (K, M)
        The terms (``cost.lookup_terms``); their sum over the BSs ranks the candidates.
    """
    grid = cand.reshape(-1, n_b, 4)
    dist = jnp.linalg.norm(grid[:, 0, None, :3] - bs_xyz, axis=-1) / C  # (K / n_b, M)
    tau = dist[:, None, :] + (grid[..., 3] / C)[..., None]  # = cost.tau_of(cand), (K / n_b, n_b, M)
    return cost.lookup_terms(corr, tau.reshape(cand.shape[0], -1) / ts * cfg.upsample)


def search(corr, g, bs_xyz, center_m, cfg: SearchConfig, num: Numerology = PAPER, with_cost: bool = True,
           first_level=None):
    """The divide-and-conquer search on precomputed correlograms.

    Traceable: used inside jit by ``dpe.fix`` and by the engine, which reuses one set of correlograms for several M.

    Parameters
    ----------
    corr : float (M, N·U) or (values (M, W), start (M,))
        From ``correlogram.energy_grid``, or its window around ``center_m`` (``grid_window``,
        ``correlogram.energy_window``: a pair of values and start).
    g : complex (M, N)
        The LS spectrum (``correlogram.ls_spectrum``), read only by the polish and for the cost.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search.
    num : Numerology
        The numerology (``nr.PAPER`` by default).
    with_cost : bool
        Return the exact cost at the fix too (else q alone).
    first_level : float (4,) or None
        The best candidate of the first level, metres, when the caller has found it (``nested_grid_fixes``); None
        searches it.

    Returns
    -------
    q : float (4,)
        The fix (x, y, z, c δt), metres.
    cost : float
        The exact cost (eq. (10)) at q; only when ``with_cost`` is True.
    """
    _checks.require_x64()
    ts, scs_hz = 1.0 / (num.n_fft * num.scs_hz), num.scs_hz
    # c δt through seconds and back, as the search has always rounded it (the recorded fixes stay bit for bit)
    q = center_m.at[3].set(center_m[3] / C * C)
    steps = cfg.steps()
    for level in range(len(steps)):
        if level == 0 and first_level is not None:
            q = first_level
            continue
        cand, n_b = level_candidates(q, cfg, level)
        q = cand[jnp.argmax(jnp.sum(candidate_terms(corr, bs_xyz, cand, n_b, cfg, ts), axis=-1))]
    if cfg.polish:
        mask = jnp.array([1.0, 1.0, float(cfg.z_half_width_m > 0), float(cfg.bias_half_width_m > 0)])
        for _ in range(cfg.polish_iters):
            q = q + cost.newton_step(g, bs_xyz, q, mask, cfg.n_taps, scs_hz, 2 * steps[-1])
    if not with_cost:
        return q
    return q, cost.ml_cost_of_spectrum(g, cost.tau_of(q, bs_xyz), cfg.n_taps, scs_hz)


def nested_grid_fixes(corr, g, bs_xyz, center_m, cfg: SearchConfig, m_values, num: Numerology = PAPER) -> WindowFix:
    """``dpe.fix`` with the grid search for each M of ``m_values``, around one shared centre (traceable).

    The first level's candidates are then the same for every M: their per-BS terms are looked up once, for the largest
    M, and the cost of each M is a running sum over the BSs — on Fig. 9's grid this level is 94 % of the candidates,
    looked up for 24 BSs instead of 6 + 12 + 18 + 24.  The finer levels run per M.  Equal to ``dpe.fix`` per M up to the
    order of the sum (a tie of two candidates within round-off could differ; a test checks the fixes agree).

    Parameters
    ----------
    corr : float (I, N·U) or (values (I, W), start (I,))
        ``receiver.receiver_correlogram`` of the I ≥ max(m_values) nearest BSs, rows nearest first (or its window
        around ``center_m``, as ``search`` reads it).
    g : complex (I, N)
        Their LS spectra.
    bs_xyz : float (I, 3)
        Their positions, metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search; ``cfg.method`` must be "grid".
    m_values : sequence of int
        The numbers M of nearest BSs to fix with.
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    WindowFix
        With a leading axis over ``m_values``.

    Raises
    ------
    ValueError
        When ``cfg.method`` is not "grid".
    """
    _checks.require_x64()
    if cfg.method != "grid":
        raise ValueError(f"nested_grid_fixes runs the grid search; cfg.method must be 'grid', got {cfg.method!r}")
    ts = num.sample_period_s
    cand, n_b = level_candidates(center_m, cfg, 0)
    m_max = max(m_values)
    running = jnp.cumsum(candidate_terms(first_rows(corr, m_max), bs_xyz[:m_max], cand, n_b, cfg, ts), axis=-1)
    q = jnp.stack([search(first_rows(corr, m), g[:m], bs_xyz[:m], center_m, cfg, num, with_cost=False,
                          first_level=cand[jnp.argmax(running[:, m - 1])]) for m in m_values])
    return grid_fix(q, center_m, cfg)


def grid_fix(q, center_m, cfg: SearchConfig) -> WindowFix:
    """The ``WindowFix`` of grid-search positions: no gap (NaN), never certified, edge from ``grid_edge``.

    Parameters
    ----------
    q : float (..., 4)
        The fixes (x, y, z, c δt), metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search.

    Returns
    -------
    WindowFix
        With leading shape (...).
    """
    shape = q.shape[:-1]
    return WindowFix(q=q, gap=jnp.full(shape, jnp.nan), certified=jnp.zeros(shape, bool), edge=grid_edge(q, center_m, cfg))


def grid_edge(q, center_m, cfg: SearchConfig):
    """Whether ``search`` fixes lie on the boundary of their grid window.

    Parameters
    ----------
    q : float (..., 4)
        The fixes (x, y, z, c δt), metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search.

    Returns
    -------
    bool (...)
        True within 1.5 final steps of the window's edge in x or y (or in c δt, where it is searched).
    """
    tol = 1.5 * cfg.final_step_m
    off = jnp.abs(q - center_m)
    edge = (off[..., 0] >= cfg.half_width_m - tol) | (off[..., 1] >= cfg.half_width_m - tol)
    if cfg.bias_half_width_m > 0:
        edge = edge | (off[..., 3] >= cfg.bias_half_width_m - tol)
    return edge
