"""What a DPE receiver is asked to do and what its search returns: ``SearchConfig`` (the window of eq. (10), L
taps, and the search over it: the paper's grid or the certified branch and bound) and ``WindowFix`` (a search's fix
in its window, a JAX pytree).

The searches themselves are ``grid_search`` and ``certified_search``; the one public fix is ``dpe.fix``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

from ..common import _checks
from ..phy.nr import C, PAPER, Numerology
from . import correlogram

#: Default receiver window L (taps).  First chosen in the DPE chapter on 8 NLoS (TDL-C) links on a 150 m ring with the
#: grid on the truth, where L = 12 gave the smallest RMSE; chosen again on the urban scenario (mixed LoS/NLoS, Figs. 9
#: and 10 set-ups) with the honest receiver (prior-centred window, certified search; ``paper.urban_window_experiments``,
#: the Fig. 9 chapter), where the rule of ``studies.choose_window`` picks L = 12 again.  Shorter windows lock onto the
#: strongest cluster of NLoS links; longer ones widen the LoS plateau and flatten the peak (the TDL-C excess delay is 69
#: samples).
DEFAULT_TAPS = 12
SEARCH_METHODS = ("grid", "bnb")


@dataclass(frozen=True)
class SearchConfig:
    """The window of eq. (10) and its search: the paper's divide-and-conquer grid or the certified branch and bound.

    The grid searches (x, y, c δt) at known UE height (the paper's set-up), or (x, y, z, c δt) with
    ``z_half_width_m`` > 0; the branch and bound searches (x, y, c δt) at the known height.

    Attributes
    ----------
    n_taps : int
        Receiver window L in taps, 1 to 4096 (default ``DEFAULT_TAPS``; the DPE chapter shows the bias-vs-L study
        behind it).
    upsample : int
        Correlogram grid T_s / upsample, 1 to 256 (4 → 0.61 m of range; cubic interpolation between grid points).
    half_width_m : float
        The window spans centre ± half_width_m in x and y, metres, 0.1 to 1000.
    bias_half_width_m : float
        And centre ± this in c δt, metres, 0 to 1000 (the paper's clock bias: σ = 5 ns = 1.5 m); 0 fixes δt.
    z_half_width_m : float
        0 (default, the paper's set-up) keeps the UE height at the centre's z; > 0 (up to 1000 m) searches z too, over
        centre ± this (the 3-D option).
    coarse_step_m : float
        Step of the first grid, metres, 0.01 to 100; each further level is a 5-point-per-axis grid around the best
        point, with the step divided by 2.5, until the step is ≤ ``final_step_m``.
    final_step_m : float
        Resolution reached by the grid, metres, 1e-4 to ``coarse_step_m`` (0.1 m by default).
    polish : bool
        After the grid, Newton steps on the exact ``ml_cost`` with JAX autodiff (accepted only if the cost rises).  Off
        by default, as in the paper, whose search ends on the grid: on the DPE chapter's ring study it moves fixes by
        4 cm (median, 13 cm at most) and costs about as much as the grid search.
    polish_iters : int
        Newton steps of ``polish``, 0 to 20.
    method : str
        ``"grid"``: the coarse-to-fine grid above (``grid_search``: the paper's divide-and-conquer search; no
        guarantee).  ``"bnb"``: ``certified_search.certified_search``, branch and bound over (x, y, c δt) boxes that
        returns the global maximum of eq. (10) (cubic-spline form) inside the window with a certified gap; the fields
        below apply to it only, and ``z_half_width_m`` must be 0.
    spline_upsample : int
        T_s / spline_upsample is the knot spacing of the spline form of eq. (10), even, 2 to 64 (8 → 0.305 m).
    box_m : float
        Side of the first boxes in x and y, metres, 0.1 to 100.
    bias_boxes : int
        Boxes the c δt window is split into at the start, 1 to 64.
    box_final_m : float
        Boxes are halved until their x, y side is ≤ this, metres, 1e-3 to ``box_m``.
    capacity : int
        Boxes kept per level (the highest bounds), 8 to 65536; a box dropped for lack of room makes the fix
        uncertified (counted, not hidden).  A level's work follows the boxes alive, not the capacity: they are
        refined ``chunk_boxes`` at a time, in order of bound, while any is left.
    chunk_boxes : int
        Boxes refined together, a divisor of ``capacity``.  A level's loop evaluates all 8 × chunk_boxes children of a
        chunk, live or not, and the levels of Fig. 9's fixes keep a few tens of boxes alive, so small chunks waste
        less: measured on the 2-core CI machine (interleaved runs), 16 took 0.85 of the time of 64 on Fig. 9's honest
        receiver and 0.82 on Fig. 10's; 8 was within 5 % of 16, and keeps more loop steps where many boxes stay alive
        (wide windows, low SNR).  Where no box is dropped the fix does not depend on it: every box holding a point
        better than the best cost found is refined, whatever the order (ties aside); its gap, the bound left over
        the final boxes, does.
    gap_tol : float
        A fix is certified when its upper bound exceeds its cost by at most gap_tol × cost, 0 to 1.
    window_decay_s : float
        0 (default): eq. (10)'s window, its L taps weighted equally.  > 0 (seconds, up to
        ``correlogram.MAX_WINDOW_DECAY_S``, ``"bnb"`` only): the first-path-aware window, our extension and not the
        paper's (the bounds chapter), tap l weighted by exp(−l T_s / window_decay_s) (``correlogram.tap_weights``).

    Raises
    ------
    ValueError
        A field outside its range, or a combination the search cannot run (``window_decay_s`` > 0 or
        ``z_half_width_m`` > 0 with the other method).
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
        _checks.plain_fields(self)  # NumPy values and ints as the types they hash as
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
        """The weights of the window's taps (``correlogram.tap_weights``).

        Parameters
        ----------
        num : Numerology
            The numerology, for the sample period T_s (``nr.PAPER`` by default).

        Returns
        -------
        numpy.ndarray float (L,)
            Weight of each of the L = ``n_taps`` taps.
        """
        return correlogram.tap_weights(self.n_taps, self.window_decay_s, num.sample_period_s)

    def steps(self) -> tuple[float, ...]:
        """Grid step of each level of the grid search.

        Returns
        -------
        tuple of float
            The steps in metres, from ``coarse_step_m`` down to the first ≤ ``final_step_m``.
        """
        s = [self.coarse_step_m]
        while s[-1] > self.final_step_m + 1e-12:
            s.append(s[-1] / 2.5)
        return tuple(s)


#: the paper's search, a labelled comparison only: its divide-and-conquer grid, ±10 m around the window's centre,
#: nothing certified (``SearchConfig()``).  The book's receiver, ``dpe.fix``'s default, is ``honest_search()``.
PAPER_GRID = SearchConfig()
#: the honest receiver's window in x and y (Figs. 9 and 10): ±30 m around a prior (6 σ of the paper's 5 m) or the
#: OTDoA fix
HONEST_HALF_WIDTH_M = 30.0
#: the UE clock a receiver assumes when told nothing else: σ = 5 ns, searched over ± 3 σ (the paper's clock model,
#: ``experiment.Scenario``'s default; an experiment's receiver takes its window from its own scenario)
CLOCK_SIGMA_S, CLOCK_BOUND_SIGMAS = 5e-9, 3.0


def honest_search() -> SearchConfig:
    """The book's honest receiver's search, ``dpe.fix``'s default: the certified branch and bound over
    ± ``HONEST_HALF_WIDTH_M`` in x and y and, in c δt, over the assumed clock's ± ``CLOCK_BOUND_SIGMAS`` σ (± 4.5 m).

    Returns
    -------
    SearchConfig
        Method "bnb"; the rest of its settings the defaults.
    """
    return SearchConfig(method="bnb", half_width_m=HONEST_HALF_WIDTH_M,
                        bias_half_width_m=CLOCK_BOUND_SIGMAS * CLOCK_SIGMA_S * C)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class WindowFix:
    """A search's fix in its window (a JAX pytree), leading shape (...): e.g. (S, J), an engine trial's SNRs and M's.

    Attributes
    ----------
    q : jax.Array float (..., 4)
        The fix (x, y, z, c δt), metres.
    gap : jax.Array float (...)
        The certified relative gap; NaN for the grid search, which certifies nothing.
    certified : jax.Array bool (...)
        The search proved the fix the window's maximum within ``gap``.
    edge : jax.Array bool (...)
        The fix lies on the window's boundary (flagged: the maximum may lie outside).
    """

    q: jax.Array
    gap: jax.Array
    certified: jax.Array
    edge: jax.Array
