"""Per-trial results of an experiment (``Results``), their export as a tidy table (CSV, JSON), and the one home of
the error statistics every product reads: RMSE, median, 90 % and 99 % points, flagged and certified shares, and their
bootstrap intervals — of one receiver, and paired between receivers run on the same trials (``paired_interval``:
differences, ratios and growths of quantiles, RMSE ratios) with the verdict of a claim against them
(``Interval.verdict``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import _checks
from .experiment import OTDOA_DETECTORS, Experiment

@dataclass(frozen=True)
class Results:
    """Per-trial results of an experiment (arrays over trials t, SNR index s, M index j, link i of the nearest).

    ue_xyz (T, 3) m; clock_bias_s (T,); bs_index (T, I) deployment index of the i-th nearest BS; los (T, I) bool;
    link_snr_db (T, S, I) per-sample SNR of each link; link_sinr_db (T, S, I) its SINR (co-channel interference of
    ``prs_reuse`` and thermal noise; equal to the SNR without interference); est_xyz (T, S, J, 3) m;
    est_bias_s (T, S, J);
    error_m (T, S, J) horizontal error; center_xyz (T, S, J, 3) the search window's centre; edge (T, S, J) the fix
    lies on the window's boundary (flagged); gap (T, S, J) the certified relative gap (NaN for the grid search);
    certified (T, S, J).  With ``otdoa``, per detector d of ``OTDOA_DETECTORS``: otdoa_toa_s (T, S, D, I) the
    estimated ToAs (clock bias included), otdoa_xyz (T, S, D, J, 3), otdoa_error_m (T, S, D, J), otdoa_ok
    (T, S, D, J) False where the fix is flagged.
    """

    experiment: Experiment
    ue_xyz: np.ndarray
    clock_bias_s: np.ndarray
    bs_index: np.ndarray
    los: np.ndarray
    link_snr_db: np.ndarray
    link_sinr_db: np.ndarray
    est_xyz: np.ndarray
    est_bias_s: np.ndarray
    error_m: np.ndarray
    center_xyz: np.ndarray
    edge: np.ndarray
    gap: np.ndarray
    certified: np.ndarray
    otdoa_toa_s: np.ndarray | None = None
    otdoa_xyz: np.ndarray | None = None
    otdoa_error_m: np.ndarray | None = None
    otdoa_ok: np.ndarray | None = None

    FIELDS = ("ue_xyz", "clock_bias_s", "bs_index", "los", "link_snr_db", "link_sinr_db", "est_xyz", "est_bias_s",
              "error_m", "center_xyz", "edge", "gap", "certified")
    OTDOA_FIELDS = ("otdoa_toa_s", "otdoa_xyz", "otdoa_error_m", "otdoa_ok")

    def rmse_m(self) -> np.ndarray:
        """(S, J) RMSE of the horizontal error over trials."""
        return np.sqrt(np.mean(self.error_m**2, axis=0))

    def otdoa_rmse_m(self, detector: str) -> np.ndarray:
        """(S, J) RMSE of the OTDoA fixes of ``detector`` (``OTDOA_DETECTORS``) over trials."""
        if self.otdoa_error_m is None:
            raise ValueError(f"experiment {self.experiment.run.name!r} ran no OTDoA baseline (otdoa=False)")
        k = OTDOA_DETECTORS.index(detector)
        return np.sqrt(np.mean(self.otdoa_error_m[:, :, k] ** 2, axis=0))

    def los_share(self, m: int | None = None) -> float:
        """Fraction of LoS links among the m nearest (all simulated links if None) over all trials."""
        return float(np.mean(self.los if m is None else self.los[:, :m]))

    def table(self) -> list[dict]:
        """Tidy rows: one per (trial, SNR, M) with the error, the estimate, the LoS count of the links used, their
        LoS flags nearest first ("L" LoS, "N" NLoS) and their per-sample SNR and SINR in dB, nearest first
        (";"-separated)."""
        e = self.experiment
        snrs = e.links.snrs_db if e.links.snr_mode != "link_budget" else ("link",)
        per_link = lambda a: ";".join(f"{v:.2f}" for v in a)
        rows = []
        for t in range(self.error_m.shape[0]):
            for s, snr in enumerate(snrs):
                for j, m in enumerate(e.receiver.m_values):
                    rows.append({"trial": t, "snr_db": snr, "m": m, "error_m": float(self.error_m[t, s, j]),
                                 "est_x_m": float(self.est_xyz[t, s, j, 0]), "est_y_m": float(self.est_xyz[t, s, j, 1]),
                                 "true_x_m": float(self.ue_xyz[t, 0]), "true_y_m": float(self.ue_xyz[t, 1]),
                                 "n_los": int(self.los[t, :m].sum()),
                                 "los_flags": "".join("L" if f else "N" for f in self.los[t, :m]),
                                 "link_snr_db": per_link(self.link_snr_db[t, s, :m]),
                                 "link_sinr_db": per_link(self.link_sinr_db[t, s, :m]),
                                 "edge": bool(self.edge[t, s, j]), "certified": bool(self.certified[t, s, j])})
                    if self.otdoa_error_m is not None:
                        for d, name in enumerate(OTDOA_DETECTORS):
                            rows[-1].update({f"otdoa_{name}_error_m": float(self.otdoa_error_m[t, s, d, j]),
                                             f"otdoa_{name}_ok": bool(self.otdoa_ok[t, s, d, j])})
        return rows

    def config(self) -> dict:
        """The experiment's settings as JSON values (``Experiment.to_dict``: the seed, trials, scenario, links and
        receiver), which every results file records."""
        return json.loads(json.dumps(self.experiment.to_dict(), default=str))

    def write_csv(self, path) -> None:
        """The tidy table as CSV, after one comment line ``# dpe5g experiment: {config JSON}`` (``config``) that
        says what produced it (``pandas.read_csv(path, comment="#")`` skips it)."""
        import csv

        rows = self.table()
        with open(path, "w", newline="") as f:
            f.write(f"# dpe5g experiment: {json.dumps(self.config(), sort_keys=True)}\n")
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)

    def write_json(self, path) -> None:
        """The tidy table as JSON, with the experiment's config beside it."""
        doc = {"experiment": self.config(), "rows": self.table()}
        Path(path).write_text(json.dumps(doc, indent=1) + "\n")


