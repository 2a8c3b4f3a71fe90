"""The reproduction chapter's readings of the paper and its claims: each reading is a set-up the paper's text allows
(or one of the NLoS chapter's), run on the figures' seeds; each claim about Figs. 9 and 10 is tested on every reading
(``claim_values``).  ``dpe5g.figures``' "readings_table" runs them.
"""

from __future__ import annotations

import numpy as np

from . import nlos_study, paper, scenario
from .experiment import Experiment

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
    **{f"excess{m * 1e9:g}": (f"the honest receiver with an NLoS excess delay of median {m * 1e9:g} ns (the NLoS "
                              "chapter)", {"centring": "honest", "nlos_excess_median_s": m})
       for m in scenario.NLOS_EXCESS_MEDIANS_S[1:]},
}


def fig9_honest_readings(n_trials: int = paper.READING_TRIALS) -> Experiment:
    """Fig. 9's honest receiver (``paper.fig9_honest``) at the readings' SNRs (``paper.READING_SNRS_DB``) with
    ``paper.READING_TRIALS`` trials: the honest reading's Fig. 9 cells.  A trial's draws, and its noise (drawn once and
    scaled to each SNR), do not depend on the SNR list, so its first trials are Fig. 9's signals at these SNRs."""
    return paper.fig9_honest(n_trials).replace(name="fig09-honest-readings", snrs_db=paper.READING_SNRS_DB)


def experiments(name: str, n_trials: int | None = None) -> dict:
    """The experiments of reading ``name`` (``READINGS``): {"fig9": Experiment, "fig10_dpe": Experiment,
    "fig10_otdoa": Experiment holding the OTDoA fixes, "otdoa_detector": "first_path" or "peak"}; Fig. 10 is its
    stated case (two of the four nearest links LoS) except in the "nearest_los" reading.  A reading that changes
    only what the figures' own runs or the NLoS chapter's already hold reads those experiments (and their stored
    trials); the others run ``paper.READING_TRIALS`` trials of Fig. 9's set-up at ``paper.READING_SNRS_DB`` and of
    Fig. 10's, with the OTDoA baseline on the same signals.  n_trials : run every experiment with this many trials
    instead (a quick look; the book uses the defaults)."""
    if name not in READINGS:
        raise ValueError(f"reading must be one of {', '.join(READINGS)}, got {name!r}")
    kw = dict(READINGS[name][1])
    detector = kw.pop("otdoa_detector", "first_path")
    runs = honest_runs if kw.pop("centring", None) == "honest" else truth_centred_runs
    fig9, fig10_dpe, fig10_otdoa = runs(kw, n_trials)
    return {"fig9": fig9, "fig10_dpe": fig10_dpe, "fig10_otdoa": fig10_otdoa, "otdoa_detector": detector}


def honest_runs(kw: dict, n_trials: int | None) -> tuple[Experiment, Experiment, Experiment]:
    """(Fig. 9, Fig. 10 DPE, Fig. 10 OTDoA) of an honest reading with the changes ``kw``: Fig. 10 centred on the
    OTDoA fix, which holds the OTDoA fixes too.  kw : the reading's changes without the detector and the centring;
    n_trials : every experiment's trial count instead of its default."""
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
        e9 = e9.replace(name=f"{e9.run.name}-excess{excess * 1e9:g}ns", nlos_excess_median_s=excess,
                        nlos_excess_sigma_lg=nlos_study.NLOS_EXCESS_SIGMA_LG)
        return e9, e10, e10
    e10 = paper.fig10(n(paper.FIG10_TRIALS))[("two_of_four", "otdoa")]
    return fig9_honest_readings(n(paper.READING_TRIALS)), e10, e10


def truth_centred_runs(kw: dict, n_trials: int | None) -> tuple[Experiment, Experiment, Experiment]:
    """(Fig. 9, Fig. 10 DPE, Fig. 10 OTDoA) of a truth-centred reading with the changes ``kw`` (without the detector
    and the centring); n_trials : every experiment's trial count instead of its default."""
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


#: the paper's quantitative claims about Figs. 9 and 10 (Section IV, abstract), tested per reading: id → (claim with
#: its test, the paper's value).  The tests are those of the reproduction chapter's claim table, at the readings' SNRs.
CLAIMS = {
    "fig9_6m": ("Fig. 9: RMSE within 6 m at 10 dB, M = 6", "≤ 6 m"),
    "fig9_falls": ("Fig. 9: RMSE falls with SNR, M = 6 (40 dB over 10 dB below ½)", "≈ 6 m → < 1 m"),
    "fig9_submetre": ("Fig. 9: sub-metre at 40 dB with M ≥ 18 (the better M)", "< 1 m"),
    "fig9_more_hurts": ("Fig. 9: more BSs hurt at 10 dB (RMSE M = 24 over M = 6 above 1)", "> 1"),
    "fig9_saturation": ("Fig. 9: saturation 18 → 24 BSs (largest change at 25 and 40 dB within 10 %)", "≈ 0"),
    "fig10_dpe_p90": ("Fig. 10: DPE, 90 % of errors within 2 m", "2 m"),
    "fig10_dpe_p99": ("Fig. 10: DPE, 99 % of errors within 7 m", "7 m"),
    "fig10_otdoa_p90": ("Fig. 10: OTDoA 90 % point 42 m (within 20 %)", "42 m"),
    "fig10_gain": ("Fig. 10: 1 − p90(DPE) / p90(OTDoA) = 95.24 % (within 2 points)", "95.24 %"),
}


def claim_values(rmse_m, snrs_db, m_values, dpe_err_m, otdoa_err_m) -> dict:
    """Test ``CLAIMS`` on one reading's results: rmse_m (S, J) Fig. 9's RMSE at SNRs snrs_db (must hold 10, 25 and
    40 dB) and M m_values (must hold 6, 18, 24); dpe_err_m, otdoa_err_m (T,) Fig. 10's horizontal errors.
    Returns {claim id: (value, reproduced)}: metres, a ratio or a share as the claim states it."""
    snrs, ms = [float(s) for s in snrs_db], [int(m) for m in m_values]
    missing = {10.0, 25.0, 40.0} - set(snrs), {6, 18, 24} - set(ms)
    if missing[0] or missing[1]:
        raise ValueError(f"claim_values needs Fig. 9 at 10, 25, 40 dB and M = 6, 18, 24; missing SNRs "
                         f"{sorted(missing[0])}, M {sorted(missing[1])}")
    r = lambda snr, m: float(np.asarray(rmse_m)[snrs.index(snr), ms.index(m)])
    d90, d99 = (float(q) for q in np.quantile(dpe_err_m, [0.9, 0.99]))
    o90 = float(np.quantile(otdoa_err_m, 0.9))
    sat = max(abs(r(s, 24) / r(s, 18) - 1) for s in (25.0, 40.0))
    return {"fig9_6m": (r(10, 6), r(10, 6) <= 6), "fig9_falls": (r(40, 6) / r(10, 6), r(40, 6) < r(10, 6) / 2),
            "fig9_submetre": (min(r(40, 18), r(40, 24)), min(r(40, 18), r(40, 24)) < 1),
            "fig9_more_hurts": (r(10, 24) / r(10, 6), r(10, 24) > r(10, 6)),
            "fig9_saturation": (sat, sat <= 0.10),
            "fig10_dpe_p90": (d90, d90 <= 2), "fig10_dpe_p99": (d99, d99 <= 7),
            "fig10_otdoa_p90": (o90, abs(o90 - 42) <= 0.2 * 42),
            "fig10_gain": (1 - d90 / o90, abs(1 - d90 / o90 - 0.9524) <= 0.02)}
