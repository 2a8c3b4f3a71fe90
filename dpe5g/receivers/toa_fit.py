"""ToA least squares with a clock prior: the OTDoA family's receiver that knows of the UE clock what the DPE knows.

The OTDoA receiver's ToAs τ_m (``otdoa.toa``, first path or strongest peak, the UE's clock bias δt included) are
pseudoranges ρ_m = c τ_m = ‖p − b_m‖ + c δt + e_m.  OTDoA differences c δt away; the DPE instead searches it in a
window of ± B around 0, B = clock_bound_sigmas · σ · c from the clock prior σ it is told
(``Experiment.receiver_search``), and its position in a window W of ± H in x and y around the OTDoA fix.  The fit
over (x, y, c δt) in the same windows is (ours, not the paper's)

    minimise over p ∈ W:  Σ_m (ρ_m − ‖p − b_m‖ − β(p))²,   β(p) = clip(mean_m(ρ_m − ‖p − b_m‖), −B, B),     (T1)

the clock bias projected out: at a fixed p the cost is a parabola in c δt, whose minimum over the window is β(p).
With no clock prior (B = ∞) β is the mean and (T1) is the range-difference fit with the differences' correlated noise
accounted for.  ``fit`` minimises it by projected Gauss–Newton from the best point of a grid over the window,
every trial at once;
``implied_bias_m`` is β, which also centres the DPE's clock window when it has no prior (``trials.otdoa_centers``).
Units: seconds, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..phy.nr import C

#: the fit stops once no trial's step is longer than this, metres
STOP_STEP_M = 1e-6
#: the grid over the position window whose best point starts Gauss–Newton, metres (the cost has local minima there)
GRID_STEP_M = 2.0
#: Gauss–Newton steps at most, and halvings of a step that raises the cost
MAX_STEPS = 50
MAX_HALVINGS = 30


def dpe_windows(e) -> tuple[float, float]:
    """The windows of eq. (T1) that give the fit what an experiment's DPE knows: its clock window B (∞ where the DPE
    has no clock prior, clock_window "free") and its position window H, metres (``Experiment.receiver_search``).

    Parameters
    ----------
    e : experiment.Experiment
        The experiment whose DPE the fit matches.

    Returns
    -------
    bias_half_m, half_width_m : float
    """
    search = e.receiver_search()
    return (np.inf if e.receiver.clock_window == "free" else search.bias_half_width_m), search.half_width_m


def implied_bias_m(bs_xyz, toa_s, xyz, bias_half_m: float = np.inf) -> np.ndarray:
    """β(p) of eq. (T1): the clock bias c δt that the ToAs imply at the position p, within ± bias_half_m.

    Parameters
    ----------
    bs_xyz : float (..., M, 3)
        The BSs, metres.
    toa_s : float (..., M)
        Their ToAs, seconds (clock bias included).
    xyz : float (..., 3) or (..., 4)
        The position p, metres (a fourth entry is ignored).
    bias_half_m : float
        The clock window's half-width B, metres (inf: no clock prior).

    Returns
    -------
    float (...)
        c δt, metres.
    """
    p = np.asarray(xyz, dtype=float)[..., None, :3]
    r = C * np.asarray(toa_s, dtype=float) - np.linalg.norm(p - np.asarray(bs_xyz, dtype=float), axis=-1)
    return np.clip(r.mean(axis=-1), -bias_half_m, bias_half_m)


@dataclass(frozen=True)
class ToaFix:
    """Fixes of eq. (T1) (``fit``).

    Attributes
    ----------
    xy : float (T, 2)
        The horizontal position, metres.
    bias_m : float (T,)
        The clock bias c δt, metres, within the window.
    on_edge : bool (T,)
        c δt lies on its window's edge (the prior, not the ToAs, set it).
    in_corner : bool (T,)
        (x, y) lies on the position window's edge.
    steps : int (T,)
        Gauss–Newton steps taken.
    """

    xy: np.ndarray
    bias_m: np.ndarray
    on_edge: np.ndarray
    in_corner: np.ndarray
    steps: np.ndarray


def _residuals(bs, rho, z, xy, half):
    """Eq. (T1)'s residuals (T, M) m, the unit vectors' xy parts (T, M, 2), whether β is inside the window (T,), β."""
    diff = np.concatenate([xy, z[:, None]], axis=-1)[:, None, :] - bs
    d = np.linalg.norm(diff, axis=-1)
    r = rho - d
    free = r.mean(axis=-1)
    beta = np.clip(free, -half, half)
    return r - beta[:, None], diff[..., :2] / np.maximum(d, 1e-9)[..., None], np.abs(free) < half, beta


def _grid_start(bs, rho, z, xy0, half_b, half_w):
    """The point of lowest eq. (T1) cost on a ``GRID_STEP_M`` grid over each trial's window (xy0 first among them, so
    that it wins a tie), (T, 2), a block of trials at a time (about 2 M residuals)."""
    g = np.arange(-half_w, half_w + 1e-9, min(GRID_STEP_M, half_w))
    step = max(1, 2_000_000 // ((len(g) ** 2 + 1) * bs.shape[1]))
    return np.concatenate([_grid_block(bs[t:t + step], rho[t:t + step], z[t:t + step], xy0[t:t + step], half_b, g)
                           for t in range(0, len(xy0), step)])


def _grid_block(bs, rho, z, xy0, half_b, g):
    """``_grid_start`` on one block of trials: each squared distance summed from its x, y and z parts, each part
    computed once per grid line."""
    k = len(g)
    x = np.concatenate([xy0[:, :1], xy0[:, :1] + g], axis=1)  # (T, 1 + k): xy0's x, then the grid's
    y = np.concatenate([xy0[:, 1:], xy0[:, 1:] + g], axis=1)
    dx2 = (x[:, :, None] - bs[:, None, :, 0]) ** 2  # (T, 1 + k, M)
    dy2 = (y[:, :, None] - bs[:, None, :, 1]) ** 2
    dz2 = (z[:, None] - bs[..., 2]) ** 2  # (T, M)
    d0 = np.sqrt(dx2[:, 0] + dy2[:, 0] + dz2)[:, None]  # at xy0
    d = np.sqrt(dx2[:, 1:, None] + dy2[:, None, 1:] + dz2[:, None, None]).reshape(len(xy0), k * k, -1)
    r = rho[:, None, :] - np.concatenate([d0, d], axis=1)  # (T, 1 + k², M)
    beta = np.clip(r.mean(axis=-1, keepdims=True), -half_b, half_b)
    best = np.argmin(np.sum((r - beta) ** 2, axis=-1), axis=1)
    i, j = np.divmod(best - 1, k)
    t = np.arange(len(xy0))
    return np.where((best == 0)[:, None], xy0, np.stack([x[t, 1 + i], y[t, 1 + j]], -1))


def _gn_step(bs, rho, z, xy, cost, lo, hi, half):
    """One projected Gauss–Newton step of ``fit`` for each trial: the step halved until the cost falls.

    Returns the new xy (T, 2) and cost (T,), whether each trial moved, and how far (m)."""
    e, u, free, _ = _residuals(bs, rho, z, xy, half)
    jac = -u + np.where(free[:, None, None], u.mean(axis=1, keepdims=True), 0.0)  # (T, M, 2)
    jtj, jte = np.einsum("tmi,tmj->tij", jac, jac), np.einsum("tmi,tm->ti", jac, e)
    step = -np.linalg.solve(jtj + 1e-12 * np.eye(2), jte[..., None])[..., 0]
    # a coordinate on the window's edge whose step leaves the window stays there: the step in the others
    free_xy = ~(((xy <= lo) & (step < 0)) | ((xy >= hi) & (step > 0)))
    if not free_xy.all():
        d = free_xy[:, :, None] & free_xy[:, None, :]
        a = np.where(d, jtj, 0.0) + np.where(free_xy, 1e-12, 1.0)[:, :, None] * np.eye(2)
        step = -np.linalg.solve(a, np.where(free_xy, jte, 0.0)[..., None])[..., 0]
    moved, dist = np.zeros(len(xy), dtype=bool), np.zeros(len(xy))
    for _ in range(MAX_HALVINGS):
        trial = np.clip(xy + step, lo, hi)
        new = np.sum(_residuals(bs, rho, z, trial, half)[0] ** 2, axis=-1)
        take = ~moved & (new <= cost)
        dist[take] = np.linalg.norm(trial[take] - xy[take], axis=-1)
        xy[take], cost[take] = trial[take], new[take]
        moved |= take
        step = np.where(moved[:, None], step, step / 2)
        if moved.all():
            break
    return xy, cost, moved, dist


def fit(bs_xyz, toa_s, ue_z, xy0, bias_half_m: float = np.inf, half_width_m: float = np.inf) -> ToaFix:
    """Eq. (T1) for T trials at once: Gauss–Newton over (x, y), each step projected on the window W and halved until
    the cost falls; a coordinate held on W's edge steps no further out, the other steps alone.  With a finite W it
    starts at the lowest-cost point of a ``GRID_STEP_M`` grid over W (xy0 among them): the cost has local minima
    there (eq. (T1)'s clip and the NLoS links), and Gauss–Newton from xy0 alone stopped in one on city trials.

    A trial stops when it moves less than ``STOP_STEP_M`` or no halving lowers its cost; all stop after
    ``MAX_STEPS``.

    Parameters
    ----------
    bs_xyz : float (T, M, 3)
        Each trial's BSs, metres (M ≥ 3).
    toa_s : float (T, M)
        Their ToAs, seconds (clock bias included).
    ue_z : float or float (T,)
        The known UE height, metres.
    xy0 : float (T, 2)
        The start, metres (the OTDoA fix).
    bias_half_m : float
        The clock window's half-width B, metres, > 0 (inf: no clock prior).
    half_width_m : float
        The position window's half-width H in x and y around xy0, metres, > 0 (inf: none).

    Returns
    -------
    ToaFix

    Raises
    ------
    ValueError
        Shapes that do not match, fewer than 3 BSs, a non-positive window, or non-finite input.
    """
    bs, toa, xy = np.asarray(bs_xyz, dtype=float), np.asarray(toa_s, dtype=float), np.array(xy0, dtype=float)
    if bs.ndim != 3 or bs.shape[2] != 3 or toa.shape != bs.shape[:2] or xy.shape != (bs.shape[0], 2):
        raise ValueError(f"fit needs bs_xyz (T, M, 3), toa_s (T, M) and xy0 (T, 2), got {bs.shape}, {toa.shape}, "
                         f"{xy.shape}")
    if bs.shape[1] < 3:
        raise ValueError(f"fit needs at least 3 BSs per trial, got M = {bs.shape[1]}")
    for name, v in (("bias_half_m", bias_half_m), ("half_width_m", half_width_m)):
        if not v > 0:
            raise ValueError(f"{name} must be > 0 m (inf: no window), got {v!r}")
    z = np.broadcast_to(np.asarray(ue_z, dtype=float), bs.shape[:1]).copy()
    if not all(np.all(np.isfinite(a)) for a in (bs, toa, xy, z)):
        raise ValueError("fit needs finite BS positions, ToAs, starts and heights")
    rho, n = C * toa, bs.shape[0]
    lo, hi = xy - half_width_m, xy + half_width_m
    if np.isfinite(half_width_m):  # the cost has local minima in the window: start at the best point of a grid
        xy = _grid_start(bs, rho, z, xy, bias_half_m, half_width_m)
    cost = np.sum(_residuals(bs, rho, z, xy, bias_half_m)[0] ** 2, axis=-1)
    active, steps = np.ones(n, dtype=bool), np.zeros(n, dtype=int)
    for _ in range(MAX_STEPS):  # each step on the trials still moving
        i = np.nonzero(active)[0]
        if not len(i):
            break
        xy[i], cost[i], moved, dist = _gn_step(bs[i], rho[i], z[i], xy[i], cost[i], lo[i], hi[i], bias_half_m)
        steps[i] += moved
        active[i] = moved & (dist >= STOP_STEP_M)
    _, _, free, beta = _residuals(bs, rho, z, xy, bias_half_m)
    return ToaFix(xy=xy, bias_m=beta, on_edge=~free, in_corner=np.any((xy <= lo) | (xy >= hi), axis=-1), steps=steps)
