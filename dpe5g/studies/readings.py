"""The reproduction chapter's readings of the paper, and its claims about Figs. 9 and 10 tested on each reading.

Each reading is a set-up the paper's text allows (or one of the NLoS chapter's), run on the figures' seeds; each claim
is tested on every reading (``claim_intervals``: each claim's statistic with its 95 % interval, and
``claim_verdicts``).  ``dpe5g.figures.registry``' "readings_table" runs them.
"""

from __future__ import annotations

import numpy as np

from ..simulation.experiment import Experiment
from . import intervals, nlos as nlos_study, paper

#: the readings, in the order of the table: name → (label, changes to the paper's set-up as we read it).  Set-up as
#: we read it: window centred on the truth (the paper's centring), RMS delay spread, per-sample SNR, L = 12,
#: first-path OTDoA, Fig. 10's stated case (two of the four nearest links LoS).  The last rows are the NLoS chapter's:
#: the paper's window with the certified search, Fig. 10's deterministic LoS case, and the honest receiver with each
#: median of the NLoS excess delay
READINGS = {
    "as_read": ("the paper's set-up as this book reads it", {}),
    "peak_otdoa": ("… with a strongest-peak ToA for OTDoA", {"otdoa_detector": "peak"}),
    "span": ("… with the delay spread as the first-to-last span (the paper's text)", {"delay_spread_def": "span"}),
    "total_snr": ("… with the SNR after correlation (total)", {"snr_convention": "total"}),
    "span_total": ("… with both", {"delay_spread_def": "span", "snr_convention": "total"}),
    "certified_window": ("… with the honest receiver's certified search in the paper's window (on the truth, ±10 m)",
                         {"search_method": "bnb"}),
    "nearest_los": ("… with Fig. 10's two nearest links LoS and the two farther NLoS (instead of two of the four at "
                    "random)", {"los_mode": "nearest_two_los"}),
    "honest": ("the honest receiver (window on a prior / the OTDoA fix, certified search)", {"centring": "honest"}),
    "reuse": (f"the honest receiver with Table I's PRS reuse {paper.REUSE} and co-channel interference, every link's "
              "power from the path loss", {"centring": "honest", "prs_reuse": paper.REUSE}),
    "umi": (f"the honest receiver with TR 38.901's UMi NLoS excess delay (median {nlos_study.UMI.median_s * 1e9:.1f} ns, "
            f"σ {nlos_study.UMI.sigma_lg:g} decade; the NLoS chapter)",
            {"centring": "honest", "nlos_excess_median_s": nlos_study.UMI.median_s}),
}


def fig9_honest_readings(n_trials: int = paper.READING_TRIALS) -> Experiment:
    """The honest reading's Fig. 9 cells: ``paper.fig9_honest`` at the readings' SNRs (``paper.READING_SNRS_DB``).

    A trial's draws, and its noise (drawn once and scaled to each SNR), do not depend on the SNR list, so its first
    trials are Fig. 9's signals at these SNRs.

    Parameters
    ----------
    n_trials : int
        Trials; default ``paper.READING_TRIALS``.

    Returns
    -------
    Experiment
        The experiment "fig09-honest-readings".
    """
    return paper.fig9_honest(n_trials).replace(name="fig09-honest-readings", snrs_db=paper.READING_SNRS_DB)


