"""The data behind each of the paper's figures: one function per figure that computes, from its config and seed,
every number it plots (a JSON-able payload ``{"seed", "config": {...}, "data": {...}}``).

``figures`` registers each of them with its caption and its drawing (``plots``, ``result_plots``) and keeps the
payloads in the store; the statistics come from ``results``, the claims and readings from ``readings``.
"""

from __future__ import annotations

from dataclasses import astuple

import jax
import numpy as np

from ..phy import channel, nr, signal
from ..phy.deployment import named as named_deployment
from ..phy.nr import C, PAPER
from ..receivers import correlogram, cost, dpe, search_config
from ..simulation import engine, experiment, results, trials
from ..bounds import crb
from ..studies import intervals, paper, readings

# ---------------------------------------------------------------------------------------------------------------
# Figs. 1–5: TDL-A … TDL-E at 65 ns.

TDL_DELAY_SPREAD_S = 65e-9  # paper: "desired RMS delay spread of 65 ns", UMi street canyon, short-delay profile
TDL_SEED = 5


def tdl_payload(profile_name: str, delay_spread_s: float = TDL_DELAY_SPREAD_S, seed: int = TDL_SEED) -> dict:
    """Data of one TDL figure: the scaled profile, one draw of its taps and the sampled CIR.

    Parameters
    ----------
    profile_name : str
        The TDL profile's letter, ``"A"`` to ``"E"``.
    delay_spread_s : float
        The desired RMS delay spread, seconds.
    seed : int
        The draw uses ``jax.random.PRNGKey(seed)`` folded with the profile letter, so each figure has its own
        reproducible realisation.

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """
    prof = channel.tdl_profile(profile_name, delay_spread_s)
    key = jax.random.fold_in(jax.random.PRNGKey(seed), ord(profile_name))
    gains = np.asarray(channel.draw_gains(prof, key))
    h = np.asarray(channel.sampled_cir(gains, prof.delays_s, PAPER))
    ts = PAPER.sample_period_s
    n_show = int(np.ceil(prof.delays_s.max() / ts)) + 3
    return {
        "seed": seed,
        "config": {
            "profile": profile_name,
            "profile_name": prof.name,
            "table": prof.table,
            "delay_spread_s": delay_spread_s,
            "k_factor_db": prof.k_factor_db,
            "scs_hz": PAPER.scs_hz,
            "n_fft": PAPER.n_fft,
        },
        "data": {
            "delays_ns": prof.delays_s * 1e9,
            "powers": prof.powers,
            "pdp_db": prof.pdp_db(),
            "los": prof.los,
            "gains_re": gains.real,
            "gains_im": gains.imag,
            "ts_ns": ts * 1e9,
            "grid_ns": np.arange(n_show) * ts * 1e9,
            "grid_abs": np.abs(h[:n_show]),
            "rms_ds_ns": channel.rms_delay_spread(prof.delays_s, prof.powers) * 1e9,
        },
    }






# ---------------------------------------------------------------------------------------------------------------
# Fig. 6: the ML cost over (x, y) from 8 BSs through the paper's 3-tap NLoS channel.

FIG6_TAPS = (0.7079, 1.0, 0.8913)  # |h_1|, |h_2|, |h_3|: LoS 3 dB and third path 1 dB below the strongest
FIG6_RADIUS_M = 150.0  # the paper gives no geometry; ours: 8 BSs evenly on a circle, 10 m high
FIG6_HALF_WIDTH_M = 10.0
FIG6_STEP_M = 0.25
#: correlogram grid points per sample T_s of the surfaces of Figs. 6 and 8 (``cost_on_grid``): cubic interpolation on a
#: T_s/32 grid is within 1.2e-5 of the peak of eq. (10) evaluated per point (measured on both figures)
SURFACE_UPSAMPLE = 32


