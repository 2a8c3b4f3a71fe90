"""Tables of results for people: claim tables, the readings' verdict counts, a run's summary and a chapter's provenance.

The claim tables give each claim's interval and verdict (Markdown, for the book), the verdict counts serve the book
and README, the run summary is text for ``dpe5g run``.  The numbers come from ``results``, ``readings`` and the
figures' payloads.
"""

from __future__ import annotations

import os
import random
from dataclasses import dataclass

import numpy as np

from ..simulation import verify
from ..simulation.experiment import OTDOA_DETECTORS
from ..simulation.results import Results
from ..simulation.store import stored
from ..studies import readings
from ..studies.intervals import quantile_difference
from . import result_plots


#: the fewest trials on which ``run_summary`` gives a paired comparison a verdict: a bootstrap interval of fewer
#: resamples nothing (of one trial it is that trial's value)
MIN_PAIRED_TRIALS = 10


def run_summary(res: Results) -> str:
    """A run's summary as text: the study in one line, each receiver's errors, and each OTDoA receiver against the DPE
    on the same trials.

    Per receiver (``receiver_errors``), per SNR (rows) and M (columns): the median, 90 % point and RMSE of the
    horizontal error, metres.  Where an OTDoA receiver ran, the DPE's median and 90 % point less its, per (SNR, M),
    with the 95 % paired interval (``intervals.quantile_difference``) and its verdict: "DPE better" or "OTDoA better"
    where the interval excludes 0, else "unresolved" (none below ``MIN_PAIRED_TRIALS`` trials).  For the honest centrings, the edge-flag and certified shares.

    Parameters
    ----------
    res : Results
        The run's results.

    Returns
    -------
    str
        The summary, lines joined by newlines.
    """
    e = res.experiment
    prior = f" (σ = {e.receiver.prior_scale_m:g} m)" if e.receiver.centring == "prior" else ""
    sc = e.scenario
    excess = (f", NLoS excess delay median {sc.nlos_excess_median_s * 1e9:.1f} ns, σ {sc.nlos_excess_sigma_lg:g} "
              f"decades" if sc.nlos_excess_median_s else "")
    channel = (f"the traced paths of {sc.deployment}" if sc.channel == "traced" else
               f"deployment {sc.deployment}, delay spread {sc.delay_spread_s * 1e9:g} ns, LoS {sc.los_mode}{excess}")
    lines = [f"{e.run.n_trials} trials, seed {e.run.seed}, {channel}, L = {e.receiver_search().n_taps}, "
             f"centring {e.receiver.centring}{prior}"]
    snrs = ["link budget"] if e.links.snr_mode == "link_budget" else [f"{snr:g}" for snr in e.links.snrs_db]
    head = f"{'SNR (dB)':>11} " + " ".join(f"{f'M = {m}':>22}" for m in e.receiver.m_values)
    errors = receiver_errors(res)
    for label, err in errors.items():
        lines += [f"{label}: median / 90 % / RMSE of the error (m)", head]
        lines += [f"{snr:>11} " + " ".join(f"{np.median(x):6.2f} /{np.quantile(x, 0.9):6.2f} /{np.sqrt(np.mean(x**2)):6.2f}"
                                           for x in np.moveaxis(err[:, s], 0, -1)) for s, snr in enumerate(snrs)]
    (dpe_label, dpe), *others = errors.items()
    for label, err in others:
        lines.append(f"{dpe_label} less {label} on the same trials, m (95 % paired interval):")
        for s, snr in enumerate(snrs):
            for j, m in enumerate(e.receiver.m_values):
                said = []
                for q, word in ((0.5, "median"), (0.9, "90 %")):
                    d = quantile_difference(dpe[:, s, j], err[:, s, j], q)
                    verdict = ("too few trials for a verdict" if e.run.n_trials < MIN_PAIRED_TRIALS else
                               "DPE better" if d.hi < 0 else "OTDoA better" if d.lo > 0 else "unresolved")
                    said.append(f"{word} {d.value:+.2f} [{d.lo:+.2f}, {d.hi:+.2f}] {verdict}")
                lines.append(f"  SNR {snr}, M = {m}: " + "; ".join(said))
    if e.receiver.centring != "truth":
        lines.append(f"DPE fixes on the window's edge (flagged): {100 * res.edge.mean():.1f} %; certified: "
                     f"{100 * res.certified.mean():.1f} % (the best point inside the search window proved found; not "
                     f"that the window holds the UE)")
    return "\n".join(lines)