def experiments(name: str, n_trials: int | None = None) -> dict:
    """The experiments of reading ``name`` (``READINGS``).

    Fig. 10 is its stated case (two of the four nearest links LoS) except in the "nearest_los" reading.  A reading that
    changes only what the figures' own runs or the NLoS chapter's already hold reads those experiments (and their
    stored trials); the others run ``paper.READING_TRIALS`` trials of Fig. 9's set-up at ``paper.READING_SNRS_DB`` and
    of Fig. 10's, with the OTDoA baseline on the same signals.

    Parameters
    ----------
    name : str
        A key of ``READINGS``.
    n_trials : int or None
        Run every experiment with this many trials instead (a quick look); None (the book's): the defaults.

    Returns
    -------
    dict
        {"fig9": Experiment, "fig10_dpe": Experiment, "fig10_otdoa": Experiment holding the OTDoA fixes,
        "otdoa_detector": "first_path" or "peak"}.

    Raises
    ------
    ValueError
        When ``name`` is not a reading.
    """
    if name not in READINGS:
        raise ValueError(f"reading must be one of {', '.join(READINGS)}, got {name!r}")
    kw = dict(READINGS[name][1])
    detector = kw.pop("otdoa_detector", "first_path")
    runs = honest_runs if kw.pop("centring", None) == "honest" else truth_centred_runs
    fig9, fig10_dpe, fig10_otdoa = runs(kw, n_trials)
    return {"fig9": fig9, "fig10_dpe": fig10_dpe, "fig10_otdoa": fig10_otdoa, "otdoa_detector": detector}


def honest_runs(kw: dict, n_trials: int | None) -> tuple[Experiment, Experiment, Experiment]:
    """(Fig. 9, Fig. 10 DPE, Fig. 10 OTDoA) of an honest reading: Fig. 10 centred on the OTDoA fix, which it holds too.

    Parameters
    ----------
    kw : dict
        The reading's changes without the detector and the centring: at most one of prs_reuse and
        nlos_excess_median_s.
    n_trials : int or None
        Every experiment's trial count instead of its default; None: the defaults.

    Returns
    -------
    fig9, fig10_dpe, fig10_otdoa : Experiment
        The reading's three experiments (the last two the same experiment).

    Raises
    ------
    ValueError
        When ``kw`` sets both prs_reuse and nlos_excess_median_s (not modelled together), or anything else.
    """
    kw = dict(kw)
    n = lambda default: default if n_trials is None else n_trials
    reuse, excess = kw.pop("prs_reuse", 0), kw.pop("nlos_excess_median_s", 0.0)
    if (reuse and excess) or kw:
        raise ValueError(f"an honest reading changes prs_reuse or nlos_excess_median_s (not both: they are not "
                         f"modelled together), got prs_reuse {reuse}, nlos_excess_median_s {excess}, and {sorted(kw)}")
    if reuse:
        e10 = paper.fig10_reuse(n(paper.REUSE_FIG10_TRIALS), reuse)["two_of_four"]
        return paper.fig9_power(n(paper.READING_TRIALS), reuse), e10, e10
    if excess:
        e10 = nlos_study.fig10_nlos_excess(excess, n(nlos_study.NLOS_EXCESS_TRIALS))[("two_of_four", "otdoa")]
        e9 = fig9_honest_readings(n(paper.READING_TRIALS))
        e9 = e9.replace(name=f"{e9.run.name}-{nlos_study.excess_tag(excess)}", nlos_excess_median_s=excess,
                        nlos_excess_sigma_lg=nlos_study.NLOS_EXCESS_SIGMA_LG)
        return e9, e10, e10
    e10 = paper.fig10(n(paper.FIG10_TRIALS))[("two_of_four", "otdoa")]
    return fig9_honest_readings(n(paper.READING_TRIALS)), e10, e10