def cost_on_grid(y, prs, bs_xyz, x_m, y_m, z_m: float, clock_bias_s: float, n_taps: int) -> np.ndarray:
    """Eq. (10) over an (x, y) grid by its FFT form: each BS's term on a T_s/``SURFACE_UPSAMPLE`` grid of ToAs (one
    FFT per BS, ``correlogram.correlogram``), read at each point's ToAs by cubic interpolation
    (``cost.correlogram_lookup``).

    One FFT per BS instead of one per BS and grid point (``cost.ml_cost``): Fig. 8's 101 × 101 points and 12 BSs take
    about 1 s instead of 22 s; the two agree within 2e-5 of the peak (``tests/figures/test_figure_data.py``).

    Parameters
    ----------
    y, prs : complex (M, N)
        Received samples (eq. (5)) and pilots.
    bs_xyz : float (M, 3)
        BS positions, metres.
    x_m, y_m : float (X,), (Y,)
        The grid's axes, metres.
    z_m : float
        The UE height, metres.
    clock_bias_s : float
        δt, seconds.
    n_taps : int
        L, the window's taps.

    Returns
    -------
    float (Y, X)
        The cost at (x_m[ix], y_m[iy]) in row iy, column ix.
    """
    gx, gy = np.meshgrid(np.asarray(x_m, float), np.asarray(y_m, float))
    xyz = np.stack([gx, gy, np.full_like(gx, z_m)], axis=-1)
    corr = correlogram.correlogram(y, prs, n_taps, SURFACE_UPSAMPLE)
    return np.asarray(cost.correlogram_lookup(corr, cost.toa(xyz, bs_xyz, clock_bias_s), PAPER.sample_period_s,
                                              SURFACE_UPSAMPLE))


def cost_surface_payload(n_taps: int | None = None) -> dict:
    """Eq. (10) on an (x, y) grid around the UE (``cost_on_grid``): 8 BSs, each through the 3-tap channel, taps one
    sample apart.

    Noise-free, taps real and positive (the paper gives amplitudes only), UE height and clock bias known (the paper:
    "the estimation for altitude and clock bias is not involved").

    Parameters
    ----------
    n_taps : int or None
        The receiver window L; None: the default (``search_config.DEFAULT_TAPS``).

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """

    n_taps = search_config.DEFAULT_TAPS if n_taps is None else n_taps
    m = 8
    ang = np.arange(m) * 2 * np.pi / m
    bs = np.stack([FIG6_RADIUS_M * np.cos(ang), FIG6_RADIUS_M * np.sin(ang), np.full(m, 10.0)], axis=-1)
    ue = np.array([0.0, 0.0, 2.0])
    prs = nr.prs_matrix(range(1, m + 1))
    ts = PAPER.sample_period_s
    gains = np.tile(FIG6_TAPS, (m, 1))
    y = signal.received_noiseless(prs, gains, np.tile(np.arange(3) * ts, (m, 1)), cost.toa(ue, bs, 0.0))
    axis = np.arange(-FIG6_HALF_WIDTH_M, FIG6_HALF_WIDTH_M + 1e-9, FIG6_STEP_M)
    surface = cost_on_grid(y, prs, bs, axis, axis, ue[2], 0.0, n_taps)  # [iy, ix]
    iy, ix = np.unravel_index(np.argmax(surface), surface.shape)
    return {
        "seed": None,
        "config": {"n_bs": m, "bs_radius_m": FIG6_RADIUS_M, "bs_height_m": 10.0, "ue_xyz": ue, "taps_abs": FIG6_TAPS,
                   "tap_spacing_samples": 1, "n_taps_receiver": n_taps, "n_fft": PAPER.n_fft, "noise": "none",
                   "grid_step_m": FIG6_STEP_M, "correlogram_upsample": SURFACE_UPSAMPLE},
        "data": {"x_m": axis, "y_m": axis, "cost_norm": surface / surface.max(), "cost_max": surface.max(),
                 "peak_xy": [axis[ix], axis[iy]], "bs_xyz": bs},
    }




# ---------------------------------------------------------------------------------------------------------------
# Figs. 7–9: the urban study (Section IV-A).

EXAMPLE_TRIAL = 0  # the example UE of Figs. 7–8 and of the 3-D scene: trial 0 of the Fig. 9 experiment
EXAMPLE_SNR_DB = 20.0
EXAMPLE_M = 12
FIG8_HALF_WIDTH_M = 10.0
FIG8_STEP_M = 0.2


def _example(deployment: str | None = None):
    """The example of Figs. 7–8: trial ``EXAMPLE_TRIAL`` of Fig. 9's truth-centred experiment, on ``deployment``
    (a packaged name or a file) instead of ours where given, with its ``EXAMPLE_M`` nearest BSs (all, if fewer)."""
    e = paper.fig9_truth(n_trials=EXAMPLE_TRIAL + 1)
    if deployment is not None:
        e = e.replace(deployment=deployment, m_values=(min(EXAMPLE_M, named_deployment(deployment).n_bs),))
    return e, trials.example(e, EXAMPLE_TRIAL, list(e.links.snrs_db).index(EXAMPLE_SNR_DB))