def quantiles(err) -> np.ndarray:
    """The 50, 90 and 99 % points (3,) of errors err (T,) m."""
    return np.quantile(err, [0.5, 0.9, 0.99])


def error_summary(err, edge=None, certified=None) -> dict:
    """Horizontal errors err (T,) m → RMSE, median, 90 % and 99 % errors (m), and the shares of fixes flagged on the
    window's edge and certified (when given, booleans (T,))."""
    err = np.asarray(err, dtype=float)
    out = {"rmse_m": float(np.sqrt(np.mean(err**2))), "median_m": float(np.median(err)),
           "p90_m": float(np.quantile(err, 0.9)), "p99_m": float(np.quantile(err, 0.99))}
    if edge is not None:
        out["edge_share"] = float(np.mean(edge))
    if certified is not None:
        out["certified_share"] = float(np.mean(certified))
    return out


def error_stats(res: Results) -> dict:
    """RMSE, median, 90 % and 99 % error per (SNR, M) over trials, (S, J) each, the RMSE without the edge-flagged
    fixes, and the shares of fixes on the window's edge and of certified fixes."""
    err, edge = res.error_m, res.edge
    kept = np.where(edge, np.nan, err)
    return {"rmse_m": res.rmse_m(), "median_m": np.median(err, axis=0), "p90_m": np.quantile(err, 0.9, axis=0),
            "p99_m": np.quantile(err, 0.99, axis=0), "rmse_unflagged_m": np.sqrt(np.nanmean(kept**2, axis=0)),
            "edge_share": edge.mean(axis=0), "certified_share": res.certified.mean(axis=0)}


def bootstrap_draws(n_trials: int, n_boot: int = 2000, seed: int = 0) -> np.ndarray:
    """(n_boot, n_trials) trial indices drawn with replacement, one row per bootstrap draw, from a generator seeded by
    ``seed`` (so every interval reproduces).  Every bootstrap of this module draws its resamples here."""
    _checks.integer("n_trials", n_trials, 1, 10**8)
    _checks.integer("n_boot", n_boot, 10, 10**6)
    rng = np.random.default_rng(seed)
    return np.stack([rng.integers(0, n_trials, n_trials) for _ in range(n_boot)])


def bootstrap_interval(err, stat=lambda e: np.quantile(e, 0.9), n_boot: int = 2000, seed: int = 0,
                       level: float = 0.95) -> tuple[float, float]:
    """The ``level`` bootstrap interval (percentile method) of ``stat`` (default: the 90 % point) of errors err (T,),
    resampling the trials ``n_boot`` times (``bootstrap_draws``).  One receiver alone; two receivers on the same trials
    are compared with ``paired_interval`` and the functions built on it."""
    err = np.asarray(err, dtype=float)
    draws = np.array([stat(err[idx]) for idx in bootstrap_draws(err.size, n_boot, seed)])
    return float(np.quantile(draws, (1 - level) / 2)), float(np.quantile(draws, (1 + level) / 2))


#: the verdicts of a claim against the range its statement allows (``Interval.verdict``)
VERDICTS = ("reproduces", "unresolved", "fails")


