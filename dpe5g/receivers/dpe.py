"""Direct position estimation (eqs. (7)–(10)): the one public fix for anyone holding received signals.

``fix(y, prs, bs_xyz, center_m, cfg)`` returns the position and clock bias that maximise eq. (10) inside a window
around ``center_m``, by the search ``cfg`` names: by default the book's honest receiver (``honest_search``, the
certified branch and bound), or the paper's grid (``search_config.PAPER_GRID``).  The pieces
are the cost (``cost``), the correlograms (``correlogram``), the receiver that reads them (``receiver``) and the two
searches (``grid_search``, ``certified_search``), configured by ``search_config.SearchConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy import signal
from ..phy.nr import C, PAPER, Numerology
from . import correlogram, cost, receiver
from .search_config import SearchConfig, honest_search  # honest_search: fix's default, public here


@partial(jax.jit, static_argnames=("cfg", "num"))
def _fix_one(y, prs, bs_xyz, center_m, cfg: SearchConfig, num: Numerology):
    g = correlogram.ls_spectrum(signal.demodulate(y), prs)
    r = receiver.fix_in_window(g, bs_xyz, center_m, cfg, num)
    c = cost.ml_cost_of_spectrum(g, cost.tau_of(r.q, bs_xyz), cfg.n_taps, num.scs_hz, jnp.asarray(cfg.tap_weights(num)))
    return r.q, c, r.gap, r.certified, r.edge


@dataclass(frozen=True)
class Fix:
    """Result of ``fix``, as NumPy arrays with the trials' leading shape (...).

    Attributes
    ----------
    xyz : float (..., 3)
        The fix, metres.
    clock_bias_s : float (...)
        The clock bias δt of the fix, seconds.
    cost : float (...)
        Eq. (10) at the fix (with the window's tap weights).
    gap : float (...)
        Relative certified gap of the branch and bound; NaN for the grid search.
    certified : bool (...)
        The branch and bound proved the fix the window's maximum within ``gap``: the best point inside the search
        window, found.  It says nothing of where the UE is: a window centred on a prior far off holds a certified
        maximum metres from the truth (a multipath peak, or the window's edge).
    edge : bool (...)
        The fix lies on the window's boundary (flagged: the likelihood still rises outside, so the maximum may lie
        outside the window; a certified fix on the edge is the window's best point, not the likelihood's).  Widen or
        re-centre the window there.
    """

    xyz: np.ndarray
    clock_bias_s: np.ndarray
    cost: np.ndarray
    gap: np.ndarray
    certified: np.ndarray
    edge: np.ndarray


def fix(y, prs, bs_xyz, center_m, cfg: SearchConfig | None = None, num: Numerology = PAPER,
        batch_size: int = 8) -> Fix:
    """The DPE fix of eq. (10) in the window ``cfg`` around ``center_m``, batched over trials.

    Parameters
    ----------
    y, prs : complex (..., M, N)
        Received samples (eq. (5)) and pilots on M ≥ 3 links (x, y and the clock bias are unknown), at least 3 of
        them with samples not all zero in each trial.
    bs_xyz : float (..., M, 3)
        Base-station positions, metres.
    center_m : float (..., 4)
        The window's centre [x, y, z, c δt], metres: a prior from a coarse fix, or (the paper's set-up, a labelled
        comparison only) the truth.  z is the known UE height (or the centre of the z search when
        ``cfg.z_half_width_m`` > 0), c δt the clock bias times c.
    cfg : SearchConfig or None
        The window and the search.  None (the default): ``honest_search()``, the certified branch and bound over a
        window that covers the clock prior; ``search_config.PAPER_GRID`` is the paper's grid (±10 m, nothing
        certified).
    num : Numerology
        The numerology (``nr.PAPER``: 3 GHz, 30 kHz SCS, N = 4096).
    batch_size : int
        Trials evaluated together (vmap) inside a sequential ``lax.map``, 1 to 65536; results do not depend on it.

    Returns
    -------
    Fix
        With leading shape (...).

    Raises
    ------
    ValueError
        Shapes that do not match, fewer than 3 links, a non-finite input, an all-zero pilot, or fewer than 3 live
        links in a trial.
    """
    _checks.require_x64()
    y = jnp.asarray(y)
    prs = jnp.asarray(prs)
    bs_xyz = jnp.asarray(bs_xyz, dtype=jnp.float64)
    center_m = jnp.asarray(center_m, dtype=jnp.float64)
    if y.ndim < 2 or y.shape[-1] != num.n_fft or prs.shape != y.shape:
        raise ValueError(f"y and prs must be (..., M, {num.n_fft}) of equal shape, got {y.shape} and {prs.shape}")
    if bs_xyz.shape[-2:] != (y.shape[-2], 3) or center_m.shape[-1] != 4:
        raise ValueError(f"bs_xyz must be (..., M, 3) and center_m (..., 4); got {bs_xyz.shape} and "
                         f"{center_m.shape}")
    if center_m.shape[:-1] != y.shape[:-2] or bs_xyz.shape[:-2] != y.shape[:-2]:
        raise ValueError(f"center_m must be {y.shape[:-2] + (4,)} and bs_xyz {y.shape[:-2] + (y.shape[-2], 3)}: one "
                         f"window centre and one set of BSs per trial of y {y.shape}; got {center_m.shape} and "
                         f"{bs_xyz.shape}")
    if y.shape[-2] < 3:
        raise ValueError(f"y must hold at least 3 links (M >= 3: x, y and the clock bias are unknown), got "
                         f"M = {y.shape[-2]}")
    if not bool(jnp.all(jnp.isfinite(center_m))) or not bool(jnp.all(jnp.isfinite(bs_xyz))):
        raise ValueError("center_m and bs_xyz must be finite")
    if not bool(jnp.all(jnp.isfinite(y))) or not bool(jnp.all(jnp.isfinite(prs))):
        raise ValueError("y and prs must be finite (a NaN or inf sample would make every cost NaN)")
    if bool(jnp.any(jnp.all(prs == 0, axis=-1))):
        raise ValueError("prs must not be all zero on a link (its correlogram would be empty)")
    live = jnp.sum(jnp.any(y != 0, axis=-1), axis=-1)  # links of each trial whose samples are not all zero
    if bool(jnp.any(live < 3)):
        raise ValueError(f"y must carry a signal on at least 3 links of each trial (x, y and the clock bias are "
                         f"unknown); a trial has {int(jnp.min(live))} (every other link's samples are zero)")
    batch_size = _checks.integer("batch_size", batch_size, 1, 1 << 16)
    cfg = honest_search() if cfg is None else cfg
    fn = partial(_fix_one, cfg=cfg, num=num)
    lead = y.shape[:-2]
    if lead:
        # trials in vmapped chunks of `batch_size` (bounded memory); each trial's result is independent of chunking
        flat = [a.reshape((-1,) + a.shape[len(lead):]) for a in (y, prs, bs_xyz, center_m)]
        out = jax.lax.map(lambda a: fn(*a), tuple(flat), batch_size=batch_size)
        out = [o.reshape(lead + o.shape[1:]) for o in out]
    else:
        out = fn(y, prs, bs_xyz, center_m)
    q, c, gap, certified, edge = (np.asarray(o) for o in out)
    return Fix(q[..., :3], q[..., 3] / C, c, gap, certified, edge)
