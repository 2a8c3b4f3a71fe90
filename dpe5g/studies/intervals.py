"""Bootstrap intervals of error statistics and the verdicts of claims: the one home of the statistics that compare.

An interval of one receiver's statistic (``quantile_interval``), or paired between receivers run on the same trials
(``paired_interval``: differences, ratios and growths of quantiles, RMSE ratios), every one drawn from the same
stream of trial indices (``bootstrap_draws``); a claim's verdict against an interval (``Interval.verdict``): it
holds, fails, or is unresolved when the interval straddles its threshold.

A quantile difference's bootstrap p value comes from its interval's own draws (``quantile_difference_test``,
``quantile_difference_p``); the tests per group of trials and their correction are ``significance``'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..common import _checks


def bootstrap_draws(n_trials: int, n_boot: int = 2000, seed: int = 0) -> np.ndarray:
    """Trial indices drawn with replacement, one row per bootstrap draw; every bootstrap of this module draws them here.

    Parameters
    ----------
    n_trials, n_boot : int
        Trials (1 to 10⁸) and draws (10 to 10⁶).
    seed : int
        Seed of the generator (so every interval reproduces).

    Returns
    -------
    int (n_boot, n_trials)
        The indices, read-only: the same array for the same arguments (kept for the process's next intervals).

    Raises
    ------
    ValueError
        When ``n_trials`` or ``n_boot`` is out of range.
    """
    _checks.integer("n_trials", n_trials, 1, 10**8)
    _checks.integer("n_boot", n_boot, 10, 10**6)
    return _draws(int(n_trials), int(n_boot), int(seed))


@lru_cache(maxsize=8)
def _draws(n_trials: int, n_boot: int, seed: int) -> np.ndarray:
    """``bootstrap_draws``'s indices, drawn once per arguments: a chapter draws them for hundreds of intervals."""
    rng = np.random.default_rng(seed)
    idx = np.stack([rng.integers(0, n_trials, n_trials) for _ in range(n_boot)])
    idx.flags.writeable = False
    return idx


def bootstrap_interval(err, stat=lambda e: np.quantile(e, 0.9), n_boot: int = 2000, seed: int = 0,
                       level: float = 0.95) -> tuple[float, float]:
    """The bootstrap interval (percentile method) of a statistic of one receiver's errors.

    Two receivers on the same trials are compared with ``paired_interval`` and the functions built on it.

    Parameters
    ----------
    err : float (T,)
        Errors, metres.
    stat : callable
        The statistic of a (T,) array; default the 90 % point.
    n_boot, seed : int
        Bootstrap draws (the trials resampled ``n_boot`` times) and their seed (``bootstrap_draws``).
    level : float
        The interval's level.

    Returns
    -------
    lo, hi : float
        The interval, in the statistic's unit.
    """
    err = np.asarray(err, dtype=float)
    draws = np.array([stat(err[idx]) for idx in bootstrap_draws(err.size, n_boot, seed)])
    return float(np.quantile(draws, (1 - level) / 2)), float(np.quantile(draws, (1 + level) / 2))


#: the verdicts of a claim against the range its statement allows (``Interval.verdict``)
VERDICTS = ("reproduces", "unresolved", "fails")


@dataclass(frozen=True)
class Interval:
    """A statistic of per-trial results and its bootstrap interval, in the statistic's unit (metres, a ratio, a share).

    Attributes
    ----------
    value : float
        The statistic on all trials.
    lo, hi : float
        The ``level`` percentile interval.
    n_trials : int
        The trials resampled.
    level : float
        The interval's level.
    """

    value: float
    lo: float
    hi: float
    n_trials: int
    level: float = 0.95

    def verdict(self, low: float = -np.inf, high: float = np.inf) -> str:
        """The verdict of a claim that the statistic lies in [low, high] (``VERDICTS``).

        Parameters
        ----------
        low, high : float
            The range the claim allows.

        Returns
        -------
        str
            "reproduces" when the whole interval lies in the range, "fails" when none of it does, "unresolved" when it
            straddles a bound.

        Raises
        ------
        ValueError
            When ``low`` > ``high``.
        """
        if low > high:
            raise ValueError(f"verdict needs low <= high, got low {low!r} and high {high!r}")
        if low <= self.lo and self.hi <= high:
            return "reproduces"
        if self.hi < low or self.lo > high:
            return "fails"
        return "unresolved"

    def below(self, x: float) -> bool:
        """Whether the whole interval lies below x.

        Parameters
        ----------
        x : float
            The bound.

        Returns
        -------
        bool
        """
        return self.hi < x

    def above(self, x: float) -> bool:
        """Whether the whole interval lies above x.

        Parameters
        ----------
        x : float
            The bound.

        Returns
        -------
        bool
        """
        return self.lo > x

    def holds(self, x: float) -> bool:
        """Whether x lies inside the interval (the data cannot tell the statistic from x).

        Parameters
        ----------
        x : float
            The value.

        Returns
        -------
        bool
        """
        return self.lo <= x <= self.hi

    def text(self, fmt: str = ".2f") -> str:
        """The interval as the book's tables print it.

        Parameters
        ----------
        fmt : str
            Format of each number.

        Returns
        -------
        str
            "value [lo, hi]".
        """
        return f"{self.value:{fmt}} [{self.lo:{fmt}}, {self.hi:{fmt}}]"


def paired_interval(stat, *arrays, n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> Interval:
    """A statistic of per-trial arrays on the same trials and its bootstrap interval, the trials resampled together.

    Parameters
    ----------
    stat : callable
        ``stat(*resampled)`` → (B,): takes each array as (B, T, ...), B draws at once (e.g.
        ``lambda a, b: np.quantile(a, 0.9, axis=1) - np.quantile(b, 0.9, axis=1)``).
    *arrays : float (T, ...)
        Trials on the first axis, each trial resampled with all its pairs (``bootstrap_draws``): errors (metres) of
        receivers, or of one receiver with and without a change, run on the same trials.
    n_boot, seed : int
        Bootstrap draws and their seed (``bootstrap_draws``).
    level : float
        The interval's level, 0.01 to 0.999.

    Returns
    -------
    Interval
        In the statistic's unit.

    Raises
    ------
    ValueError
        When the arrays do not share their first axis, or ``level`` is out of range.
    """
    value, draws, n_trials = _paired_draws(stat, arrays, n_boot, seed, level)
    lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2])
    return Interval(value, float(lo), float(hi), n_trials, level)


