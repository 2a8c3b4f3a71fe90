"""Significance of paired differences per group of trials: rank tests, Holm's correction, and the bootstrap's coverage.

Receivers run on the same trials, compared in groups of them (by the number of NLoS links, say): the Wilcoxon
signed-rank test of the paired differences (``signed_rank``), Holm's step-down correction for many tests (``holm``),
and both with ``intervals``' paired quantile differences and their bootstrap p values per group, every verdict
corrected together (``group_comparisons``), the best of two families of receivers per group likewise
(``best_group_comparisons``); and the coverage of a quantile difference's bootstrap interval at a
given number of trials, simulated (``bootstrap_coverage``), which says how far a small group's interval can be trusted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..common import _checks
from .intervals import Interval, quantile_difference, quantile_difference_p, quantile_difference_test


def _paired_errors(err_a, err_b):
    """err_a, err_b as float (T,) arrays of the same trials, T ≥ 1, finite; else ValueError."""
    a, b = np.asarray(err_a, dtype=float), np.asarray(err_b, dtype=float)
    if a.ndim != 1 or a.shape != b.shape or a.size == 0:
        raise ValueError(f"err_a and err_b must be errors on the same trials, both of shape (T,) with T >= 1, got "
                         f"shapes {a.shape} and {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("err_a and err_b must be finite")
    return a, b


@dataclass(frozen=True)
class RankTest:
    """The Wilcoxon signed-rank test of paired errors (``signed_rank``).

    Attributes
    ----------
    n : int
        The trials (pairs), those with a zero difference included.
    n_a_lower : int
        The trials where err_a < err_b.
    median : float
        The median of the paired differences err_a − err_b, metres.
    p : float
        The two-sided p value; 1 when every difference is zero.
    """

    n: int
    n_a_lower: int
    median: float
    p: float


def signed_rank(err_a, err_b) -> RankTest:
    """The Wilcoxon signed-rank test, two-sided, of the paired differences err_a − err_b (``scipy.stats.wilcoxon``).

    Is the law of the differences symmetric about 0?  Zero differences (ties between the receivers) are dropped
    before ranking (Wilcoxon's convention, scipy's ``zero_method="wilcox"``); ties among the others take their mean
    rank.  The p value is exact for up to 50 distinct differences, from all sign permutations for up to 13 with
    ties, and from the normal approximation (tie-corrected) otherwise (scipy's ``method="auto"``).

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres, on the same trials.

    Returns
    -------
    RankTest

    Raises
    ------
    ValueError
        When the shapes differ, T is 0, or an error is not finite.
    """
    from scipy import stats  # here, so that importing the module does not load scipy.stats

    a, b = _paired_errors(err_a, err_b)
    d = a - b
    nonzero = d[d != 0]
    p = float(stats.wilcoxon(nonzero).pvalue) if nonzero.size else 1.0
    return RankTest(int(d.size), int(np.sum(d < 0)), float(np.median(d)), p)


def holm(pvalues, alpha: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Holm–Bonferroni step-down correction of m p values (Holm 1979), the family-wise error rate held at alpha.

    With the p values sorted, p_(1) ≤ … ≤ p_(m), the adjusted p_(i) = min(1, max_{j ≤ i} (m − j + 1) p_(j)):
    monotone in p, capped at 1.  A test is rejected where its adjusted p ≤ alpha (Holm's rule).

    Parameters
    ----------
    pvalues : float (m,)
        The p values, each in [0, 1]; m may be 0.
    alpha : float
        The family-wise level, 10⁻⁶ to 0.5.

    Returns
    -------
    adjusted : float (m,)
        The adjusted p values, in the order given.
    reject : bool (m,)
        Where adjusted ≤ alpha.

    Raises
    ------
    ValueError
        When ``pvalues`` is not a (m,) sequence of numbers in [0, 1], or ``alpha`` is out of range.
    """
    _checks.in_range("alpha", alpha, 1e-6, 0.5)
    try:
        p = np.asarray(pvalues, dtype=float)
    except (TypeError, ValueError):
        p = np.full(1, np.nan)
    if p.ndim != 1 or not np.all((p >= 0) & (p <= 1)):
        raise ValueError(f"pvalues must be a (m,) sequence of p values in [0, 1], got {pvalues!r:.60}")
    order = np.argsort(p, kind="stable")
    adjusted = np.empty(p.size)
    adjusted[order] = np.minimum(1.0, np.maximum.accumulate((p.size - np.arange(p.size)) * p[order]))
    return adjusted, adjusted <= alpha


#: the verdict of a group too small to test (``group_comparisons``'s ``min_n``)
TOO_FEW = "too few trials"


@dataclass(frozen=True)
class GroupRow:
    """Receivers a and b compared on one group of trials (``group_comparisons``): a row of its table.

    Attributes
    ----------
    label : str
        The group.
    n : int
        Its trials.
    qs : tuple of float
        The quantiles compared.
    differences : tuple of Interval
        Q_q(a) − Q_q(b) for each q with its paired interval (``quantile_difference``), metres; () when too few.
    p, p_holm : tuple of float
        Each difference's bootstrap p (``quantile_difference_p``) and its Holm-adjusted value; () when too few.
    verdicts : tuple of str
        Each q's "a better", "b better", "unresolved" or ``TOO_FEW``.
    rank : RankTest or None
        The signed-rank test (``signed_rank``); None when too few.
    rank_p_holm : float
        Its Holm-adjusted p; NaN when too few.
    rank_verdict : str
        As ``verdicts``, from the rank test and the sign of ``rank.median``.
    """

    label: str
    n: int
    qs: tuple
    differences: tuple
    p: tuple
    p_holm: tuple
    verdicts: tuple
    rank: RankTest | None
    rank_p_holm: float
    rank_verdict: str

    def header(self, a: str = "a", b: str = "b") -> list[str]:
        """The column headings of ``cells``.

        Parameters
        ----------
        a, b : str
            The receivers' names.

        Returns
        -------
        list of str
        """
        return ["group", "n", *[f"Q{100 * q:g} {a} − {b}" for q in self.qs], f"signed rank, {a} − {b}"]

    def cells(self, a: str = "a", b: str = "b", fmt: str = ".2f") -> list[str]:
        """The row's cells as text, for ``dpe5g.figures.tables.markdown_table(row.header(a, b), [row.cells(a, b), …])``.

        Parameters
        ----------
        a, b : str
            The receivers' names, in the verdicts ("<a> better").
        fmt : str
            Format of metres.

        Returns
        -------
        list of str
            Label, n, "difference [lo, hi] m, p … (Holm …): verdict" for each q, and the rank test's "median … m,
            a lower in k/n, p … (Holm …): verdict".
        """
        def word(v):
            return {"a better": f"{a} better", "b better": f"{b} better"}.get(v, v)

        if self.rank is None:
            return [str(self.label), str(self.n), *[TOO_FEW] * len(self.qs), TOO_FEW]
        diffs = [f"{d.text(fmt)} m, p {p:.2g} (Holm {h:.2g}): {word(v)}"
                 for d, p, h, v in zip(self.differences, self.p, self.p_holm, self.verdicts)]
        r = self.rank
        return [str(self.label), str(self.n), *diffs, f"median {r.median:{fmt}} m, {a} lower in {r.n_a_lower}/{r.n}, "
                f"p {r.p:.2g} (Holm {self.rank_p_holm:.2g}): {word(self.rank_verdict)}"]


def _verdict(reject, difference) -> str:
    return "a better" if reject and difference < 0 else "b better" if reject and difference > 0 else "unresolved"


def _group_masks(groups, n_trials) -> dict:
    """{label: bool (T,)} checked: a non-empty dict of bool masks of the trials, each with at least one trial."""
    if not isinstance(groups, dict) or not groups:
        raise ValueError(f"groups must be a non-empty dict of label to bool mask (T,), got {groups!r:.60}")
    masks = {label: np.asarray(m) for label, m in groups.items()}
    for label, m in masks.items():
        if m.dtype != bool or m.shape != (n_trials,) or not m.any():
            held = f", {int(m.sum())} trials" if m.dtype == bool else ""
            raise ValueError(f"groups[{label!r}] must be a bool mask of shape ({n_trials},) holding at least one "
                             f"trial, got dtype {m.dtype}, shape {m.shape}{held}")
    return masks


def group_comparisons(err_a, err_b, groups: dict, qs=(0.5, 0.9), alpha: float = 0.05, min_n: int = 5,
                      **boot) -> list[GroupRow]:
    """Receivers a and b on the same trials, compared in each group of trials, corrected for the number of tests.

    In each group of at least ``min_n`` trials: each q's paired difference Q_q(a) − Q_q(b) with its interval and
    bootstrap p (``quantile_difference``, ``quantile_difference_p``; the same ``boot`` in every group), and the
    signed-rank test of the differences (``signed_rank``).  The quantile p values of every (group, q) are
    Holm-corrected together (``holm``), the rank tests' across the groups; a verdict is "a better" where the
    adjusted p ≤ alpha and the difference (the rank test: the median difference) is below 0, "b better" where it
    is above, "unresolved" otherwise.  A smaller group is reported with its n, outside both corrections, its
    verdicts ``TOO_FEW``.

    Parameters
    ----------
    err_a, err_b : float (T,)
        Errors, metres, on the same trials.
    groups : dict of str to bool (T,)
        The trials of each group (they may overlap); each holds at least one.
    qs : sequence of float
        The quantiles, at least one, each in [0, 1].
    alpha : float
        The family-wise level of each correction, 10⁻⁶ to 0.5.
    min_n : int
        The fewest trials a group is tested with, 2 to 10⁸.
    **boot
        ``paired_interval``'s options (``n_boot``, ``seed``, ``level``).

    Returns
    -------
    list of GroupRow
        In the order of ``groups``.

    Raises
    ------
    ValueError
        When the errors' shapes differ, a mask is not a bool (T,) or holds no trial, or a q, ``alpha`` or
        ``min_n`` is out of range.
    """
    a, b = _paired_errors(err_a, err_b)
    masks = _group_masks(groups, a.size)
    qs = tuple(_checks.in_range("qs", q, 0.0, 1.0) for q in np.atleast_1d(qs))
    if not qs:
        raise ValueError("qs must hold at least one quantile")
    _checks.in_range("alpha", alpha, 1e-6, 0.5)
    _checks.integer("min_n", min_n, 2, 10**8)
    tested = [g for g, m in masks.items() if m.sum() >= min_n]
    quantile = {g: [quantile_difference_test(a[masks[g]], b[masks[g]], q, **boot) for q in qs] for g in tested}
    rank = {g: signed_rank(a[masks[g]], b[masks[g]]) for g in tested}
    adj_q, rej_q = holm([p for g in tested for _, p in quantile[g]], alpha)
    adj_r, rej_r = holm([rank[g].p for g in tested], alpha)
    rows = []
    for label, m in masks.items():
        if label not in tested:
            rows.append(GroupRow(label, int(m.sum()), qs, (), (), (), (TOO_FEW,) * len(qs), None, np.nan, TOO_FEW))
            continue
        k, j = tested.index(label) * len(qs), tested.index(label)
        ivs, ps = zip(*quantile[label])
        rows.append(GroupRow(label, int(m.sum()), qs, tuple(ivs), tuple(ps), tuple(map(float, adj_q[k:k + len(qs)])),
                             tuple(_verdict(r, iv.value) for r, iv in zip(rej_q[k:k + len(qs)], ivs)),
                             rank[label], float(adj_r[j]), _verdict(rej_r[j], rank[label].median)))
    return rows


def bootstrap_coverage(n: int, q: float, n_rep: int, seed: int, n_boot: int = 1000, level: float = 0.95,
                       medians=(3.0, 4.0), p90s=(50.0, 70.0), rho: float = 0.7) -> tuple[float, float]:
    """How often ``quantile_difference``'s percentile interval holds the true Q_q(a) − Q_q(b), with n trials.

    The synthetic errors are heavy-tailed like the ray-traced city's: a and b log-normal, err_k = median_k
    exp(σ_k z_k) with σ_k = ln(p90_k / median_k) / Φ⁻¹(0.9), (z_a, z_b) standard normal with correlation ``rho``
    (the receivers run on the same trials).  The true difference is exact: median_a exp(σ_a Φ⁻¹(q)) − median_b
    exp(σ_b Φ⁻¹(q)).  Replication r draws its n trials from ``np.random.default_rng([seed, r])``, then from the
    same generator the seed of its bootstrap.  ``n_boot`` is 1000 by default, half ``quantile_difference``'s, for
    speed: it moves the interval's ends by Monte Carlo noise, not its coverage on average.

    Parameters
    ----------
    n : int
        Trials per replication, 2 to 10⁶.
    q : float
        The quantile, 0.01 to 0.99.
    n_rep, seed : int
        Replications (1 to 10⁶) and their seed (≥ 0).
    n_boot, level
        ``quantile_difference``'s draws and level.
    medians, p90s : (float, float)
        Medians and 90 % points of a and b, metres; each 90 % point above its median.
    rho : float
        Correlation of the log-errors, −0.99 to 0.99.

    Returns
    -------
    coverage : float
        The share of replications whose interval holds the true difference.
    se : float
        Its binomial standard error, sqrt(coverage (1 − coverage) / n_rep).

    Raises
    ------
    ValueError
        When an argument is out of range.
    """
    from scipy import stats

    _checks.integer("n", n, 2, 10**6)
    _checks.in_range("q", q, 0.01, 0.99)
    _checks.integer("n_rep", n_rep, 1, 10**6)
    _checks.integer("seed", seed, 0, 2**63 - 1)
    _checks.in_range("rho", rho, -0.99, 0.99)
    med = np.array([_checks.in_range("medians", m, 1e-6, 1e6, "m") for m in medians])
    p90 = np.array([_checks.in_range("p90s", p, 1e-6, 1e6, "m") for p in p90s])
    if med.shape != (2,) or p90.shape != (2,) or np.any(p90 <= med):
        raise ValueError(f"medians and p90s must be two values each, each 90 % point above its median, got "
                         f"{medians!r} and {p90s!r}")
    sigma = np.log(p90 / med) / stats.norm.ppf(0.9)
    true_a, true_b = med * np.exp(sigma * stats.norm.ppf(q))
    chol = np.linalg.cholesky(np.array([[1.0, rho], [rho, 1.0]]))
    hits = 0
    for r in range(n_rep):
        rng = np.random.default_rng([seed, r])
        a, b = med[:, None] * np.exp(sigma[:, None] * (chol @ rng.standard_normal((2, n))))
        iv = quantile_difference(a, b, q, n_boot=n_boot, seed=int(rng.integers(2**63 - 1)), level=level)
        hits += iv.holds(true_a - true_b)
    coverage = float(hits / n_rep)
    return coverage, float(np.sqrt(coverage * (1 - coverage) / n_rep))


@dataclass(frozen=True)
class BestGroupRow:
    """The best receiver of one family against the best of another on one group of trials (``best_group_comparisons``).

    Attributes
    ----------
    label : str
        The group.
    n : int
        Its trials.
    best_a, best_b : str
        Each family's receiver with the lowest q point on the group ("" when too few).
    difference : Interval or None
        Q_q(best_a) − Q_q(best_b) with its paired interval, metres; None when too few.
    p, p_holm : float
        The p value that one family's best beats every receiver of the other (the largest of those paired tests' p
        values: an intersection–union test), and its Holm-adjusted value across the groups; NaN when too few.
    verdict : str
        "a better", "b better", "unresolved" or ``TOO_FEW``.
    """

    label: str
    n: int
    best_a: str
    best_b: str
    difference: Interval | None
    p: float
    p_holm: float
    verdict: str


def _wins(best, errs: dict, others: dict, q: float, boot: dict) -> float:
    """The intersection–union p value that ``errs[best]`` beats every receiver of ``others`` at q (1 where a point
    estimate says it does not)."""
    ps = []
    for e in others.values():
        d, p = quantile_difference_test(errs[best], e, q, **boot)
        if not d.value < 0:
            return 1.0
        ps.append(p)
    return max(ps)


def best_group_comparisons(family_a: dict, family_b: dict, groups: dict, q: float = 0.9, alpha: float = 0.05,
                           min_n: int = 20, **boot) -> list[BestGroupRow]:
    """``intervals.best_comparison`` on each group of trials, its verdicts Holm-corrected across the groups.

    In each group a family wins where its best receiver (the lowest q point there) beats every receiver of the other
    family; the test of that is the largest of the paired tests' bootstrap p values (``quantile_difference_test``),
    and those p values, one per group, are corrected together (``holm``).

    Parameters
    ----------
    family_a, family_b : dict of str to float (T,)
        Each family's receivers by name, their errors (metres) on the same T trials.
    groups : dict of str to bool (T,)
        The groups, by label.
    q : float
        The quantile.
    alpha : float
        The family-wise level.
    min_n : int
        Groups with fewer trials are reported as ``TOO_FEW`` and left out of the correction.
    **boot
        ``paired_interval``'s options.

    Returns
    -------
    list of BestGroupRow
        One per group, in the order of ``groups``.

    Raises
    ------
    ValueError
        An empty family, masks that are not bool (T,), or alpha out of range.
    """
    if not family_a or not family_b:
        raise ValueError("best_group_comparisons needs at least one receiver in each family")
    n_trials = len(next(iter(family_a.values())))
    masks = _group_masks(groups, n_trials)
    rows, tested = [], []
    for label, m in masks.items():
        if m.sum() < min_n:
            rows.append(BestGroupRow(str(label), int(m.sum()), "", "", None, math.nan, math.nan, TOO_FEW))
            continue
        fa, fb = ({k: np.asarray(v, dtype=float)[m] for k, v in f.items()} for f in (family_a, family_b))
        ba = min(fa, key=lambda k: np.quantile(fa[k], q))
        bb = min(fb, key=lambda k: np.quantile(fb[k], q))
        pa, pb = _wins(ba, fa, fb, q, boot), _wins(bb, fb, fa, q, boot)
        rows.append(BestGroupRow(str(label), int(m.sum()), ba, bb, quantile_difference(fa[ba], fb[bb], q, **boot),
                                 min(pa, pb), math.nan, "b better" if pb < pa else "a better"))
        tested.append(len(rows) - 1)
    adjusted, reject = holm([rows[i].p for i in tested], alpha)
    for i, h, r in zip(tested, adjusted, reject):
        rows[i] = replace(rows[i], p_holm=float(h), verdict=rows[i].verdict if r else "unresolved")
    return rows
