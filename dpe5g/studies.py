"""Small Monte Carlo studies behind the choices of Chapter 3 (receiver window L, grid centring).

Each trial draws its UE position, TDL-C taps, clock bias and noise from ``jax.random.fold_in(PRNGKey(seed), trial)``,
so a trial's data do not depend on how many trials run or how they are batched.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from . import channel, correlogram, cost, dpe, engine, nr, results, search_config, signal
from .nr import C


@dataclass(frozen=True)
class RingScenario:
    """M BSs evenly on a circle around the origin, every link TDL-C (NLoS) at 65 ns, UE uniform in a square."""

    n_bs: int = 8
    radius_m: float = 150.0
    bs_height_m: float = 10.0
    ue_height_m: float = 2.0
    ue_half_width_m: float = 5.0
    snr_db: float = 20.0
    clock_sigma_s: float = 5e-9
    profile: str = "C"
    delay_spread_s: float = 65e-9

    def bs_xyz(self) -> np.ndarray:
        ang = np.arange(self.n_bs) * 2 * np.pi / self.n_bs + 0.3
        return np.stack([self.radius_m * np.cos(ang), self.radius_m * np.sin(ang),
                         np.full(self.n_bs, self.bs_height_m)], axis=-1)


def ring_trials(sc: RingScenario, seed: int, n_trials: int):
    """Received samples of ``n_trials`` trials: y (T, M, N), true xyz (T, 3), clock bias (T,) s, prs (M, N)."""
    prof = channel.tdl_profile(sc.profile, sc.delay_spread_s)
    prs = nr.prs_matrix(range(1, sc.n_bs + 1))
    bs = sc.bs_xyz()
    delays = jnp.broadcast_to(prof.delays_s, (sc.n_bs, prof.n_taps))

    def one(trial):
        k_ue, k_ch, k_n, k_b = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), trial), 4)
        xy = jax.random.uniform(k_ue, (2,), minval=-sc.ue_half_width_m, maxval=sc.ue_half_width_m)
        ue = jnp.concatenate([xy, jnp.array([sc.ue_height_m])])
        bias = sc.clock_sigma_s * jax.random.normal(k_b, ())
        g = jax.vmap(lambda k: channel.draw_gains(prof, k))(jax.random.split(k_ch, sc.n_bs))
        y = signal.received_noiseless(prs, g, delays, cost.toa(ue, bs, 0.0), bias)
        y = y + signal.awgn(k_n, y.shape, signal.noise_variance(sc.snr_db, prs))
        return y, ue, bias

    y, ue, bias = jax.lax.map(one, jnp.arange(n_trials), batch_size=16)
    return y, np.asarray(ue), np.asarray(bias), prs


def run_estimates(sc: RingScenario, y, prs, center_m, cfg: search_config.SearchConfig) -> dpe.Fix:
    """``dpe.fix`` of every ring trial y (T, M, N) in the window around center_m (T, 4) = [x, y, z, c δt] m."""
    t = y.shape[0]
    return dpe.fix(y, jnp.broadcast_to(prs, y.shape), np.broadcast_to(sc.bs_xyz(), (t, sc.n_bs, 3)), center_m, cfg)


def errors(est: dpe.Fix, ue: np.ndarray) -> np.ndarray:
    """Horizontal position error in metres, (T,)."""
    return np.linalg.norm(est.xyz[:, :2] - ue[:, :2], axis=1)


def window_study(sc: RingScenario, taps, seed: int, n_trials: int, cfg: search_config.SearchConfig) -> list[dict]:
    """Position error against the receiver window L, grid centred on the truth (the paper's set-up)."""
    y, ue, bias, prs = ring_trials(sc, seed, n_trials)
    center = np.concatenate([ue, bias[:, None] * C], axis=-1)
    rows = []
    for n_taps in taps:
        c = replace(cfg, n_taps=int(n_taps))
        est = run_estimates(sc, y, prs, center, c)
        rows.append({"n_taps": int(n_taps), **results.error_summary(errors(est, ue)),
                     "bias_rmse_m": float(np.sqrt(np.mean(((est.clock_bias_s - bias) * C) ** 2)))})
    return rows


#: grid step of ``coarse_prior``'s fix, metres
COARSE_PRIOR_STEP_M = 2.0


def coarse_prior(sc: RingScenario, y, prs, cfg: search_config.SearchConfig) -> np.ndarray:
    """A prior from a coarse fix: eq. (10) on a ``COARSE_PRIOR_STEP_M`` grid over the whole UE square ± 10 m, centred
    on the BSs.  Returns the fixes (T, 4) = [x, y, z, c δt] m."""
    t = y.shape[0]
    coarse = search_config.SearchConfig(n_taps=cfg.n_taps, upsample=cfg.upsample, half_width_m=sc.ue_half_width_m + 10.0,
                              bias_half_width_m=max(cfg.bias_half_width_m, 4 * sc.clock_sigma_s * C),
                              coarse_step_m=COARSE_PRIOR_STEP_M, final_step_m=COARSE_PRIOR_STEP_M, polish=False)
    center0 = np.tile([0.0, 0.0, sc.ue_height_m, 0.0], (t, 1))
    est = run_estimates(sc, y, prs, center0, coarse)
    return np.concatenate([est.xyz, est.clock_bias_s[:, None] * C], axis=-1)


# ---------------------------------------------------------------------------------------------------------------
# The plateau of eq. (10) for one link, and the receiver window L re-selected on the urban scenario.

PLATEAU_TAPS = (1, 4, 12)
PLATEAU_UPSAMPLE = 8
PLATEAU_CIR_SAMPLES = 40


def plateau_payload(seed: int = 5, delay_spread_s: float = 65e-9, k_factor_db: float = 13.3,
                    span_m: tuple[float, float] = (-40.0, 15.0)) -> dict:
    """One BS term of eq. (10), ‖S_m(τ)^H y_m‖², against the candidate ToA for a TDL-D (LoS) and a TDL-C (NLoS)
    link, noise-free, for the windows L of ``PLATEAU_TAPS``.

    Each link is one draw of its profile's tap gains (key ``fold_in(PRNGKey(seed), i)``, i = 0 TDL-D, 1 TDL-C) at
    the given RMS delay spread; its first path arrives at τ₀ = 0.  Returns a payload: offset_m (K,) the candidate
    c (τ − τ₀) in metres over ``span_m``; per profile and L the cost normalised to its maximum over the whole
    correlogram, and the realised CIR power |h[n]|² on the first ``PLATEAU_CIR_SAMPLES`` samples (normalised).
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
    """Run (or load) ``paper.urban_window_experiments`` and score every (set-up, M, L): RMSE, median, 90 % error, edge
    and certified shares, and the median certified gap (how far, relative, the window's maximum can lie above the
    fix's cost).  Adds ``rmse_rel``: the RMSE over the smallest RMSE of the same (set-up, M) column."""

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
    """The rule fixed before the study ran: the L with the smallest mean of ``rmse_rel`` over all (set-up, M)
    columns, i.e. the window that is closest to the best in every set-up at once."""
    taps = sorted({r["n_taps"] for r in rows})
    score = {n: np.mean([r["rmse_rel"] for r in rows if r["n_taps"] == n]) for n in taps}
    return min(taps, key=lambda n: score[n])


def range_offsets_m(res) -> np.ndarray:
    """c·(τ_m(fix) − τ_m(truth)) in metres for every link of a ``results.Results``: the ToA each fix assigns to a
    link (its clock bias included) minus the true one, (T, S, J, I); links beyond the J-th M are NaN.  A positive
    offset means the fix places the link's window start after its first path."""
    bs = res.experiment.load_deployment().bs_xyz[res.bs_index]  # (T, I, 3)
    true = np.linalg.norm(res.ue_xyz[:, None, :] - bs, axis=-1) + C * res.clock_bias_s[:, None]  # (T, I)
    est = (np.linalg.norm(res.est_xyz[..., None, :] - bs[:, None, None], axis=-1)
           + C * res.est_bias_s[..., None])  # (T, S, J, I)
    out = est - true[:, None, None, :]
    used = np.arange(bs.shape[1])[None, :] < np.asarray(res.experiment.receiver.m_values)[:, None]  # (J, I)
    return np.where(used[None, None], out, np.nan)