def _paired_draws(stat, arrays, n_boot, seed, level):
    """``paired_interval``'s statistic on all trials, on each of its draws (n_boot,), and the number of trials."""
    arrs = [np.asarray(a, dtype=float) for a in arrays]
    if not arrs or arrs[0].ndim == 0 or any(a.ndim == 0 or a.shape[0] != arrs[0].shape[0] for a in arrs):
        raise ValueError(f"paired_interval needs arrays of the same trials (the same first axis), got shapes "
                         f"{[a.shape for a in arrs]}")
    _checks.in_range("level", level, 0.01, 0.999)
    value = float(np.asarray(stat(*(a[None] for a in arrs)))[0])
    idx = bootstrap_draws(arrs[0].shape[0], n_boot, seed)
    per_draw = max(1, int(np.prod(arrs[0].shape)) * len(arrs))
    block = max(1, 4_000_000 // per_draw)  # draws per block: about 4 M resampled values in memory at once
    draws = np.concatenate([np.asarray(stat(*(np.take(a, idx[i:i + block], axis=0) for a in arrs)), dtype=float)
                            for i in range(0, n_boot, block)])
    return value, draws, int(arrs[0].shape[0])


def _q(a, q):
    return np.quantile(a, q, axis=1)


def quantile_interval(err, q: float = 0.9, **boot) -> Interval:
    """The q point of one receiver's errors and its bootstrap interval.

    Parameters
    ----------
    err : float (T,)
        Errors, metres.
    q, **boot
        The quantile (float, 0.9: the 90 % point) and ``paired_interval``'s options.

    Returns
    -------
    Interval
        Metres.
    """
    return paired_interval(lambda a: _q(a, q), err, **boot)


def quantile_difference(err_a, err_b, q: float = 0.9, **boot) -> Interval:
    """Q_q(err_a) − Q_q(err_b) of two receivers' errors on the same trials, with its paired interval.

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres.
    q, **boot
        The quantile (float, 0.9: the 90 % point) and ``paired_interval``'s options.

    Returns
    -------
    Interval
        Metres; the growth a change causes when err_a and err_b are one receiver with and without it.
    """
    return paired_interval(lambda a, b: _q(a, q) - _q(b, q), err_a, err_b, **boot)


def quantile_difference_test(err_a, err_b, q: float = 0.9, n_boot: int = 2000, seed: int = 0,
                             level: float = 0.95) -> tuple[Interval, float]:
    """``quantile_difference``'s Interval and ``quantile_difference_p``'s p value, from one set of draws.

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres, on the same trials.
    q : float
        The quantile (0.9: the 90 % point).
    n_boot, seed, level
        ``paired_interval``'s options.

    Returns
    -------
    difference : Interval
        Equal to ``quantile_difference`` with the same arguments, metres.
    p : float
        Equal to ``quantile_difference_p`` with the same arguments.
    """
    value, draws, n_trials = _paired_draws(lambda a, b: _q(a, q) - _q(b, q), (err_a, err_b), n_boot, seed, level)
    lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2])
    p = max(1 / draws.size, min(1.0, 2 * min(np.mean(draws <= 0), np.mean(draws >= 0))))
    return Interval(value, float(lo), float(hi), n_trials, level), float(p)