def deployment_payload(deployment: str | None = None) -> dict:
    """Fig. 7: the deployment (region, buildings, streets, 26 BSs) and the example UE with its M nearest links.

    Parameters
    ----------
    deployment : str or None
        A deployment file (or a packaged name) to draw instead of ours (``dpe5g scene --deployment``); None: ours.

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """
    e, ex = _example(deployment)
    dep = e.load_deployment()
    m = min(EXAMPLE_M, max(e.receiver.m_values))
    return {
        "seed": paper.URBAN_SEED,
        "config": {"deployment": dep.name, "n_bs": dep.n_bs, "area_m2": dep.area_m2, "example_trial": EXAMPLE_TRIAL,
                   "m": m, "anchor_lat_lon_deg": [dep.anchor_lat_deg, dep.anchor_lon_deg]},
        "data": {"region": dep.region, "buildings": dep.buildings, "streets": [dict(s) for s in dep.streets],
                 "bs_ids": list(dep.bs_ids), "bs_xyz": dep.bs_xyz, "ue_xyz": ex.ue_xyz,
                 "link_bs_xyz": ex.bs_xyz[:m], "link_los": ex.los[:m]},
    }


def urban_correlogram_payload(deployment: str | None = None) -> dict:
    """Fig. 8: eq. (10) — the correlograms of the M nearest BSs summed — over (x, y) around the example UE
    (``cost_on_grid``), at the fix's clock bias, with the DPE fix (grid centred on the truth, the paper's set-up) and the truth.

    Parameters
    ----------
    deployment : str or None
        As for ``deployment_payload``.

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """
    e, ex = _example(deployment)
    m = min(EXAMPLE_M, max(e.receiver.m_values))
    y, prs, bs = ex.y[:m], ex.prs[:m], ex.bs_xyz[:m]
    ue, bias = ex.ue_xyz, float(ex.clock_bias_s)
    est = dpe.fix(y, prs, bs, np.concatenate([ue, [bias * C]]), e.receiver.search)
    axis = np.arange(-FIG8_HALF_WIDTH_M, FIG8_HALF_WIDTH_M + 1e-9, FIG8_STEP_M)
    surface = cost_on_grid(y, prs, bs, ue[0] + axis, ue[1] + axis, ue[2], float(est.clock_bias_s),
                           e.receiver.search.n_taps)
    return {
        "seed": paper.URBAN_SEED,
        "config": {"example_trial": EXAMPLE_TRIAL, "snr_db": EXAMPLE_SNR_DB, "m": m, "n_taps": e.receiver.search.n_taps,
                   "grid_step_m": FIG8_STEP_M, "centring": "truth", "correlogram_upsample": SURFACE_UPSAMPLE},
        "data": {"x_m": ue[0] + axis, "y_m": ue[1] + axis, "cost_norm": surface / surface.max(), "ue_xyz": ue,
                 "true_bias_s": bias, "est_xyz": est.xyz, "est_bias_s": est.clock_bias_s,
                 "error_m": float(np.linalg.norm(est.xyz[:2] - ue[:2])), "n_los": int(ex.los[:m].sum())},
    }


def experiment_config(e) -> dict:
    """The settings of an experiment's receiver that a payload records.

    Parameters
    ----------
    e : experiment.Experiment
        The experiment.

    Returns
    -------
    dict
        Its name, trials, seed, centring, prior, search method, half widths (metres) and window L.
    """
    s = e.receiver_search()
    return {"name": e.run.name, "n_trials": e.run.n_trials, "seed": e.run.seed, "centring": e.receiver.centring,
            "prior": f"{e.receiver.prior_kind} {e.receiver.prior_scale_m:g} m" if e.receiver.centring == "prior" else None,
            "search": s.method, "half_width_m": s.half_width_m, "bias_half_width_m": s.bias_half_width_m,
            "n_taps": s.n_taps}