def receiver_errors(res: Results) -> dict[str, np.ndarray]:
    """Each receiver's horizontal errors in a run: the DPE, and where they ran, the OTDoA fix of the receiver's ToA
    method and the NLoS-aware OTDoA.

    Parameters
    ----------
    res : Results
        The run's results.

    Returns
    -------
    dict
        Label → float (T, S, J), metres; the DPE first.
    """
    e = res.experiment
    out = {"NLoS-aware DPE" if e.receiver.dpe_nlos else "DPE": res.error_m}
    if res.otdoa_error_m is not None:
        k = OTDOA_DETECTORS.index(e.receiver.toa_method)
        out[f"OTDoA ({e.receiver.toa_method} ToA)"] = res.otdoa_error_m[:, :, k]
    if res.otdoa_nlos_error_m is not None:
        out["NLoS-aware OTDoA"] = res.otdoa_nlos_error_m
    return out


def readings_summary(p: dict) -> dict:
    """Verdict counts of a ``figure_data.readings_payload``.

    Parameters
    ----------
    p : dict
        The readings payload.

    Returns
    -------
    dict
        ``"verdicts"``: {reading: {verdict: claims}} (``readings.verdict_counts``); ``"counts"``: {reading: claims
        reproduced}; ``"n_claims"``; ``"best"``: the most claims reproduced by one reading; ``"best_readings"``: the
        readings that reproduce that many; ``"never"``: the claims no reading reproduces.
    """
    names = p["config"]["reading_order"]
    verdicts = {n: readings.verdict_counts(p["data"][n]["verdicts"].values()) for n in names}
    counts = {n: verdicts[n]["reproduces"] for n in names}
    best = max(counts.values())
    never = [c for c in p["config"]["claim_order"]
             if not any(d["verdicts"][c] == "reproduces" for d in p["data"].values())]
    return {"verdicts": verdicts, "counts": counts, "n_claims": len(p["config"]["claim_order"]), "best": best,
            "best_readings": [n for n, c in counts.items() if c == best], "never": never}


def verdict_text(counts: dict) -> str:
    """The counts of verdicts as text: "k reproduce, u unresolved, f fail".

    Parameters
    ----------
    counts : dict
        {verdict: count}, as ``readings.verdict_counts`` gives.

    Returns
    -------
    str
        The text.
    """
    return f"{counts['reproduces']} reproduce, {counts['unresolved']} unresolved, {counts['fails']} fail"


def claim_text(claim_id: str, iv) -> str:
    """A claim's value and 95 % interval as the claim tables print it: "value [lo, hi]".

    Parameters
    ----------
    claim_id : str
        The claim's id (a key of ``readings.CLAIMS``); sets the unit (``result_plots.format_claim``).
    iv : intervals.Interval
        The value and its 95 % interval.

    Returns
    -------
    str
        The text.
    """
    f = lambda v: result_plots.format_claim(claim_id, v)
    return f"{f(iv.value)} [{f(iv.lo)}, {f(iv.hi)}]"


def claims_markdown(intervals: dict, bracket: dict | None = None) -> str:
    """A claim table in Markdown, one row per claim.

    Each row: the claim and its test, the paper's value, ours with its 95 % interval (and ``bracket``'s value in
    brackets), and the verdict (the range of ``readings.CLAIMS`` against the interval).

    Parameters
    ----------
    intervals : dict
        {claim id: ``intervals.Interval``}, from ``readings.claim_intervals`` or a half of it.
    bracket : dict or None
        {claim id: ``intervals.Interval``} whose values are shown in brackets: a labelled comparison; None: none.

    Returns
    -------
    str
        The Markdown table.
    """
    verdicts = readings.claim_verdicts(intervals)
    lines = ["| claim and its test | paper | ours [95 % interval] | verdict |", "|---|---|---|---|"]
    for c, iv in intervals.items():
        extra = f" ({result_plots.format_claim(c, bracket[c].value)})" if bracket else ""
        lines.append(f"| {readings.CLAIMS[c][0]} | {readings.CLAIMS[c][1]} | {claim_text(c, iv)}{extra} | "
                     f"{result_plots.VERDICT_MARKS[verdicts[c]]} {verdicts[c]} |")
    return "\n".join(lines)