def truth_centred_runs(kw: dict, n_trials: int | None) -> tuple[Experiment, Experiment, Experiment]:
    """(Fig. 9, Fig. 10 DPE, Fig. 10 OTDoA) of a truth-centred reading with the changes ``kw``.

    Parameters
    ----------
    kw : dict
        The reading's changes without the detector and the centring.
    n_trials : int or None
        Every experiment's trial count instead of its default; None: the defaults.

    Returns
    -------
    fig9, fig10_dpe, fig10_otdoa : Experiment
        The reading's three experiments.

    Raises
    ------
    ValueError
        When ``kw`` sets los_mode or search_method and anything else.
    """
    kw = dict(kw)
    n = lambda default: default if n_trials is None else n_trials
    f10 = paper.fig10(n(paper.FIG10_TRIALS))
    los, method = kw.pop("los_mode", None), kw.pop("search_method", None)
    if (los or method) and kw:
        raise ValueError(f"a reading that sets los_mode or search_method changes nothing else, got also {sorted(kw)}")
    if los == "nearest_two_los":  # Fig. 10's LoS case only: Fig. 9 is as read
        near = nlos_study.fig10_nearest_los(n(paper.FIG10_TRIALS))
        return paper.fig9_truth(n(paper.FIG9_TRUTH_TRIALS)), near["truth"], near["otdoa"]
    if method == "bnb":  # the certified search in the truth-centred grid's window
        e10 = nlos_study.fig10_window_confound(n(paper.FIG10_TRIALS))[("two_of_four", "certified ±10 m")]
        e9 = paper.fig9_truth(n(paper.READING_TRIALS)).replace(
            name="fig09-readings-bnb10", snrs_db=paper.READING_SNRS_DB, search=nlos_study.certified_in_paper_window())
        return e9, e10, f10[("two_of_four", "otdoa")]
    truth, otdoa = f10[("two_of_four", "truth")], f10[("two_of_four", "otdoa")]
    if not kw:
        return paper.fig9_truth(n(paper.FIG9_TRUTH_TRIALS)), truth, otdoa
    tag = "-".join(str(v).replace("_", "-") for v in kw.values())
    e10 = truth.replace(name=f"fig10-two-of-four-truth-{tag}", n_trials=n(paper.READING_TRIALS), otdoa=True, **kw)
    e9 = paper.fig9_truth(n(paper.READING_TRIALS)).replace(name=f"fig09-{tag}", snrs_db=paper.READING_SNRS_DB, **kw)
    return e9, e10, e10


#: our tolerances where the paper's statement is approximate (the reproduction chapter says why each): OTDoA's
#: 90 % point is a "42-meter" read off a CDF, taken as ±``OTDOA_P90_TOLERANCE`` of it; the gain 95.24 % is
#: 1 − 2/42 from two such readings, ± ``GAIN_TOLERANCE`` (fraction); "saturation" from 18 to 24 BSs, a change of
#: the RMSE of at most ``SATURATION_TOLERANCE`` (fraction); "falls with SNR", to below ``FALLS_RATIO`` of its 10 dB
#: value at 40 dB
OTDOA_P90_TOLERANCE = 0.20
GAIN_TOLERANCE = 0.02
SATURATION_TOLERANCE = 0.10
FALLS_RATIO = 0.5
_F9, _SUB = paper.PAPER_FIG9_RMSE_M, paper.PAPER_FIG9_SUB_METRE_M
_D90, _D99, _O90 = paper.PAPER_FIG10_DPE_M[0.9], paper.PAPER_FIG10_DPE_M[0.99], paper.PAPER_FIG10_OTDOA_M[0.9]
_GAIN = paper.PAPER_FIG10_GAIN