def rmse_payload(experiments: dict, progress: bool = False) -> dict:
    """Fig. 9 from the experiments' results (run or loaded from the cache).

    One entry per receiver: RMSE, median, 90/99 % error per (SNR, M), edge-flag and certified shares; and the LoS
    share (and, for a fixed SNR, the bounds chapter's bound on the honest receiver's trials).

    Parameters
    ----------
    experiments : dict
        {receiver (``"honest"``, ``"truth"``): ``experiment.Experiment``}.
    progress : bool
        Show a progress bar where a Monte Carlo runs.

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """

    data, config = {}, {}
    for name, e in experiments.items():
        res = engine.run(e, progress=progress)
        data[name] = results.error_stats(res)
        config[name] = experiment_config(e)
    e = next(iter(experiments.values()))
    bound, bound_cfg = {}, {}
    if "honest" in experiments and experiments["honest"].links.snr_mode == "fixed":  # the bounds chapter's bound, on the same trials
        n_b = min(paper.BOUND_TRIALS, experiments["honest"].run.n_trials)
        bound, bound_cfg = {"bound_m": crb.rmse_bound_m(experiments["honest"], n_b)}, {"bound_trials": n_b}
    return {
        "seed": e.run.seed,
        "config": {"snrs_db": e.links.snrs_db, "m_values": e.receiver.m_values, "los_mode": e.scenario.los_mode,
                   "delay_spread_s": e.scenario.delay_spread_s, "k_factor_db": e.scenario.k_factor_db, "clock_sigma_s": e.scenario.clock_sigma_s,
                   "clock_bound_sigmas": e.scenario.clock_bound_sigmas, "deployment": e.scenario.deployment, "receivers": config,
                   **bound_cfg},
        "data": {**data, **bound, "los_share_all": res.los_share(),
                 "los_share_by_m": [res.los_share(m) for m in e.receiver.m_values]},
    }




# ---------------------------------------------------------------------------------------------------------------
# Fig. 10: DPE against OTDoA with the 4 nearest BSs (Section IV-B).

CDF_GRID_M = np.logspace(-2, 3, 251)  # error axis of the stored CDFs, 1 cm … 1 km


def cdf_payload(experiments: dict, progress: bool = False) -> dict:
    """Fig. 10 from the experiments' results.

    Error CDFs and 50/90/99 % points of each DPE receiver and of OTDoA with each detector (all fixes, and without the
    flagged ones), flagged shares, and the improvement 1 − p90(DPE)/p90(OTDoA) as the paper computes it (honest DPE
    against first-path OTDoA).

    Parameters
    ----------
    experiments : dict
        {(LoS case, centring): ``experiment.Experiment``}.
    progress : bool
        Show a progress bar where a Monte Carlo runs.

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """

    data, config = {}, {}
    cdf = lambda err: np.searchsorted(np.sort(err), CDF_GRID_M, side="right") / err.size
    for (case, cen), e in experiments.items():
        res = engine.run(e, progress=progress)
        d = data.setdefault(case, {})
        err = res.error_m[:, 0, 0]
        d[f"dpe_{cen}"] = {"cdf": cdf(err), "p50_p90_p99_m": results.quantiles(err),
                           "edge_share": float(np.mean(res.edge[:, 0, 0])),
                           "certified_share": float(np.mean(res.certified[:, 0, 0]))}
        if e.receiver.otdoa:
            for k, det in enumerate(experiment.OTDOA_DETECTORS):
                ot, ok = res.otdoa_error_m[:, 0, k, 0], res.otdoa_ok[:, 0, k, 0]
                d[f"otdoa_{det}"] = {"cdf": cdf(ot), "p50_p90_p99_m": results.quantiles(ot),
                                     "p50_p90_p99_unflagged_m": results.quantiles(ot[ok]),
                                     "flagged_share": float(np.mean(~ok))}
            d["los_share"] = res.los_share(4)
            d["median_link_snr_db"] = float(np.median(res.link_snr_db))
        config[f"{case}/{cen}"] = {**experiment_config(e), "los_mode": e.scenario.los_mode, "m": 4,
                                   "noise_figure_db": e.links.budget.noise_figure_db}
    for d in data.values():
        d["improvement_p90"] = 1.0 - d["dpe_otdoa"]["p50_p90_p99_m"][1] / d["otdoa_first_path"]["p50_p90_p99_m"][1]
    return {"seed": paper.FIG10_SEED, "config": {"experiments": config, "error_grid_m": CDF_GRID_M}, "data": data}




# ---------------------------------------------------------------------------------------------------------------
# the reproduction chapter: the readings of the paper against its claims about Figs. 9 and 10 (not a figure of the
# paper).

