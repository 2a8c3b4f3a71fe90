"""Small Monte Carlo studies behind the choices of Chapter 3 (receiver window L, grid centring).

Each trial draws its UE position, TDL-C taps, clock bias and noise from ``jax.random.fold_in(PRNGKey(seed), trial)``,
so a trial's data do not depend on how many trials run or how they are batched.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from . import channel, dpe, nr, signal
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
        y = signal.received_noiseless(prs, g, delays, dpe.toa(ue, bs, 0.0), bias)
        y = y + signal.awgn(k_n, y.shape, signal.noise_variance(sc.snr_db, prs))
        return y, ue, bias

    y, ue, bias = jax.lax.map(one, jnp.arange(n_trials), batch_size=16)
    return y, np.asarray(ue), np.asarray(bias), prs


def run_estimates(sc: RingScenario, y, prs, center, cfg: dpe.SearchConfig) -> dpe.Estimate:
    t = y.shape[0]
    return dpe.estimate(y, jnp.broadcast_to(prs, y.shape), np.broadcast_to(sc.bs_xyz(), (t, sc.n_bs, 3)), center, cfg)


def errors(est: dpe.Estimate, ue: np.ndarray) -> np.ndarray:
    """Horizontal position error in metres, (T,)."""
    return np.linalg.norm(est.xyz[:, :2] - ue[:, :2], axis=1)


def summary(err: np.ndarray) -> dict:
    return {"rmse_m": float(np.sqrt(np.mean(err**2))), "median_m": float(np.median(err)),
            "p90_m": float(np.quantile(err, 0.9))}


def window_study(sc: RingScenario, taps, seed: int, n_trials: int, cfg: dpe.SearchConfig) -> list[dict]:
    """Position error against the receiver window L, grid centred on the truth (the paper's set-up)."""
    y, ue, bias, prs = ring_trials(sc, seed, n_trials)
    center = np.concatenate([ue, bias[:, None]], axis=-1)
    rows = []
    for n_taps in taps:
        c = replace(cfg, n_taps=int(n_taps))
        est = run_estimates(sc, y, prs, center, c)
        rows.append({"n_taps": int(n_taps), **summary(errors(est, ue)),
                     "bias_rmse_m": float(np.sqrt(np.mean(((est.clock_bias_s - bias) * C) ** 2)))})
    return rows


def coarse_prior(sc: RingScenario, y, prs, cfg: dpe.SearchConfig) -> np.ndarray:
    """A prior from a coarse fix: eq. (8) on a 2 m grid over the whole UE square ± 10 m, centred on the BSs."""
    t = y.shape[0]
    coarse = dpe.SearchConfig(n_taps=cfg.n_taps, upsample=cfg.upsample, half_width_m=sc.ue_half_width_m + 10.0,
                              bias_half_width_m=max(cfg.bias_half_width_m, 4 * sc.clock_sigma_s * C),
                              coarse_step_m=2.0, final_step_m=2.0, polish=False)
    center0 = np.tile([0.0, 0.0, sc.ue_height_m, 0.0], (t, 1))
    est = run_estimates(sc, y, prs, center0, coarse)
    return np.concatenate([est.xyz, est.clock_bias_s[:, None]], axis=-1)
