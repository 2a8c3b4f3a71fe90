"""The NLoS-bias chapter's experiments (ours, beyond the paper): the figures' experiments with one setting changed.

They are Fig. 10's receivers with TR 38.901's NLoS excess delay on every NLoS link (the UMi row, and its median
swept), the honest DPE with a clock window that covers it, Fig. 10's unstated SNR swept, the optimiser and the window
of the paper's truth-centred receiver apart, the deterministic reading of Fig. 10's LoS case, and Fig. 9 with the
excess delay and with a blind window.  Each is one of ``dpe5g.studies.paper``'s figure experiments with a few settings
changed (the excess delay, the SNR offset, the search, the LoS rule or the window's centre), on the figure's seed, so
that its trials are the figure's signals with that change.
"""

from __future__ import annotations

from dataclasses import replace

from ..phy import propagation as scenario
from ..receivers import search_config
from ..simulation.experiment import Experiment
from . import paper

#: the excess delay of the paper's scenario: TR 38.901 Table 7.6.9-1's UMi street-canyon row (lg Δτ: mean −7.5,
#: σ 0.5 decade; median 31.6 ns), ``scenario.TR38901_EXCESS_DELAY``
UMI = scenario.TR38901_EXCESS_DELAY[scenario.NLOS_EXCESS_ROW]
#: σ_lg of every excess-delay run of this study: the UMi row's
NLOS_EXCESS_SIGMA_LG = UMI.sigma_lg
#: the medians at which Fig. 10's receivers run: 0 (Fig. 10 itself), the UMi row's (the headline) and, as a
#: sensitivity study with the same σ_lg, 10 ns and 100 ns
NLOS_EXCESS_MEDIANS_S = (0.0, 10e-9, UMI.median_s, 100e-9)
#: Fig. 10's own trial count, so that every comparison with and without the delay pairs all of Fig. 10's trials; the
#: NLoS chapter asserts that it resolves the paired 90 % point difference of DPE and OTDoA to ±15 % of the 90 % point
NLOS_EXCESS_TRIALS = paper.FIG10_TRIALS


def excess_tag(median_s: float) -> str:
    """The name tag of an excess-delay experiment.

    Parameters
    ----------
    median_s : float
        The median of the excess delay, seconds.

    Returns
    -------
    str
        "umi" for the UMi row's median, else "excess{ns}ns" (the median in ns).
    """
    return "umi" if median_s == UMI.median_s else f"excess{median_s * 1e9:g}ns"


def fig10_nlos_excess(median_s: float, n_trials: int = NLOS_EXCESS_TRIALS) -> dict:
    """``fig10``'s experiments with every NLoS link's paths late by a log-normal excess delay Δτ.

    Δτ has median ``median_s`` and the UMi row's σ_lg (``scenario.nlos_excess_delay``, drawn per link); the receivers do
    not know it.

    Parameters
    ----------
    median_s : float
        The median of Δτ, seconds; 0 gives Fig. 10's own experiments (``paper.fig10``).
    n_trials : int
        Trials of each experiment (their first ``n_trials``); default Fig. 10's own count.

    Returns
    -------
    dict
        {(case, centring): Experiment}, as ``paper.fig10``.
    """
    if median_s == 0:
        return paper.fig10(n_trials)
    return {k: e.replace(name=f"{e.run.name}-{excess_tag(median_s)}", nlos_excess_median_s=median_s,
                         nlos_excess_sigma_lg=NLOS_EXCESS_SIGMA_LG) for k, e in paper.fig10(n_trials).items()}


def fig10_clock_nlos(n_trials: int = NLOS_EXCESS_TRIALS) -> dict:
    """The honest DPE on Fig. 10's OTDoA fix under the UMi excess delay, with a clock window that covers that delay.

    The clock window is clock_window "clock_nlos" (± 3 σ c + the 99th percentile of c Δτ) instead of the clock model's
    ± 3 σ c: the same trials as ``fig10_nlos_excess(UMI.median_s)``, only the window differs.

    Parameters
    ----------
    n_trials : int
        Trials of each experiment; default Fig. 10's own count.

    Returns
    -------
    dict
        {case: Experiment}, the cases of ``paper.FIG10_CASES``.
    """
    ex = fig10_nlos_excess(UMI.median_s, n_trials)
    return {case: ex[(case, "otdoa")].replace(name=f"{ex[(case, 'otdoa')].run.name}-clock-nlos",
                                              clock_window="clock_nlos") for case in paper.FIG10_CASES}


#: Fig. 10's unstated SNR, swept: every link's link-budget SNR offset by these dB (0: Fig. 10; −36 dB is about the
#: correlation gain 10 log10 N, the "total SNR" reading), the paper's stated case, FIG10_SWEEP_TRIALS trials each
FIG10_SNR_OFFSETS_DB = (0.0, -6.0, -12.0, -18.0, -24.0, -30.0, -36.0)
FIG10_SWEEP_TRIALS = 1000
#: the medians of the NLoS excess delay at which Fig. 9's receivers are run (σ_lg the UMi row's): the UMi row's
#: and 100 ns
FIG9_EXCESS_MEDIANS_S = (UMI.median_s, 100e-9)


