"""The studies behind the receiver's choices: the window L on the DPE chapter's ring (``ring_window_table``) and again
on the urban scenario (``urban_window_table``, ``choose_window``), the plateau of eq. (10) for one link
(``plateau_payload``), and where each fix places each link's ToA (``range_offsets_m``).  Their experiments are
defined in ``dpe5g.studies.paper`` and run by the engine like every other.
"""

from __future__ import annotations

import jax
import numpy as np

from ..phy import channel, nr, signal
from ..phy.nr import C
from ..receivers import correlogram, toa_fit
from ..receivers.otdoa import POSITION_ATOL_M as OTDOA_POSITION_ATOL_M  # (a function here names its result otdoa)
from ..simulation import engine, results
from ..simulation.experiment import OTDOA_DETECTORS
from . import intervals, nlos as nlos_study, paper


def ring_window_table(experiments: dict, progress: bool = False) -> list[dict]:
    """Run (or load) ``paper.ring_window_experiments`` and score each window L.

    The scores are the horizontal error's RMSE, median, 90 % and 99 % points, and the RMSE of the fixes' clock bias
    c (δt̂ − δt) in metres.

    Parameters
    ----------
    experiments : dict
        {L: experiment}, the same trials for every L.
    progress : bool
        Show the engine's progress.

    Returns
    -------
    list of dict
        One row per L: "n_taps", the error summary (``results.error_summary``, metres) and "bias_rmse_m".
    """
    rows = []
    for n_taps, e in experiments.items():
        res = engine.run(e, progress=progress)
        bias_m = (res.est_bias_s[:, 0, 0] - res.clock_bias_s) * C
        rows.append({"n_taps": int(n_taps), **results.error_summary(res.error_m[:, 0, 0]),
                     "bias_rmse_m": float(np.sqrt(np.mean(bias_m**2)))})
    return rows


# ---------------------------------------------------------------------------------------------------------------
# The plateau of eq. (10) for one link, and the receiver window L re-selected on the urban scenario.

PLATEAU_TAPS = (1, 4, 12)
PLATEAU_UPSAMPLE = 8
PLATEAU_CIR_SAMPLES = 40