#: the paper's quantitative claims about Figs. 9 and 10 (Section IV, abstract), tested per reading: id → (claim with
#: its test, the paper's value, the range [low, high] of our statistic that meets the claim).  The tests are those of
#: the reproduction chapter's claim table, at the readings' SNRs; the numbers are ``dpe5g.studies.paper``'s PAPER_*.
CLAIMS = {
    "fig9_6m": (f"Fig. 9: RMSE within {_F9['rmse_m']:g} m at {_F9['snr_db']:g} dB, M = {_F9['m']}",
                f"≤ {_F9['rmse_m']:g} m", (0.0, _F9["rmse_m"])),
    "fig9_falls": (f"Fig. 9: RMSE falls with SNR, M = 6 (40 dB over 10 dB below {FALLS_RATIO:g})",
                   f"≈ {_F9['rmse_m']:g} m → < {_SUB:g} m", (0.0, FALLS_RATIO)),
    "fig9_submetre": ("Fig. 9: sub-metre at 40 dB with M ≥ 18 (the better M)", f"< {_SUB:g} m", (0.0, _SUB)),
    "fig9_more_hurts": ("Fig. 9: more BSs hurt at 10 dB (RMSE M = 24 over M = 6 above 1)", "> 1", (1.0, np.inf)),
    "fig9_saturation": (f"Fig. 9: saturation 18 → 24 BSs (largest change at 25 and 40 dB within "
                        f"{100 * SATURATION_TOLERANCE:g} %)", "≈ 0", (0.0, SATURATION_TOLERANCE)),
    "fig10_dpe_p90": (f"Fig. 10: DPE, 90 % of errors within {_D90:g} m", f"{_D90:g} m", (0.0, _D90)),
    "fig10_dpe_p99": (f"Fig. 10: DPE, 99 % of errors within {_D99:g} m", f"{_D99:g} m", (0.0, _D99)),
    "fig10_otdoa_p90": (f"Fig. 10: OTDoA 90 % point {_O90:g} m (within {100 * OTDOA_P90_TOLERANCE:g} %)",
                        f"{_O90:g} m", ((1 - OTDOA_P90_TOLERANCE) * _O90, (1 + OTDOA_P90_TOLERANCE) * _O90)),
    "fig10_gain": (f"Fig. 10: 1 − p90(DPE) / p90(OTDoA) = {100 * _GAIN:.2f} % (within {100 * GAIN_TOLERANCE:g} "
                   "points)", f"{100 * _GAIN:.2f} %", (_GAIN - GAIN_TOLERANCE, _GAIN + GAIN_TOLERANCE)),
}


def fig9_claim_intervals(fig9_err_m, snrs_db, m_values, n_boot: int = 2000) -> dict:
    """The Fig. 9 claims of ``CLAIMS`` on one receiver's Fig. 9 errors, each with its 95 % bootstrap interval.

    The interval is ``intervals.paired_interval``'s, a trial resampled with all its cells.

    Parameters
    ----------
    fig9_err_m : float (T, S, J)
        Horizontal errors, metres, at the SNRs ``snrs_db`` and the M of ``m_values``.
    snrs_db : sequence of float (S,)
        The SNRs, dB; must hold 10, 25 and 40.
    m_values : sequence of int (J,)
        The numbers of links M; must hold 6, 18 and 24.
    n_boot : int
        Bootstrap draws.

    Returns
    -------
    dict
        {claim id: ``intervals.Interval``}, in metres or a ratio, as the claim states it.

    Raises
    ------
    ValueError
        When an SNR or M the claims need is missing, or ``fig9_err_m`` is not (T, S, J).
    """
    snrs, ms = [float(s) for s in snrs_db], [int(m) for m in m_values]
    missing = {10.0, 25.0, 40.0} - set(snrs), {6, 18, 24} - set(ms)
    if missing[0] or missing[1]:
        raise ValueError(f"the Fig. 9 claims need Fig. 9 at 10, 25, 40 dB and M = 6, 18, 24; missing SNRs "
                         f"{sorted(missing[0])}, M {sorted(missing[1])}")
    if np.ndim(fig9_err_m) != 3 or np.shape(fig9_err_m)[1:] != (len(snrs), len(ms)):
        raise ValueError(f"fig9_err_m must be (T, {len(snrs)}, {len(ms)}) errors for the SNRs and M given, got "
                         f"shape {np.shape(fig9_err_m)}")
    rmse = lambda a, snr, m: np.sqrt(np.mean(a[:, :, snrs.index(snr), ms.index(m)] ** 2, axis=1))  # (B,)
    stats = {"fig9_6m": lambda a: rmse(a, 10.0, 6), "fig9_falls": lambda a: rmse(a, 40.0, 6) / rmse(a, 10.0, 6),
             "fig9_submetre": lambda a: np.minimum(rmse(a, 40.0, 18), rmse(a, 40.0, 24)),
             "fig9_more_hurts": lambda a: rmse(a, 10.0, 24) / rmse(a, 10.0, 6),
             "fig9_saturation": lambda a: np.maximum(*(np.abs(rmse(a, s, 24) / rmse(a, s, 18) - 1)
                                                       for s in (25.0, 40.0)))}
    return {k: intervals.paired_interval(f, fig9_err_m, n_boot=n_boot) for k, f in stats.items()}


