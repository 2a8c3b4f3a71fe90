"""Per-trial results of an experiment (``Results``), their export as a table, and their error summaries.

The table is written as CSV, its provenance beside it as JSON.  The summaries every product reads are here: RMSE,
median, 90 % and 99 % points, flagged and certified shares; their bootstrap intervals, paired between receivers run
on the same trials, and the verdicts of claims are in ``intervals``.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from .code_key import numerics
from .experiment import OTDOA_DETECTORS, Experiment

@dataclass(frozen=True)
class Results:
    """Per-trial results of an experiment (arrays over trials t, SNR index s, M index j, link i of the nearest).

    Attributes
    ----------
    experiment : Experiment
        The experiment that produced them.
    ue_xyz : float (T, 3)
        The UE's position, metres.
    clock_bias_s : float (T,)
        The UE's clock bias, seconds.
    bs_index : int (T, I)
        Deployment index of the i-th nearest BS.
    los : bool (T, I)
        The link is LoS.
    link_snr_db, link_sinr_db : float (T, S, I)
        Per-sample SNR and SINR of each link, dB (the SINR: co-channel interference of ``prs_reuse`` and thermal noise;
        equal to the SNR without interference).
    est_xyz, center_xyz : float (T, S, J, 3)
        The DPE fix and the search window's centre, metres.
    est_bias_s : float (T, S, J)
        The fix's clock bias, seconds.
    error_m : float (T, S, J)
        Horizontal error of the fix, metres.
    edge, certified : bool (T, S, J)
        The fix lies on the window's boundary (flagged); the certified search proved it.
    gap : float (T, S, J)
        The certified relative gap (NaN for the grid search).
    otdoa_toa_s, otdoa_xyz, otdoa_error_m, otdoa_ok : arrays (T, S, D, ...) or None
        With ``otdoa`` (else None), per detector d of ``OTDOA_DETECTORS``: the estimated ToAs (T, S, D, I), seconds
        (clock bias included); the fixes (T, S, D, J, 3) and their horizontal errors (T, S, D, J), metres; and, bool
        (T, S, D, J), False where the fix is flagged.
    otdoa_sigma_m, otdoa_nlos_xyz, otdoa_nlos_error_m, otdoa_nlos_detected, otdoa_nlos_excluded : arrays or None
        With ``otdoa_nlos`` (else None), the NLoS-aware OTDoA receiver on the first-path ToAs: each link's ToA
        standard deviation (T, S, I), metres, eq. (O1); the fixes (T, S, J, 3) and their horizontal errors (T, S, J),
        metres; bool (T, S, J), the residual test rejected the M links; bool (T, S, J, I), the links it excluded.
    otdoa_nlos_fallback : bool (T, S, J) or None
        With ``otdoa_nlos``: the weighted fit's polish moved farther than ``otdoa.MAX_POLISH_MOVE_M`` and its convex
        solution was kept (``otdoa_nlos.NlosFix.fallback``).
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
    otdoa_sigma_m: np.ndarray | None = None
    otdoa_nlos_xyz: np.ndarray | None = None
    otdoa_nlos_error_m: np.ndarray | None = None
    otdoa_nlos_detected: np.ndarray | None = None
    otdoa_nlos_excluded: np.ndarray | None = None
    otdoa_nlos_fallback: np.ndarray | None = None

    FIELDS = ("ue_xyz", "clock_bias_s", "bs_index", "los", "link_snr_db", "link_sinr_db", "est_xyz", "est_bias_s",
              "error_m", "center_xyz", "edge", "gap", "certified")
    OTDOA_FIELDS = ("otdoa_toa_s", "otdoa_xyz", "otdoa_error_m", "otdoa_ok")
    OTDOA_NLOS_FIELDS = ("otdoa_sigma_m", "otdoa_nlos_xyz", "otdoa_nlos_error_m", "otdoa_nlos_detected",
                         "otdoa_nlos_excluded", "otdoa_nlos_fallback")

    def rmse_m(self) -> np.ndarray:
        """RMSE of the horizontal error over trials.

        Returns
        -------
        float (S, J)
            Metres.
        """
        return np.sqrt(np.mean(self.error_m**2, axis=0))

    def otdoa_rmse_m(self, detector: str) -> np.ndarray:
        """RMSE of the OTDoA fixes of ``detector`` over trials.

        Parameters
        ----------
        detector : str
            One of ``OTDOA_DETECTORS``.

        Returns
        -------
        float (S, J)
            Metres.

        Raises
        ------
        ValueError
            When the experiment ran no OTDoA baseline.
        """
        if self.otdoa_error_m is None:
            raise ValueError(f"experiment {self.experiment.run.name!r} ran no OTDoA baseline (otdoa=False)")
        k = OTDOA_DETECTORS.index(detector)
        return np.sqrt(np.mean(self.otdoa_error_m[:, :, k] ** 2, axis=0))

    def los_share(self, m: int | None = None) -> float:
        """Fraction of LoS links among the m nearest over all trials.

        Parameters
        ----------
        m : int or None
            Links counted, nearest first; None: all simulated links.

        Returns
        -------
        float
            The fraction, 0 to 1.
        """
        return float(np.mean(self.los if m is None else self.los[:, :m]))

    def table(self) -> list[dict]:
        """The per-trial table: one row per (trial, SNR, M), every cell one value (``COLUMNS`` says what each holds).

        Returns
        -------
        list of dict
            The rows, in the order of ``COLUMNS`` (the OTDoA columns only with ``otdoa``), then the per-link
            columns ``link<k>_los``, ``link<k>_snr_db``, ``link<k>_sinr_db`` of the k-th nearest BS, k = 1 … max M.
        """
        e = self.experiment
        snrs = e.links.snrs_db if e.links.snr_mode != "link_budget" else ("link_budget",)
        n_links = max(e.receiver.m_values)
        rows = []
        for t in range(self.error_m.shape[0]):
            for s, snr in enumerate(snrs):
                links = {}
                for k in range(n_links):
                    links |= {f"link{k + 1}_los": int(self.los[t, k]),
                              f"link{k + 1}_snr_db": round(float(self.link_snr_db[t, s, k]), 2),
                              f"link{k + 1}_sinr_db": round(float(self.link_sinr_db[t, s, k]), 2)}
                for j, m in enumerate(e.receiver.m_values):
                    row = {"trial": t, "snr_db": snr, "m": m, "error_m": float(self.error_m[t, s, j]),
                           "est_x_m": float(self.est_xyz[t, s, j, 0]), "est_y_m": float(self.est_xyz[t, s, j, 1]),
                           "true_x_m": float(self.ue_xyz[t, 0]), "true_y_m": float(self.ue_xyz[t, 1]),
                           "n_los": int(self.los[t, :m].sum()), "edge": bool(self.edge[t, s, j]),
                           "certified": bool(self.certified[t, s, j])}
                    if self.otdoa_error_m is not None:
                        for d, name in enumerate(OTDOA_DETECTORS):
                            row |= {f"otdoa_{name}_error_m": float(self.otdoa_error_m[t, s, d, j]),
                                    f"otdoa_{name}_ok": bool(self.otdoa_ok[t, s, d, j])}
                    rows.append(row | links)
        return rows

    def config(self) -> dict:
        """The experiment's settings as JSON values, which every results file records.

        Returns
        -------
        dict
            ``Experiment.to_dict``: the seed, trials, scenario, links and receiver.
        """
        return json.loads(json.dumps(self.experiment.to_dict(), default=str))

    def write_csv(self, path) -> None:
        """Write ``table`` as CSV: a header line, then one row per (trial, SNR, M); any CSV reader reads it as it is.

        Parameters
        ----------
        path : str or os.PathLike
            The file written.
        """
        rows = self.table()
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)

    def write_provenance(self, path, commit: str | None) -> None:
        """Write what produced the table, as JSON: the experiment, the code and libraries, and what each column holds.

        Parameters
        ----------
        path : str or os.PathLike
            The file written (``dpe5g run`` puts it beside its CSV, with .json in place of .csv): an object with
            "experiment" (``config``), "provenance" (the config key, ``commit``, the dpe5g and numerical libraries'
            versions) and "columns" ({column: what it holds}).
        commit : str or None
            The commit of the code that computed the results (``store.git_commit``); None outside git.
        """

        columns = list(self.table()[0])
        doc = {"experiment": self.config(),
               "provenance": {"config_key": self.experiment.config_key(), "commit": commit,
                              "dpe5g": __version__, "libraries": numerics()},
               "columns": {c: column_note(c) for c in columns}}
        Path(path).write_text(json.dumps(doc, indent=1) + "\n")