def fig10_snr_offset(offset_db: float, n_trials: int = FIG10_SWEEP_TRIALS) -> dict:
    """Fig. 10's paper's case (two of the four nearest links LoS) with every link's SNR offset by ``offset_db``.

    Parameters
    ----------
    offset_db : float
        The offset of every link's link-budget SNR, dB; 0 gives Fig. 10's own experiments.
    n_trials : int
        Trials of each experiment; default ``FIG10_SWEEP_TRIALS``.

    Returns
    -------
    dict
        {centring: Experiment}, the centrings of ``paper.FIG10_CENTRINGS`` ("otdoa" also holds both OTDoA detectors'
        fixes).
    """
    f10 = paper.fig10(n_trials)
    out = {cen: f10[("two_of_four", cen)] for cen in paper.FIG10_CENTRINGS}
    if offset_db == 0:
        return out
    return {cen: e.replace(name=f"{e.run.name}-snr{offset_db:+g}db", snr_offset_db=offset_db) for cen, e in out.items()}


def certified_in_paper_window() -> search_config.SearchConfig:
    """The honest receiver's certified search (``paper.honest_search``) inside the paper's window.

    The window is the default grid search's half-widths (±10 m in position, its clock-bias window), for a receiver
    centred on the truth as the paper's is, so that only the optimiser differs from the paper's set-up.

    Returns
    -------
    search_config.SearchConfig
        The certified search with the paper's half-widths.
    """
    grid = paper.fig10()[("two_of_four", "truth")].receiver.search
    return replace(paper.honest_search(), half_width_m=grid.half_width_m, bias_half_width_m=grid.bias_half_width_m)


def fig10_window_confound(n_trials: int = paper.FIG10_TRIALS) -> dict:
    """The optimiser and the window apart, on Fig. 10's trials.

    Two variants per case, both centred on the truth: "certified ±10 m", the certified search inside the paper's
    truth-centred window (±10 m, the clock window of the truth-centred grid), and "certified ±30 m", the certified
    search inside the honest receivers' ±30 m window.  The grid in the ±10 m window is Fig. 10's "truth" experiment.

    Parameters
    ----------
    n_trials : int
        Trials of each experiment; default Fig. 10's own count.

    Returns
    -------
    dict
        {(case, variant): Experiment}.
    """
    out, f10 = {}, paper.fig10(n_trials)
    for case in paper.FIG10_CASES:
        truth = f10[(case, "truth")]
        for variant, search in (("certified ±10 m", certified_in_paper_window()),
                                ("certified ±30 m", paper.honest_search())):
            tag = "bnb10" if variant.endswith("10 m") else "bnb30"
            out[(case, variant)] = truth.replace(name=f"{truth.run.name}-{tag}", search=search)
    return out


def fig10_nearest_los(n_trials: int = paper.FIG10_TRIALS) -> dict:
    """Fig. 10 with the deterministic reading of its case: the two nearest links LoS, the next two NLoS.

    Of the four nearest links, the two nearest are LoS and the two farther NLoS (los_mode "nearest_two_los"); the
    same seed, and so the same UEs, as Fig. 10.

    Parameters
    ----------
    n_trials : int
        Trials of each experiment; default Fig. 10's own count.

    Returns
    -------
    dict
        {centring: Experiment}.
    """
    return {cen: e.replace(name=e.run.name.replace("two-of-four", "nearest-two-los"), los_mode="nearest_two_los")
            for (case, cen), e in paper.fig10(n_trials).items() if case == "two_of_four"}


def fig9_excess(median_s: float, n_trials: int = paper.FIG9_HONEST_TRIALS) -> Experiment:
    """Fig. 9's honest receiver (``paper.fig9_honest``) with every NLoS link's paths late by an excess delay Δτ.

    Δτ has median ``median_s`` and σ_lg ``NLOS_EXCESS_SIGMA_LG``; the trials are the same otherwise, with the OTDoA
    fixes of both detectors on the same signals.

    Parameters
    ----------
    median_s : float
        The median of Δτ, seconds.
    n_trials : int
        Trials; default ``paper.FIG9_HONEST_TRIALS``.

    Returns
    -------
    Experiment
        The experiment, named "fig09-honest-" + ``excess_tag(median_s)``.
    """
    return paper.fig9_honest(n_trials).replace(name=f"fig09-honest-{excess_tag(median_s)}", otdoa=True,
                                               nlos_excess_median_s=median_s, nlos_excess_sigma_lg=NLOS_EXCESS_SIGMA_LG)


def fig9_truth_excess(n_trials: int = paper.FIG9_TRUTH_TRIALS) -> Experiment:
    """Fig. 9 in the paper's truth-centred set-up (``paper.fig9_truth``, a labelled comparison), UMi excess delay added.

    Parameters
    ----------
    n_trials : int
        Trials; default ``paper.FIG9_TRUTH_TRIALS``.

    Returns
    -------
    Experiment
        The same trials as ``paper.fig9_truth`` otherwise.
    """
    return paper.fig9_truth(n_trials).replace(name="fig09-umi", nlos_excess_median_s=UMI.median_s,
                                              nlos_excess_sigma_lg=NLOS_EXCESS_SIGMA_LG)


