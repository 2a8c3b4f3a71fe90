"""Benchmark of the Monte Carlo engine (a script, not a test): prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_engine.py [--trials 300] [--full] [--out benchmarks/bench_engine.json]

1. The correlogram work per BS and SNR against one 4096-point FFT measured in the same run, two ways: one FFT per
   call (what a single transform costs with its dispatch) and the per-row time of 24 FFTs in one call (the
   throughput the correlograms compete with).  Target: ≤ 3 FFT-equivalents.  Measured on the engine's path, one
   trial of Fig. 9 (24 BSs, 7 SNRs): the three parts of the correlograms computed once for the trial and mixed per
   SNR (``receiver.grid_windows`` in the grid search's window; ``receiver.spline_correlograms`` for the
   certified search), divided by 24 × 7; and, for reference, one whole correlogram from one LS spectrum
   (``correlogram.energy_grid``, ``correlogram.spline_coefficients``).
2. Precision: complex64 against complex128 correlograms on the same signals — the time of each and the ToA error
   that complex64 adds to the OTDoA detector's peak (which reads the same correlogram).
3. The profile of one (trial, SNR) of Fig. 9's truth-centred experiment (24 links, M = 6, 12, 18, 24): draws and
   noise, correlograms, searches.
4. Fig. 9's truth-centred experiment from an empty cache, in a fresh process with an empty JAX compilation cache:
   the first chunk (compile + 100 trials) and ``--trials`` in all are timed; the 5000-trial time is extrapolated
   from them (or measured with ``--full``).  Target: ≤ 120 s.
5. Fig. 9's honest receiver (the certified search, the book's costliest runs): time per trial (7 SNRs × 4 M)
   after the compile, with the engine's batches on one thread and on ``engine.default_workers()`` threads,
   each in a fresh process with an empty result cache (``--honest-trials`` trials).
6. The OTDoA fix (Fig. 10: the 4 nearest BSs of a random UE, noisy ToAs, no polish): per fix with cvxpy's own
   ``Problem.solve`` (Parameters set, the reduction chain applies them) and with ``otdoa.Solver.solve`` (the data
   map read from cvxpy once, then Clarabel through cvxpy's solving chain), on the same problems.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import jax
import jax.numpy as jnp
import numpy as np

from benchutil import median_time, write

from dpe5g.phy import deployment
from dpe5g.receivers import correlogram, grid_search, otdoa, receiver
from dpe5g.simulation import draw, engine, trial_draw, trials
from dpe5g.studies import paper
from dpe5g.phy.nr import C, PAPER

HERE = os.path.dirname(os.path.abspath(__file__))


RUN_FIG9 = """
import json, sys, time
from dpe5g import engine
from dpe5g.studies import paper
n, cache = int(sys.argv[1]), sys.argv[2]
t0 = time.perf_counter()
engine.run(paper.fig9_truth(100), cache=cache, progress=False)
t1 = time.perf_counter()
engine.run(paper.fig9_truth(n), cache=cache, progress=False)
print(json.dumps({"first_chunk_s": t1 - t0, "total_s": time.perf_counter() - t0}))
"""


RUN_HONEST = """
import json, sys, time
from dpe5g import engine
from dpe5g.studies import paper
n, cache, workers = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
engine.run(paper.fig9_honest(1), cache=cache, progress=False, workers=workers)  # compile
t0 = time.perf_counter()
engine.run(paper.fig9_honest(1 + n), cache=cache, progress=False, workers=workers)
print(json.dumps({"per_trial_s": (time.perf_counter() - t0) / n}))
"""


def fig9_honest_per_trial(n_trials: int, workers: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "DPE5G_CACHE": os.path.join(tmp, "mc")}
        r = subprocess.run([sys.executable, "-c", RUN_HONEST, str(n_trials), os.path.join(tmp, "mc"), str(workers)],
                           env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])["per_trial_s"]


def fig9_from_empty_cache(n_trials: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "DPE5G_JAX_CACHE": os.path.join(tmp, "jax"), "DPE5G_CACHE": os.path.join(tmp, "mc")}
        r = subprocess.run([sys.executable, "-c", RUN_FIG9, str(n_trials), os.path.join(tmp, "mc")], env=env,
                           capture_output=True, text=True, check=True)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    per_trial = (out["total_s"] - out["first_chunk_s"]) / (n_trials - 100)
    out["per_trial_s"] = per_trial
    out["trials"] = n_trials
    out["full_5000_s"] = out["first_chunk_s"] + per_trial * (paper.URBAN_TRIALS - 100)
    out["full_measured"] = n_trials == paper.URBAN_TRIALS
    return out


def otdoa_per_fix(n: int = 200) -> tuple[float, float]:
    """Seconds per OTDoA fix (M = 4, no polish) on n problems: (cvxpy's ``Problem.solve``, ``Solver.solve``)."""
    import cvxpy as cp

    dep = deployment.tst()
    rng = np.random.default_rng(0)
    cases = []
    for _ in range(n):
        ue = np.array([*rng.uniform(0, dep.region[2], 2), dep.ue_height_m])
        bs = dep.bs_xyz[dep.nearest(ue[:2], 4)]
        cases.append((bs, np.linalg.norm(ue - bs, axis=1) / C + rng.normal(0, 3e-9, 4), float(ue[2])))
    solver = otdoa.Solver(4)

    def via_problem_solve():
        for bs, t, z in cases:
            solver.set_parameters(bs, t, z)
            solver.problem.solve(solver=cp.CLARABEL, warm_start=False)

    def via_solver():
        for bs, t, z in cases:
            solver.solve(bs, t, z, polish=False)

    return median_time(via_problem_solve, 3) / n, median_time(via_solver, 3) / n


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=300, help="Fig. 9 trials to time (> 100; default 300)")
    ap.add_argument("--full", action="store_true", help="time all 5000 trials of Fig. 9 instead of extrapolating")
    ap.add_argument("--honest-trials", type=int, default=40,
                    help="Fig. 9 honest-receiver trials to time per thread count (default 40)")
    ap.add_argument("--out", default=os.path.join(HERE, "bench_engine.json"))
    args = ap.parse_args(argv)
    n_fig9 = paper.URBAN_TRIALS if args.full else args.trials
    if n_fig9 <= 100:
        ap.error("--trials must exceed 100 (the first chunk is timed separately)")

    # signals of one Fig. 9 trial at 20 dB: 24 links, engine's own draws
    e = paper.fig9_truth(1)
    ex = trials.example(e, 0, list(e.links.snrs_db).index(20.0))
    g = correlogram.ls_spectrum(jnp.fft.fft(jnp.asarray(ex.y), axis=-1, norm="ortho"), jnp.asarray(ex.prs))
    m = g.shape[0]
    cfg, honest = e.receiver_search(), paper.fig9_honest(1).receiver_search()
    window = jnp.asarray(correlogram.window_spectrum(honest.n_taps, PAPER.n_fft))

    # 1. FFT floor and correlogram work per BS
    fft = jax.jit(lambda x: jnp.fft.ifft(x, axis=-1))
    t_fft_call = median_time(lambda: fft(g[0]), 300)
    t_fft_row = median_time(lambda: fft(g), 100) / m
    grid = jax.jit(lambda x: correlogram.energy_grid(x, cfg.n_taps, cfg.upsample))  # complex128 in, as g is
    spline = jax.jit(lambda x: correlogram.spline_coefficients(x, window, honest.spline_upsample))
    t_grid = median_time(lambda: grid(g), 50) / m
    t_spline = median_time(lambda: spline(g), 50) / m

    # the engine's path: one trial's parts, mixed for its 7 SNRs (the grid's in the search's window)
    e_d = draw.draw_fn(e, e.load_deployment())(trial_draw.trial_key(e.run.seed, 0), 0)
    n_snr = e.n_snr

    @jax.jit
    def grid_engine(d):  # the draws, a pytree (Fig. 9: every link at the SNR, per_link_power a static False)
        parts, _ = receiver.grid_windows(d, cfg)
        centre = jnp.concatenate([d.ue_xyz, d.clock_bias_s[None] * C])
        p = parts(grid_search.grid_window(d.bs_xyz, centre, cfg))  # once a trial
        a, b = receiver.noise_scales(d)
        return jnp.stack([receiver.mix_parts(p, a[s], b[s]) for s in range(n_snr)])  # as ``windows`` mixes

    @jax.jit
    def spline_engine(d):
        f = receiver.spline_correlograms(d, honest, window)
        return jnp.stack([f(s) for s in range(n_snr)])

    assert not e_d.per_link_power
    t_grid_engine = median_time(lambda: grid_engine(e_d), 20) / (m * n_snr)
    t_spline_engine = median_time(lambda: spline_engine(e_d), 10) / (m * n_snr)

    # 2. complex64 against complex128, same signals: time, and the ToA error complex64 adds to the detector's peak
    g64 = g.astype(jnp.complex64)
    grid64 = jax.jit(lambda x: correlogram.energy_grid(x, cfg.n_taps, cfg.upsample))
    t_grid64 = median_time(lambda: grid64(g64), 50) / m
    toa = lambda dt: np.asarray(otdoa.toa_from_spectrum(g, "peak", 8, -10.0, 64, PAPER.sample_period_s, dt),
                                dtype=np.float64)
    err_mm = float(np.max(np.abs(toa(jnp.complex64) - toa(jnp.complex128)))) * 299792458.0 * 1e3
    dtype64 = str(grid64(g64).dtype)

    # 3. profile of one (trial, SNR) of the Fig. 9 truth-centred experiment, batch of 2 trials as the engine runs
    dep = e.load_deployment()
    draw_one = draw.draw_fn(e, dep)
    keys = jax.vmap(lambda t: trial_draw.trial_key(e.run.seed, t))(jnp.arange(20))
    f_draw = jax.jit(lambda k: jax.lax.map(lambda kk: (lambda d: d.y0.sum() + d.noise.sum())(draw_one(kk, 0)), k,
                                           batch_size=2))

    def corr_all(kk):  # the correlogram parts in the search's window, once per trial (``receiver.grid_windows``)
        d = draw_one(kk, 0)  # the TDL source reads the key only
        parts, _ = receiver.grid_windows(d, cfg)
        return parts(grid_search.grid_window(d.bs_xyz, jnp.concatenate([d.ue_xyz, d.clock_bias_s[None] * C]),
                                             cfg)).sum()

    f_corr = jax.jit(lambda k: jax.lax.map(corr_all, k, batch_size=2))
    fn = trials.grid_trial_fn(e, dep)
    ext = jnp.zeros((20, e.n_snr, len(e.receiver.m_values), 4))
    f_all = jax.jit(lambda k: jax.lax.map(lambda a: fn(a[0], 0, a[1]), (k, ext), batch_size=2))
    n_ts = 20 * e.n_snr
    p_draw = median_time(lambda: f_draw(keys), 3) / n_ts
    p_corr = median_time(lambda: f_corr(keys), 3) / n_ts - p_draw
    p_all = median_time(lambda: f_all(keys), 3) / n_ts
    p_search = p_all - p_draw - p_corr

    # 4. Fig. 9 from an empty cache
    f9 = fig9_from_empty_cache(n_fig9)

    # 5. the honest receiver per trial, one thread against the default
    n_workers = engine.default_workers()
    h1 = fig9_honest_per_trial(args.honest_trials, 1)
    hw = fig9_honest_per_trial(args.honest_trials, n_workers)

    # 6. the OTDoA fix
    t_ot_cvxpy, t_ot_solver = otdoa_per_fix()

    rows = [
        ("one 4096-point FFT, one call (with dispatch)", t_fft_call, "s"),
        ("grid correlogram per BS and SNR, engine (parts per trial, 7 SNRs, window)", t_grid_engine, "s"),
        ("  in FFT-equivalents, per-row FFT (target <= 3)", t_grid_engine / t_fft_row, "x"),
        ("spline correlogram per BS and SNR, engine (parts per trial, 7 SNRs)", t_spline_engine, "s"),
        ("  in FFT-equivalents, per-row FFT", t_spline_engine / t_fft_row, "x"),
        ("one 4096-point FFT, per row of 24 in one call", t_fft_row, "s"),
        ("grid correlogram per BS and SNR (L = 12, U = 4), complex128", t_grid, "s"),
        ("  in FFT-equivalents, one-call FFT (target <= 3)", t_grid / t_fft_call, "x"),
        ("  in FFT-equivalents, per-row FFT", t_grid / t_fft_row, "x"),
        ("spline correlogram per BS and SNR (certified search, U = 8)", t_spline, "s"),
        ("  in FFT-equivalents, per-row FFT", t_spline / t_fft_row, "x"),
        (f"grid correlogram per BS and SNR, complex64 ({dtype64} out; the engine's)", t_grid64, "s"),
        ("  ToA error complex64 adds (OTDoA peak, 24 links, max)", err_mm, "mm"),
        ("Fig. 9 truth: draws + noise per (trial, SNR)", p_draw, "s"),
        ("Fig. 9 truth: correlogram parts of 24 BSs per (trial, SNR)", p_corr, "s"),
        ("Fig. 9 truth: 4 grid searches per (trial, SNR)", p_search, "s"),
        ("Fig. 9 truth: all per (trial, SNR)", p_all, "s"),
        ("Fig. 9 truth from empty caches: compile + first 100 trials", f9["first_chunk_s"], "s"),
        (f"Fig. 9 truth: per trial (7 SNRs), from {n_fig9} trials", f9["per_trial_s"], "s"),
        ("Fig. 9 truth, 5000 trials " + ("(measured)" if f9["full_measured"] else "(extrapolated)")
         + " (target <= 120 s)", f9["full_5000_s"], "S"),
        ("Fig. 9 honest: per trial (7 SNRs x 4 M), one thread", h1, "s"),
        (f"Fig. 9 honest: per trial, {n_workers} threads", hw, "s"),
        ("OTDoA fix (M = 4): cvxpy's Problem.solve", t_ot_cvxpy, "s"),
        ("OTDoA fix (M = 4): otdoa.Solver.solve (data map + Clarabel)", t_ot_solver, "s"),
    ]
    print(f"{'quantity':<78} {'value':>12}")
    for name, v, unit in rows:
        s = {"s": f"{v * 1e3:.3g} ms", "S": f"{v:.0f} s", "x": f"{v:.1f}x", "mm": f"{v:.2g} mm"}[unit]
        print(f"{name:<78} {s:>12}")
    result = {
        "seconds": {"fft_4096_call": t_fft_call, "fft_4096_row": t_fft_row, "grid_correlogram_per_bs": t_grid,
                    "grid_engine_per_bs_snr": t_grid_engine, "spline_engine_per_bs_snr": t_spline_engine,
                    "spline_correlogram_per_bs": t_spline, "grid_correlogram_per_bs_c64": t_grid64,
                    "fig9_draw_per_trial_snr": p_draw, "fig9_correlograms_per_trial_snr": p_corr,
                    "fig9_searches_per_trial_snr": p_search, "fig9_all_per_trial_snr": p_all},
        "ratios": {"grid_engine_vs_fft_row": t_grid_engine / t_fft_row,
                   "spline_engine_vs_fft_row": t_spline_engine / t_fft_row,
                   "grid_correlogram_vs_fft_call": t_grid / t_fft_call,
                   "grid_correlogram_c64_vs_fft_row": t_grid64 / t_fft_row,
                   "grid_correlogram_vs_fft_row": t_grid / t_fft_row,
                   "spline_correlogram_vs_fft_row": t_spline / t_fft_row},
        "c64_toa_error_mm": err_mm,
        "fig9_empty_cache": f9,
        "fig9_honest": {"trials": args.honest_trials, "per_trial_s_one_thread": h1, "workers": n_workers,
                        "per_trial_s_workers": hw},
        "otdoa_fix_s": {"problem_solve": t_ot_cvxpy, "solver": t_ot_solver},
    }
    write(args.out, result)


if __name__ == "__main__":
    main()