def quantile_difference_p(err_a, err_b, q: float = 0.9, **boot) -> float:
    """The two-sided bootstrap p value of Q_q(err_a) − Q_q(err_b) = 0, from ``quantile_difference``'s own draws.

    p = min(1, 2 min(share of the draws ≤ 0, share ≥ 0)), floored at 1/n_boot (no finer share exists).  With the
    same ``q`` and ``boot``, p < 1 − level where ``quantile_difference``'s percentile interval excludes 0, up to the
    interpolation of its ends (a draw or two).  ``quantile_difference_test`` returns both from one set of draws.

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres, on the same trials.
    q, **boot
        The quantile and ``paired_interval``'s options (``n_boot``, ``seed``: the same draws); ``level`` leaves p as
        it is.

    Returns
    -------
    float
        In [1/n_boot, 1].
    """
    return quantile_difference_test(err_a, err_b, q, **boot)[1]


@dataclass(frozen=True)
class BestComparison:
    """The best receiver of one family against the best of another, on the same trials (``best_comparison``).

    Attributes
    ----------
    best_a, best_b : str
        Each family's receiver with the lowest q point on all the trials.
    difference : Interval
        Q_q(best_a) − Q_q(best_b) with its paired interval, metres.
    a_better, b_better : bool
        best_a's paired interval against every receiver of family b lies below zero; or best_b's against every
        receiver of family a lies above it.  Neither: unresolved.
    """

    best_a: str
    best_b: str
    difference: Interval
    a_better: bool
    b_better: bool

    def verdict(self, a: str = "DPE", b: str = "OTDoA") -> str:
        """The answer in words: "<a> better", "<b> better" or "unresolved".

        Parameters
        ----------
        a, b : str
            The families' names.

        Returns
        -------
        str
        """
        return f"{a} better" if self.a_better else f"{b} better" if self.b_better else "unresolved"


def best_comparison(family_a: dict, family_b: dict, q: float = 0.9, **boot) -> BestComparison:
    """Does the best receiver of family a beat the best of family b at the q point?  All on the same trials.

    Each family's best is the receiver with the lowest q point on all the trials.  A family wins only where its best
    beats every receiver of the other family, each paired interval resolved: then it beats the other family's best,
    whichever that is (an intersection of tests, so no correction for their number).  The choice of the best from
    the point estimates is not in the intervals.

    Parameters
    ----------
    family_a, family_b : dict of str to float (T,)
        Each family's receivers by name, their errors (metres) on the same T trials.
    q, **boot
        The quantile and ``paired_interval``'s options.

    Returns
    -------
    BestComparison

    Raises
    ------
    ValueError
        An empty family.
    """
    if not family_a or not family_b:
        raise ValueError("best_comparison needs at least one receiver in each family")
    best_a = min(family_a, key=lambda k: np.quantile(family_a[k], q))
    best_b = min(family_b, key=lambda k: np.quantile(family_b[k], q))
    a_better = all(quantile_difference(family_a[best_a], e, q, **boot).below(0) for e in family_b.values())
    b_better = all(quantile_difference(family_b[best_b], e, q, **boot).below(0) for e in family_a.values())
    return BestComparison(best_a, best_b, quantile_difference(family_a[best_a], family_b[best_b], q, **boot),
                          a_better, b_better)


def quantile_ratio(err_a, err_b, q: float = 0.9, **boot) -> Interval:
    """Q_q(err_a) / Q_q(err_b) of two receivers' errors on the same trials, with its paired interval.

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres.
    q, **boot
        The quantile (float, 0.9: the 90 % point) and ``paired_interval``'s options.

    Returns
    -------
    Interval
        The ratio.
    """
    return paired_interval(lambda a, b: _q(a, q) / _q(b, q), err_a, err_b, **boot)


def growth_difference(a_with, a_without, b_with, b_without, q: float = 0.9, **boot) -> Interval:
    """How much more a change grows receiver a's q point than receiver b's, with its paired interval.

    Parameters
    ----------
    a_with, a_without, b_with, b_without : float (T,)
        Errors of a and b with and without the change, metres, all on the same trials.
    q, **boot
        The quantile (float, 0.9: the 90 % point) and ``paired_interval``'s options.

    Returns
    -------
    Interval
        (Q_q(a_with) − Q_q(a_without)) − (Q_q(b_with) − Q_q(b_without)), metres.
    """
    return paired_interval(lambda a1, a0, b1, b0: (_q(a1, q) - _q(a0, q)) - (_q(b1, q) - _q(b0, q)),
                           a_with, a_without, b_with, b_without, **boot)


def rmse_ratio(err_a, err_b, **boot) -> Interval:
    """RMSE(err_a) / RMSE(err_b) of two receivers' errors on the same trials, with its paired interval.

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres.
    **boot
        ``paired_interval``'s options.

    Returns
    -------
    Interval
        The ratio.
    """
    return paired_interval(lambda a, b: np.sqrt(np.mean(a**2, axis=1) / np.mean(b**2, axis=1)), err_a, err_b, **boot)