def fig9_blind(n_trials: int = paper.FIG9_HONEST_TRIALS) -> Experiment:
    """Fig. 9 blind: the honest receiver's certified search in the ±30 m window centred on each trial's OTDoA fix.

    The OTDoA fix is the first-path detector's on the M nearest links; the window is centred on it instead of on the
    prior.

    Parameters
    ----------
    n_trials : int
        Trials; default ``paper.FIG9_HONEST_TRIALS``.

    Returns
    -------
    Experiment
        The same trials as ``paper.fig9_honest``.
    """
    return paper.fig9_honest(n_trials).replace(name="fig09-blind", centring="otdoa", otdoa=True)


def fig9_blind_readings(n_trials: int = paper.READING_TRIALS) -> Experiment:
    """``fig9_blind`` at the readings' SNRs (``paper.READING_SNRS_DB``).

    The blind receiver beside the honest reading's Fig. 9 (``readings.fig9_honest_readings``, the same trials), with
    enough trials to count the rare fixes that the blind window misses.

    Parameters
    ----------
    n_trials : int
        Trials; default ``paper.READING_TRIALS``.

    Returns
    -------
    Experiment
        The experiment "fig09-blind-readings".
    """
    return fig9_blind(n_trials).replace(name="fig09-blind-readings", snrs_db=paper.READING_SNRS_DB)


def nlos_otdoa() -> dict:
    """The NLoS-aware OTDoA receiver (``otdoa_nlos``) beside the naive one on the UMi trials.

    Fig. 10's experiments centred on OTDoA (``fig10_nlos_excess`` at the UMi median; the 4 nearest BSs: the residual
    test can detect, not exclude) and Fig. 9's honest one (``fig9_excess``; M = 6 to 24: it can exclude), each with
    ``otdoa_nlos`` set: the same trials, and the same DPE and naive OTDoA fixes.

    Returns
    -------
    dict
        {"fig10-" + case: Experiment for each case of ``paper.FIG10_CASES``, "fig9": Experiment}, named as their
        source experiments with "-nlos-otdoa" added.
    """
    out = {f"fig10-{case}": e.replace(name=f"{e.run.name}-nlos-otdoa", otdoa_nlos=True)
           for (case, centring), e in fig10_nlos_excess(UMI.median_s).items() if centring == "otdoa"}
    e9 = fig9_excess(UMI.median_s)
    return out | {"fig9": e9.replace(name=f"{e9.run.name}-nlos-otdoa", otdoa_nlos=True)}


#: the SNRs of Fig. 9 at which the NLoS-aware DPE runs (the NLoS-aware OTDoA's comparison reads 20 dB)
NLOS_DPE_FIG9_SNRS_DB = (20.0,)


def nlos_dpe() -> dict:
    """The NLoS-aware DPE (``dpe_nlos``, eq. (D1)) beside the naive one in the same window, on the UMi trials.

    Fig. 10's honest DPE on the OTDoA fix with the clock window that covers the delay (``fig10_clock_nlos``, whose
    naive DPE is the comparison), and Fig. 9's honest one (``fig9_excess``) with that clock window, naive and aware:
    the same trials as every other UMi experiment of the chapter, so that the NLoS-aware OTDoA (``nlos_otdoa``) pairs
    with them by trial.

    Returns
    -------
    dict
        {"fig10-" + case: the aware DPE for each case of ``paper.FIG10_CASES``, "fig9-naive": Fig. 9's naive DPE in the
        wide clock window, "fig9": its aware DPE}; the aware ones named as their source with "-nlos-dpe" for "-clock-nlos".
    """
    out = {f"fig10-{case}": e.replace(name=e.run.name.replace("-clock-nlos", "-nlos-dpe"), dpe_nlos=True)
           for case, e in fig10_clock_nlos().items()}
    e9 = fig9_excess(UMI.median_s)
    naive9 = e9.replace(name=f"{e9.run.name}-clock-nlos", clock_window="clock_nlos", snrs_db=NLOS_DPE_FIG9_SNRS_DB)
    return out | {"fig9-naive": naive9, "fig9": naive9.replace(name=f"{e9.run.name}-nlos-dpe", dpe_nlos=True)}


def all_experiments() -> list[Experiment]:
    """Every experiment of the NLoS-bias chapter, at the trial counts it reads.

    Returns
    -------
    list of Experiment
        The experiments, in the order the chapter reads them.
    """
    out = []
    for median in NLOS_EXCESS_MEDIANS_S[1:]:
        out += list(fig10_nlos_excess(median).values())
    out += list(fig10_clock_nlos().values())
    for offset in FIG10_SNR_OFFSETS_DB[1:]:
        out += list(fig10_snr_offset(offset).values())
    out += list(fig10_window_confound().values()) + list(fig10_nearest_los().values())
    out += [fig9_excess(m) for m in FIG9_EXCESS_MEDIANS_S] + [fig9_truth_excess(), fig9_blind(), fig9_blind_readings()]
    return out + list(nlos_otdoa().values()) + list(nlos_dpe().values())