#: short names of the claims and readings for the table's axes
CLAIM_SHORT = {"fig9_6m": f"Fig. 9: ≤ {paper.PAPER_FIG9_RMSE_M['rmse_m']:g} m\n10 dB, M = 6",
               "fig9_falls": f"Fig. 9: falls\nwith SNR (< {readings.FALLS_RATIO:g})",
               "fig9_submetre": f"Fig. 9: < {paper.PAPER_FIG9_SUB_METRE_M:g} m\n40 dB, M ≥ 18",
               "fig9_more_hurts": "Fig. 9: more BSs\nhurt (> 1)",
               "fig9_saturation": f"Fig. 9: saturates\n18 → 24 (≤ {100 * readings.SATURATION_TOLERANCE:g} %)",
               "fig10_dpe_p90": f"Fig. 10: DPE\np90 ≤ {paper.PAPER_FIG10_DPE_M[0.9]:g} m",
               "fig10_dpe_p99": f"Fig. 10: DPE\np99 ≤ {paper.PAPER_FIG10_DPE_M[0.99]:g} m",
               "fig10_otdoa_p90": f"Fig. 10: OTDoA\np90 ≈ {paper.PAPER_FIG10_OTDOA_M[0.9]:g} m",
               "fig10_gain": f"Fig. 10: gain\n≈ {100 * paper.PAPER_FIG10_GAIN:.2f} %"}
READING_SHORT = {"as_read": "as this book reads it", "peak_otdoa": "… peak-ToA OTDoA", "span": "… DS = span",
                 "total_snr": "… total SNR", "span_total": "… span and total SNR",
                 "certified_window": "… certified search", "nearest_los": "… nearest two LoS",
                 "honest": "honest receiver", "reuse": f"honest, PRS reuse {paper.REUSE}",
                 "umi": "honest, UMi NLoS delay"}


def readings_payload(progress: bool = False, trials: int | None = None) -> dict:
    """Each reading of ``readings.READINGS`` tested on each claim of ``readings.CLAIMS``.

    Per claim its value, 95 % bootstrap interval and verdict (``readings.claim_intervals``,
    ``readings.claim_verdicts``), from its experiments' results (run or loaded from the cache), with the share (a
    fraction, 0 to 1) of its DPE fixes on the search window's edge: in Fig. 9 over every (SNR, M) cell at the
    readings' SNRs, in Fig. 10 over its trials.

    Parameters
    ----------
    progress : bool
        Show a progress bar where a Monte Carlo runs.
    trials : int or None
        Trials per experiment instead of the readings' own (``readings.experiments``).

    Returns
    -------
    dict
        The payload (``"seed"``, ``"config"``, ``"data"``).
    """

    data = {}
    for name, (label, changes) in readings.READINGS.items():
        ex = readings.experiments(name, trials)
        r9 = engine.run(ex["fig9"], progress=progress)
        e9 = ex["fig9"]
        si = [list(e9.links.snrs_db).index(s) for s in paper.READING_SNRS_DB]
        r10 = engine.run(ex["fig10_dpe"], progress=progress)
        o10 = engine.run(ex["fig10_otdoa"], progress=progress)
        det = experiment.OTDOA_DETECTORS.index(ex["otdoa_detector"])
        claims = readings.claim_intervals(r9.error_m[:, si], paper.READING_SNRS_DB, e9.receiver.m_values,
                                          r10.error_m[:, 0, 0], o10.otdoa_error_m[:, 0, det, 0])
        data[name] = {"label": label, "short": READING_SHORT[name], "changes": changes,
                      "n_trials": {"fig9": e9.run.n_trials, "fig10_dpe": ex["fig10_dpe"].run.n_trials,
                                   "fig10_otdoa": ex["fig10_otdoa"].run.n_trials},
                      "values": {k: iv.value for k, iv in claims.items()},
                      "intervals": {k: [iv.lo, iv.hi] for k, iv in claims.items()},
                      "verdicts": readings.claim_verdicts(claims),
                      "dpe_minus_otdoa_p90_m": list(astuple(intervals.quantile_difference(
                          r10.error_m[:, 0, 0], o10.otdoa_error_m[:, 0, det, 0]))[:3]),
                      "edge_share": {"fig9": float(np.mean(r9.edge[:, si])),
                                     "fig10_dpe": float(np.mean(r10.edge[:, 0, 0]))}}
    return {"seed": {"fig9": paper.URBAN_SEED, "fig10": paper.FIG10_SEED},
            "config": {"snrs_db": paper.READING_SNRS_DB, "claim_order": list(readings.CLAIMS),
                       "reading_order": list(readings.READINGS), "claims": {k: {"claim": c, "paper": v,
                                                                        "short": CLAIM_SHORT[k],
                                                                        "range": [None if abs(x) == np.inf else x for x in r]}
                                                                    for k, (c, v, r) in readings.CLAIMS.items()}},
            "data": data}