#: what each column of ``Results.table`` holds (the per-link ones by ``column_note``)
COLUMNS = {
    "trial": "trial index t (its draws depend only on the seed and t)",
    "snr_db": "per-sample SNR of every link, dB; 'link_budget' where each link's SNR comes from the path loss",
    "m": "number M of nearest BSs the fix used",
    "error_m": "horizontal error of the DPE fix, metres",
    "est_x_m": "the fix's x, metres", "est_y_m": "the fix's y, metres",
    "true_x_m": "the UE's true x, metres", "true_y_m": "the UE's true y, metres",
    "n_los": "number of LoS links among the M used",
    "edge": "the fix lies on its search window's boundary (flagged)",
    "certified": "the certified search proved the fix the window's maximum (False for the grid search)",
    "otdoa_first_path_error_m": "horizontal error of the OTDoA fix with the first-path ToA, metres",
    "otdoa_first_path_ok": "that OTDoA fix is not flagged",
    "otdoa_peak_error_m": "horizontal error of the OTDoA fix with the strongest-peak ToA, metres",
    "otdoa_peak_ok": "that OTDoA fix is not flagged",
}


def column_note(column: str) -> str:
    """What a column of ``Results.table`` holds.

    Parameters
    ----------
    column : str
        A key of ``COLUMNS``, or a per-link column ``link<k>_los``, ``link<k>_snr_db`` or ``link<k>_sinr_db``.

    Returns
    -------
    str
        One sentence, with the unit.
    """
    if column in COLUMNS:
        return COLUMNS[column]
    k, _, what = column.removeprefix("link").partition("_")
    notes = {"los": "1 if the link is LoS, else 0",
             "snr_db": "per-sample SNR of the link, dB",
             "sinr_db": "per-sample SINR of the link (co-channel interference of PRS reuse and noise), dB"}
    if not k.isdigit() or what not in notes:
        raise ValueError(f"column must be one of {', '.join(COLUMNS)} or link<k>_los/_snr_db/_sinr_db; got {column!r}")
    return f"link {k} (the {k}-th nearest BS): {notes[what]}"