def fig10_claim_intervals(dpe_err_m, otdoa_err_m, n_boot: int = 2000) -> dict:
    """The Fig. 10 claims of ``CLAIMS`` on DPE's and OTDoA's errors, each with its 95 % bootstrap interval.

    Parameters
    ----------
    dpe_err_m, otdoa_err_m : float (T,)
        DPE's and OTDoA's horizontal errors, metres, on the same trials (resampled together).
    n_boot : int
        Bootstrap draws.

    Returns
    -------
    dict
        {claim id: ``intervals.Interval``}.
    """
    q = lambda a, p: np.quantile(a, p, axis=1)
    stats = {"fig10_dpe_p90": lambda d, o: q(d, 0.9), "fig10_dpe_p99": lambda d, o: q(d, 0.99),
             "fig10_otdoa_p90": lambda d, o: q(o, 0.9), "fig10_gain": lambda d, o: 1 - q(d, 0.9) / q(o, 0.9)}
    return {k: intervals.paired_interval(f, dpe_err_m, otdoa_err_m, n_boot=n_boot) for k, f in stats.items()}


def claim_intervals(fig9_err_m, snrs_db, m_values, dpe_err_m, otdoa_err_m, n_boot: int = 2000) -> dict:
    """Every claim of ``CLAIMS`` on one reading's results, in the table's order.

    ``fig9_claim_intervals`` of its Fig. 9 errors and ``fig10_claim_intervals`` of its Fig. 10 errors.

    Parameters
    ----------
    fig9_err_m : float (T, S, J)
        Fig. 9's horizontal errors, metres.
    snrs_db : sequence of float (S,)
        Fig. 9's SNRs, dB (10, 25 and 40 among them).
    m_values : sequence of int (J,)
        Fig. 9's M (6, 18 and 24 among them).
    dpe_err_m, otdoa_err_m : float (T',)
        Fig. 10's errors of DPE and OTDoA, metres, on the same trials.
    n_boot : int
        Bootstrap draws.

    Returns
    -------
    dict
        {claim id: ``intervals.Interval``}.
    """
    out = fig9_claim_intervals(fig9_err_m, snrs_db, m_values, n_boot)
    out |= fig10_claim_intervals(dpe_err_m, otdoa_err_m, n_boot)
    return {k: out[k] for k in CLAIMS}


def claim_verdicts(claim_ivs: dict) -> dict:
    """The verdict of each claim interval against the claim's range (``intervals.Interval.verdict``).

    Parameters
    ----------
    claim_ivs : dict
        {claim id: ``intervals.Interval``}: ``claim_intervals`` or either half of it.

    Returns
    -------
    dict
        {claim id: "reproduces", "unresolved" or "fails"}.
    """
    return {k: iv.verdict(*CLAIMS[k][2]) for k, iv in claim_ivs.items()}


def verdict_counts(verdicts) -> dict:
    """How many of each verdict an iterable of verdicts holds.

    Parameters
    ----------
    verdicts : iterable of str
        Verdicts of ``intervals.VERDICTS``.

    Returns
    -------
    dict
        {verdict: how many}, every verdict of ``intervals.VERDICTS`` present.
    """
    verdicts = list(verdicts)
    return {v: verdicts.count(v) for v in intervals.VERDICTS}