@dataclass(frozen=True)
class Interval:
    """A statistic of per-trial results and its bootstrap interval: ``value`` on all trials, [``lo``, ``hi``] the
    ``level`` percentile interval over ``n_trials`` resampled trials (in the statistic's unit: m, a ratio, a share)."""

    value: float
    lo: float
    hi: float
    n_trials: int
    level: float = 0.95

    def verdict(self, low: float = -np.inf, high: float = np.inf) -> str:
        """A claim that the statistic lies in [low, high]: "reproduces" when the whole interval does, "fails" when none
        of it does, "unresolved" when the interval straddles a bound (``VERDICTS``)."""
        if low > high:
            raise ValueError(f"verdict needs low <= high, got low {low!r} and high {high!r}")
        if low <= self.lo and self.hi <= high:
            return "reproduces"
        if self.hi < low or self.lo > high:
            return "fails"
        return "unresolved"

    def below(self, x: float) -> bool:
        """The whole interval lies below x."""
        return self.hi < x

    def above(self, x: float) -> bool:
        """The whole interval lies above x."""
        return self.lo > x

    def holds(self, x: float) -> bool:
        """x lies inside the interval (the data cannot tell the statistic from x)."""
        return self.lo <= x <= self.hi

    def text(self, fmt: str = ".2f") -> str:
        """"value [lo, hi]", as the book's tables print an interval."""
        return f"{self.value:{fmt}} [{self.lo:{fmt}}, {self.hi:{fmt}}]"


def paired_interval(stat, *arrays, n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> Interval:
    """The statistic ``stat`` of per-trial arrays on the same trials and its ``level`` bootstrap interval, the trials
    resampled together so that each keeps its pairs (``bootstrap_draws``).

    arrays : each (T, ...) with trials on the first axis (errors in m of receivers, or of one receiver with and
    without a change, run on the same trials).  stat(*resampled) → (B,) takes each array as (B, T, ...), B draws at
    once (e.g. ``lambda a, b: np.quantile(a, 0.9, axis=1) - np.quantile(b, 0.9, axis=1)``)."""
    arrs = [np.asarray(a, dtype=float) for a in arrays]
    if not arrs or arrs[0].ndim == 0 or any(a.ndim == 0 or a.shape[0] != arrs[0].shape[0] for a in arrs):
        raise ValueError(f"paired_interval needs arrays of the same trials (the same first axis), got shapes "
                         f"{[a.shape for a in arrs]}")
    _checks.in_range("level", level, 0.01, 0.999)
    value = float(np.asarray(stat(*(a[None] for a in arrs)))[0])
    idx = bootstrap_draws(arrs[0].shape[0], n_boot, seed)
    per_draw = max(1, int(np.prod(arrs[0].shape)) * len(arrs))
    block = max(1, 4_000_000 // per_draw)  # draws per block: about 4 M resampled values in memory at once
    draws = np.concatenate([np.asarray(stat(*(a[idx[i:i + block]] for a in arrs)), dtype=float)
                            for i in range(0, n_boot, block)])
    lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2])
    return Interval(value, float(lo), float(hi), int(arrs[0].shape[0]), level)


def _q(a, q):
    return np.quantile(a, q, axis=1)


def quantile_interval(err, q: float = 0.9, **boot) -> Interval:
    """The q point of one receiver's errors err (T,) m and its bootstrap interval (``paired_interval``'s options)."""
    return paired_interval(lambda a: _q(a, q), err, **boot)


def quantile_difference(err_a, err_b, q: float = 0.9, **boot) -> Interval:
    """Q_q(err_a) − Q_q(err_b) (m) of two receivers' errors on the same trials, (T,) each, with its paired interval;
    the growth a change causes when err_a and err_b are one receiver with and without it on the same trials."""
    return paired_interval(lambda a, b: _q(a, q) - _q(b, q), err_a, err_b, **boot)


def quantile_ratio(err_a, err_b, q: float = 0.9, **boot) -> Interval:
    """Q_q(err_a) / Q_q(err_b) of two receivers' errors on the same trials, (T,) each, with its paired interval."""
    return paired_interval(lambda a, b: _q(a, q) / _q(b, q), err_a, err_b, **boot)


def growth_difference(a_with, a_without, b_with, b_without, q: float = 0.9, **boot) -> Interval:
    """How much more a change grows receiver a's q point than receiver b's, all four (T,) on the same trials:
    (Q_q(a_with) − Q_q(a_without)) − (Q_q(b_with) − Q_q(b_without)) m, with its paired interval."""
    return paired_interval(lambda a1, a0, b1, b0: (_q(a1, q) - _q(a0, q)) - (_q(b1, q) - _q(b0, q)),
                           a_with, a_without, b_with, b_without, **boot)


def rmse_ratio(err_a, err_b, **boot) -> Interval:
    """RMSE(err_a) / RMSE(err_b) of two receivers' errors (m) on the same trials, (T,) each, with its paired
    interval."""
    return paired_interval(lambda a, b: np.sqrt(np.mean(a**2, axis=1) / np.mean(b**2, axis=1)), err_a, err_b, **boot)