def quantiles(err) -> np.ndarray:
    """The 50, 90 and 99 % points of errors.

    Parameters
    ----------
    err : float (T,)
        Errors, metres.

    Returns
    -------
    float (3,)
        Metres.
    """
    return np.quantile(err, [0.5, 0.9, 0.99])


def error_summary(err, edge=None, certified=None) -> dict:
    """RMSE, median, 90 % and 99 % errors, and the shares of fixes flagged on the window's edge and certified.

    Parameters
    ----------
    err : float (T,)
        Horizontal errors, metres.
    edge, certified : bool (T,) or None
        Each fix is on the window's edge / certified; None: that share is left out.

    Returns
    -------
    dict
        {"rmse_m", "median_m", "p90_m", "p99_m": metres; "edge_share", "certified_share": fractions, when given}.
    """
    err = np.asarray(err, dtype=float)
    out = {"rmse_m": float(np.sqrt(np.mean(err**2))), "median_m": float(np.median(err)),
           "p90_m": float(np.quantile(err, 0.9)), "p99_m": float(np.quantile(err, 0.99))}
    if edge is not None:
        out["edge_share"] = float(np.mean(edge))
    if certified is not None:
        out["certified_share"] = float(np.mean(certified))
    return out


def error_stats(res: Results) -> dict:
    """The error statistics of ``res`` per (SNR, M) over trials.

    Parameters
    ----------
    res : Results
        The results.

    Returns
    -------
    dict
        (S, J) each: "rmse_m", "median_m", "p90_m", "p99_m" and "rmse_unflagged_m" (the RMSE without the edge-flagged
        fixes), metres; "edge_share" and "certified_share", the shares of fixes on the window's edge and certified.
    """
    err, edge = res.error_m, res.edge
    kept = np.where(edge, np.nan, err)
    return {"rmse_m": res.rmse_m(), "median_m": np.median(err, axis=0), "p90_m": np.quantile(err, 0.9, axis=0),
            "p99_m": np.quantile(err, 0.99, axis=0), "rmse_unflagged_m": np.sqrt(np.nanmean(kept**2, axis=0)),
            "edge_share": edge.mean(axis=0), "certified_share": res.certified.mean(axis=0)}