def provenance_markdown(experiments, recomputed: dict | None = None) -> str:
    """Where a chapter's Monte Carlo numbers come from, as a Markdown table.

    A row per experiment (listed once): the trials the chapter reads, the results store's entry that holds them
    (``figures/trials/<name>-<key>``: its key, trials held, the code version and commit that computed it; "computed
    in this build" when the store lacks it) and the trials recomputed in this build to check the entry.

    Parameters
    ----------
    experiments : iterable of experiment.Experiment
        The chapter's experiments.
    recomputed : dict or None
        {experiment name: trial indices} recomputed in this build (``verify.verify_sample``); None: none.

    Returns
    -------
    str
        The Markdown table.
    """

    recomputed = recomputed or {}
    lines = ["| experiment | trials read (stored) | entry key | code version | commit | recomputed in this build |",
             "|---|---|---|---|---|---|"]
    seen = set()
    for e in experiments:
        if e.run.name in seen:
            continue
        seen.add(e.run.name)
        hit = stored(e)
        if hit is None:
            lines.append(f"| {e.run.name} | {e.run.n_trials} | none: computed in this build | – | – | all |")
            continue
        c = hit.meta.get("commit") or ""
        commit = c[:7] + (" + changes" if "+" in c else "") if c else "outside git"  # (+changes, +diff.<digest>)
        again = ", ".join(f"trial {t}" for t in recomputed.get(e.run.name, [])) or "–"
        lines.append(f"| {e.run.name} | {e.run.n_trials} ({hit.n_trials}) | `{hit.meta['config_key']}` | "
                     f"`{hit.meta['code_version']}` | {commit} | {again} |")
    return "\n".join(lines)


def markdown_table(header, rows) -> str:
    """A Markdown pipe table, every cell converted with ``str()``.

    Parameters
    ----------
    header : sequence
        The column headings.
    rows : iterable of sequence
        The rows, each a list of cells.

    Returns
    -------
    str
        The Markdown table.
    """
    lines = ["| " + " | ".join(map(str, header)) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(map(str, r)) + " |" for r in rows])


@dataclass(frozen=True)
class Provenance:
    """Where a chapter's Monte Carlo numbers come from (``provenance``).

    Attributes
    ----------
    seed : int
        The sample's seed.
    recomputed : dict
        {experiment name: trials recomputed}.
    table_md : str
        The table of entries, Markdown (``provenance_markdown``).
    """

    seed: int
    recomputed: dict
    table_md: str

    @property
    def n_recomputed(self) -> int:
        """The number of trials recomputed, over every experiment."""
        return sum(len(v) for v in self.recomputed.values())


def provenance(experiments, seed: int | None = None, n_families: int = 1, n_trials: int = 1) -> Provenance:
    """Check a chapter's experiments against the store on a random sample and describe where their numbers come from.

    The sample is ``verify.verify_sample``'s: ``n_trials`` trials of every experiment in ``n_families`` of their families.

    Parameters
    ----------
    experiments : iterable of Experiment
        The chapter's experiments (those the store lacks are left out).
    seed : int or None
        The sample's seed; None: DPE5G_VERIFY_SEED if set, else a new one.
    n_families, n_trials : int
        Families sampled, and trials of each of their experiments.

    Returns
    -------
    Provenance
        The seed, the trials recomputed and the table.

    Raises
    ------
    AssertionError
        Naming every mismatch (and ``make reproduce``).
    """
    if seed is None:
        seed = int(os.environ.get("DPE5G_VERIFY_SEED") or random.SystemRandom().randrange(2**31))
    exps = [e for e in experiments if stored(e) is not None]
    found, done = verify.verify_sample(seed, exps, n_families, n_trials, log=None)
    if found:
        raise AssertionError("\n".join(map(str, found)))
    return Provenance(seed, dict(done), provenance_markdown(experiments, dict(done)))