def plateau_payload(seed: int = 5, delay_spread_s: float = 65e-9, k_factor_db: float = 13.3,
                    span_m: tuple[float, float] = (-40.0, 15.0)) -> dict:
    """One BS term of eq. (10), ``‖S_m(τ)^H y_m‖²``, against the candidate ToA for a LoS and an NLoS link.

    The links are TDL-D (LoS) and TDL-C (NLoS), noise-free, for the windows L of ``PLATEAU_TAPS``.  Each link is one
    draw of its profile's tap gains (key ``fold_in(PRNGKey(seed), i)``, i = 0 TDL-D, 1 TDL-C) at the given RMS delay
    spread; its first path arrives at τ₀ = 0.

    Parameters
    ----------
    seed : int
        The seed of the tap gains.
    delay_spread_s : float
        The RMS delay spread, seconds.
    k_factor_db : float
        TDL-D's K-factor, dB.
    span_m : (float, float)
        The range of candidate offsets c (τ − τ₀) shown, metres.

    Returns
    -------
    dict
        "config" (seed, delay spread, K-factor, ``PLATEAU_TAPS``, ``PLATEAU_UPSAMPLE``, the sample in metres) and
        "data": offset_m (K,) the candidate c (τ − τ₀) in metres over ``span_m``; per profile and L the cost normalised
        to its maximum over the whole correlogram, and the realised CIR power ``|h[n]|²`` on the first
        ``PLATEAU_CIR_SAMPLES`` samples (normalised).
    """
    num = nr.PAPER
    prs = nr.prs_matrix([1])
    ts = num.sample_period_s
    j = np.arange(num.n_fft * PLATEAU_UPSAMPLE)
    off = np.where(j < j.size // 2, j, j - j.size) * ts / PLATEAU_UPSAMPLE * C  # periodic: negative offsets wrap
    keep = (off >= span_m[0]) & (off <= span_m[1])
    order = np.argsort(off[keep])
    data = {"offset_m": off[keep][order]}
    for i, (name, k_db) in enumerate((("D", k_factor_db), ("C", None))):
        prof = channel.tdl_profile(name, delay_spread_s, k_db)
        g = channel.draw_gains(prof, jax.random.fold_in(jax.random.PRNGKey(seed), i))[None]
        y = signal.received_noiseless(prs, g, prof.delays_s[None], np.zeros(1))
        cir = np.abs(np.asarray(channel.sampled_cir(g[0], prof.delays_s))[:PLATEAU_CIR_SAMPLES]) ** 2
        cost = {}
        for n in PLATEAU_TAPS:
            c = np.asarray(correlogram.correlogram(y, prs, n, PLATEAU_UPSAMPLE))[0]
            cost[str(n)] = c[keep][order] / c.max()
        data[f"TDL-{name}"] = {"cost": cost, "cir_offset_m": np.arange(cir.size) * ts * C,
                               "cir_power": cir / cir.max()}
    return {"config": {"seed": seed, "delay_spread_s": delay_spread_s, "k_factor_db": k_factor_db,
                       "taps": PLATEAU_TAPS, "upsample": PLATEAU_UPSAMPLE, "sample_m": ts * C}, "data": data}


def urban_window_table(experiments: dict, progress: bool = False) -> list[dict]:
    """Run (or load) ``paper.urban_window_experiments`` and score every (set-up, M, L).

    The scores are the RMSE, median, 90 % error, edge and certified shares, and the median certified gap (how far,
    relative, the window's maximum can lie above the fix's cost).

    Parameters
    ----------
    experiments : dict
        {(set-up name, L): experiment}.
    progress : bool
        Show the engine's progress.

    Returns
    -------
    list of dict
        One row per (set-up, M, L), with ``rmse_rel``: the RMSE over the smallest RMSE of the same (set-up, M) column.
    """

    rows = []
    for (name, n), e in experiments.items():
        res = engine.run(e, progress=progress)
        for j, m in enumerate(e.receiver.m_values):
            err = res.error_m[:, 0, j]
            rows.append({"setup": name, "m": m, "n_taps": n, "n_trials": e.run.n_trials, **results.error_summary(err, res.edge[:, 0, j], res.certified[:, 0, j]),
                         "gap_median": float(np.median(res.gap[:, 0, j]))})
    for r in rows:
        best = min(o["rmse_m"] for o in rows if (o["setup"], o["m"]) == (r["setup"], r["m"]))
        r["rmse_rel"] = r["rmse_m"] / best
    return rows


def choose_window(rows: list[dict]) -> int:
    """The rule fixed before the study ran: the L with the smallest mean of ``rmse_rel`` over all (set-up, M) columns.

    That is, the window that is closest to the best in every set-up at once.

    Parameters
    ----------
    rows : list of dict
        ``urban_window_table``'s rows.

    Returns
    -------
    int
        The chosen L.
    """
    taps = sorted({r["n_taps"] for r in rows})
    score = {n: np.mean([r["rmse_rel"] for r in rows if r["n_taps"] == n]) for n in taps}
    return min(taps, key=lambda n: score[n])


def range_offsets_m(res) -> np.ndarray:
    """c·(τ_m(fix) − τ_m(truth)) for every link: the ToA each fix assigns to a link minus the true one.

    The fix's ToA includes its clock bias.  A positive offset means the fix places the link's window start after its
    first path.

    Parameters
    ----------
    res : results.Results
        The run.

    Returns
    -------
    numpy.ndarray, float (T, S, J, I)
        The offsets, metres; links beyond the J-th M are NaN.
    """
    bs = res.experiment.load_deployment().bs_xyz[res.bs_index]  # (T, I, 3)
    true = np.linalg.norm(res.ue_xyz[:, None, :] - bs, axis=-1) + C * res.clock_bias_s[:, None]  # (T, I)
    est = (np.linalg.norm(res.est_xyz[..., None, :] - bs[:, None, None], axis=-1)
           + C * res.est_bias_s[..., None])  # (T, S, J, I)
    out = est - true[:, None, None, :]
    used = np.arange(bs.shape[1])[None, :] < np.asarray(res.experiment.receiver.m_values)[:, None]  # (J, I)
    return np.where(used[None, None], out, np.nan)


#: the receivers of a Fig. 10 row of ``fig10_rows``: DPE by centring, OTDoA by detector
FIG10_RECEIVERS = ("dpe_otdoa", "dpe_prior", "dpe_truth", "otdoa_first_path", "otdoa_peak")


def fig10_errors(by_centring: dict) -> dict:
    """The per-trial errors of each receiver of Fig. 10-like experiments on the same trials, run or loaded.

    Parameters
    ----------
    by_centring : dict
        {centring: Experiment}, the "otdoa" one holding both OTDoA detectors' fixes.

    Returns
    -------
    dict
        {receiver of ``FIG10_RECEIVERS``: (error (T,) m, DPE's window-edge flags (T,) or None for OTDoA)}.
    """
    out = {}
    for cen, e in by_centring.items():
        res = engine.run(e)
        out[f"dpe_{cen}"] = (res.error_m[:, 0, 0], res.edge[:, 0, 0])
        if e.receiver.otdoa:
            out |= {f"otdoa_{det}": (res.otdoa_error_m[:, 0, k, 0], None) for k, det in enumerate(OTDOA_DETECTORS)}
    return out


def fig10_rows(experiments: dict, n_boot: int = 1000) -> list[dict]:
    """One row per (key, receiver) of Fig. 10-like experiments (``fig10_errors``).

    Parameters
    ----------
    experiments : dict
        {key: {centring: Experiment}}.
    n_boot : int
        Bootstrap resamples.

    Returns
    -------
    list of dict
        The key, the receiver, its 50 / 90 / 99 % errors (m), the 95 % bootstrap interval of its 90 % error
        (``intervals.bootstrap_interval``) and, for DPE, the share of fixes on the window's edge.
    """
    rows = []
    for key, by_centring in experiments.items():
        for rx, (err, edge) in fig10_errors(by_centring).items():
            p50, p90, p99 = results.quantiles(err)
            lo, hi = intervals.bootstrap_interval(err, n_boot=n_boot)
            rows.append({"key": key, "receiver": rx, "n_trials": int(err.size), "p50_m": p50, "p90_m": p90,
                         "p99_m": p99, "p90_lo_m": lo, "p90_hi_m": hi,
                         "edge_share": None if edge is None else float(np.mean(edge))})
    return rows


def clock_edge(res, tol_m: float = 0.1) -> np.ndarray:
    """Whether each DPE fix's clock bias lies within ``tol_m`` of its search window's c δt boundary.

    The boundary is ± bias_half_width_m (``Experiment.receiver_search``) around 0 for a receiver not centred on the
    truth, around the true bias for one centred on it: the flagged fixes are those whose clock estimate the window
    stopped.

    Parameters
    ----------
    res : results.Results
        The run.
    tol_m : float
        The tolerance, metres.

    Returns
    -------
    numpy.ndarray, bool (T, S, J)
        The flags.
    """
    e = res.experiment
    half_b = e.receiver_search().bias_half_width_m
    centre = res.clock_bias_s[:, None, None] * C if e.receiver.centring == "truth" else 0.0
    return np.abs(res.est_bias_s * C - centre) >= half_b - tol_m


def rising_crossings(xs, values, level: float) -> list[tuple]:
    """The consecutive pairs (xs[i], xs[i + 1]) between which ``values`` rises through ``level``.

    That is, values[i] < level ≤ values[i + 1] (e.g. the SNR offsets between which a receiver's 90 % error passes the
    paper's 42 m).

    Parameters
    ----------
    xs : sequence
        The x values.
    values : sequence of float
        One value per x.
    level : float
        The level.

    Returns
    -------
    list of tuple
        The pairs, in order.

    Raises
    ------
    ValueError
        When ``xs`` and ``values`` differ in length.
    """
    xs, values = list(xs), [float(v) for v in values]
    if len(xs) != len(values):
        raise ValueError(f"crossings needs one value per x, got {len(xs)} x and {len(values)} values")
    return [(xs[i], xs[i + 1]) for i in range(len(xs) - 1) if values[i] < level <= values[i + 1]]


def window_misses(blind, reference, margin_m: float = 1.0) -> dict:
    """Where a receiver whose window is centred on each trial's OTDoA fix does worse than one centred elsewhere.

    Parameters
    ----------
    blind : results.Results
        The receiver centred on each trial's OTDoA fix.
    reference : results.Results
        The same trials with the window centred elsewhere.
    margin_m : float
        How much worse a fix must be to count, metres.

    Returns
    -------
    dict
        Per (SNR, M), (S, J) integer counts of the trials whose fix is more than ``margin_m`` worse ("worse"), of those
        whose window does not contain the UE (its centre more than the search's half-width off in x or y: "outside")
        and of both ("worse_outside"), and the (T, S, J) boolean mask of the worse trials ("worse_mask").

    Raises
    ------
    ValueError
        When the two runs' errors differ in shape (not the same trials, SNRs and M).
    """
    if blind.error_m.shape != reference.error_m.shape:
        raise ValueError(f"window_misses compares the same trials, SNRs and M: got errors of shape "
                         f"{blind.error_m.shape} and {reference.error_m.shape}")
    half = blind.experiment.receiver_search().half_width_m
    worse = blind.error_m - reference.error_m > margin_m  # (T, S, J)
    outside = np.max(np.abs(blind.center_xyz[..., :2] - blind.ue_xyz[:, None, None, :2]), axis=-1) > half
    return {"worse": worse.sum(axis=0), "outside": outside.sum(axis=0), "worse_outside": (worse & outside).sum(axis=0),
            "worse_mask": worse}


def umi_families(case: str | None, n_trials: int | None = None, snr_db: float = 20.0) -> tuple[dict, dict]:
    """Every DPE and every OTDoA receiver of the NLoS chapter on one set of UMi trials, in two families (run or loaded).

    ``receiver_families`` of the naive DPE and first-path OTDoA (``nlos_study.fig10_nlos_excess`` at the UMi median,
    or Fig. 9's ``fig9_excess``), the naive DPE in the wide clock window and the NLoS-aware DPE
    (``nlos_study.nlos_dpe``), and the NLoS-aware OTDoA (``nlos_study.nlos_otdoa``).

    Parameters
    ----------
    case : str or None
        A case of ``paper.FIG10_CASES`` for Fig. 10 (the 4 nearest BSs, the DPE on the OTDoA fix), or None for Fig. 9's
        honest experiment.
    n_trials : int or None
        The first trials only (a quick look); None, each experiment's own count.
    snr_db : float
        Fig. 9's SNR, one of ``nlos_study.NLOS_DPE_FIG9_SNRS_DB``.

    Returns
    -------
    dpe, otdoa : dict
        ``receiver_families``' families: errors (T,) m for Fig. 10, (T, J) m, a column per M, for Fig. 9.

    Raises
    ------
    ValueError
        ``case`` or ``snr_db`` not one of the above; or first-path OTDoA fixes that differ between the experiments
        (not the same trials).
    """
    aware, aware_ot = nlos_study.nlos_dpe(), nlos_study.nlos_otdoa()
    if case is None:
        if snr_db not in nlos_study.NLOS_DPE_FIG9_SNRS_DB:
            raise ValueError(f"snr_db must be one of {nlos_study.NLOS_DPE_FIG9_SNRS_DB}, got {snr_db!r}")
        exps = {"naive": aware_ot["fig9"], "wide": aware["fig9-naive"], "aware": aware["fig9"], "ot": aware_ot["fig9"]}
    elif case in paper.FIG10_CASES:
        exps = {"naive": nlos_study.fig10_nlos_excess(nlos_study.UMI.median_s)[(case, "otdoa")],
                "wide": nlos_study.fig10_clock_nlos()[case], "aware": aware[f"fig10-{case}"],
                "ot": aware_ot[f"fig10-{case}"]}
    else:
        raise ValueError(f"case must be one of {paper.FIG10_CASES} or None (Fig. 9), got {case!r}")
    return receiver_families({k: e.replace(n_trials=n_trials) if n_trials else e for k, e in exps.items()},
                             snr_db if case is None else None)


def receiver_families(exps: dict, snr_db: float | None = None) -> tuple[dict, dict]:
    """The naive and NLoS-aware receivers of four experiments on the same trials, as a DPE and an OTDoA family.

    DPE: "naive DPE" (the honest receiver, its clock window the clock model's), "naive DPE, wide clock window"
    ("clock_nlos"), "NLoS-aware DPE" (eq. (D1)).  OTDoA: "first-path OTDoA" (the paper's baseline),
    "strongest-peak OTDoA" (the other detector, same signals), "NLoS-aware OTDoA" (``otdoa_nlos``), and the ToA fits
    of eq. (T1) with the naive DPE's clock window, "first-path ToA fit" and "strongest-peak ToA fit"
    (``toa_fit_errors``): the same knowledge of the UE clock as the naive DPE.  The first-path OTDoA fixes, in every
    experiment, are checked to be the same.

    Parameters
    ----------
    exps : dict
        {"naive": the honest DPE's experiment, "ot": its otdoa_nlos twin, and optionally "wide": its clock_window
        "clock_nlos" twin, "aware": the dpe_nlos twin}, one seed; run or loaded.
    snr_db : float or None
        None: one SNR and one M (Fig. 10's shape); else the column of that SNR in each experiment, every M.

    Returns
    -------
    dpe, otdoa : dict
        {receiver: errors (T,) m} with snr_db None, else {receiver: errors (T, J) m, a column per M}.

    Raises
    ------
    ValueError
        First-path OTDoA fixes that differ between the experiments (not the same trials).
    """
    res = {k: engine.run(e, progress=False) for k, e in exps.items()}
    snr = {k: 0 if snr_db is None else list(e.to_dict()["snrs_db"]).index(snr_db) for k, e in exps.items()}
    cols = lambda a, k: a[:, snr[k], 0] if snr_db is None else a[:, snr[k]]  # noqa: E731
    first_path = {k: cols(r.otdoa_error_m[:, :, 0], k) for k, r in res.items()}
    for k, v in first_path.items():
        if not np.allclose(v, first_path["naive"], rtol=0, atol=OTDOA_POSITION_ATOL_M):
            raise ValueError(f"the first-path OTDoA fixes of {exps[k].run.name} and {exps['naive'].run.name} differ: "
                             "not the same trials")
    names = {"naive": "naive DPE", "wide": "naive DPE, wide clock window", "aware": "NLoS-aware DPE"}
    dpe = {name: cols(res[k].error_m, k) for k, name in names.items() if k in res}
    otdoa = {"first-path OTDoA": first_path["naive"],
             "strongest-peak OTDoA": cols(res["naive"].otdoa_error_m[:, :, OTDOA_DETECTORS.index("peak")], "naive"),
             "NLoS-aware OTDoA": cols(res["ot"].otdoa_nlos_error_m, "ot")}
    fits = toa_fit_errors(res["naive"], snr["naive"])
    return dpe, otdoa | {k: v[:, 0] if snr_db is None else v for k, v in fits.items()}


def toa_fit_errors(res: results.Results, s: int = 0) -> dict:
    """Eq. (T1)'s fixes (``toa_fit``) from a run's OTDoA ToAs, with the clock knowledge of the run's DPE.

    Each detector's fit starts at its own OTDoA fix (the centroid of the M BSs where that failed) and searches the
    DPE's windows around it (``Experiment.receiver_search``): ± half_width_m in x and y, and the DPE's clock window
    (none with clock_window "free").

    Parameters
    ----------
    res : results.Results
        A run with ``otdoa``, centred on a prior or the OTDoA fix.
    s : int
        The SNR index.

    Returns
    -------
    dict
        {"first-path ToA fit": errors (T, J), "strongest-peak ToA fit": errors (T, J)}, metres, a column per M.
    """
    e = res.experiment
    dep = e.load_deployment()
    half, half_w = toa_fit.dpe_windows(e)
    out = {}
    for k, det in enumerate(OTDOA_DETECTORS):
        cols = []
        for j, m in enumerate(e.receiver.m_values):
            bs = dep.bs_xyz[res.bs_index[:, :m]]
            start = res.otdoa_xyz[:, s, k, j, :2]
            start = np.where(np.isfinite(start), start, bs[..., :2].mean(axis=1))
            f = toa_fit.fit(bs, res.otdoa_toa_s[:, s, k, :m], res.ue_xyz[:, 2], start, half, half_w)
            cols.append(np.linalg.norm(f.xy - res.ue_xyz[:, :2], axis=-1))
        out[f"{det.replace('_', '-').replace('peak', 'strongest-peak')} ToA fit"] = np.stack(cols, axis=1)
    return out
